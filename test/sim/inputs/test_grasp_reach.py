"""A live grasp target is kept within what the cloth reaches from its other held
points (sim/inputs/grasps.py ``MAX_REACH_STRAIN``; issue 34): a grasp sent to the
workspace's edge used to stretch the cloth without limit into unphysical motion."""

from __future__ import annotations

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.inputs.grasps import MAX_REACH_STRAIN, Grasp
from cloth_lod_ros.sim.scene.config import scene_from_dict

SCENE = {
    "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": 2},
    "simulation": {"time_step": 0.02, "duration": 1.0},
    "material": {"air_drag": 1.0},
    "pins": [{"name": "corner", "uv": [0.0, 1.0]}],
    "grasps": [{"name": "hand", "uv": [1.0, 1.0], "close_time": 0.0, "max_speed": 5.0}],
}


def test_reachable_is_the_nearest_point_of_one_ball_and_inside_all():
    g = Grasp.from_config(scene_from_dict(SCENE).grasps[0])
    radius = (1 + MAX_REACH_STRAIN) * 1.0
    far = np.array([10.0, 0.0, 0.0])
    assert np.allclose(g.reachable(far, [(np.zeros(3), 1.0)]), [radius, 0.0, 0.0])
    inside = np.array([0.3, 0.2, 0.1])
    assert np.array_equal(g.reachable(inside, [(np.zeros(3), 1.0)]), inside)
    anchors = [(np.zeros(3), 1.0), (np.array([1.5, 0.0, 0.0]), 1.0)]
    point = g.reachable(np.array([0.75, 10.0, 0.0]), anchors)
    for centre, rest in anchors:
        assert np.linalg.norm(point - centre) <= (1 + MAX_REACH_STRAIN) * rest + 1e-9


@pytest.mark.parametrize("target", [(10.0, 1.0, 1.0), (1.0, 10.0, -9.0), (-10.0, 1.0, 1.0)])
def test_a_grasp_sent_to_the_workspace_edge_stays_within_reach(target):
    # Self-collision off: this is about where the grasp goes.  Brought back from
    # beyond the pin (target2) the sheet folds over itself and self-collision's
    # re-solves made the last 50 steps ~30 s (issue 31); the grasp's path is the same.
    sim = ClothSim(scene_from_dict({**SCENE, "self_collision": {"enabled": False}}))
    sim.step()                                     # closes at t = 0
    grasp, pin = sim.grasp("hand"), sim.pins[0]
    sim.set_grasp_target("hand", target)
    for _ in range(100):                           # 2 s: 10 m at 5 m/s would be reached
        sim.step()
    rest = float(np.linalg.norm(grasp.uv - pin.uv))
    reach = np.linalg.norm(grasp.position - pin.target(sim.time))
    assert reach <= (1 + MAX_REACH_STRAIN) * rest + 1e-9
    assert sim.stats[-1].max_strain < 4 * 0.3      # below the node's ERROR bound
    assert np.all(np.isfinite(sim.state.positions))
    # A target within reach is followed exactly again.
    sim.set_grasp_target("hand", (0.9, 1.0, 1.0))
    for _ in range(50):
        sim.step()
    assert np.allclose(grasp.position, (0.9, 1.0, 1.0))
