"""The compiled kernels (physics/forces_kernels.py, hinges_kernels.py,
energies_kernels.py) equal the numpy reference (physics/forces.py, hinges.py,
energies.py; solve/pattern.py).

Forces, ``(∂f/∂x) v``, energies, hinge angles and gradients, element blocks and
assembled matrices on random deformed meshes, uniform and graded, with damping
and air, including degenerate-ish elements; and a short simulation.  All
float results are compared to tolerances (test/tolerances.py): the hinge
angles come from numpy's arctan2 on one side and the C library's on the
other, which may differ by a few ULP on some CPUs (AVX-512), and the
reference's sums (``np.einsum``, the assembly) are in an order and with
fused multiply-adds that depend on the numpy build.  The hinge gradients are
basic operations only, in the reference's order: bitwise on every CPU.
"""

from __future__ import annotations

import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("numba")

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.physics import forces_kernels
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.physics import hinges_kernels
from cloth_lod_ros.sim.physics import energies_kernels  # noqa: E402
from cloth_lod_ros.sim.scene.config import load_scene  # noqa: E402
from cloth_lod_ros.sim.physics.forces import evaluate as reference  # noqa: E402
from cloth_lod_ros.sim.physics.elements import precompute  # noqa: E402
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48  # noqa: E402
from cloth_lod_ros.sim.solve.pattern import PatternStorage, SparsePattern  # noqa: E402
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform  # noqa: E402
from tolerances import assert_close_ulps  # noqa: E402

RTOL = 1e-12


@pytest.fixture(autouse=True)
def compiled():
    """Every test starts on the compiled path and leaves the setting as found."""
    previous = runtime_compiled.use(True)
    yield
    runtime_compiled.use(previous)


def material(bs=0.01, bsh=0.02, bb=0.03):
    return SimpleNamespace(stretch_stiffness=100.0, shear_stiffness=20.0, bend_stiffness=1e-2,
                           stretch_damping=bs, shear_damping=bsh, bend_damping=bb)


AIR = SimpleNamespace(density=1.2, drag_coefficient=1.2, wind=(0.3, -0.1, 0.2))
STILL = SimpleNamespace(density=0.0, drag_coefficient=1.2, wind=(0.0, 0.0, 0.0))


def uniform_mesh(level=3):
    return refine_uniform(base_mesh(1.0, 0.5, 2, 1), level)


def graded_mesh(seed, refinements=40):
    base = base_mesh(1.0, 1.0, 2, 2)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(base.vertex_count)]), 1.0, 7)
    rng = np.random.default_rng(seed)
    for _ in range(refinements):
        tids = h.active_triangles()
        h.refine(int(tids[rng.integers(len(tids))]))
    return h.active_mesh()[0]


def deformed(mesh, seed, noise=0.05, stretch=1.0):
    rng = np.random.default_rng(seed)
    x = np.column_stack([stretch * mesh.uv, np.zeros(mesh.vertex_count)])
    x += rng.normal(scale=noise, size=x.shape)
    return x, rng.normal(scale=0.5, size=x.shape)


def both(elements, mat, x, v, air, with_blocks=True, pattern=None):
    """(compiled, reference) evaluations of one state (weights h², h at h = 1/120 s)."""
    h = 1.0 / 120.0
    ours = forces_kernels.evaluate(elements, mat, x, v, h * h, h, with_blocks, air, pattern)
    ref = reference(elements, mat, x, v, h * h, h, with_blocks, air)
    return ours, ref


def assert_close(actual, expected, rtol=RTOL, floor=0.0):
    """Equal to ``rtol`` relative to the largest entry or ``floor`` (NaNs in the
    same places): the forces, blocks and matrix entries are sums of element
    terms of about the largest entry's size, whose rounding differences
    (about 1e-16 of the terms, per term) do not shrink with the sum."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    finite = np.isfinite(expected)
    scale = max(np.abs(expected[finite]).max() if finite.any() else 1.0, floor)
    assert_close_ulps(actual, expected, abs_floor=rtol * scale)


def compare(ours, ref, floor=0.0):
    """``floor``: the force scale (N) for states where the forces are round-off
    (at rest), to which their differences are relative."""
    for name in ("force", "stiffness_times_velocity"):
        assert_close(getattr(ours, name), getattr(ref, name), floor=floor)
    for name in ("hinge_angle", "hinge_gradient"):
        assert_close(getattr(ours, name), getattr(ref, name))
    for name in ("stretch_energy", "shear_energy", "bend_energy", "max_strain"):
        assert getattr(ours, name) == pytest.approx(getattr(ref, name), rel=RTOL, abs=1e-300,
                                                    nan_ok=True)
    a, b = ours.triangle_blocks, ref.triangle_blocks
    if b is None:
        assert a is None
    else:
        assert_close(a, b)
    a, b = ours.hinge_blocks, ref.hinge_blocks          # one array per bend stencil kind
    if b is None:
        assert a is None
    else:
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_close(x, y)


def assembled_pair(elements, mat, x, v, air, storage=None):
    pattern = SparsePattern(elements.vertex_count, elements.element_vertices,
                            storage=storage)
    diagonal = np.linspace(0.5, 1.5, elements.vertex_count)
    fused, ref = both(elements, mat, x, v, air, pattern=pattern)
    assert fused.triangle_blocks is None and fused.assembled is not None
    ours = forces_kernels.assemble(pattern, fused, diagonal)
    unfused = forces_kernels.assemble(pattern, both(elements, mat, x, v, air)[0], diagonal)
    runtime_compiled.use(False)
    try:
        theirs = forces_kernels.assemble(pattern, ref, diagonal)
    finally:
        runtime_compiled.use(True)
    return pattern, fused, ref, ours, unfused, theirs, diagonal


@pytest.mark.parametrize("air", [None, AIR, STILL], ids=["no-air", "air", "still"])
@pytest.mark.parametrize("kind,seed", [("uniform", 0), ("uniform", 1), ("graded", 2),
                                       ("graded", 3)])
def test_evaluation_matches_reference(kind, seed, air):
    mesh = uniform_mesh() if kind == "uniform" else graded_mesh(seed)
    elements = precompute(mesh)
    for stretch in (1.0, 0.8, 1.2):          # tension, compression (the clamped term)
        x, v = deformed(mesh, seed, stretch=stretch)
        compare(*both(elements, material(), x, v, air))
        compare(*both(elements, material(), x, v, air, with_blocks=False))


@pytest.mark.parametrize("kind,seed", [("uniform", 4), ("graded", 5), ("graded", 6)])
def test_assembled_matrices_match_reference(kind, seed):
    mesh = uniform_mesh(4) if kind == "uniform" else graded_mesh(seed, 60)
    elements = precompute(mesh)
    x, v = deformed(mesh, seed, noise=0.1)
    _, fused, ref, ours, unfused, theirs, _ = assembled_pair(elements, material(), x, v, AIR)
    compare(fused, SimpleNamespace(**{**ref.__dict__, "triangle_blocks": None,
                                      "hinge_blocks": None}))
    # Each data entry is summed in element order, as np.bincount does, but of
    # blocks that are the kernels' and the reference's: to their tolerance.
    assert_close(ours.data, theirs.data)
    assert_close(unfused.data, theirs.data)
    np.testing.assert_array_equal(ours.indices, theirs.indices)
    np.testing.assert_array_equal(ours.indptr, theirs.indptr)


def test_assembled_data_is_not_modified_by_assembly():
    """A reused evaluation (a contact re-solve) assembles the same matrix again."""
    mesh = uniform_mesh(2)
    elements = precompute(mesh)
    x, v = deformed(mesh, 7)
    pattern, fused, _, first, _, _, diagonal = assembled_pair(elements, material(), x, v, None)
    again = forces_kernels.evaluate(elements, material(), x, v, 1e-4, 1e-2, pattern=pattern)
    a = forces_kernels.assemble(pattern, again, diagonal)
    b = forces_kernels.assemble(pattern, again, diagonal)
    np.testing.assert_array_equal(a.data, b.data)      # the same code twice: bitwise


def test_pattern_on_reused_storage_gives_the_same_matrix():
    storage = PatternStorage()
    for seed, refinements in ((8, 10), (9, 50), (10, 30)):
        mesh = graded_mesh(seed, refinements)
        elements = precompute(mesh)
        x, v = deformed(mesh, seed)
        pattern, _, _, ours, _, theirs, _ = assembled_pair(elements, material(), x, v, AIR,
                                                           storage)
        assert_close(ours.data, theirs.data)
        pattern.retire(storage)


def test_degenerate_elements_match_reference():
    """Flat hinges, a fold to ~π, a collapsed triangle (zero normal for the air),
    coincident vertices (NaN), a huge strain: the same numbers or NaNs as numpy."""
    mesh = uniform_mesh(2)
    elements = precompute(mesh)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    v = np.zeros_like(x)
    with np.errstate(all="ignore"):
        compare(*both(elements, material(), x, v, AIR), floor=1.0)      # rest, at rest
        folded = x.copy()
        right = folded[:, 0] > 0.5
        folded[right, 0] = 1.0 - folded[right, 0] + 1e-9                 # folded flat onto itself
        folded[right, 2] = 1e-7
        compare(*both(elements, material(), folded, v + 0.1, AIR), floor=1.0)
        collapsed = x.copy()
        t0 = elements.triangles[0]
        collapsed[t0[2]] = 0.5 * (collapsed[t0[0]] + collapsed[t0[1]])   # a zero-area face
        compare(*both(elements, material(), collapsed, v + 0.2, AIR), floor=1.0)
        coincident = x.copy()
        coincident[t0[1]] = coincident[t0[0]]                            # |w| = 0: NaN
        ours, ref = both(elements, material(), coincident, v + 0.3, AIR)
        assert np.isnan(ref.force).any()
        compare(ours, ref, floor=1.0)
        huge = 1e3 * x
        compare(*both(elements, material(), huge, v, AIR))


def test_numpy_switch_selects_the_reference():
    mesh = uniform_mesh(1)
    elements = precompute(mesh)
    x, v = deformed(mesh, 11)
    runtime_compiled.use(False)
    assert not runtime_compiled.enabled()
    ev = forces_kernels.evaluate(elements, material(), x, v, 1.0, 1.0)
    # Switched off, forces_kernels.evaluate is the reference's code: bitwise.
    np.testing.assert_array_equal(ev.force, reference(elements, material(), x, v, 1.0, 1.0).force)
    code = "from cloth_lod_ros.sim.runtime import compiled; print(compiled.enabled())"
    env = dict(os.environ, CLOTH_LOD_KERNELS="numpy")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"


def _trajectory(compiled: bool, overrides, steps):
    runtime_compiled.use(compiled)
    sim = ClothSim(load_scene("hang_two_corners", overrides))
    substeps = [(s.substeps, s.rejected_steps) for s in (sim.step() for _ in range(steps))]
    return sim.positions.copy(), sim.velocities.copy(), substeps, sim.time_step


def test_short_simulation_follows_the_reference():
    """Uniform mesh, no LOD: the same trajectory to round-off after a few steps.

    The two paths' forces differ by round-off (~1e-16 of the forces, more
    where numpy's arctan2 and the C library's differ); each implicit step
    turns that into a velocity difference of about u κ |v| (u = 2⁻⁵³, κ the
    condition number of its linear system), and the A-stable step does not
    amplify earlier differences, so they add up at most linearly: after k
    steps |Δv| ≤ k · 1e-10 · max|v| and |Δx| ≤ k h · that.  Measured after 6
    steps: 2e-14 m/s and 1e-16 m, here and with numpy's arctan2, tan and
    einsum moved by 1 ULP (a factor 2e4 under the bound; a 1e-6 relative
    change of the forces exceeds it).  The error control's step sizes are
    decisions on an error estimate: they must be the same (an estimate
    within round-off of its tolerance could split a step on one path only,
    with a chance of ~1e-12 per step)."""
    overrides = ["lod.enabled=false", "cloth.level=4"]
    steps = 6
    x1, v1, substeps1, h = _trajectory(True, overrides, steps)
    x0, v0, substeps0, _ = _trajectory(False, overrides, steps)
    assert substeps1 == substeps0
    dv = steps * 1e-10 * np.abs(v0).max()
    assert np.abs(v1 - v0).max() <= dv
    assert np.abs(x1 - x0).max() <= steps * h * dv


@pytest.mark.parametrize("kind,seed", [("uniform", 12), ("graded", 13)])
def test_measures_match_reference(kind, seed):
    """Hinge angles (to a few ULP: arctan2), gradients (bitwise: basic
    operations in the reference's order), stretch lengths and elastic energies
    (to round-off): what the LOD criterion, the step test and the stats use."""
    from cloth_lod_ros.sim.physics import hinges
    from cloth_lod_ros.sim.physics import energies
    mesh = uniform_mesh(3) if kind == "uniform" else graded_mesh(seed)
    elements = precompute(mesh)
    x, _ = deformed(mesh, seed, noise=0.1)
    hv = elements.hinge_vertices
    theta, grad = hinges_kernels.hinge_angles(x, hv, with_gradient=True)
    ref_theta, ref_grad = hinges.hinge_angles(x, hv, with_gradient=True)
    assert_close_ulps(theta, ref_theta)
    np.testing.assert_array_equal(grad, ref_grad)
    assert_close_ulps(hinges_kernels.hinge_angles(x, hv[:5]), ref_theta[:5])
    assert hinges_kernels.hinge_angles(x, hv[:0]).shape == (0,)
    assert_close(energies_kernels.stretch_lengths(elements, x),
                 energies.stretch_lengths(elements, x))
    ours = energies_kernels.elastic_energies(elements, material(), x)
    ref = energies.elastic_energies(elements, material(), x)
    assert ours == pytest.approx(ref, rel=RTOL)
