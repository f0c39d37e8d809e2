"""The scene cost budget (sim/scene/budget.py): hostile scenes refused before anything
is built, and the estimate an upper bound of the mesh the simulator really builds."""

from __future__ import annotations

import copy

import pytest

from cloth_lod_ros.sim.scene import budget
from cloth_lod_ros.sim.scene.config import (SceneError, builtin_scene_names, load_scene,
                                            scene_from_dict)

MINIMAL = {"cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4]},
           "simulation": {"time_step": 0.02, "duration": 1.0}}


def scene(**sections) -> dict:
    data = copy.deepcopy(MINIMAL)
    for key, value in sections.items():
        if isinstance(value, dict) and key in data:
            data[key].update(value)
        else:
            data[key] = value
    return data


# -- the cases of issue 34: within every field's range, minutes and gigabytes ---------

def test_a_uniform_level_12_mesh_is_refused_with_its_size():
    with pytest.raises(SceneError, match="'cloth.level' 12 with LOD off") as info:
        scene_from_dict(scene(cloth={"level": 12}))
    assert "131,072 triangles" in str(info.value)
    assert f"{budget.MAX_START_TRIANGLES:,}" in str(info.value)
    # The same mesh as LOD's finest starts coarse and is accepted.
    accepted = scene_from_dict(scene(cloth={"level": 12}, lod={"enabled": True}))
    assert budget.estimate(accepted).triangles == 32


def test_the_largest_finest_mesh_with_lod_off_is_refused():
    data = scene(cloth={"width": 32.0, "height": 32.0, "base_blocks": [32, 32], "level": 10},
                 lod={"enabled": False})
    with pytest.raises(SceneError, match="2,097,152 triangles"):
        scene_from_dict(data)


def test_counts_of_pins_grasps_obstacles_and_waypoints_are_limited():
    grasps = [{"name": f"g{i}", "uv": [0.5, 0.5]} for i in range(budget.MAX_GRASPS + 1)]
    with pytest.raises(SceneError, match=f"'grasps' has {budget.MAX_GRASPS + 1} entries"):
        scene_from_dict(scene(grasps=grasps))
    assert len(scene_from_dict(scene(grasps=grasps[:-1])).grasps) == budget.MAX_GRASPS
    pins = [{"uv": [i / 100, 0.0]} for i in range(budget.MAX_PINS + 1)]
    with pytest.raises(SceneError, match="'pins' has"):
        scene_from_dict(scene(pins=pins))
    obstacles = [{"type": "sphere", "centre": [0, 0, -i]} for i in range(budget.MAX_OBSTACLES + 1)]
    with pytest.raises(SceneError, match="'obstacles' has"):
        scene_from_dict(scene(obstacles=obstacles))
    # Waypoints count over every path together: two paths of just over half each.
    half = budget.MAX_WAYPOINTS // 2 + 1
    path = [[i * 0.01, 0.0, 0.0, 1.0] for i in range(half)]
    two = scene(pins=[{"uv": [0, 0], "waypoints": path}],
                grasps=[{"name": "g", "uv": [1, 1], "waypoints": path}])
    with pytest.raises(SceneError, match=f"{2 * half:,} rows"):
        scene_from_dict(two)
    two["grasps"][0]["waypoints"] = path[:budget.MAX_WAYPOINTS - half]
    scene_from_dict(two)
    # A million entries are refused by count, never converted one by one.
    with pytest.raises(SceneError, match="1,000,000 entries"):
        scene_from_dict(scene(grasps=[{"name": 1}] * 1_000_000))


def test_the_first_steps_work_counts_every_solve_it_may_take():
    # 2^13 triangles (4 x 4 blocks at level 8) are well within the start limit, but
    # backward Euler with 50 Newton iterations and 6 friction rounds may solve 300
    # times in one step: 2.5 million triangle-solves.  (Self-collision off: its
    # re-solves multiply this, below.)
    data = scene(cloth={"level": 8},
                 simulation={"integrator": "backward_euler", "newton_iterations": 50},
                 obstacles=[{"type": "plane"}], self_collision={"enabled": False})
    with pytest.raises(SceneError, match="up to 300 linear solves per step"):
        scene_from_dict(data)
    data["simulation"]["newton_iterations"] = 2
    cost = budget.estimate(scene_from_dict(data))
    assert cost.solves_per_step == 2 * 6 and cost.step_work == 8192 * 12
    # Self-collision may re-solve each of those max_resolves more times; `auto`
    # counts as on, since the budget bounds what the first step may take.
    data["cloth"]["level"] = 4
    for enabled in (True, "auto"):
        data["self_collision"] = {"enabled": enabled, "max_resolves": 4}
        assert budget.estimate(scene_from_dict(data)).solves_per_step == 2 * 6 * 5


def test_every_builtin_scene_is_within_the_budget():
    for name in builtin_scene_names():
        cost = budget.estimate(load_scene(name))
        assert cost.triangles <= budget.MAX_START_TRIANGLES
        assert cost.step_work <= budget.MAX_STEP_WORK


def test_every_builtin_scenes_converged_reference_is_within_the_budget():
    """What `cloth-lod bench` checks a scene against, and what a user would: its
    uniform mesh at its level and one finer, LOD off, fixed steps, 3 Newton
    iterations per stage (:class:`ConvergedReference`).  Under 2^18 the budget
    refused drop_on_sphere's (2,048 triangles x 180 solves)."""
    from cloth_lod_ros.tools.reference import ConvergedReference
    for name in builtin_scene_names():
        base = load_scene(name)
        for level in (base.cloth.level, base.cloth.level + 1):
            ref = ConvergedReference(level=level, frame=base.simulation.time_step)
            for run in ref.runs(mesh_check=False):
                cost = budget.check(load_scene(name, run["overrides"]))
                assert cost.step_work <= budget.MAX_STEP_WORK


# -- the estimate bounds what is built -------------------------------------------------

@pytest.mark.parametrize("level,radius,uv", [
    (6, 0.0625, (0.0, 1.0)), (8, 0.2, (0.5, 0.5)), (10, 0.05, (0.3, 0.7)),
    (12, 0.03, (0.5, 0.5)), (12, 0.2, (1.0, 0.0)), (9, 0.0, (0.5, 0.5))])
def test_the_estimate_is_an_upper_bound_of_the_mesh_built(level, radius, uv):
    from cloth_lod_ros.sim import ClothSim
    data = scene(cloth={"level": level}, lod={"enabled": True, "initial_level": 2},
                 pins=[{"uv": list(uv), "radius": radius},
                       {"uv": [0.0, 0.0], "radius": radius / 4}])
    config = scene_from_dict(data)
    built = len(ClothSim(config).mesh.triangles)
    cost = budget.estimate(config)
    assert built <= cost.triangles, (built, cost)
    # ... and not a loose one: within a factor of 6 of a patch that is all inside.
    if radius > 0 and 0 < uv[0] < 1 and 0 < uv[1] < 1:
        assert cost.triangles <= 6 * built, (built, cost)


def test_with_lod_off_the_estimate_is_the_uniform_mesh():
    from cloth_lod_ros.sim import ClothSim
    config = scene_from_dict(scene(cloth={"level": 5, "base_blocks": [3, 3],
                                          "width": 0.6, "height": 0.6}))
    sim = ClothSim(config)
    cost = budget.estimate(config)
    assert cost.triangles == len(sim.mesh.triangles) == 2 * 9 * 32
    assert cost.particles >= sim.mesh.vertex_count
