"""The air on each face along its normal: terminal speed, no drag in the plane,
wind, exact velocity Jacobian, dissipation (design §2)."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.cloth import live_update
from cloth_lod_ros.sim.scene.config import SceneError, load_scene, scene_from_dict, scene_to_dict
from cloth_lod_ros.sim.physics.air import air_forces
from cloth_lod_ros.sim.physics.forces import evaluate
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.solve.pattern import SparsePattern
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform

G = 9.81


def sheet(v_axis=(0.0, 1.0, 0.0), level=2, gravity=(0.0, 0.0, -G), air=None, pins=(),
          h=1 / 60, self_collision=None, **material):
    """A free 1 m sheet (horizontal by default) with the default material and air."""
    data = {"name": "air",
            "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": level,
                      "origin": [0.0, 0.0, 0.0], "v_axis": list(v_axis)},
            "material": material, "pins": [dict(p) for p in pins],
            "simulation": {"time_step": h, "duration": 1.0, "gravity": list(gravity)},
            "solver": {"method": "direct", "tolerance": 1e-10}}
    if air is not None:
        data["air"] = air
    if self_collision is not None:
        data["self_collision"] = self_collision
    return ClothSim(scene_from_dict(data))


@pytest.mark.parametrize("density, air", [(0.2, {}), (0.2, {"drag_coefficient": 0.6}),
                                          (0.5, {"density": 1.0, "wind": [0.0, 0.0, 0.0]})])
def test_a_flat_sheet_falls_at_its_terminal_speed(density, air):
    """Face-on, the drag balances the weight at v = √(2 ρ_areal g / (ρ_air C_d))
    (1.65 m/s for the default cloth), whatever the level."""
    sim = sheet(air=air, density=density)
    rho, cd = air.get("density", 1.2), air.get("drag_coefficient", 1.2)
    terminal = np.sqrt(2.0 * density * G / (rho * cd))
    for _ in range(120):                                   # 2 s, > 10 time constants v_t/g
        stats = sim.step()
    np.testing.assert_allclose(sim.velocities[:, 2], -terminal, rtol=0.01)
    assert np.ptp(sim.positions[:, 2]) < 1e-9                # and it stays flat
    # The air takes what gravity gives.
    np.testing.assert_allclose(stats.air_power, -density * G * terminal, rtol=0.02)


def test_a_sheet_falling_edge_on_or_sliding_in_its_plane_feels_no_air():
    """With the default scene settings only the normal motion is resisted: an
    edge-on fall is a free fall and an in-plane slide keeps its speed.  The
    isotropic material.air_drag, when set, slows both (and only it does)."""
    steps, h = 60, 1 / 60
    edge_on = sheet(v_axis=(0.0, 0.0, 1.0))
    for _ in range(steps):
        edge_on.step()
    np.testing.assert_allclose(edge_on.velocities[:, 2], -steps * h * G, rtol=0, atol=1e-9)
    sliding = sheet(gravity=(0.0, 0.0, 0.0))
    sliding.state.velocities[:] = [1.5, -0.5, 0.0]
    for _ in range(steps):
        stats = sliding.step()
    np.testing.assert_allclose(sliding.velocities, [[1.5, -0.5, 0.0]] * len(sliding.velocities),
                               rtol=0, atol=1e-12)
    assert stats.air_power == 0.0
    # The isotropic term alone: the same edge-on fall with or without the air model.
    runs = []
    for air in ({}, {"density": 0.0}):
        sim = sheet(v_axis=(0.0, 0.0, 1.0), air=air, air_drag=0.5)
        for _ in range(steps):
            sim.step()
        runs.append(sim.velocities[:, 2].copy())
    np.testing.assert_allclose(runs[0], runs[1], rtol=1e-12)
    assert np.all(runs[0] > -0.8 * steps * h * G)             # it did slow the fall


def hanging(wind, seconds=2.0):
    pins = [{"name": "a", "uv": [0.0, 1.0], "radius": 0.0625},
            {"name": "b", "uv": [1.0, 1.0], "radius": 0.0625}]
    sim = sheet(v_axis=(0.0, 0.0, 1.0), level=3, air={"wind": list(wind)}, pins=pins)
    for _ in range(int(seconds / sim.time_step)):
        sim.step()
    return sim.sample([[0.5, 0.0], [0.5, 0.5]])


def test_wind_pushes_a_hanging_cloth_downwind():
    """A cloth hanging in the x-z plane, wind along ±y: the free edge goes
    downwind, symmetrically; the wind along the cloth's plane does nothing."""
    still = hanging((0.0, 0.0, 0.0))
    plus, minus = hanging((0.0, 4.0, 0.0)), hanging((0.0, -4.0, 0.0))
    np.testing.assert_allclose(still[:, 1], 0.0, atol=1e-9)
    assert plus[0, 1] > 0.15 and plus[1, 1] > 0.05        # m downwind, bottom more
    assert plus[0, 1] > plus[1, 1]
    np.testing.assert_allclose(minus[:, 1], -plus[:, 1], atol=1e-9)
    np.testing.assert_allclose(minus[:, [0, 2]], plus[:, [0, 2]], atol=1e-9)
    along = hanging((3.0, 0.0, 0.0))
    np.testing.assert_allclose(along, still, atol=1e-9)


def air(density=1.2, cd=1.2, wind=(0.0, 0.0, 0.0)):
    return SimpleNamespace(density=density, drag_coefficient=cd, wind=np.asarray(wind))


def crumpled(level=2, seed=0):
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
    rng = np.random.default_rng(seed)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    x += rng.normal(scale=0.05, size=x.shape)
    v = rng.normal(scale=1.0, size=x.shape)
    return precompute(mesh), x, v


def dense(elements, blocks):
    pattern = SparsePattern(elements.vertex_count, [elements.triangles])
    return pattern.assemble([blocks], np.zeros(elements.vertex_count)).toarray()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_air_velocity_jacobian_matches_finite_differences(seed):
    elements, x, v = crumpled(seed=seed)
    a = air(wind=(0.3, -0.2, 0.5))
    force, blocks = air_forces(elements, a, x, v, damping_weight=1.0, with_blocks=True)
    jacobian = -dense(elements, blocks)                      # blocks = −∂f/∂v
    eps = 1e-6
    numeric = np.zeros_like(jacobian)
    for k in range(v.size):
        dv = np.zeros(v.size)
        dv[k] = eps
        plus = air_forces(elements, a, x, v + dv.reshape(v.shape))[0]
        minus = air_forces(elements, a, x, v - dv.reshape(v.shape))[0]
        numeric[:, k] = (plus - minus).ravel() / (2 * eps)
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-6, atol=1e-8 * np.abs(numeric).max())
    np.testing.assert_allclose(jacobian, jacobian.T, rtol=0, atol=1e-14)   # symmetric ...
    assert np.linalg.eigvalsh(jacobian).max() < 1e-12        # ... negative semi-definite
    assert np.abs(jacobian).max() > 1e-3                     # not trivially zero
    # evaluate() adds exactly these forces, and the blocks times damping_weight.
    mat = SimpleNamespace(stretch_stiffness=100.0, shear_stiffness=20.0, bend_stiffness=1e-2,
                          stretch_damping=0.01, shear_damping=0.01, bend_damping=0.1)
    with_air = evaluate(elements, mat, x, v, 0.01, 0.1, air=a)
    without = evaluate(elements, mat, x, v, 0.01, 0.1)
    np.testing.assert_allclose(with_air.force - without.force, force, atol=1e-12)
    np.testing.assert_allclose(with_air.triangle_blocks - without.triangle_blocks,
                               0.1 * blocks, atol=1e-12)
    # Net force along the normals only: it has no component in any face's plane
    # when every face is in one plane.
    flat = np.column_stack([x[:, :2], np.zeros(len(x))])
    f_flat = air_forces(elements, a, flat, v)[0]
    np.testing.assert_allclose(f_flat[:, :2], 0.0, atol=1e-15)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.1, 10.0))
def test_still_air_only_takes_energy(seed, scale):
    """In still air the face forces' power is −Σ ½ρC_d A |v_n|³ ≤ 0, and whole
    implicit steps with nothing but the air (no gravity, no stiffness) never
    raise the kinetic energy."""
    elements, x, v = crumpled(seed=seed)
    v *= scale
    force, _ = air_forces(elements, air(), x, v)
    assert np.sum(force * v) <= 0.0
    assert np.sum(force * v) < 0.0 or not np.any(v)


def test_whole_steps_with_only_the_air_never_gain_energy():
    # Only the air: no elastic forces, no gravity, and no self-collision (the
    # tangled, unstretchable sheet crossed itself at every step, and its
    # re-solves made this 25x slower; its impulses are not the air's).
    sim = sheet(level=3, gravity=(0.0, 0.0, 0.0), stretch_stiffness=0.0, shear_stiffness=0.0,
                bend_stiffness=0.0, stretch_damping=0.0, shear_damping=0.0, bend_damping=0.0,
                air={"density": 5.0}, self_collision={"enabled": False})
    rng = np.random.default_rng(3)
    sim.state.positions += rng.normal(scale=0.05, size=sim.positions.shape)
    sim.state.velocities[:] = rng.normal(scale=3.0, size=sim.positions.shape)
    kinetic = [sim.energy()["kinetic"]]
    # 15 steps (17 substeps each): the air takes half the energy by step 5, and
    # its power has fallen from -22 W to -0.5 W (-0.07 W at step 40).
    for _ in range(15):
        stats = sim.step()
        kinetic.append(stats.kinetic_energy)
        assert stats.air_power <= 0.0
    assert np.all(np.diff(kinetic) <= 1e-15 * kinetic[0])
    assert kinetic[-1] < 0.5 * kinetic[0]                     # and it does take it


def test_air_section_is_validated_live_and_round_trips():
    scene = load_scene("hang_two_corners")
    assert scene.air.density == 1.2 and scene.air.drag_coefficient == 1.2
    assert scene.air.wind == (0.0, 0.0, 0.0) and scene.material.air_drag == 0.0
    assert scene_from_dict(scene_to_dict(scene)) == scene
    windy = live_update(scene, {"air.wind": [2.0, 0.0, 0.0], "air.density": 1.0})
    assert windy.air.wind == (2.0, 0.0, 0.0) and windy.air.density == 1.0
    for bad, field in (({"air.density": -1.0}, "air.density"),
                       ({"air.wind": [1.0, 2.0]}, "air.wind"),
                       ({"air.wind": [0.0, float("nan"), 0.0]}, "air.wind[1]"),
                       ({"air.drag_coefficient": "big"}, "air.drag_coefficient")):
        with pytest.raises(SceneError, match=rf"'{field.replace('[', '.').replace(']', '.')}'"):
            live_update(scene, bad)
    with pytest.raises(SceneError, match="air.viscosity"):
        load_scene("hang_two_corners", ["air.viscosity=1e-5"])


def test_live_wind_reaches_a_running_simulation():
    sim = sheet(v_axis=(0.0, 0.0, 1.0), level=2)
    sim.step()
    assert np.allclose(sim.velocities[:, 1], 0.0)
    sim.update_parameters({"air.wind": [0.0, 5.0, 0.0]})
    sim.step()
    assert np.all(sim.velocities[:, 1] > 0.0)                  # blown along +y
