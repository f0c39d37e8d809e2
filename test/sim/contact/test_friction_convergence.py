"""Coulomb friction converges as the step goes to 0 (issue 31).

Outside truths: the closed-form motion of a sheet sliding down an incline,
and the step-converged motion of a sheet sliding off a sharp table edge
(successive halvings of the step must get closer, not drift apart)."""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import scene_from_dict

THICKNESS = 0.004


def _scene(obstacles, origin, h, level, u_axis=(1, 0, 0)):
    return scene_from_dict({
        "name": "friction_convergence",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level,
                  "origin": list(origin), "u_axis": list(u_axis), "v_axis": [0, 1, 0]},
        "material": {"air_drag": 0.0},
        "air": {"density": 0.0},
        "obstacles": obstacles,
        "contact": {"thickness": THICKNESS},
        "self_collision": {"enabled": False},
        "simulation": {"time_step": h, "duration": 1.0, "integrator": "sdirk2",
                       "error_tolerance": 0, "newton_iterations": 3,
                       "newton_tolerance": 1e-8},
        "lod": {"enabled": False},
    })


def _run(scene, duration):
    sim = ClothSim(scene)
    start = sim.positions.copy()
    while sim.time < duration - 1e-9:
        sim.step()
    return start, sim.positions


@pytest.mark.parametrize("h", [1 / 60, 1 / 240])
def test_sheet_slides_down_an_incline_as_coulomb_says(h):
    """A sheet on a 30° slope with μ = 0.3 slides ½ g (sin θ − μ cos θ) t²
    along it, whatever the step."""
    angle, mu, duration = np.radians(30.0), 0.3, 0.4
    normal = np.array([-np.sin(angle), 0.0, np.cos(angle)])
    down = np.array([-np.cos(angle), 0.0, -np.sin(angle)])
    slope = {"type": "plane", "centre": [0, 0, 0], "normal": normal.tolist(), "friction": mu}
    u_axis = -down                       # the sheet lies in the slope
    origin = THICKNESS * normal - 0.5 * u_axis - np.array([0.0, 0.5, 0.0])
    start, end = _run(_scene([slope], origin, h, 2, tuple(u_axis)), duration)
    slid = float(np.mean((end - start) @ down))
    expected = 0.5 * 9.81 * (np.sin(angle) - mu * np.cos(angle)) * duration ** 2
    assert slid == pytest.approx(expected, rel=0.03)


def test_sheet_sliding_off_a_sharp_edge_converges_with_the_step():
    """A sheet 60 % over a sharp table edge (μ 0.2) slides off it; its rear
    edge's travel at 0.4 s must converge as h halves (1/60 .. 1/480 s).
    The Coulomb limit taken from the solve that held the contacts (before
    issue 31) made the friction at the edge grow as 1/h: the travel shrank
    with every halving (0.067, 0.081, 0.043, 0.021 m at level 4) and at
    1/480 s the sheet stuck on the edge."""
    table = {"type": "box", "centre": [0.0, 0.0, -0.4], "half_extents": [0.5, 0.6, 0.4],
             "friction": 0.2}
    travel = []
    for divisor in (1, 2, 4, 8):
        start, end = _run(_scene([table], (0.1, -0.5, THICKNESS), 1 / 60 / divisor, 3), 0.4)
        rear = start[:, 0] < start[:, 0].min() + 1e-9
        travel.append(float(np.mean(end[rear, 0] - start[rear, 0])))
    changes = np.abs(np.diff(travel))
    assert travel[-1] > 0.05                    # it slides (free fall of the overhang: ~0.3 m)
    assert changes[2] < 0.5 * changes[0]        # converging
    assert changes[2] < 0.05 * travel[-1]       # to within 5 %
