"""Filtered PCG and assembly: constraints held exactly, tolerance reached, failures reported."""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from cloth_lod_ros.sim.physics.forces import evaluate
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, lumped_masses, refine_uniform
from cloth_lod_ros.sim.solve.constraints import Constraints
from cloth_lod_ros.sim.solve.pattern import SparsePattern
from cloth_lod_ros.sim.solve.pcg import filtered_pcg
from cloth_lod_ros.sim.solve.projection import solve_projected_direct

MATERIAL = SimpleNamespace(stretch_stiffness=2000.0, shear_stiffness=200.0,
                           bend_stiffness=2e-4, stretch_damping=0.01,
                           shear_damping=0.01, bend_damping=0.1)


def cloth_system(level, seed=0, h=1 / 60, stiffness_scale=1.0):
    """A real system matrix and right-hand side from a deformed cloth."""
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
    el = precompute(mesh)
    rng = np.random.default_rng(seed)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    x += rng.normal(scale=0.01, size=x.shape)
    v = rng.normal(scale=0.3, size=x.shape)
    mat = SimpleNamespace(**{**vars(MATERIAL),
                             "stretch_stiffness": MATERIAL.stretch_stiffness * stiffness_scale})
    ev = evaluate(el, mat, x, v, h * h, h)
    masses = lumped_masses(mesh.uv, mesh.triangles, 0.2)
    pattern = SparsePattern(mesh.vertex_count, el.element_vertices)
    matrix = pattern.assemble(ev.blocks, masses)
    rhs = h * (ev.force + masses[:, None] * np.array([0, 0, -9.81])
               + h * ev.stiffness_times_velocity)
    return matrix, rhs, pattern.diagonal_blocks(matrix), mesh


def plane_projector(normal):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    return np.eye(3) - np.outer(n, n)


def make_constraints(kind, n, rng):
    if kind == "free":
        return Constraints.none()
    idx = rng.choice(n, size=max(2, n // 20), replace=False)
    if kind == "pins":
        proj = np.zeros((len(idx), 3, 3))
    elif kind == "planes":
        proj = np.array([plane_projector(rng.normal(size=3)) for _ in idx])
    else:  # mixed: half fully held, half held along a normal
        proj = np.array([np.zeros((3, 3)) if k % 2 else plane_projector(rng.normal(size=3))
                         for k in range(len(idx))])
    return Constraints(idx, proj, rng.normal(scale=0.5, size=(len(idx), 3)))


CASES = [(level, kind, tol, scale)
         for level, kind, tol, scale in [
             (2, "free", 1e-6, 1.0), (2, "pins", 1e-6, 1.0), (3, "planes", 1e-5, 1.0),
             (4, "mixed", 1e-4, 1.0), (4, "pins", 1e-8, 1.0), (3, "mixed", 1e-6, 100.0),
             (5, "pins", 1e-4, 1.0), (5, "mixed", 1e-6, 100.0)]]


@pytest.mark.parametrize("level,kind,tol,scale", CASES)
def test_filtered_pcg_reaches_tolerance_and_holds_constraints(level, kind, tol, scale):
    matrix, rhs, diag, _ = cloth_system(level, seed=level, stiffness_scale=scale)
    rng = np.random.default_rng(level + 100)
    cons = make_constraints(kind, len(rhs), rng)
    result = filtered_pcg(matrix, rhs, cons, diag, tolerance=tol, max_iterations=20000)
    assert result.converged and result.residual <= tol
    assert result.iterations > 0
    # Held directions take exactly the prescribed change (rounding only).
    if len(cons.indices):
        held = lambda a: a - np.einsum("kab,kb->ka", cons.projectors, a)  # noqa: E731
        np.testing.assert_allclose(held(result.dv[cons.indices]), held(cons.prescribed),
                                   rtol=0, atol=1e-13)
    # Same answer as the direct solve of the projected system.
    direct = solve_projected_direct(matrix, rhs, cons)
    assert direct.residual < 1e-10
    scale_dv = np.abs(direct.dv).max()
    assert np.abs(result.dv - direct.dv).max() <= 50 * tol * scale_dv * np.sqrt(len(rhs))


def test_fully_held_components_are_bitwise_exact():
    matrix, rhs, diag, _ = cloth_system(3)
    rng = np.random.default_rng(1)
    cons = make_constraints("pins", len(rhs), rng)
    result = filtered_pcg(matrix, rhs, cons, diag, tolerance=1e-6)
    np.testing.assert_array_equal(result.dv[cons.indices], cons.prescribed)


def test_non_convergence_is_reported():
    matrix, rhs, diag, _ = cloth_system(4)
    result = filtered_pcg(matrix, rhs, Constraints.none(), diag, tolerance=1e-8,
                          max_iterations=3)
    assert result.iterations == 3
    assert not result.converged
    assert result.residual > 1e-8


def test_warm_start_from_the_solution_needs_no_iterations():
    matrix, rhs, diag, _ = cloth_system(3)
    cons = make_constraints("pins", len(rhs), np.random.default_rng(2))
    first = filtered_pcg(matrix, rhs, cons, diag, tolerance=1e-6)
    again = filtered_pcg(matrix, rhs, cons, diag, guess=first.dv, tolerance=1e-6)
    assert again.iterations == 0 and again.converged


def test_zero_right_hand_side_gives_zero():
    matrix, rhs, diag, _ = cloth_system(2)
    result = filtered_pcg(matrix, np.zeros_like(rhs), Constraints.none(), diag)
    assert result.converged and result.iterations == 0
    np.testing.assert_array_equal(result.dv, 0.0)


def test_pattern_assembly_matches_a_dense_reference():
    mesh = refine_uniform(base_mesh(1.0, 1.0, 2, 2), 2)
    el = precompute(mesh)
    rng = np.random.default_rng(3)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)]) + rng.normal(
        scale=0.05, size=(mesh.vertex_count, 3))
    ev = evaluate(el, MATERIAL, x, rng.normal(size=x.shape), 1e-3, 1e-2)
    diagonal = rng.uniform(1, 2, size=mesh.vertex_count)
    pattern = SparsePattern(mesh.vertex_count, el.element_vertices)
    assembled = pattern.assemble(ev.blocks, diagonal)
    reference = np.zeros((3 * mesh.vertex_count,) * 2)
    for verts, blocks in zip(el.element_vertices, ev.blocks):
        for e, vs in enumerate(verts):                       # loops: reference only
            for i, vi in enumerate(vs):
                for j, vj in enumerate(vs):
                    reference[3 * vi:3 * vi + 3, 3 * vj:3 * vj + 3] += blocks[e, i, :, j, :]
    reference += np.kron(np.diag(diagonal), np.eye(3))
    np.testing.assert_allclose(assembled.toarray(), reference, rtol=1e-13, atol=1e-15)
    blocks = pattern.diagonal_blocks(assembled)
    dense = assembled.toarray()
    for i in range(mesh.vertex_count):
        np.testing.assert_array_equal(blocks[i], dense[3 * i:3 * i + 3, 3 * i:3 * i + 3])
    assert sp.issparse(assembled) and assembled.blocksize == (3, 3)


def test_csr_operator_products_equal_scipys():
    """CsrOperator calls scipy's compiled CSR kernel directly: same numbers as
    ``A @ x``, for any sparse input format, and falls back for other inputs."""
    from cloth_lod_ros.sim.solve.sparse import CsrOperator
    rng = np.random.default_rng(5)
    a = sp.random(60, 45, density=0.1, random_state=7, format="coo")
    a = sp.coo_matrix((np.concatenate([a.data, [1.5]]), (np.concatenate([a.row, [a.row[0]]]),
                                                          np.concatenate([a.col, [a.col[0]]]))),
                      shape=a.shape)                  # a duplicate entry, summed
    x = rng.normal(size=45)
    op = CsrOperator(a)
    np.testing.assert_allclose(op @ x, a.tocsr() @ x, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(op @ x[::-1][::-1].copy(), a @ x, rtol=1e-14, atol=1e-14)
    block = rng.normal(size=(45, 2))
    np.testing.assert_allclose(op @ block, a @ block, rtol=1e-14)
    assert op.shape == (60, 45)
