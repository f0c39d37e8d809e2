"""The compiled projection kernels against the numpy reference: bitwise where
no partly held particle is involved (those blocks are copies of the matrix's
or zeros, on both paths), to round-off where one is (products with the
projectors, summed in another order)."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings, strategies as st

from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.solve import backends, projection_kernels as pk
from cloth_lod_ros.sim.solve import projection
from cloth_lod_ros.sim.solve.constraints import Constraints

pytestmark = [pytest.mark.skipif(not runtime_compiled.available, reason="numba not installed"),
              pytest.mark.usefixtures("kernels_restored")]



def _system(seed, n=12, density=0.3):
    """An SPD BSR matrix with 3 × 3 blocks on a random particle graph (every
    diagonal block stored), a right-hand side and random constraints: fully
    held, sliding (``I − n nᵀ``) and one particle listed twice."""
    rng = np.random.default_rng(seed)
    coupled = np.triu(rng.random((n, n)) < density, 1)
    dense = np.zeros((3 * n, 3 * n))
    for r, c in zip(*np.nonzero(coupled)):
        block = rng.standard_normal((3, 3))
        dense[3 * r:3 * r + 3, 3 * c:3 * c + 3] = block
        dense[3 * c:3 * c + 3, 3 * r:3 * r + 3] = block.T
    for r in range(n):                      # symmetric, diagonally dominant: SPD
        block = rng.standard_normal((3, 3))
        dense[3 * r:3 * r + 3, 3 * r:3 * r + 3] = block + block.T \
            + (np.abs(dense[3 * r:3 * r + 3]).sum() + 7.0) * np.eye(3)
    matrix = sp.bsr_matrix(dense, blocksize=(3, 3))
    matrix.sort_indices()
    rhs = rng.standard_normal((n, 3))
    chosen = rng.choice(n, size=n // 2, replace=False)
    projectors = np.zeros((len(chosen), 3, 3))
    normals = rng.standard_normal((len(chosen), 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    sliding = rng.random(len(chosen)) < 0.5
    projectors[sliding] = np.eye(3) - normals[sliding, :, None] * normals[sliding, None, :]
    prescribed = rng.standard_normal((len(chosen), 3))
    indices = np.concatenate([chosen, chosen[:1]]).astype(np.int64)    # a duplicate: last wins
    projectors = np.concatenate([projectors, np.zeros((1, 3, 3))])
    prescribed = np.concatenate([prescribed, rng.standard_normal((1, 3))])
    return matrix, rhs, Constraints(indices, projectors, prescribed)


def _both(function, *args, **kwargs):
    runtime_compiled.use(False)
    reference = function(*args, **kwargs)
    runtime_compiled.use(True)
    return reference, function(*args, **kwargs)


def _partly_held(matrix, constraints):
    """Per block: whether a partly held particle (the last entry wins) is in
    its row or column and no fully held one is."""
    n = matrix.shape[0] // 3
    state = np.zeros(n, dtype=int)
    for i, s in zip(constraints.indices, constraints.projectors):
        state[i] = 1 if not s.any() else 2
    rows = np.repeat(np.arange(n), np.diff(matrix.indptr))
    cols = matrix.indices
    held = (state[rows] == 1) | (state[cols] == 1)
    return ((state[rows] == 2) | (state[cols] == 2)) & ~held


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_projected_system_matches_the_reference(seed):
    matrix, rhs, constraints = _system(seed)
    (data0, b0, z0), (data1, b1, z1) = _both(projection.projected_data, matrix, rhs, constraints)
    partial = _partly_held(matrix, constraints)
    assert data0[~partial].tobytes() == data1[~partial].tobytes()
    np.testing.assert_allclose(data1[partial], data0[partial], rtol=0, atol=1e-12 * abs(data0).max())
    np.testing.assert_allclose(z1, z0, rtol=0, atol=1e-14 * abs(z0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * abs(b0).max())
    # Â is symmetric: the compiled blocks too.
    dense = sp.bsr_matrix((data1, matrix.indices, matrix.indptr), shape=matrix.shape).toarray()
    np.testing.assert_allclose(dense, dense.T, atol=1e-12 * abs(dense).max())
    (b0, z0), (b1, z1) = _both(projection.projected_rhs, matrix, rhs, constraints)
    np.testing.assert_allclose(z1, z0, rtol=0, atol=1e-14 * abs(z0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * abs(b0).max())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_block_ldl_solve_matches_the_reference_and_holds_the_constraints(seed):
    matrix, rhs, constraints = _system(seed)
    results = []
    for compiled in (False, True):
        runtime_compiled.use(compiled)
        backend = backends.make_solver("block_ldl", 1e-8, 100)
        backend.reset_topology(None, None)
        results.append(backend.solve(matrix, rhs, constraints, None))
    reference, compiled = results
    np.testing.assert_allclose(compiled.dv, reference.dv, rtol=0,
                               atol=1e-10 * abs(reference.dv).max())
    assert compiled.converged and compiled.residual < 1e-10
    assert abs(compiled.residual - reference.residual) < 1e-12
    # Held directions exactly at the prescribed change (the last entry wins).
    last = {int(i): k for k, i in enumerate(constraints.indices)}
    for i, k in last.items():
        s = constraints.projectors[k]
        held = compiled.dv[i] - s @ compiled.dv[i]
        np.testing.assert_allclose(held, constraints.prescribed[k] - s @ constraints.prescribed[k],
                                   atol=1e-14)


def test_no_constraints_is_the_matrix_itself():
    matrix, rhs, _ = _system(3)
    runtime_compiled.use(True)
    data, b, z = projection.projected_data(matrix, rhs, Constraints.none())
    assert data.tobytes() == matrix.data.tobytes() and b.tobytes() == rhs.tobytes()
    assert not z.any()


def test_the_output_storage_is_reused():
    matrix, rhs, constraints = _system(4)
    runtime_compiled.use(True)
    storage = np.empty_like(matrix.data)
    data, _, _ = projection.projected_data(matrix, rhs, constraints, out=storage)
    assert data is storage
    data, _, _ = projection.projected_data(matrix, rhs, constraints, out=np.empty((1, 3, 3)))
    assert data.shape == matrix.data.shape      # a wrong shape is not written into


def test_inputs_the_kernels_do_not_take_go_to_the_reference():
    matrix, rhs, constraints = _system(5)
    runtime_compiled.use(True)
    outside = Constraints(np.array([0, matrix.shape[0] // 3]), np.zeros((2, 3, 3)),
                          np.zeros((2, 3)))
    assert pk.projected_data(matrix, rhs, outside) is None
    with pytest.raises(IndexError):
        projection.projected_data(matrix, rhs, outside)
    as_int32 = Constraints(constraints.indices.astype(np.int32), constraints.projectors,
                           constraints.prescribed)
    assert pk.projected_rhs(matrix, rhs, as_int32) is None
    runtime_compiled.use(False)
    assert pk.solution(matrix, rhs, constraints, np.zeros_like(rhs), rhs) is None
