"""Pins as material patches: convergence of the drape, membership, exact targets,
release, and patches on the adaptive mesh (design §2-§3)."""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import SceneError, load_scene, scene_from_dict
from cloth_lod_ros.sim.mesh.operations import Merge, Split
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform, uniform_vertices_within

RADIUS = 0.0625          # the built-in scenes' patch radius, m

# The built-in hanging cloth, started vertical (already hanging) and brought to
# rest fast: large implicit steps with strong isotropic drag only change the way
# there, not the equilibrium.  An exact solve (block LDLᵀ: the same factorisation
# as ``direct``, on 3 x 3 blocks, 0.3-0.4x its time on the level-8 mesh; the
# rest states agree to 1e-16 J and m).
AT_REST = {"lod.enabled": False, "cloth.origin": [0.0, 0.0, 0.0],
           "cloth.v_axis": [0.0, 0.0, 1.0], "simulation.time_step": 0.1,
           "material.air_drag": 5.0, "solver.method": "block_ldl", "solver.tolerance": 1e-10}
POINT_PINS = {"pins": [{"name": "top_left", "uv": [0.0, 1.0]},
                       {"name": "top_right", "uv": [1.0, 1.0]}]}


def drape_at_rest(level, overrides=None):
    """Potential energy (J: gravity + elastic) and centre height (m) at rest."""
    sim = ClothSim.from_scene("hang_two_corners",
                              {**AT_REST, "cloth.level": level, **(overrides or {})})
    for _ in range(20):
        sim.step()
    e = sim.energy()
    assert e["kinetic"] < 1e-12, e                      # really at rest
    potential = e["gravity"] + e["stretch"] + e["shear"] + e["bend"]
    return potential, float(sim.sample([[0.5, 0.5]])[0, 2])


def test_hanging_drape_converges_with_refinement():
    """Held over patches, the static sag converges: from level 4 to 6 to 8 the
    energy and the centre's height change less and less (measured: 0.107 then
    0.012 mJ, 0.11 then 0.014 mm).  Held by single particles it does not (each
    two levels lower it by a constant 0.7 mJ and 0.7 mm: a point load on a
    membrane).  Even levels only: odd ones add cell centres to the lattice, so a
    patch of the same radius catches a different set of particles."""
    patch = [drape_at_rest(level) for level in (4, 6, 8)]
    point = [drape_at_rest(level, POINT_PINS) for level in (4, 6, 8)]
    for k in (0, 1):                                   # energy, then height
        first, second = (abs(patch[1][k] - patch[0][k]), abs(patch[2][k] - patch[1][k]))
        assert second < 0.5 * first, (k, patch)
        coarse, fine = (abs(point[1][k] - point[0][k]), abs(point[2][k] - point[1][k]))
        assert fine > 0.8 * coarse, (k, point)          # what the patch fixes
        assert first < 0.5 * coarse                    # and far closer already


def pinned_scene(level=5, lod=False, pins=None, **extra):
    data = {
        "name": "pins",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level},
        "material": {"air_drag": 0.0},
        "pins": pins if pins is not None else [
            {"name": "a", "uv": [0.0, 1.0], "radius": RADIUS},
            {"name": "b", "uv": [0.5, 1.0], "radius": 0.1},
            {"name": "c", "uv": [1.0, 1.0]}],
        "simulation": {"time_step": 1 / 60, "duration": 1.0},
        "solver": {"method": "direct", "tolerance": 1e-10},
        "lod": {"enabled": lod, "initial_level": 0},
    }
    data.update(extra)
    return scene_from_dict(data)


@pytest.mark.parametrize("lod", [False, True])
def test_a_patch_holds_every_particle_within_its_radius(lod):
    sim = ClothSim(pinned_scene(level=6, lod=lod))
    uniform = refine_uniform(base_mesh(1.0, 1.0, 4, 4), 6)
    for pin, radius in zip(sim.pins, (RADIUS, 0.1, 0.0)):
        held = sim.rest_uv[pin.vertices]
        assert np.all(np.linalg.norm(held - pin.uv, axis=1) <= radius + 1e-12)
        # Every particle of the uniform level-6 mesh inside: on the adaptive mesh
        # too (refined over the patch when the simulation is built).
        inside = uniform.uv[np.linalg.norm(uniform.uv - pin.uv, axis=1) <= radius + 1e-12]
        assert len(held) == len(inside) == len(pin.nodes) == len(pin.offsets)
        assert sorted(map(tuple, held.round(12))) == sorted(map(tuple, inside.round(12)))
        assert pin.vertex in pin.vertices
    assert len(sim.pins[2].vertices) == 1                 # radius 0: a point pin
    assert len(sim.pins[0].vertices) == 6 and len(sim.pins[1].vertices) > 6
    assert sim.step().pinned_count == sum(len(p.vertices) for p in sim.pins)


def test_uniform_lattice_helper_matches_the_refined_mesh():
    for level in range(7):
        mesh = refine_uniform(base_mesh(1.0, 0.5, 4, 2), level)
        for centre, radius in (((0.0, 0.5), RADIUS), ((0.3, 0.2), 0.2), ((1.0, 0.0), 0.6)):
            inside = mesh.uv[np.linalg.norm(mesh.uv - centre, axis=1) <= radius + 1e-12]
            got = uniform_vertices_within(1.0, 0.5, 0.25, level, centre, radius)
            assert sorted(map(tuple, got.round(12))) == sorted(map(tuple, inside.round(12)))


@pytest.mark.parametrize("lod", [False, True])
def test_every_patch_particle_lands_exactly_on_its_moving_target(lod):
    waypoints = [[0.0, 0.0, 1.0, 1.0], [0.5, 0.2, 1.1, 1.3], [1.0, -0.1, 0.9, 1.1]]
    pins = [{"name": "hand", "uv": [0.0, 1.0], "radius": 0.1, "waypoints": waypoints},
            {"name": "still", "uv": [1.0, 1.0], "radius": RADIUS}]
    # Self-collision off: this is about the held particles.  Yanked at step 30, the
    # sheet is dragged into a knot whose layers self-collision re-solves at every step
    # (117-147 s with it, 5 s without, after the pleat fix; issue 31).
    sim = ClothSim(pinned_scene(level=5, lod=lod, pins=pins,
                                self_collision={"enabled": False}))
    hand, still = sim.pin("hand"), sim.pin("still")
    shape = {p.name: sim.positions[p.vertices] - sim.positions[p.vertex] for p in sim.pins}
    for step in range(50):
        if step == 30:
            sim.set_pin_target("still", [1.05, 1.0, 1.2])       # the whole patch follows
        stats = sim.step()
        for p in (hand, still):
            np.testing.assert_array_equal(sim.positions[p.vertices], p.held_targets(sim.time))
            np.testing.assert_array_equal(sim.positions[p.vertex], p.target(sim.time))
            # A rigid translation: each particle keeps its offset from the centre.
            np.testing.assert_allclose(sim.positions[p.vertices] - sim.positions[p.vertex],
                                       shape[p.name], atol=1e-12)
        assert stats.pinned_count == len(hand.vertices) + len(still.vertices)
    np.testing.assert_array_equal(sim.positions[still.vertex], [1.05, 1.0, 1.2])
    assert np.all(np.isfinite(sim.positions))


def test_release_lets_the_whole_patch_go():
    sim = ClothSim(pinned_scene(level=4))
    patch = sim.pin("b").vertices.copy()
    for _ in range(5):
        sim.step()
    z = sim.positions[patch, 2].copy()
    for name in ("a", "b", "c"):
        sim.release_pin(name)
    for _ in range(10):
        assert sim.step().pinned_count == 0
    assert np.all(sim.positions[patch, 2] < z - 0.05)       # every particle of it falls


def test_patch_on_the_adaptive_mesh_stays_resolved_and_held():
    """LOD on: no patch particle is merged away while the cloth swings and the
    mesh adapts around it; a particle a scripted merge removes from a patch is
    let go, and the one a split makes there again is held, without a jump."""
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=6"])
    pins = {p.name: (p.nodes.copy(), p.radius) for p in sim.pins}
    assert all(radius == RADIUS and len(nodes) == 6 for nodes, radius in pins.values())
    changes = 0
    for _ in range(60):
        stats = sim.step()
        changes += stats.refines + stats.merges
        for p in sim.pins:
            assert sim.hierarchy.vertex_active[p.nodes].all()
            assert set(p.nodes) == set(pins[p.name][0])
            np.testing.assert_array_equal(sim.positions[p.vertices], p.held_targets(sim.time))
    assert changes > 20                                     # the mesh did adapt
    pin = sim.pin("top_left")
    h = sim.hierarchy
    mergeable = set(h.split_vertices()[0].tolist())
    held_split = [int(n) for n in pin.nodes if n in mergeable]
    assert held_split, "a patch particle made by a split"
    edge = tuple(int(e) for e in h.vertex_edge[held_split[0]])
    sim.apply_mesh_operations([Merge(edge)])
    assert len(pin.nodes) == 5 and held_split[0] not in pin.nodes
    sim.apply_mesh_operations([Split(edge)])
    assert len(pin.nodes) == 6
    new = int(pin.nodes[-1])
    before = sim.positions[np.searchsorted(sim.vertex_ids, new)].copy()
    stats = sim.step()
    np.testing.assert_array_equal(sim.positions[pin.vertices], pin.held_targets(sim.time))
    np.testing.assert_allclose(sim.positions[np.searchsorted(sim.vertex_ids, new)], before,
                               atol=1e-12)                   # held where it was made
    assert stats.pinned_count == 12


def test_patch_radius_is_validated():
    with pytest.raises(SceneError, match=r"'pins\[0\]\.radius'"):
        pinned_scene(pins=[{"uv": [0.0, 1.0], "radius": -0.1}])
    with pytest.raises(SceneError, match=r"'pins\[1\]\.radius'.*overlaps.*pins\[0\]"):
        pinned_scene(pins=[{"uv": [0.0, 1.0], "radius": 0.3}, {"uv": [0.5, 1.0], "radius": 0.2}])
    assert load_scene("hang_two_corners").pins[0].radius == RADIUS
