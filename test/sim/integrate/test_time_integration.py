"""Time integration (design §3): order, numerical damping, Newton, error control.

Errors here are distances from a converged solution of the same model (same
mesh, much smaller step), never from a same-step run.
"""

import math

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import SceneError, load_scene, scene_from_dict
from cloth_lod_ros.sim.physics.forces import evaluate
from cloth_lod_ros.sim.solve.pattern import SparsePattern
from cloth_lod_ros.sim.integrate.schemes import SCHEMES


def hanging(integrator="sdirk2", h=1 / 60, tolerance=0.0, newton=4, **extra):
    """A 1 m cloth (25 particles) held by its two top corners, horizontal at t = 0,
    in vacuum (the face drag's |v_n| v_n is not smooth where v_n changes sign,
    which would blur the observed order)."""
    simulation = {"time_step": h, "duration": 1.0, "integrator": integrator,
                  "error_tolerance": tolerance, "newton_iterations": newton,
                  "newton_tolerance": 1e-9}
    simulation.update(extra)
    return scene_from_dict({
        "name": "hanging", "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [2, 2],
                                     "level": 2},
        "pins": [{"uv": [0, 1]}, {"uv": [1, 1]}], "air": {"density": 0.0},
        "simulation": simulation, "solver": {"method": "direct"}, "lod": {"enabled": False}})


def positions_at(scene, duration):
    sim = ClothSim(scene)
    while sim.time < duration - 1e-9:
        sim.step()
    return sim.positions.copy(), sim


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.fixture(scope="module")
def converged():
    """SDIRK2 at h = 1/1920 s: its own error at 0.25 s is below 1e-7 m (it
    shrinks 4x per halving, see the order test)."""
    return positions_at(hanging(h=1 / 1920), 0.25)[0]


@pytest.mark.parametrize("integrator,order", [("sdirk2", 2), ("backward_euler", 1),
                                              ("baraff_witkin", 1)])
def test_observed_order_when_halving_the_step(integrator, order, converged):
    errors = [rms(positions_at(hanging(integrator, h), 0.25)[0], converged)
              for h in (1 / 60, 1 / 120, 1 / 240)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    expected = 2.0 ** order
    for ratio in ratios:
        assert 0.8 * expected < ratio < 1.2 * expected, (errors, ratios)
    assert SCHEMES[integrator].order == order


def test_second_order_is_far_more_accurate_at_the_default_step(converged):
    second = rms(positions_at(hanging("sdirk2"), 0.25)[0], converged)
    paper = rms(positions_at(hanging("baraff_witkin"), 0.25)[0], converged)
    assert second < paper / 20


def pendulum(integrator):
    """A 0.5 x 1 m cloth held at its top edge's corners, released 20° from the
    vertical with no material damping and no air: a pendulum that should keep
    its energy."""
    a = math.radians(20.0)
    return ClothSim(scene_from_dict({
        "name": "pendulum",
        "cloth": {"width": 0.5, "height": 1.0, "base_blocks": [1, 2], "level": 2,
                  "origin": [0.0, math.sin(a), 1.0 - math.cos(a)], "u_axis": [1, 0, 0],
                  "v_axis": [0.0, -math.sin(a), math.cos(a)]},
        "pins": [{"uv": [0, 1]}, {"uv": [0.5, 1]}],
        "material": {"air_drag": 0.0, "stretch_damping": 0.0, "shear_damping": 0.0,
                     "bend_damping": 0.0},
        "air": {"density": 0.0},
        "simulation": {"time_step": 1 / 60, "duration": 4.0, "integrator": integrator},
        "solver": {"method": "direct"}, "lod": {"enabled": False}}))


def test_numerical_damping_of_a_pendulum_mode():
    """Over 4 s (about two periods) backward Euler removes most of the swing's
    energy by itself; the L-stable second-order scheme keeps almost all of it."""
    swing = 0.1 * 9.81 * 0.5 * (1.0 - math.cos(math.radians(20.0)))   # m g (L/2)(1 − cos a), J
    lost = {}
    for integrator in ("sdirk2", "backward_euler", "baraff_witkin"):
        sim = pendulum(integrator)
        energy = [sim.step().total_energy for _ in range(240)]
        lost[integrator] = energy[0] - energy[-1]
        assert max(energy) <= energy[0] + 1e-4 * swing       # never gains energy
    assert lost["backward_euler"] > 0.4 * swing
    assert lost["baraff_witkin"] > 0.4 * swing
    assert lost["sdirk2"] < 0.1 * swing
    assert lost["sdirk2"] < lost["backward_euler"] / 10


def stage_problem():
    sim = ClothSim(hanging(newton=1))
    for _ in range(20):                  # mid-swing: the forces are far from linear
        sim.step()
    x, v = sim.positions, sim.velocities
    held = (np.array([p.vertex for p in sim.pins]), x[[p.vertex for p in sim.pins]])
    return sim, x, v, held


def test_newton_iterations_reduce_the_residual_of_the_implicit_equations():
    sim, x, v, held = stage_problem()
    solver, h = sim.solver, sim.time_step
    norms = []
    for iterations in range(0, 7):
        if iterations == 0:
            velocities = v.copy()
            velocities[held[0]] = 0.0
        else:
            velocities = solver.solve_stage(sim.elements, sim.masses, x, v, h, held, v,
                                            max_iterations=iterations).velocities
        norms.append(solver.residual_norm(sim.elements, sim.masses, x, v, h, velocities,
                                          held[0]))
    assert all(b < a for a, b in zip(norms, norms[1:])), norms
    # Linear convergence (the kept Jacobian is Gauss–Newton): ~0.1 per iteration.
    assert norms[-1] < 1e-4 * norms[0]


def test_the_paper_configuration_is_bw_equation_15():
    """``baraff_witkin``: one solve per step (BW §5) of
    Δv = (M − h ∂f/∂v − h² ∂f/∂x)⁻¹ h (f₀ + h ∂f/∂x v₀), held particles filtered."""
    sim, x, v, held = stage_problem()
    h = sim.time_step
    mat = sim.scene.material
    ev = evaluate(sim.elements, mat, x, v, stiffness_weight=h * h, damping_weight=h)
    m = sim.masses
    force = ev.force + m[:, None] * (np.array(sim.scene.simulation.gravity)
                                     - mat.air_drag * v)
    rhs = h * (force + h * ev.stiffness_times_velocity)
    pattern = SparsePattern(sim.mesh.vertex_count,
                            sim.elements.element_vertices)
    matrix = pattern.assemble(ev.blocks, m * (1 + h * mat.air_drag))
    free = np.ones(len(x), dtype=bool)
    free[held[0]] = False
    dofs = np.repeat(free, 3)
    dv = np.zeros_like(x)
    dv[held[0]] = -v[held[0]]                              # pins stay where they are
    a = matrix.tocsr()
    reduced = rhs.ravel() - a @ dv.ravel()
    dv.ravel()[dofs] += spla.spsolve(a[dofs][:, dofs].tocsc(), reduced[dofs])
    expected = x + h * (v + dv)

    paper = ClothSim(hanging("baraff_witkin"))
    paper.state = sim.state.copy()
    stats = paper.step()
    assert stats.solves == 1 and stats.newton_iterations == 1 and stats.substeps == 1
    np.testing.assert_allclose(paper.positions, expected, atol=1e-9)


def test_error_control_meets_its_tolerance_against_the_converged_motion(converged):
    """Global error after 0.25 s stays within the sum of the local tolerances
    and shrinks with the tolerance; steps are cut while the cloth swings."""
    errors = {}
    for tolerance in (1e-4, 1e-5):
        end, sim = positions_at(hanging(tolerance=tolerance, min_time_step=1e-4), 0.25)
        steps = sum(s.substeps for s in sim.stats)
        errors[tolerance] = rms(end, converged)
        assert errors[tolerance] <= tolerance * steps
        assert steps > len(sim.stats)                       # it did cut the frame period
        assert min(s.smallest_step for s in sim.stats) < sim.time_step
    assert errors[1e-5] < errors[1e-4] / 3


def test_error_control_takes_the_frame_period_when_the_cloth_is_at_rest():
    sim = ClothSim(hanging(tolerance=1e-4, newton=1, h=1 / 30))
    # A cloth hanging in its static shape: settle it first with the paper's step.
    settle = ClothSim(hanging("baraff_witkin", h=1 / 30))
    for _ in range(300):
        settle.step()
    sim.state = settle.state.copy()
    stats = [sim.step() for _ in range(10)]
    assert all(s.substeps == 1 and s.rejected_steps == 0 for s in stats[2:])


def test_error_controlled_pins_and_grasp_targets_are_exact_at_every_frame():
    scene = load_scene("grasp_lift", ["cloth.level=3", "simulation.error_tolerance=2e-4",
                                      "lod.enabled=false"])
    sim = ClothSim(scene)
    split = 0
    for _ in range(90):
        stats = sim.step()
        split += stats.substeps > 1
        held, targets = sim._held(sim.time)
        np.testing.assert_allclose(sim.positions[held], targets, atol=1e-12)
    assert split > 0


@pytest.mark.parametrize("key,value", [("simulation.integrator", "rk4"),
                                       ("simulation.newton_iterations", 0),
                                       ("simulation.error_tolerance", -1e-3),
                                       ("simulation.min_time_step", 0.0)])
def test_bad_integration_settings_are_refused(key, value):
    with pytest.raises(SceneError):
        load_scene("hang_two_corners", [f"{key}={value}"])


def test_the_time_stepping_can_change_between_steps():
    """The node lets a user trade accuracy for speed live: the scheme and the
    tolerance take effect at the next step; the frame period cannot change."""
    sim = ClothSim(hanging(tolerance=1e-5, min_time_step=1e-4))
    sim.step()
    assert sim.stats[-1].substeps > 1
    sim.update_parameters({"simulation.integrator": "baraff_witkin",
                           "simulation.error_tolerance": 0.0})
    stats = sim.step()
    assert stats.substeps == 1 and stats.newton_iterations == 1
    assert sim.stepper.scheme.name == "baraff_witkin"
    with pytest.raises(SceneError):
        sim.update_parameters({"simulation.time_step": 0.01})
    with pytest.raises(SceneError):
        sim.update_parameters({"simulation.integrator": "rk4"})
    assert sim.stepper.scheme.name == "baraff_witkin"      # a refusal changes nothing
