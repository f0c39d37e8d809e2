"""Sparse products without scipy's per-call dispatch, and block-diagonal
matrices: what the iterative solvers multiply with hundreds of times a step.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["CsrOperator", "bsr_product", "block_diagonal_matrix"]


try:        # the compiled kernel behind scipy's CSR products (see CsrOperator)
    from scipy.sparse._sparsetools import bsr_matvec as _bsr_matvec
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec
except ImportError:             # pragma: no cover - a scipy without it
    _bsr_matvec = _csr_matvec = None


def bsr_product(matrix: sp.bsr_matrix, x: np.ndarray) -> np.ndarray:
    """``A x`` for a BSR matrix with 3 × 3 blocks and ``x`` ``(n, 3)``, returned
    ``(n, 3)``: scipy's compiled kernel without its per-call checks (which cost
    as much as the product at a few thousand unknowns; cf. :class:`CsrOperator`).
    Any other matrix is multiplied the ordinary way."""
    if _bsr_matvec is None or getattr(matrix, "blocksize", None) != (3, 3) \
            or matrix.format != "bsr" or matrix.data.dtype != np.float64:
        return (matrix @ x.ravel()).reshape(-1, 3)
    n_rows = matrix.shape[0] // 3
    y = np.zeros(3 * n_rows)
    _bsr_matvec(n_rows, matrix.shape[1] // 3, 3, 3, matrix.indptr, matrix.indices,
                matrix.data.ravel(), np.ascontiguousarray(x, dtype=np.float64).ravel(), y)
    return y.reshape(-1, 3)


def block_diagonal_matrix(blocks: np.ndarray) -> sp.csr_matrix:
    """Block-diagonal CSR matrix from ``(n, 3, 3)`` blocks (no sorting needed)."""
    n = len(blocks)
    indptr = np.arange(0, 9 * n + 1, 3, dtype=np.int32)
    indices = (3 * np.arange(n, dtype=np.int32)[:, None, None]
               + np.arange(3, dtype=np.int32)[None, None, :]).repeat(3, 1).ravel()
    return sp.csr_matrix((np.ascontiguousarray(blocks).ravel(), indices, indptr),
                         shape=(3 * n, 3 * n))


class CsrOperator:
    """``y = A x`` for a fixed CSR matrix without scipy's per-call dispatch.

    The iterative solvers multiply small matrices by vectors hundreds of times
    per step (CG: one product per iteration; the V-cycle: ~28 over its levels);
    ``A @ x`` spends more time in scipy's Python-level checks than in the
    product itself at these sizes (measured: 1.3 s of 2.0 s on uniform L6), so
    this calls the same compiled kernel directly.  Falls back to ``A @ x`` if
    that kernel is missing or ``x`` is not a float vector.

    Args:
        matrix: any scipy sparse matrix (converted to CSR, float64).
    """

    __slots__ = ("matrix", "shape", "_indptr", "_indices", "_data")

    def __init__(self, matrix):
        m = sp.csr_matrix(matrix, dtype=np.float64)
        m.sum_duplicates()
        self.matrix, self.shape = m, m.shape
        self._indptr, self._indices, self._data = m.indptr, m.indices, m.data

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        if _csr_matvec is None or x.ndim != 1 or x.dtype != np.float64:
            return self.matrix @ x
        y = np.zeros(self.shape[0])
        _csr_matvec(self.shape[0], self.shape[1], self._indptr, self._indices, self._data,
                    np.ascontiguousarray(x), y)
        return y
