"""Whole-step behaviour: free fall, momentum, settling, exact pins, stiff stability."""

import numpy as np
import pytest

from cloth_lod_ros.sim.scene.config import load_scene, scene_from_dict, scene_to_dict
from cloth_lod_ros.sim import ClothSim, SimulationError

G = np.array([0.0, 0.0, -9.81])


def scene(level=2, pins=(), gravity=(0, 0, -9.81), h=1 / 60, duration=1.0, **material):
    mat = dict(air_drag=0.0)
    mat.update(material)
    return scene_from_dict({
        "name": "test",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level},
        "material": mat,
        "air": {"density": 0.0},        # no air: test/sim/physics/test_air.py tests it
        "pins": [dict(p) for p in pins],
        "simulation": {"time_step": h, "duration": duration, "gravity": list(gravity)},
        "solver": {"tolerance": 1e-8, "max_iterations": 5000},
    })


def edge_lengths(sim):
    t = sim.triangles
    x = sim.positions
    return np.linalg.norm(x[t] - x[np.roll(t, 1, axis=1)], axis=2)


@pytest.mark.parametrize("integrator", ["sdirk2", "backward_euler", "baraff_witkin"])
def test_free_fall_accelerates_at_g_without_deforming(integrator):
    cfg = scene(level=3)
    sim = ClothSim(scene_from_dict({**scene_to_dict(cfg), "simulation": {
        **scene_to_dict(cfg)["simulation"], "integrator": integrator,
        "error_tolerance": 0.0}}))
    rest = edge_lengths(sim).copy()
    x0 = sim.positions.copy()
    h, steps = sim.time_step, 30
    for _ in range(steps):
        stats = sim.step()
        assert stats.converged
    np.testing.assert_allclose(sim.velocities, np.tile(steps * h * G, (len(x0), 1)),
                               atol=1e-8)
    if integrator == "sdirk2":
        # Second order: exact for a constant force, x = x_0 + g t²/2.
        expected = x0 + 0.5 * G * (steps * h) ** 2
    else:
        # Backward Euler with constant force: v_n = n h g, x_n = x_0 + h² g n(n+1)/2.
        expected = x0 + h * h * G * steps * (steps + 1) / 2
    np.testing.assert_allclose(sim.positions, expected, atol=1e-8)
    np.testing.assert_allclose(edge_lengths(sim), rest, atol=1e-9)


@pytest.mark.parametrize("method,bound", [("direct", 1e-11), ("pcg", 1e-6)])
def test_momentum_is_conserved_without_pins_gravity_or_drag(method, bound):
    """Internal forces and their Jacobians have zero column sums, so Σ m Δv equals
    the sum of the linear-solve residual: exact for LU, within tolerance for PCG."""
    cfg = scene(level=3, gravity=(0, 0, 0), stretch_damping=0.05, bend_damping=0.2)
    # Self-collision off: the crumpled start brings layers together, and the
    # self-contact handling does not conserve momentum (see the next test).
    sim = ClothSim(scene_from_dict({**scene_to_dict(cfg),
                                    "solver": {"method": method, "tolerance": 1e-10},
                                    "self_collision": {"enabled": False}}))
    rng = np.random.default_rng(0)
    sim.state.positions += rng.normal(scale=0.02, size=sim.positions.shape)
    sim.state.velocities[:] = rng.normal(scale=0.5, size=sim.positions.shape)
    p0 = (sim.masses[:, None] * sim.velocities).sum(axis=0)
    com0 = (sim.masses[:, None] * sim.positions).sum(axis=0) / sim.masses.sum()
    ke0 = sim.energy()["kinetic"]
    for _ in range(40):
        sim.step()
    p1 = (sim.masses[:, None] * sim.velocities).sum(axis=0)
    scale = sim.masses.sum() * 0.5
    np.testing.assert_allclose(p1, p0, rtol=0, atol=bound * scale)
    com1 = (sim.masses[:, None] * sim.positions).sum(axis=0) / sim.masses.sum()
    np.testing.assert_allclose(com1, com0 + sim.time * p0 / sim.masses.sum(), rtol=0,
                               atol=bound)
    # Internal dissipation only: the relative motion loses energy.
    assert sim.energy()["kinetic"] < ke0


@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "self-contact is not momentum-conserving: the post-solve removal of normal "
    "velocity and the stopped zone act on one side of a pair (measured: "
    "|delta p| 0.009 kg m/s of |p0| 0.014 in 40 steps); issue 31, open"))
def test_self_contact_conserves_momentum():
    """Contact between two layers of one cloth is internal: equal and opposite
    impulses, so the total momentum of a free cloth stays what it was."""
    cfg = scene(level=3, gravity=(0, 0, 0), stretch_damping=0.05, bend_damping=0.2)
    sim = ClothSim(scene_from_dict({**scene_to_dict(cfg),
                                    "solver": {"method": "direct", "tolerance": 1e-10},
                                    "self_collision": {"enabled": True}}))
    rng = np.random.default_rng(0)
    sim.state.positions += rng.normal(scale=0.02, size=sim.positions.shape)
    sim.state.velocities[:] = rng.normal(scale=0.5, size=sim.positions.shape)
    p0 = (sim.masses[:, None] * sim.velocities).sum(axis=0)
    for _ in range(40):
        sim.step()
    p1 = (sim.masses[:, None] * sim.velocities).sum(axis=0)
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-9 * sim.masses.sum())


def test_hung_cloth_settles_with_pins_exactly_on_target():
    # Air drag 2/s: the swing's energy decays as exp(−2 t) (the second-order
    # integrator adds almost no damping of its own).
    cfg = load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=2",
                                          "simulation.duration=8.0", "material.air_drag=2.0"])
    sim = ClothSim(cfg)
    targets = {p.name: p.anchor.copy() for p in sim.pins}
    kinetic = []
    for _ in range(int(8.0 / sim.time_step)):
        stats = sim.step()
        assert stats.converged
        kinetic.append(stats.kinetic_energy)
        for p in sim.pins:
            np.testing.assert_array_equal(sim.positions[p.vertex], targets[p.name])
    kinetic = np.array(kinetic)
    assert kinetic.max() > 0.1                  # it really swung
    assert kinetic[-30:].max() < 1e-3 * kinetic.max()
    # Hangs below its pins, stretched only a little.
    assert sim.positions[:, 2].min() < 0.2
    assert sim.stats[-1].max_strain < 0.05


def test_moving_pin_follows_waypoints_exactly():
    waypoints = [[0.0, 0.0, 1.0, 1.0], [0.5, 0.3, 1.2, 1.4], [1.0, -0.2, 1.0, 1.1]]
    sim = ClothSim(scene(level=2, pins=[{"name": "hand", "uv": [0.0, 1.0],
                                         "waypoints": waypoints},
                                        {"name": "fixed", "uv": [1.0, 1.0]}]))
    hand = sim.pin("hand")
    for _ in range(60):
        sim.step()
        expected = hand.target(sim.time)
        np.testing.assert_array_equal(sim.positions[hand.vertex], expected)
        # The prescribed velocity is the one that lands on the target.
    np.testing.assert_allclose(sim.positions[hand.vertex], [-0.2, 1.0, 1.1], atol=1e-12)
    assert np.all(np.isfinite(sim.positions))


def test_set_pin_target_and_release():
    sim = ClothSim(scene(level=2, pins=[{"name": "a", "uv": [0.0, 1.0]},
                                        {"name": "b", "uv": [1.0, 1.0]}]))
    sim.set_pin_target("a", [0.1, 1.0, 1.2])
    sim.step()
    np.testing.assert_array_equal(sim.positions[sim.pin("a").vertex], [0.1, 1.0, 1.2])
    with pytest.raises(ValueError):
        sim.set_pin_target("a", [np.nan, 0, 0])
    with pytest.raises(KeyError):
        sim.set_pin_target("nobody", [0, 0, 0])
    sim.release_pin("a")
    sim.release_pin("b")
    z0 = sim.positions[:, 2].mean()
    for _ in range(20):
        stats = sim.step()
        assert stats.pinned_count == 0
    assert sim.positions[:, 2].mean() < z0 - 0.1       # released: it falls


def test_release_time_from_the_scene():
    sim = ClothSim(scene(level=2, pins=[{"uv": [0.0, 1.0], "release_time": 0.1},
                                        {"uv": [1.0, 1.0]}]))
    counts = [sim.step().pinned_count for _ in range(12)]
    assert counts[:5] == [2] * 5 and counts[-1] == 1


@pytest.mark.parametrize("level", [2, 4])
def test_stiff_material_at_large_step_stays_finite_and_bounded(level):
    """Stretch stiffness x100 at h = 1/30 s stays finite and bounded, then settles.

    BW's single linearised step cannot see the second-order stretch of
    triangles that rotate fast (those next to the pins in the first steps), so
    a transient with a few per cent strain and a few times the initial energy
    appears with it (measured: peak 2.4x at level 2, 4.8x at level 4); with
    any integrator it must stay bounded and be dissipated (air drag 2/s: the
    swing's energy decays as exp(−2 t)).
    """
    cfg = load_scene("hang_two_corners", ["lod.enabled=false", f"cloth.level={level}",
                                          "simulation.time_step=0.0333333",
                                          "material.stretch_stiffness=200000.0",
                                          "material.shear_stiffness=20000.0",
                                          "material.air_drag=2.0"])
    sim = ClothSim(cfg)
    initial = sum(sim.energy().values())
    for _ in range(120):
        stats = sim.step()
        assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))
        assert stats.converged
    energies = np.array([s.total_energy for s in sim.stats])
    assert max(s.max_strain for s in sim.stats) < 0.1
    assert energies.max() < 6 * initial
    assert energies[-1] < initial                  # dissipated overall
    # A stiff cloth at rest barely stretches (the most, 0.2 %, where the rigid
    # pin patch meets the free edge).
    assert sim.stats[-1].max_strain < 3e-3
    assert sim.stats[-1].kinetic_energy < 5e-3 * max(s.kinetic_energy for s in sim.stats)


def test_energy_never_grows_for_the_default_material():
    """With fixed pins nothing does work on the cloth: implicit Euler dissipates."""
    sim = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=3"]))
    energies = [sum(sim.energy().values())] + [sim.step().total_energy for _ in range(120)]
    assert np.all(np.diff(energies) <= 1e-9 * abs(energies[0]))


def test_non_finite_forces_are_reported_not_frozen():
    sim = ClothSim(scene(level=2, gravity=(0, 0, -1e308)))
    with np.errstate(all="ignore"), pytest.raises(SimulationError):
        sim.step()


def test_sample_matches_particles_and_interpolates():
    sim = ClothSim(scene(level=2))
    for _ in range(3):
        sim.step()
    np.testing.assert_allclose(sim.sample(sim.rest_uv), sim.positions, atol=1e-12)
    mid = sim.sample([[0.125, 0.0]])          # midpoint of a boundary edge at level 2
    a = np.flatnonzero(np.all(np.isclose(sim.rest_uv, [0.0, 0.0]), axis=1))[0]
    b = np.flatnonzero(np.all(np.isclose(sim.rest_uv, [0.25, 0.0]), axis=1))[0]
    np.testing.assert_allclose(mid[0], 0.5 * (sim.positions[a] + sim.positions[b]), atol=1e-12)


def test_non_finite_state_is_refused_and_state_kept():
    sim = ClothSim(scene(level=2))
    sim.step()
    sim.state.velocities[3] = np.nan
    before = sim.state.copy()
    with pytest.raises(SimulationError):
        sim.step()
    assert sim.time == before.time
    assert len(sim.stats) == 1


def test_direct_and_pcg_agree():
    cfg = load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=3", "solver.tolerance=1e-8"])
    a = ClothSim(cfg)
    b = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=3", "solver.method=direct"]))
    for _ in range(30):
        a.step()
        b.step()
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-7)


@pytest.mark.parametrize("overrides, target", [
    (["simulation.gravity=[0,0,-1e12]"], None),           # singular system
    ([], [1e30, 0.0, 0.0]),                                 # a pin target 1e30 m away
    (["cloth.level=6", "material.stretch_damping=1e12"], None),
], ids=["gravity_1e12", "target_1e30", "damping_1e12"])
def test_absurd_inputs_fail_as_a_simulation_error_with_the_state_kept(overrides, target):
    """Whatever the numerics do with absurd inputs (LinAlgError, overflow), a step
    either succeeds with a finite state or raises SimulationError and keeps the
    previous state: callers (the node) handle one exception type."""
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=3", *overrides])
    if target is not None:
        sim.set_pin_target("top_left", target)
    grid = np.array([[u, v] for u in np.linspace(0, 1, 5) for v in np.linspace(0, 1, 5)])
    for _ in range(5):
        time, version, before = sim.time, sim.hierarchy.version, sim.sample(grid)
        try:
            sim.step()
        except SimulationError as exc:
            assert "refused" in str(exc)
            # The same cloth; the LOD phase before the solve may have split it
            # (the face rule puts new particles on it), so compare by material point.
            if sim.hierarchy.version == version:
                np.testing.assert_array_equal(sim.sample(grid), before)
            np.testing.assert_allclose(sim.sample(grid), before, rtol=1e-9)
            assert sim.time == time
            break
        assert np.all(np.isfinite(sim.positions))


@pytest.mark.parametrize("method", ["pcg", "multigrid", "direct", "superlu", "auto"])
def test_no_backend_lets_another_exception_out_of_a_step(method):
    """Gravity of 1e12 m/s^2 on an adaptive cloth: with the LDL^T backend the
    projected system stops being quasi-definite at the third step (QDLDL raises
    RuntimeError); every backend's breakdown must surface as SimulationError."""
    sim = ClothSim.from_scene("hang_two_corners", [
        "cloth.level=5", "lod.initial_level=2", "simulation.gravity=[0,0,-1e12]",
        f"solver.method={method}"])
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 9)), -1).reshape(-1, 2)
    with np.errstate(all="ignore"):
        for _ in range(15):
            time, surface = sim.time, sim.sample(grid)
            try:
                sim.step()
            except SimulationError:
                # The cloth is where it was (the criterion may have split
                # triangles first: new particles lie on the old surface).
                assert sim.time == time
                np.testing.assert_allclose(sim.sample(grid), surface,
                                           atol=1e-9 * np.abs(surface).max())
                return
    assert np.all(np.isfinite(sim.positions))


def test_scripted_mesh_operations_are_refused_whole():
    """An invalid operation in a list undoes the ones before it: the mesh, the
    compact arrays and the state are as before the call."""
    from cloth_lod_ros.sim.mesh.operations import Merge
    from cloth_lod_ros.sim.mesh.topology import MeshError
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=4"])
    h = sim.hierarchy
    made = sim.refine(int(h.active_triangles()[0]))
    assert made
    active, x = h.active_triangles().copy(), sim.positions.copy()
    undo = [op.inverse() for op in reversed(made)]
    with pytest.raises(MeshError):
        sim.apply_mesh_operations(undo + [Merge((0, h.vertex_end - 1))])   # never split
    np.testing.assert_array_equal(h.active_triangles(), active)
    np.testing.assert_array_equal(sim.positions, x)
    assert sim.mesh.triangle_count == len(active)
    h.check()
    sim.step()
