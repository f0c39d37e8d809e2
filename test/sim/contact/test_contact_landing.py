"""Landings over edges, corners and rims: contact adds no energy (issue 31).

A 5 cm x 30 cm strip is dropped 2 cm onto a table with 10 cm of it beyond
the edge (or over a corner, or over a round table's rim).  Outside truths:

* friction, damping and an inelastic contact only take energy: the total
  (kinetic + gravity + elastic) never rises from one frame to the next;
* contact pushes, it never throws: no particle leaves a contact faster than
  it arrived there (1.1x, the issue's bound);
* a strip lying still on a table stays still.

Before issue 31 the Newton-based schemes gained 5.5x the drop energy in the
landing frame over a sharp edge (78x with a smaller error tolerance), and
particles left the edge at 1.4-6 m/s after arriving at 0.5 m/s.
"""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim.contact.contacts import ContactSet, nearest_surface
from cloth_lod_ros.sim.integrate.implicit_stage import _short_of_surface

G = 9.81
DROP = 0.02            # m, from the strip's start to the table top
THICKNESS = 0.004      # the default contact thickness
TABLE = {"type": "box", "name": "table", "centre": [-0.5, 0.0, 0.25],
         "half_extents": [0.5, 0.3, 0.25], "rounding": 0.0, "friction": 1.0}
RIM = {"type": "cylinder", "name": "table", "centre": [-0.3, 0.0, 0.25], "axis": [0, 0, 1],
       "radius": 0.3, "half_height": 0.25, "friction": 1.0}
DIAGONAL = np.sqrt(0.5)

CASES = {
    # 10 cm over the sharp edge x = 0 of the table top z = 0.5.
    "sharp edge": (TABLE, {"origin": [-0.2, -0.025, 0.5 + DROP]}),
    "rounded edge": (dict(TABLE, rounding=0.01), {"origin": [-0.2, -0.025, 0.5 + DROP]}),
    # Diagonally over the corner (0, 0.3): 10 cm of the centre line beyond it.
    "corner": (TABLE, {"origin": [-0.2 * DIAGONAL + 0.025 * DIAGONAL,
                                  0.3 - 0.2 * DIAGONAL - 0.025 * DIAGONAL, 0.5 + DROP],
                       "u_axis": [DIAGONAL, DIAGONAL, 0.0],
                       "v_axis": [-DIAGONAL, DIAGONAL, 0.0]}),
    # 10 cm over the rim of a round table of radius 0.3 m.
    "rim": (RIM, {"origin": [-0.2, -0.025, 0.5 + DROP]}),
}


def strip(case, stretch=2e3, level=5, **simulation):
    obstacle, placement = CASES[case]
    cloth = {"width": 0.3, "height": 0.05, "base_blocks": [6, 1], "level": level}
    cloth.update(placement)
    return ClothSim(scene_from_dict({
        "name": "strip", "cloth": cloth,
        "material": {"density": 0.2, "stretch_stiffness": stretch,
                     "shear_stiffness": stretch / 10, "bend_stiffness": 2e-3},
        "simulation": {"time_step": 1 / 60, "duration": 2.0, **simulation},
        "lod": {"enabled": False}, "obstacles": [obstacle]}))


def total_energy(sim):
    e = sim.energy()
    return e["kinetic"] + e["gravity"] + e["stretch"] + e["shear"] + e["bend"]


def watch_landing(sim, frames):
    """Run ``frames`` frames; returns ``(largest one-frame energy rise in units
    of the drop energy m g DROP, worst ratio of the normal speed at which a
    particle leaves a contact to the normal speed at which it arrived)``.

    A particle *touches* when it is within 1.5 thickness of the surface at a
    frame's end; it arrived with the normal speed it had in the frame before
    it first touched, and leaves with the normal velocity away from the
    surface that it has in a frame after one in which it touched."""
    obstacles = sim.obstacles
    n = len(sim.masses)
    arrival = np.zeros(n)
    touched = np.zeros(n, dtype=bool)
    touching = np.zeros(n, dtype=bool)
    worst = 0.0
    energies = [total_energy(sim)]
    for _ in range(frames):
        before = sim.velocities.copy()
        sim.step()
        phi, normal, _ = nearest_surface(obstacles, sim.positions)
        normal_speed = np.einsum("nd,nd->n", sim.velocities, normal)
        leaving = touching & (normal_speed > 0.0)
        if leaving.any():
            worst = max(worst, float(np.max(normal_speed[leaving] / arrival[leaving])))
        touching = phi < 1.5 * THICKNESS
        first = touching & ~touched
        arrival[first] = np.abs(np.einsum("nd,nd->n", before[first], normal[first]))
        touched |= touching
        energies.append(total_energy(sim))
    assert touched.sum() > n // 2               # the strip did land
    assert arrival[touched].min() > 0.3         # on its fall (0.56 m/s free fall)
    drop = G * float(sim.masses.sum()) * DROP
    return float(np.max(np.diff(energies))) / drop, worst


@pytest.mark.parametrize("case", list(CASES))
def test_a_landing_over_an_edge_gains_no_energy_and_throws_nothing(case):
    rise, leave = watch_landing(strip(case), 40)
    # 2 % of the drop energy: round-off and the error of one Newton iteration
    # (before issue 31: 5.5x over the sharp edge, 10.8x over the rounded one).
    assert rise < 0.02
    assert leave < 1.1


@pytest.mark.parametrize("case", ["sharp edge", "corner", "rim"])
def test_a_stiff_strip_landing_in_small_steps_gains_no_energy(case):
    """Stretch 2e4 N/m, ten times the default, and ``error_tolerance`` 1e-5 m
    (1 ms steps at the landing): in-plane stiffness couples each contact to
    its neighbours far more strongly than its mass resists, so one contact
    held where it should not be drags the whole strip (before issue 31:
    355-532x the drop energy in one frame, particles dragged into the table
    at 6 m/s and thrown off at 7-10 m/s)."""
    rise, leave = watch_landing(strip(case, stretch=2e4, error_tolerance=1e-5), 20)
    assert rise < 0.02
    assert leave < 1.1


@pytest.mark.parametrize("case", ["sharp edge", "rim"])
def test_smaller_steps_do_not_kick_harder(case):
    """``error_tolerance`` 1e-5 m: steps of 1 ms at the landing.  Before issue
    31 a contact 4 mm above the edge was held at its landing velocity d/γh,
    13 m/s in a 0.3 ms stage, and the landing frame gained 78x the drop
    energy: the smaller the step, the harder the kick."""
    rise, leave = watch_landing(strip(case, error_tolerance=1e-5), 20)
    assert rise < 0.02
    assert leave < 1.1


def test_a_strip_lying_still_at_the_edge_stays_still():
    """Flat on the table with its end on the edge line, on the offset surface
    and at rest: nothing moves (static equilibrium)."""
    obstacle = TABLE
    sim = ClothSim(scene_from_dict({
        "name": "strip",
        "cloth": {"width": 0.3, "height": 0.05, "base_blocks": [6, 1], "level": 4,
                  "origin": [-0.3, -0.025, 0.5 + THICKNESS]},
        "material": {"density": 0.2, "bend_stiffness": 2e-3},
        "simulation": {"time_step": 1 / 60, "duration": 1.0},
        "lod": {"enabled": False}, "obstacles": [obstacle]}))
    start = sim.positions.copy()
    for _ in range(60):
        sim.step()
    assert np.abs(sim.velocities).max() < 1e-3           # 1 mm/s
    assert np.abs(sim.positions - start).max() < 1e-5
    assert sim.stats[-1].max_strain < 1e-3


@pytest.mark.parametrize("case", [
    "rounded edge", "corner",
    pytest.param("rim", marks=pytest.mark.xfail(
        strict=True, reason="measured 1.25 cm/s at 1 s with the squared-Hessian bending "
        "(the overhang still rings; the hinge sum, 0.7x as stiff, settled; issue 31, open)"))])
def test_a_strip_landed_over_an_edge_comes_to_rest(case):
    """The issue's rest target: after 1 s every particle is slower than
    1 cm/s, the strain below 1 %."""
    sim = strip(case)
    for _ in range(60):
        sim.step()
    assert np.linalg.norm(sim.velocities, axis=1).max() < 0.01
    assert sim.stats[-1].max_strain < 0.01


def test_a_strip_landed_over_a_sharp_edge_comes_to_rest():
    sim = strip("sharp edge")
    for _ in range(60):
        sim.step()
    assert np.linalg.norm(sim.velocities, axis=1).max() < 0.01


def test_a_gap_the_particle_cannot_close_in_the_stage_is_not_held():
    """The contact filter: a particle 3.9 mm above the offset surface falling
    at 0.48 m/s reaches it in 8 ms.  In a 1 ms stage holding it there would
    pull it in at 3.9 m/s; in a 16.7 ms one it lands.  Resting on the surface
    (no gap) it is held; found past the surface (``hold``) it always is."""
    up = np.array([[0.0, 0.0, 1.0]])
    falling = np.array([[0.0, 0.0, -0.48]])
    gravity = np.array([0.0, 0.0, -G])

    def short(gap, velocity, h, hold=False):
        contact = ContactSet(np.array([0]), up.copy(), np.array([gap]), np.array([1.0]),
                             hold=np.array([hold]))
        return bool(_short_of_surface(contact, np.array([gap]), velocity, h, gravity)[0])

    assert short(3.9e-3, falling, 1e-3)
    assert not short(3.9e-3, falling, 1 / 60)
    assert not short(0.0, np.zeros((1, 3)), 1e-3)          # resting: gravity holds it on
    assert not short(1e-6, np.zeros((1, 3)), 1e-3)         # a hair above it, too
    assert short(3.9e-3, -falling, 1 / 60)                 # moving away
    assert not short(3.9e-3, falling, 1e-3, hold=True)
