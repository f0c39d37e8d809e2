"""The block LDLᵀ (3 × 3 blocks, numba): a factorisation of the projected
system exact to round-off, the same fill as QDLDL's under the same ordering,
its analysis kept per topology, and a clear refusal of a singular system."""

import numpy as np
import pytest
import scipy.sparse as sp

from cloth_lod_ros.sim.solve import backends
from cloth_lod_ros.sim.solve.constraints import Constraints
from cloth_lod_ros.sim.solve.projection import project_system
from cloth_lod_ros.sim.solve.backends import make_solver, particle_ordering

from test_backends import constraints_for, system

block_ldl = pytest.importorskip("cloth_lod_ros.sim.solve.block_ldl")


def _factor(projected, held=None):
    n = projected.shape[0] // 3
    indptr, indices = projected.indptr.astype(np.int64), projected.indices.astype(np.int64)
    perm = particle_ordering(indptr, indices, n)
    pinv = np.empty(n, dtype=np.int64)
    pinv[perm] = np.arange(n)
    parent, pointers = block_ldl.symbolic(indptr, indices, perm, pinv)
    rows = np.empty(pointers[-1], dtype=np.int64)
    factor = np.empty((pointers[-1], 3, 3))
    inverse_diagonal = np.empty((n, 3, 3))
    failed = block_ldl.numeric(indptr, indices, np.ascontiguousarray(projected.data), perm,
                               pinv, parent, pointers, rows, factor, inverse_diagonal,
                               np.zeros(n, dtype=bool) if held is None else held)
    return failed, perm, pointers, rows, factor, inverse_diagonal


@pytest.mark.parametrize("level", [2, 3, 4])
def test_the_factor_reproduces_the_permuted_matrix(level):
    matrix, rhs, pattern, mesh = system(level)
    projected, _, _ = project_system(matrix, rhs, constraints_for(mesh), pattern)
    failed, perm, pointers, rows, factor, inverse_diagonal = _factor(projected)
    assert failed == -1
    n = len(perm)
    low = np.eye(3 * n)
    for j in range(n):
        for p in range(pointers[j], pointers[j + 1]):
            assert rows[p] > j                       # strictly below the diagonal
            low[3 * rows[p]:3 * rows[p] + 3, 3 * j:3 * j + 3] = factor[p]
    d = sp.block_diag(list(np.linalg.inv(inverse_diagonal))).toarray()
    dofs = (3 * perm[:, None] + np.arange(3)).ravel()
    a = projected.toarray()[np.ix_(dofs, dofs)]
    np.testing.assert_allclose(low @ d @ low.T, a, atol=1e-11 * np.abs(a).max())


def test_same_fill_as_the_scalar_factorisation_and_the_same_solution():
    qdldl = pytest.importorskip("qdldl")
    matrix, rhs, pattern, mesh = system(4, seed=2)
    constraints = constraints_for(mesh)
    projected, b, _ = project_system(matrix, rhs, constraints, pattern)
    failed, perm, pointers, rows, factor, inverse_diagonal = _factor(projected)
    x = block_ldl.solve(perm, pointers, rows, factor, inverse_diagonal, b)
    exact = np.linalg.solve(projected.toarray(), b.ravel())
    np.testing.assert_allclose(x.ravel(), exact, atol=1e-10 * np.abs(exact).max())
    upper = sp.triu(projected.tocsc(), format="csc")
    scalar = qdldl.Solver(upper, upper=True).factors()[0]
    # Blocks of L below the diagonal plus the strictly lower parts of the pivots.
    assert 9 * pointers[-1] + 3 * len(perm) == scalar.nnz


def test_the_backend_analyses_once_per_topology_and_agrees_with_qdldl(monkeypatch):
    matrix, rhs, pattern, mesh = system(3)
    analyses = []
    real = backends.particle_ordering
    monkeypatch.setattr(backends, "particle_ordering",
                        lambda *a: analyses.append(1) or real(*a))
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    direct = make_solver("direct", 1e-8, 100)
    direct.reset_topology(pattern, mesh.uv)
    for k in range(4):
        c = constraints_for(mesh, seed=k) if k % 2 else Constraints.none()
        got = backend.solve(matrix * (1.0 + 0.1 * k), rhs, c, None)
        want = direct.solve(matrix * (1.0 + 0.1 * k), rhs, c, None)
        assert got.converged and got.residual < 1e-10
        np.testing.assert_allclose(got.dv, want.dv, atol=1e-10 * np.abs(want.dv).max())
    assert len(analyses) == 1
    backend.reset_topology(pattern, mesh.uv)
    backend.solve(matrix, rhs, Constraints.none(), None)
    assert len(analyses) == 2


def test_a_singular_system_is_refused_with_a_linalg_error():
    matrix, rhs, pattern, mesh = system(2)
    broken = matrix.copy()
    broken.data[pattern.diagonal_block[3]] = 0.0
    for slot in np.flatnonzero(pattern.block_rows == 3):
        broken.data[slot] = 0.0                      # particle 3 couples to nothing
    for slot in np.flatnonzero(broken.indices == 3):
        broken.data[slot] = 0.0
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    with pytest.raises(np.linalg.LinAlgError, match="particle 3"):
        backend.solve(broken, rhs, Constraints.none(), None)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_held_particles_skipped_give_the_same_factor_bit_for_bit(seed):
    """Rows and columns of held particles are zero in L: writing them as zeros
    without their block updates changes no number of the factor."""
    matrix, rhs, pattern, mesh = system(4, seed=seed)
    n = mesh.vertex_count
    rng = np.random.default_rng(seed)
    held_ids = rng.choice(n, size=n // 4, replace=False)
    sliding = rng.choice(np.setdiff1d(np.arange(n), held_ids), size=n // 8, replace=False)
    nz = np.array([0.0, 0.0, 1.0])
    constraints = Constraints(
        np.concatenate([held_ids, sliding]),
        np.concatenate([np.zeros((len(held_ids), 3, 3)),
                        np.repeat((np.eye(3) - np.outer(nz, nz))[None], len(sliding), 0)]),
        rng.normal(scale=0.01, size=(len(held_ids) + len(sliding), 3)))
    projected, b, _ = project_system(matrix, rhs, constraints, pattern)
    held = np.zeros(n, dtype=bool)
    held[held_ids] = True
    plain = _factor(projected)
    skipped = _factor(projected, held)
    assert plain[0] == skipped[0] == -1
    for a, b_ in zip(plain[1:], skipped[1:]):
        np.testing.assert_array_equal(a, b_)
    # The backend finds the held particles itself, and its solve holds them.
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    result = backend.solve(matrix, rhs, constraints, None)
    assert result.converged
    np.testing.assert_array_equal(result.dv[held_ids], constraints.prescribed[:len(held_ids)])
    assert np.all(backends._held_particles(matrix, rhs, constraints) == held)
