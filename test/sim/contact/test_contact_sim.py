"""Contact, friction and grasps in whole simulation steps."""

import logging
from dataclasses import replace

import numpy as np
import pytest

from cloth_lod_ros.sim.integrate import step_control as stepping_module
from cloth_lod_ros.sim.scene.config import load_scene, scene_from_dict
from cloth_lod_ros.sim.contact.obstacles import make_obstacle
from cloth_lod_ros.sim import ClothSim

THICKNESS = 0.004


def scene(level=3, obstacles=(), grasps=(), origin=(0, 0, 1.0), u_axis=(1, 0, 0),
          v_axis=(0, 1, 0), lod=None, duration=1.0, gravity=(0, 0, -9.81), **material):
    mat = {"air_drag": 0.0}
    mat.update(material)
    return scene_from_dict({
        "name": "contact_test",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level,
                  "origin": list(origin), "u_axis": list(u_axis), "v_axis": list(v_axis)},
        "material": mat,
        "air": {"density": 0.0},        # no air: test/sim/physics/test_air.py tests it
        "obstacles": [dict(o) for o in obstacles],
        "contact": {"thickness": THICKNESS},
        "grasps": [dict(g) for g in grasps],
        "simulation": {"time_step": 1 / 60, "duration": duration, "gravity": list(gravity)},
        "solver": {"tolerance": 1e-6},
        "lod": lod or {"enabled": False},
    })


def min_distance(sim):
    return min(make_obstacle(o).distance(sim.positions)[0].min() for o in sim.scene.obstacles)


# -- contact ---------------------------------------------------------------------

def test_cloth_at_rest_on_a_plane_stays_at_rest():
    floor = {"type": "plane", "centre": [0, 0, 0], "normal": [0, 0, 1], "friction": 0.5}
    sim = ClothSim(scene(obstacles=[floor], origin=(0, 0, THICKNESS)))
    start = sim.positions.copy()
    for _ in range(120):
        s = sim.step()
        assert s.contact_count == sim.mesh.vertex_count
    assert np.abs(sim.positions - start).max() < 1e-6          # no creep
    assert np.abs(sim.velocities).max() < 1e-6                 # no jitter
    assert sim.stats[-1].max_strain < 1e-6


@pytest.mark.parametrize("angle_deg,slides", [(15.0, False), (40.0, True)])
def test_friction_holds_below_the_critical_angle_and_slides_above(angle_deg, slides):
    """μ = 0.5: the critical angle is atan(0.5) = 26.6°."""
    a = np.radians(angle_deg)
    normal = [0.0, -np.sin(a), np.cos(a)]
    slope = {"type": "plane", "centre": [0, 0, 0], "normal": normal, "friction": 0.5}
    sim = ClothSim(scene(obstacles=[slope], origin=tuple(THICKNESS * np.array(normal)),
                         v_axis=(0, np.cos(a), np.sin(a)), level=2))
    start = sim.positions.copy()
    sim.run(1.0)
    moved = np.linalg.norm(sim.positions - start, axis=1).mean()
    if slides:
        # Sliding with a = g (sin a − μ cos a): 1.27 m in 1 s without other losses.
        expected = 0.5 * 9.81 * (np.sin(a) - 0.5 * np.cos(a)) * 1.0**2
        assert 0.8 * expected < moved < 1.05 * expected
    else:
        assert moved < 1e-3
    assert min_distance(sim) > 0.5 * THICKNESS


@pytest.mark.parametrize("name,overrides", [
    ("drop_on_sphere", ["cloth.level=4", "simulation.duration=1.2"]),
    ("drop_on_disc", ["cloth.level=4", "lod.initial_level=4", "simulation.duration=1.2"]),
    ("table_drape", ["cloth.level=4", "simulation.duration=1.2"]),
])
def test_no_particle_enters_an_obstacle(name, overrides):
    sim = ClothSim(load_scene(name, overrides))
    worst = np.inf
    for _ in range(int(round(1.2 / sim.time_step))):
        sim.step()
        worst = min(worst, min_distance(sim))
        assert np.all(np.isfinite(sim.positions))
    # Particles stay outside the solid, at most a quarter of the contact
    # thickness inside the offset surface they are held on.
    assert worst > 0.75 * sim.scene.contact.thickness
    # No lasting over-stretch.  (table_drape's cloth is still landing on the
    # floor at 0.9 s: with the second-order default, a triangle whose corners
    # stop at different times stretches by ~5 % for a frame, within the
    # stretch-growth control's 0.1 per step; the paper's damped step, 2 %.)
    assert max(s.max_strain for s in sim.stats[-20:]) < 0.1
    assert sim.stats[-1].max_strain < 0.05


def test_drop_on_disc_coarsens_where_it_lies_flat():
    sim = ClothSim(load_scene("drop_on_disc", ["cloth.level=4", "lod.initial_level=4",
                                               "simulation.duration=2.0"]))

    def flat_region_triangles():
        centroid = sim.positions[sim.triangles].mean(axis=1)
        return int((np.hypot(centroid[:, 0], centroid[:, 1]) < 0.2).sum())

    before = flat_region_triangles()
    sim.run(2.0)
    after = flat_region_triangles()
    # Coarsened on the table top: 64 -> 48 triangles measured.  (32 before merges
    # had to respect lod.max_merge_speed: they now wait until the landing has
    # settled, and by then a shallow wrinkle, d between the thresholds, holds 16.)
    assert after < 0.9 * before
    rim = np.abs(np.hypot(*sim.positions[sim.triangles].mean(axis=1)[:, :2].T) - 0.32) < 0.04
    assert sim.triangle_levels[rim].mean() > sim.triangle_levels[~rim].mean()
    # Every merge in the flat region removes two of its triangles.  (The count
    # itself follows the trajectory chaotically: 24 merges on the main of
    # 2026-11-28, 12 with converged stages (3 Newton iterations, 1e-4 m), 8
    # with the paper's integrator; 8 and 23 after issue 31's contact changes.)
    assert sum(s.merges for s in sim.stats) >= (before - after) // 2


def test_a_scene_without_obstacles_never_runs_contact_code(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("contact code ran in a scene without obstacles")
    monkeypatch.setattr(stepping_module, "find_contacts", forbidden)
    sim = ClothSim(load_scene("hang_two_corners", ["cloth.level=2"]))
    for _ in range(10):
        assert sim.step().contact_count == 0


# -- grasps ------------------------------------------------------------------------

def grasp(name="hand", uv=(0.0, 1.0), **kw):
    g = {"name": name, "uv": list(uv), "close_time": 0.0}
    g.update(kw)
    return g


def test_held_particle_follows_its_target_exactly():
    sim = ClothSim(scene(grasps=[grasp(max_speed=2.0)]))
    sim.step()
    g = sim.grasp("hand")
    node = int(np.searchsorted(sim.vertex_ids, g.nodes[0]))
    start = sim.positions[node].copy()
    for k in range(1, 40):
        target = start + np.array([0.3 * np.sin(0.1 * k), 0.0, 0.01 * k])
        sim.set_grasp_target("hand", target)          # within 2 m/s at 60 Hz
        sim.step()
        np.testing.assert_allclose(sim.positions[node], target, rtol=0, atol=1e-12)


def test_teleporting_target_is_caught_up_at_the_speed_limit(caplog):
    sim = ClothSim(scene(grasps=[grasp(max_speed=1.0)]))
    sim.step()
    g = sim.grasp("hand")
    node = int(np.searchsorted(sim.vertex_ids, g.nodes[0]))
    target = sim.positions[node] + np.array([0.5, 0.0, 0.0])
    with caplog.at_level(logging.INFO):
        sim.set_grasp_target("hand", target)
        previous = sim.positions[node].copy()
        for _ in range(40):
            sim.step()
            assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))
            step = np.linalg.norm(sim.positions[node] - previous)
            assert step <= 1.0 * sim.time_step + 1e-12      # never faster than max_speed
            previous = sim.positions[node].copy()
    np.testing.assert_allclose(sim.positions[node], target, atol=1e-12)   # caught up
    assert g.jumps == 1
    assert any("catching up" in r.message for r in caplog.records)
    assert max(s.max_strain for s in sim.stats) < 0.2


def test_bad_targets_are_refused_and_the_old_one_kept():
    sim = ClothSim(scene(grasps=[grasp()]))
    sim.step()
    before = sim.grasp("hand").command_position.copy()
    for bad in ([np.nan, 0, 0], [0, np.inf, 0], [1, 2]):
        with pytest.raises(ValueError):
            sim.set_grasp_target("hand", bad)
    with pytest.raises(ValueError):
        sim.set_grasp_target("hand", [0, 0, 1], orientation=[0, 0, 0, 0])
    with pytest.raises(KeyError):
        sim.set_grasp_target("nobody", [0, 0, 1])
    np.testing.assert_array_equal(sim.grasp("hand").command_position, before)


def test_releasing_a_grasp_lets_the_cloth_fall():
    sim = ClothSim(scene(grasps=[grasp("a", (0.0, 1.0)), grasp("b", (1.0, 1.0))]))
    for _ in range(60):
        sim.step()
    hung = sim.positions[:, 2].mean()
    # Still swinging when let go: free fall adds g t to the momentum it has.
    released = np.average(sim.velocities[:, 2], weights=sim.masses)
    sim.open_grasp("a")
    sim.open_grasp("b")
    for _ in range(30):
        s = sim.step()
        assert s.pinned_count == 0
    assert sim.positions[:, 2].mean() < hung - 0.3
    falling = np.average(sim.velocities[:, 2], weights=sim.masses)
    np.testing.assert_allclose(falling - released, -9.81 * 0.5, rtol=1e-6)


def test_closing_again_holds_the_cloth_where_it_is_unless_a_pose_was_commanded():
    sim = ClothSim(scene(grasps=[grasp("a", (0.0, 1.0)), grasp("b", (1.0, 1.0))]))
    for _ in range(10):
        sim.step()
    sim.open_grasp("a")
    for _ in range(15):
        sim.step()
    corner = sim.sample([[0.0, 1.0]])[0]
    sim.close_grasp("a")                       # no pose commanded: hold it here
    for _ in range(20):
        sim.step()
    np.testing.assert_allclose(sim.sample([[0.0, 1.0]])[0], corner, atol=1e-9)
    # A commanded pose outlives open/close: the grip goes where it was sent.
    target = corner + [0.0, 0.0, 0.1]
    sim.set_grasp_target("a", target)
    sim.open_grasp("a")
    sim.step()
    sim.close_grasp("a")
    for _ in range(30):
        sim.step()
    np.testing.assert_allclose(sim.grasp("a").position, target, atol=1e-9)


def test_patch_grasp_holds_several_particles_rigidly_and_turns_them():
    # Self-collision off: this is about the held patch.  The level-4 sheet hanging
    # from it folds as it turns, and self-collision's step rejections and re-solves
    # made the run ~30x slower (49 s after the pleat fix; issue 31); the held particles
    # are the same.
    cfg = scene(grasps=[grasp(uv=(0.5, 1.0), width=0.3)], level=4)
    sim = ClothSim(replace(cfg, self_collision=replace(cfg.self_collision, enabled=False)))
    sim.step()
    g = sim.grasp("hand")
    assert len(g.nodes) >= 3
    held = np.searchsorted(sim.vertex_ids, g.nodes)
    before = sim.positions[held].copy()
    centre = g.position.copy()
    quarter_turn = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]     # 90° about z
    sim.set_grasp_target("hand", centre, orientation=quarter_turn)
    for _ in range(30):
        sim.step()
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(sim.positions[held], centre + (before - centre) @ rot.T,
                               atol=1e-9)


def test_grasp_at_an_arbitrary_point_refines_there_and_is_never_merged():
    uv = (0.3, 0.7)                                  # no particle there at level 0
    lod = {"enabled": True, "initial_level": 0, "min_lifetime": 0.0}
    sim = ClothSim(scene(level=7, lod=lod, gravity=(0, 0, 0),
                         grasps=[grasp(uv=uv, tolerance=0.01)]))
    assert sim.mesh.vertex_count == 25
    sim.step()
    g = sim.grasp("hand")
    node = int(g.nodes[0])
    assert np.linalg.norm(sim.hierarchy.uv[node] - uv) <= 0.01
    assert sim.mesh.vertex_count > 25
    for _ in range(60):                 # flat and still: the mesh would coarsen
        sim.step()
        assert sim.hierarchy.vertex_active[node]
    sim.open_grasp("hand")
    for _ in range(60):
        sim.step()
    assert sim.mesh.vertex_count == 25  # released: back to the base mesh
    assert sum(s.merges for s in sim.stats) > 0


def test_grasp_detail_level_is_kept_around_closed_grasps():
    lod = {"enabled": True, "initial_level": 0, "detail_level": 4, "detail_radius": 0.1}
    sim = ClothSim(scene(level=5, lod=lod, grasps=[grasp(uv=(0.5, 1.0))]))
    for _ in range(20):
        sim.step()
    centroid = sim.rest_uv[sim.triangles].mean(axis=1)
    near = np.linalg.norm(centroid - [0.5, 1.0], axis=1) < 0.1
    assert near.any() and sim.triangle_levels[near].min() >= 4


def test_grasp_lift_scene_lifts_the_cloth_off_the_table():
    sim = ClothSim(load_scene("grasp_lift", ["cloth.level=4", "simulation.duration=1.4"]))
    sim.run(1.4)
    assert all(g.closed for g in sim.grasps)
    assert sim.positions[:, 2].max() > 0.8          # corners up near 0.9 m
    assert min_distance(sim) > 0.5 * THICKNESS
    assert np.all(np.isfinite(sim.positions))
