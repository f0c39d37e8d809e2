"""tools/dissipation: the undamped swing conserves energy but for the integrator, and
the schemes' damping per step matches their closed-form stability functions."""

import math

import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.tools import dissipation


@pytest.mark.parametrize("omega_h", [0.1, 1.0, 10.0])
def test_damping_per_step_matches_closed_forms(omega_h):
    # Backward Euler: R(iy) = 1/(1 − iy); midpoint: (1 + iy/2)/(1 − iy/2), |R| = 1.
    assert dissipation.damping_per_step("backward_euler", omega_h) == pytest.approx(
        1.0 - 1.0 / math.sqrt(1.0 + omega_h ** 2), rel=1e-12)
    assert abs(dissipation.damping_per_step("midpoint", omega_h)) < 1e-14
    # The L-stable second-order R with a double pole at 1/γ is unique: TR-BDF2 = SDIRK2.
    assert dissipation.damping_per_step("tr_bdf2", omega_h) == pytest.approx(
        dissipation.damping_per_step("sdirk2", omega_h), rel=1e-9)


def test_the_swing_has_nothing_that_takes_energy_out_but_the_integrator():
    scene_overrides = dissipation.swing_overrides(2, "sdirk2", duration=0.5)
    sim = ClothSim.from_scene("hang_two_corners", scene_overrides)
    material, air = sim.scene.material, sim.scene.air
    assert (material.stretch_damping, material.shear_damping, material.bend_damping,
            material.air_drag, air.density) == (0, 0, 0, 0, 0)
    assert all(not p.waypoints and p.release_time is None for p in sim.scene.pins)
    assert sim.hierarchy is None                       # no LOD: merges change the energy
    # At rest and flat at z = 1 m: all the energy is gravity's, m g z.
    mass = sim.scene.material.density * sim.scene.cloth.width * sim.scene.cloth.height
    assert dissipation.total_energy(sim) == pytest.approx(mass * 9.81 * 1.0, rel=1e-12)


def test_a_second_order_scheme_loses_less_of_the_swing_than_the_paper_step():
    rest = 0.0          # any reference below E(0) orders the losses the same way
    lost = {name: dissipation.energy_loss(2, name, 1.0, 1 / 60, 0.0, rest)["lost"]
            for name in ("sdirk2", "baraff_witkin")}
    assert 0.0 <= lost["sdirk2"] < lost["baraff_witkin"]
