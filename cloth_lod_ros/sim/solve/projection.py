"""The projected system of a filtered step, ``Â = S A S + (I − S) D (I − S)``,
``b̂ = S (b − A z)`` (BW §5.3, design §3), the residual every backend
reports, and the SuperLU baseline on it.  Compiled:
:mod:`.projection_kernels`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import projection_kernels as _projection
from .constraints import Constraints, SolveResult
from .pattern import SparsePattern
from .sparse import bsr_product

__all__ = ["project_system", "projected_data", "projected_rhs", "relative_residual",
           "solve_projected_direct"]


def project_system(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints,
                   pattern: SparsePattern | None = None):
    """The projected system ``Â y = b̂`` of a filtered step, on the topology's pattern.

    ``Â = S A S + (I − S) D (I − S)`` (D: the 3 × 3 diagonal blocks of A) is SPD,
    equals ``S A S`` on the free subspace and has A's scale in the held
    directions; ``b̂ = S (b − A z)``.  Then ``Δv = z + S y`` solves the filtered
    problem.  Only blocks in a constrained row or column change, so ``Â`` keeps
    A's sparsity pattern (explicit zeros included): a factorisation's symbolic
    analysis stays valid for the whole topology.

    A fully held particle (``S_i = 0``: pins, sticking contacts, most of the
    constraints) zeroes its row and column and keeps its diagonal block, so
    only blocks between partly held particles (sliding contacts) and their
    neighbours need the 3 × 3 products (BW §5.3).

    Args:
        matrix: A, BSR with 3 × 3 blocks (every diagonal block stored).
        rhs: ``(n, 3)`` b.  constraints: S and z.
        pattern: A's :class:`SparsePattern` if the caller has it (saves
            finding the block rows and diagonal blocks again).

    Returns:
        ``(Â as BSR, b̂ (n, 3), z (n, 3))``.
    """
    data, b, z = projected_data(matrix, rhs, constraints, pattern)
    projected = sp.bsr_matrix((data, matrix.indices, matrix.indptr), shape=matrix.shape)
    return projected, b, z


def projected_data(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints,
                   pattern: SparsePattern | None = None, out: np.ndarray | None = None):
    """:func:`project_system` without building the BSR matrix: ``(Â's data
    (blocks, 3, 3) on A's pattern, b̂ (n, 3), z (n, 3))``.  Compiled where
    numba is (:mod:`.projection_kernels`, writing ``Â`` into ``out`` if it has
    the right shape); the numpy below is the reference."""
    fast = _projection.projected_data(matrix, rhs, constraints, out)
    if fast is not None:
        return fast
    n = rhs.shape[0]
    z = constraints.start(np.zeros_like(rhs))
    data = matrix.data.copy()
    b = rhs
    if len(constraints.indices):
        # The last entry of a particle listed twice wins, as in Constraints.filter.
        last = len(constraints.indices) - 1 - np.unique(constraints.indices[::-1],
                                                        return_index=True)[1]
        indices, filters = constraints.indices[last], constraints.projectors[last]
        zero = np.zeros(n, dtype=bool)
        partial = np.zeros(n, dtype=bool)
        is_zero = ~filters.reshape(-1, 9).any(axis=1)
        zero[indices[is_zero]] = True
        partial[indices[~is_zero]] = True
        cols = matrix.indices
        if pattern is not None:
            rows, diagonal_block = pattern.block_rows, pattern.diagonal_block
        else:
            rows = np.repeat(np.arange(n), np.diff(matrix.indptr))
            diagonal_block = np.flatnonzero(rows == cols)       # one per row, in row order
        # Blocks in a fully held row or column vanish (their diagonal block is
        # put back below: (I − 0) D (I − 0) = D).
        data[zero[rows] | zero[cols]] = 0.0
        full_diagonal = diagonal_block[indices[is_zero]]
        data[full_diagonal] = matrix.data[full_diagonal]
        if partial.any():
            projectors = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            projectors[indices[~is_zero]] = filters[~is_zero]
            mixed = np.flatnonzero((partial[rows] | partial[cols])
                                   & ~(zero[rows] | zero[cols]))
            data[mixed] = projectors[rows[mixed]] @ matrix.data[mixed] \
                @ projectors[cols[mixed]]
            diagonal = diagonal_block[indices[~is_zero]]
            complement = np.eye(3) - filters[~is_zero]
            data[diagonal] += complement @ matrix.data[diagonal] @ complement
        b = constraints.filter(rhs - bsr_product(matrix, z))
    return data, b, z


def projected_rhs(matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints):
    """``(b̂, z)`` of :func:`projected_data` without ``Â`` (both ``(n, 3)``):
    for a solve that reuses a factorisation of the same ``Â``."""
    if not len(constraints.indices):
        return rhs, np.zeros_like(rhs)
    fast = _projection.projected_rhs(matrix, rhs, constraints)
    if fast is not None:
        return fast
    z = constraints.start(np.zeros_like(rhs))
    return constraints.filter(rhs - bsr_product(matrix, z)), z


def relative_residual(matrix, rhs: np.ndarray, constraints: Constraints,
                      dv: np.ndarray) -> float:
    """``|S(b − A Δv)| / |S b|`` (0 if ``S b`` = 0): the measure every backend reports."""
    residual = constraints.filter(rhs - bsr_product(matrix, dv))
    norm_b = float(np.linalg.norm(constraints.filter(rhs)))
    return float(np.linalg.norm(residual)) / norm_b if norm_b > 0 else 0.0


def solve_projected_direct(matrix, rhs: np.ndarray, constraints: Constraints,
                           pattern: SparsePattern | None = None) -> SolveResult:
    """Direct baseline: SuperLU (symmetric mode) of :func:`project_system`'s
    system, analysed anew at every call (design §3); ``Δv = z + S y``."""
    if not (sp.isspmatrix_bsr(matrix) and matrix.blocksize == (3, 3)):
        matrix = sp.bsr_matrix(matrix, blocksize=(3, 3))
    projected, b, z = project_system(matrix, rhs, constraints, pattern)
    lu = spla.splu(projected.tocsc(), permc_spec="MMD_AT_PLUS_A",
                   diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    dv = z + constraints.filter(lu.solve(b.ravel()).reshape(-1, 3))
    rel = relative_residual(matrix, rhs, constraints, dv)
    return SolveResult(dv=dv, iterations=0, residual=rel, converged=bool(np.isfinite(rel)))
