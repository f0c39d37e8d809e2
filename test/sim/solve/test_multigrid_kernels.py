"""The compiled block V-cycle against the scipy reference (multigrid.VCycle):
the same operators and the same cycle, to round-off."""

import numpy as np
import pytest
import scipy.sparse as sp

from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.solve import backends, multigrid, multigrid_kernels as mk
from cloth_lod_ros.sim.solve import projection
from cloth_lod_ros.sim.solve import sparse
from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import load_scene

pytestmark = [pytest.mark.skipif(not runtime_compiled.available, reason="numba not installed"),
              pytest.mark.usefixtures("kernels_restored")]



def _captured_system(overrides):
    """The first projected system a multigrid solve of a scene sees, with its
    backend (pattern, lattice)."""
    captured = []
    original = backends.Multigrid.solve

    def solve(self, matrix, rhs, constraints, guess):
        if not captured:
            captured.append((self, matrix.copy(), rhs.copy(), constraints))
        return original(self, matrix, rhs, constraints, guess)

    # Built before the patch: building runs the kernels' warm-up, whose tiny
    # cloth's solves are not the scene's.
    sim = ClothSim(load_scene("hang_two_corners", ["solver.method=multigrid", *overrides]))
    backends.Multigrid.solve = solve
    try:
        sim.step()
    finally:
        backends.Multigrid.solve = original
    backend, matrix, rhs, constraints = captured[0]
    projected, _, _ = projection.project_system(matrix, rhs, constraints, backend.pattern)
    lattice = multigrid.lattice_hierarchy(backend.uv, *backend.geometry)
    return projected, lattice


@pytest.mark.parametrize("overrides", [["cloth.level=6", "lod.enabled=false"],
                                       ["cloth.level=6"]])
def test_block_v_cycle_is_the_reference_cycle(overrides):
    projected, lattice = _captured_system(overrides)
    assert lattice, "the case must coarsen"
    arrays = mk.block_arrays(projected)
    inverse = mk.inverse_diagonal_blocks(*arrays)
    reference = multigrid.VCycle(projected.tocsr(), sparse.block_diagonal_matrix(inverse),
                                 multigrid.block_transfers(lattice))
    compiled = mk.BlockVCycle(arrays, inverse, lattice)
    for ours, theirs in zip(compiled.levels, reference.levels):
        assert ours[4] == pytest.approx(theirs[4], rel=1e-12)     # Chebyshev intervals
    r = np.random.default_rng(0).standard_normal(projected.shape[0])
    expected = reference(r)
    np.testing.assert_allclose(compiled(r), expected, rtol=0, atol=1e-12 * abs(expected).max())
    # A symmetric preconditioner, as CG needs.
    s = np.random.default_rng(1).standard_normal(projected.shape[0])
    assert s @ compiled(r) == pytest.approx(r @ compiled(s), rel=1e-10)


def test_galerkin_product_equals_the_sparse_triple_product():
    projected, lattice = _captured_system(["cloth.level=6", "lod.enabled=false"])
    arrays = mk.block_arrays(projected)
    p = lattice[0].tocsr()
    r = p.T.tocsr()
    as_int = (lambda m: (m.indptr.astype(np.int64), m.indices.astype(np.int64), m.data))
    indptr, indices, data = mk._galerkin(*arrays, *as_int(p), *as_int(r), p.shape[1])
    p3 = sp.kron(p, sp.identity(3), format="csr")
    expected = (p3.T @ projected.tocsr() @ p3).toarray()
    ours = sp.bsr_matrix((data, indices, indptr), shape=expected.shape).toarray()
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-12 * abs(expected).max())
    assert np.all(np.diff(indptr) > 0)


def test_block_operator_is_the_matrix_product():
    projected, _ = _captured_system(["cloth.level=4", "lod.enabled=false"])
    x = np.random.default_rng(2).standard_normal(projected.shape[0])
    np.testing.assert_allclose(mk.BlockOperator(mk.block_arrays(projected)) @ x,
                               projected @ x, rtol=0, atol=1e-13 * abs(projected @ x).max())


def test_multigrid_steps_agree_compiled_and_reference():
    """Same scene, both paths: the CG iterates differ by round-off only, so
    the positions agree far inside the solver tolerance."""
    positions = []
    for compiled in (False, True):
        runtime_compiled.use(compiled)
        sim = ClothSim(load_scene("hang_two_corners", ["solver.method=multigrid",
                                                       "cloth.level=6", "lod.enabled=false"]))
        stats = [sim.step() for _ in range(5)]
        assert all(s.solver == "multigrid" for s in stats)
        positions.append(sim.positions.copy())
    assert np.abs(positions[0] - positions[1]).max() < 1e-7


def test_inverse_blocks_match_numpy_and_refuse_singular_blocks():
    rng = np.random.default_rng(3)
    blocks = rng.standard_normal((50, 3, 3))
    np.testing.assert_allclose(mk.inverse_blocks(blocks), np.linalg.inv(blocks), rtol=1e-9,
                               atol=1e-12)
    blocks[7] = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 0.0]]
    with pytest.raises(np.linalg.LinAlgError, match="row 7"):
        mk.inverse_blocks(blocks)
    blocks[7] = np.eye(3)
    blocks[9, 1, 1] = np.nan
    with pytest.raises(np.linalg.LinAlgError, match="row 9"):
        mk.inverse_blocks(blocks)
