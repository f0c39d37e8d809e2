"""Sparse LDLᵀ on 3 × 3 blocks, compiled with numba (design §3).

The projected system of a step (:func:`~cloth_lod_ros.sim.solve.projection.project_system`,
``S A S + (I − S) D (I − S)``, SPD) has one 3 × 3 block per pair of coupled
particles.  A scalar LDLᵀ (QDLDL) spends its time on index arithmetic per
scalar entry; here the unknowns of a particle stay together, so every index
step carries 9 numbers and 27 multiply-adds, and the factor is ``L`` (unit
lower block-triangular, ``(blocks, 3, 3)``) and the inverses of the 3 × 3
diagonal blocks ``D_k``.  Same fill as the scalar factorisation under the same
ordering (the particle graph's); measured on a ``grasp_lift`` system of 1,083
unknowns: 0.8–1.1 ms against QDLDL's 2.9 ms, back-substitution 0.05 against
0.12 ms (README, Linear solvers).

The algorithm is the up-looking one of QDLDL (T. Davis, "Algorithm 849: a
concise sparse Cholesky factorization package", 2005), on blocks:

* per topology, :func:`symbolic`: the elimination tree and the number of
  blocks in every column of ``L`` (the ordering comes from the caller);
* per solve, :func:`numeric`: row ``k`` of ``L`` solves
  ``L₀:ₖ D₀:ₖ L(k, :)ᵀ = A(0:k, k)`` by a sparse forward substitution along the
  elimination tree, then ``D_k = A(k, k) − Σ_i L(k, i) D_i L(k, i)ᵀ``;
* :func:`solve`: forward substitution, ``D⁻¹``, back substitution.

This module imports numba at its top: import it only where numba is wanted
(:mod:`~cloth_lod_ros.sim.solve.backends` does so lazily).  Kernels are cached on disk
(``cache=True``): the first run on a machine compiles them (a few seconds), later
processes load them.
"""

from __future__ import annotations

import numba
import numpy as np

from ..runtime import compiled  # noqa: F401  (keys the kernels' cache: before they are decorated)
__all__ = ["symbolic", "numeric", "factor_rows", "solve", "forward_part", "back_part"]


@numba.njit(cache=True)
def symbolic(indptr, indices, perm, pinv):
    """Elimination tree and column pointers of ``L`` for ``P A Pᵀ``.

    Args:
        indptr, indices: ``(n + 1,)``, ``(blocks,)`` int64: A's block pattern
            (BSR; symmetric, every diagonal block present).
        perm: ``(n,)`` int64, ``perm[k]`` = the particle eliminated k-th.
        pinv: ``(n,)`` int64, its inverse.

    Returns:
        ``(parent (n,), column_pointers (n + 1,))``: ``parent[k]`` = the
        elimination-tree parent of k (−1 for a root); column k of ``L`` has
        ``column_pointers[k + 1] − column_pointers[k]`` blocks.
    """
    n = len(perm)
    parent = np.full(n, -1, np.int64)
    flag = np.full(n, -1, np.int64)
    counts = np.zeros(n, np.int64)
    for k in range(n):
        flag[k] = k
        row = perm[k]
        for p in range(indptr[row], indptr[row + 1]):
            i = pinv[indices[p]]
            # Every i < k coupled to k, and its path up the tree, gets L(k, ·).
            while i < k and flag[i] != k:
                if parent[i] == -1:
                    parent[i] = k
                counts[i] += 1
                flag[i] = k
                i = parent[i]
    column_pointers = np.zeros(n + 1, np.int64)
    for k in range(n):
        column_pointers[k + 1] = column_pointers[k] + counts[k]
    return parent, column_pointers


@numba.njit(cache=True)
def numeric(indptr, indices, data, perm, pinv, parent, column_pointers,
            rows, factor, inverse_diagonal, held):
    """Numeric factorisation ``P A Pᵀ = L D Lᵀ``, written into the arrays given.

    Args:
        indptr, indices, data: A in BSR (``data`` ``(blocks, 3, 3)``, float64;
            only its numbers change between calls for one topology).
        perm, pinv, parent, column_pointers: the ordering and :func:`symbolic`'s
            output.
        held: ``(n,)`` bool by particle: particles whose off-diagonal blocks
            in ``A`` are all zero (held ones in a projected system: a pin, a
            sticking contact).  Their rows and columns of ``L`` are zero, so
            they are written as zeros without the block updates that would
            compute them (the same numbers: the updates only add ``0 · L``).
        rows: ``(nnz_L,)`` int64, out: the block row of every stored block of ``L``.
        factor: ``(nnz_L, 3, 3)`` out: the blocks ``L(rows[p], j)`` of column j at
            ``column_pointers[j]:column_pointers[j + 1]``.
        inverse_diagonal: ``(n, 3, 3)`` out: ``D_k⁻¹``.

    Returns:
        −1 on success, else the position k whose pivot block was singular
        or not finite (the matrix is not definite).
    """
    return factor_rows(indptr, indices, data, perm, pinv, parent, column_pointers, rows,
                       factor, inverse_diagonal, held, len(perm), np.zeros((0, 0, 3, 3)))


@numba.njit(cache=True)
def factor_rows(indptr, indices, data, perm, pinv, parent, column_pointers, rows, factor,
                inverse_diagonal, held, first, schur):
    """:func:`numeric` for the positions before ``first``; the rows from
    ``first`` on (the trailing block, :mod:`cloth_lod_ros.sim.solve.trailing_ldl`) get their blocks
    in the columns before ``first`` (``L_CI``), and ``schur`` ``(c, c, 3, 3)``
    gets ``T = A_CC − L_CI D_I L_CIᵀ`` (position ``first + a`` is ``schur[a]``);
    nothing is eliminated there.  Returns −1, or the position of a singular
    pivot block before ``first``."""
    n = len(perm)
    filled = np.zeros(n, np.int64)          # blocks of column i written so far
    flag = np.full(n, -1, np.int64)
    work = np.zeros((n, 3, 3))              # the sparse column A(0:k, k), then y
    stack = np.empty(n, np.int64)
    path = np.empty(n, np.int64)
    pivot = np.empty((3, 3))
    for k in range(n):
        flag[k] = k
        row = perm[k]
        top = n
        row_held = held[row]
        for p in range(indptr[row], indptr[row + 1]):
            i = pinv[indices[p]]
            if i == k:
                for a in range(3):
                    for b in range(3):
                        pivot[a, b] = data[p, a, b]
            elif i < k:
                # A(i, k) = A(k, i)ᵀ, and the BSR row of particle perm[k] holds A(k, i).
                for a in range(3):
                    for b in range(3):
                        work[i, a, b] = data[p, b, a]
                # The nodes this entry reaches in the tree, pushed in topological order.
                m = 0
                while flag[i] != k:
                    path[m] = i
                    m += 1
                    flag[i] = k
                    i = parent[i]
                while m > 0:
                    m -= 1
                    top -= 1
                    stack[top] = path[m]
        for t in range(top, n):
            i = stack[t]
            y = work[i]
            if i >= first:
                # Row k of the trailing block: y is T(i, k), final (every
                # interior column has updated it); no elimination here.
                for a in range(3):
                    for b in range(3):
                        schur[i - first, k - first, a, b] = y[a, b]
                        schur[k - first, i - first, b, a] = y[a, b]
                        y[a, b] = 0.0
                continue
            if row_held or held[perm[i]]:
                # y_i is zero (row k or row i of L is): L(k, i) = 0, nothing to update.
                q = column_pointers[i] + filled[i]
                rows[q] = k
                factor[q, :, :] = 0.0
                filled[i] += 1
                y[:, :] = 0.0
                continue
            y00, y01, y02 = y[0, 0], y[0, 1], y[0, 2]
            y10, y11, y12 = y[1, 0], y[1, 1], y[1, 2]
            y20, y21, y22 = y[2, 0], y[2, 1], y[2, 2]
            # y_r −= L(r, i) y_i for the rows r of column i found so far.
            for p in range(column_pointers[i], column_pointers[i] + filled[i]):
                low = factor[p]
                out = work[rows[p]]
                for a in range(3):
                    l0, l1, l2 = low[a, 0], low[a, 1], low[a, 2]
                    out[a, 0] -= l0 * y00 + l1 * y10 + l2 * y20
                    out[a, 1] -= l0 * y01 + l1 * y11 + l2 * y21
                    out[a, 2] -= l0 * y02 + l1 * y12 + l2 * y22
            # L(k, i) = y_iᵀ D_i⁻¹ and D_k −= L(k, i) y_i.
            q = column_pointers[i] + filled[i]
            rows[q] = k
            d_inv = inverse_diagonal[i]
            new = factor[q]
            for a in range(3):
                for b in range(3):
                    new[a, b] = y[0, a] * d_inv[0, b] + y[1, a] * d_inv[1, b] \
                        + y[2, a] * d_inv[2, b]
            for a in range(3):
                for b in range(3):
                    pivot[a, b] -= new[a, 0] * y[0, b] + new[a, 1] * y[1, b] \
                        + new[a, 2] * y[2, b]
            filled[i] += 1
            for a in range(3):
                for b in range(3):
                    y[a, b] = 0.0
        if k >= first:
            for a in range(3):
                for b in range(3):
                    schur[k - first, k - first, a, b] = 0.5 * (pivot[a, b] + pivot[b, a])
            continue
        # D_k⁻¹ by cofactors of the symmetric part (D_k is symmetric up to round-off).
        a00, a11, a22 = pivot[0, 0], pivot[1, 1], pivot[2, 2]
        a01 = 0.5 * (pivot[0, 1] + pivot[1, 0])
        a02 = 0.5 * (pivot[0, 2] + pivot[2, 0])
        a12 = 0.5 * (pivot[1, 2] + pivot[2, 1])
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        det = a00 * c00 + a01 * c01 + a02 * c02
        if not (det != 0.0 and np.isfinite(det)):
            return k
        inv = 1.0 / det
        d_inv = inverse_diagonal[k]
        d_inv[0, 0] = c00 * inv
        d_inv[0, 1] = d_inv[1, 0] = c01 * inv
        d_inv[0, 2] = d_inv[2, 0] = c02 * inv
        d_inv[1, 1] = (a00 * a22 - a02 * a02) * inv
        d_inv[1, 2] = d_inv[2, 1] = (a01 * a02 - a00 * a12) * inv
        d_inv[2, 2] = (a00 * a11 - a01 * a01) * inv
    return -1


@numba.njit(cache=True)
def solve(perm, column_pointers, rows, factor, inverse_diagonal, rhs):
    """``x = A⁻¹ b`` from :func:`numeric`'s factor; ``rhs`` and the result ``(n, 3)``."""
    n = len(perm)
    x = forward_part(perm, column_pointers, rows, factor, inverse_diagonal, n, rhs)
    return back_part(perm, column_pointers, rows, factor, n, x)


@numba.njit(cache=True)
def forward_part(perm, column_pointers, rows, factor, inverse_diagonal, first, rhs):
    """``x`` ``(n, 3)`` in elimination order: ``D_I⁻¹ L_I⁻¹ b_I`` before
    ``first`` and ``b_C − L_CI L_I⁻¹ b_I`` from it on (``first = n``: the
    forward substitution and ``D⁻¹`` of :func:`solve`)."""
    n = len(perm)
    x = np.empty((n, 3))
    for k in range(n):
        for a in range(3):
            x[k, a] = rhs[perm[k], a]
    for i in range(first):
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        for p in range(column_pointers[i], column_pointers[i + 1]):
            low = factor[p]
            r = rows[p]
            for a in range(3):
                x[r, a] -= low[a, 0] * x0 + low[a, 1] * x1 + low[a, 2] * x2
    for i in range(first):
        d_inv = inverse_diagonal[i]
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        for a in range(3):
            x[i, a] = d_inv[a, 0] * x0 + d_inv[a, 1] * x1 + d_inv[a, 2] * x2
    return x


@numba.njit(cache=True)
def back_part(perm, column_pointers, rows, factor, first, x):
    """Back substitution ``L_Iᵀ x_I = x_I − L_CIᵀ x_C`` in place (``x`` in
    elimination order, its trailing part already solved); returns the
    solution by particle ``(n, 3)``."""
    n = len(perm)
    for i in range(first - 1, -1, -1):
        s0, s1, s2 = x[i, 0], x[i, 1], x[i, 2]
        for p in range(column_pointers[i], column_pointers[i + 1]):
            low = factor[p]
            r = rows[p]
            s0 -= low[0, 0] * x[r, 0] + low[1, 0] * x[r, 1] + low[2, 0] * x[r, 2]
            s1 -= low[0, 1] * x[r, 0] + low[1, 1] * x[r, 1] + low[2, 1] * x[r, 2]
            s2 -= low[0, 2] * x[r, 0] + low[1, 2] * x[r, 1] + low[2, 2] * x[r, 2]
        x[i, 0], x[i, 1], x[i, 2] = s0, s1, s2
    out = np.empty((n, 3))
    for k in range(n):
        for a in range(3):
            out[perm[k], a] = x[k, a]
    return out
