"""Compiled (numba) kernels for what every filtered solve builds around a
factorisation: the projected system and the solution's residual (design §3).

A factorising backend (``block_ldl``, ``cholmod``, ``direct``) solves
``Â y = b̂`` with ``Â = S A S + (I − S) D (I − S)``, ``b̂ = S (b − A z)`` and
returns ``Δv = z + S y`` with ``|S(b − A Δv)| / |S b|``
(:func:`~cloth_lod_ros.sim.solve.projection.project_system`, BW §5.3).  On a contact
scene that is done at every friction round and re-solve, ten times a frame
on ``grasp_lift``, and in numpy it is some thirty passes over the blocks and
the particles (fancy indexing, masks, ``unique``, ``einsum``): about a third
of what the factorisation itself costs at a few hundred particles.  Here
each is one or two loops.

Agreement with the numpy reference (:mod:`~cloth_lod_ros.sim.solve.pattern`):

* blocks of free and fully held particles (``S_i = I`` or ``0``: pins,
  sticking contacts) and every ``A x`` product are *bitwise* equal (the
  products accumulate in scipy's ``bsr_matvec`` order);
* blocks that touch a partly held particle (a sliding contact), its
  ``S r`` and ``(I − S) z`` are the same sums in another order (numpy's
  ``matmul``/``einsum`` go through BLAS), so they agree to round-off;
* the norms of the relative residual likewise.

The switch is :func:`~cloth_lod_ros.sim.runtime.compiled.enabled`
(``CLOTH_LOD_KERNELS=numpy``);
without numba the reference runs.  The functions here return ``None`` for
inputs they do not take (other dtypes, indices out of range), and the caller
runs the reference, which gives its result or its error.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled

__all__ = ["particle_filters", "projected_data", "projected_rhs", "solution", "warm_up"]

_jit = _compiled._jit

FREE, HELD, PARTIAL = 0, 1, 2           # particle states: S_i = I, S_i = 0, anything else


@_jit
def _particle_filters(n, indices, projectors):
    """Per-particle ``S_i`` from a constraint list (the last entry of a
    particle listed twice wins, as in ``Constraints.filter``).

    Returns ``(ok, state (n,) int8, filters (n, 3, 3))``; ``filters`` holds
    ``S_i`` for constrained particles only (free ones are not read).
    """
    state = np.zeros(n, np.int8)
    filters = np.empty((n, 3, 3))
    for k in range(len(indices)):
        i = indices[k]
        if i < 0 or i >= n:
            return False, state, filters
        zero = True
        for a in range(3):
            for b in range(3):
                s = projectors[k, a, b]
                filters[i, a, b] = s
                if s != 0.0:
                    zero = False
        state[i] = HELD if zero else PARTIAL
    return True, state, filters


@_jit
def _filter_row(state, filters, i, r0, r1, r2):
    """``S_i r`` for one particle (the three sums of ``einsum('kab,kb->ka')``)."""
    if state[i] == FREE:
        return r0, r1, r2
    if state[i] == HELD:
        return 0.0, 0.0, 0.0
    return (filters[i, 0, 0] * r0 + filters[i, 0, 1] * r1 + filters[i, 0, 2] * r2,
            filters[i, 1, 0] * r0 + filters[i, 1, 1] * r1 + filters[i, 1, 2] * r2,
            filters[i, 2, 0] * r0 + filters[i, 2, 1] * r1 + filters[i, 2, 2] * r2)


@_jit
def _filtered_residual(indptr, indices, data, rhs, x, state, filters):
    """``S (b − A x)`` ``(n, 3)``; ``A x`` summed block by block and entry by
    entry in the order of scipy's ``bsr_matvec`` (bitwise its result)."""
    n = len(indptr) - 1
    out = np.empty((n, 3))
    for r in range(n):
        y0 = y1 = y2 = 0.0
        for p in range(indptr[r], indptr[r + 1]):
            c = indices[p]
            x0, x1, x2 = x[c, 0], x[c, 1], x[c, 2]
            y0 = y0 + data[p, 0, 0] * x0
            y0 = y0 + data[p, 0, 1] * x1
            y0 = y0 + data[p, 0, 2] * x2
            y1 = y1 + data[p, 1, 0] * x0
            y1 = y1 + data[p, 1, 1] * x1
            y1 = y1 + data[p, 1, 2] * x2
            y2 = y2 + data[p, 2, 0] * x0
            y2 = y2 + data[p, 2, 1] * x1
            y2 = y2 + data[p, 2, 2] * x2
        out[r, 0], out[r, 1], out[r, 2] = _filter_row(
            state, filters, r, rhs[r, 0] - y0, rhs[r, 1] - y1, rhs[r, 2] - y2)
    return out


@_jit
def _start(n, indices, projectors, prescribed):
    """``z = (I − S) z_prescribed`` on the constrained particles, 0 elsewhere
    (``Constraints.start`` of a zero guess; the last entry wins)."""
    z = np.zeros((n, 3))
    for k in range(len(indices)):
        i = indices[k]
        z0, z1, z2 = prescribed[k, 0], prescribed[k, 1], prescribed[k, 2]
        for a in range(3):
            z[i, a] = prescribed[k, a] - (projectors[k, a, 0] * z0 + projectors[k, a, 1] * z1
                                          + projectors[k, a, 2] * z2)
    return z


@_jit
def _sandwich(left, middle, right, out, p, accumulate):
    """``out[p] (+)= (left @ middle[p]) @ right`` for 3 × 3 blocks (scalar
    loops: numba makes no array views here)."""
    for a in range(3):
        t0 = left[a, 0] * middle[p, 0, 0] + left[a, 1] * middle[p, 1, 0] \
            + left[a, 2] * middle[p, 2, 0]
        t1 = left[a, 0] * middle[p, 0, 1] + left[a, 1] * middle[p, 1, 1] \
            + left[a, 2] * middle[p, 2, 1]
        t2 = left[a, 0] * middle[p, 0, 2] + left[a, 1] * middle[p, 1, 2] \
            + left[a, 2] * middle[p, 2, 2]
        for b in range(3):
            value = t0 * right[0, b] + t1 * right[1, b] + t2 * right[2, b]
            out[p, a, b] = out[p, a, b] + value if accumulate else value


@_jit
def _project_blocks(indptr, indices, data, state, filters, out):
    """``Â``'s blocks on A's pattern into ``out`` ``(blocks, 3, 3)``:
    0 in a fully held row or column except its diagonal block (A's),
    ``S_r A_rc S_c`` where a partly held particle is involved, plus
    ``(I − S) A_rr (I − S)`` on such a particle's diagonal block, A elsewhere."""
    n = len(indptr) - 1
    left = np.empty((3, 3))
    right = np.empty((3, 3))
    for r in range(n):
        sr = state[r]
        for p in range(indptr[r], indptr[r + 1]):
            c = indices[p]
            sc = state[c]
            if (sr == HELD or sc == HELD) and r != c:
                for a in range(3):
                    for b in range(3):
                        out[p, a, b] = 0.0
            elif sr == PARTIAL or sc == PARTIAL:
                for a in range(3):
                    for b in range(3):
                        one = 1.0 if a == b else 0.0
                        left[a, b] = filters[r, a, b] if sr == PARTIAL else one
                        right[a, b] = filters[c, a, b] if sc == PARTIAL else one
                _sandwich(left, data, right, out, p, False)
                if r == c:
                    for a in range(3):
                        for b in range(3):
                            left[a, b] = (1.0 if a == b else 0.0) - filters[r, a, b]
                    _sandwich(left, data, left, out, p, True)
            else:                   # free, or a held particle's diagonal block
                for a in range(3):
                    for b in range(3):
                        out[p, a, b] = data[p, a, b]


@_jit
def _solution(indptr, indices, data, rhs, z, y, state, filters):
    """``Δv = z + S y`` and the squared norms of ``S(b − A Δv)`` and ``S b``."""
    n = len(indptr) - 1
    dv = np.empty((n, 3))
    for i in range(n):
        f0, f1, f2 = _filter_row(state, filters, i, y[i, 0], y[i, 1], y[i, 2])
        dv[i, 0], dv[i, 1], dv[i, 2] = z[i, 0] + f0, z[i, 1] + f1, z[i, 2] + f2
    residual = _filtered_residual(indptr, indices, data, rhs, dv, state, filters)
    norm_r = 0.0
    norm_b = 0.0
    for i in range(n):
        b0, b1, b2 = _filter_row(state, filters, i, rhs[i, 0], rhs[i, 1], rhs[i, 2])
        norm_b += b0 * b0 + b1 * b1 + b2 * b2
        for a in range(3):
            norm_r += residual[i, a] * residual[i, a]
    return dv, norm_r, norm_b


def _usable(matrix, rhs, constraints) -> bool:
    return (_compiled.enabled() and getattr(matrix, "blocksize", None) == (3, 3)
            and matrix.format == "bsr" and matrix.data.dtype == np.float64
            and rhs.dtype == np.float64 and rhs.ndim == 2 and rhs.shape[1] == 3
            and constraints.indices.dtype == np.int64
            and constraints.projectors.dtype == np.float64
            and constraints.prescribed.dtype == np.float64)


def _arrays(matrix):
    indptr, indices = matrix.indptr, matrix.indices
    if indptr.dtype != np.int64:
        indptr, indices = indptr.astype(np.int64), indices.astype(np.int64)
    return indptr, indices, np.ascontiguousarray(matrix.data)


def particle_filters(matrix, rhs, constraints):
    """``(state (n,) int8, filters (n, 3, 3))`` of the constraints, or None
    where the kernels do not apply (the caller runs the reference)."""
    if not _usable(matrix, rhs, constraints):
        return None
    n = rhs.shape[0]
    ok, state, filters = _particle_filters(n, np.ascontiguousarray(constraints.indices),
                                           np.ascontiguousarray(constraints.projectors))
    return (state, filters) if ok else None


def projected_data(matrix, rhs, constraints, out=None):
    """:func:`~cloth_lod_ros.sim.solve.projection.projected_data` compiled:
    ``(Â's data (blocks, 3, 3), b̂ (n, 3), z (n, 3))`` or None.

    Args:
        matrix: A, BSR with 3 × 3 float64 blocks.  rhs: ``(n, 3)`` b.
        constraints: S and the prescribed changes.
        out: ``(blocks, 3, 3)`` storage for ``Â``'s data (reused between
            solves of one topology), or None for a new array.
    """
    filters = particle_filters(matrix, rhs, constraints)
    if filters is None:
        return None
    state, filters = filters
    indptr, indices, data = _arrays(matrix)
    if out is None or out.shape != data.shape:
        out = np.empty_like(data)
    _project_blocks(indptr, indices, data, state, filters, out)
    rhs = np.ascontiguousarray(rhs)
    z = _start(rhs.shape[0], np.ascontiguousarray(constraints.indices),
               np.ascontiguousarray(constraints.projectors),
               np.ascontiguousarray(constraints.prescribed))
    b = _filtered_residual(indptr, indices, data, rhs, z, state, filters)
    return out, b, z


def projected_rhs(matrix, rhs, constraints):
    """:func:`~cloth_lod_ros.sim.solve.projection.projected_rhs` compiled: ``(b̂, z)`` or None."""
    filters = particle_filters(matrix, rhs, constraints)
    if filters is None:
        return None
    state, filters = filters
    indptr, indices, data = _arrays(matrix)
    rhs = np.ascontiguousarray(rhs)
    z = _start(rhs.shape[0], np.ascontiguousarray(constraints.indices),
               np.ascontiguousarray(constraints.projectors),
               np.ascontiguousarray(constraints.prescribed))
    return _filtered_residual(indptr, indices, data, rhs, z, state, filters), z


def solution(matrix, rhs, constraints, z, y):
    """``(Δv = z + S y (n, 3), |S(b − A Δv)| / |S b|)`` or None; the relative
    residual is 0 when ``S b`` is 0, as in
    :func:`~cloth_lod_ros.sim.solve.projection.relative_residual`."""
    filters = particle_filters(matrix, rhs, constraints)
    if filters is None or z.dtype != np.float64 or y.dtype != np.float64:
        return None
    state, filters = filters
    indptr, indices, data = _arrays(matrix)
    dv, norm_r, norm_b = _solution(indptr, indices, data, np.ascontiguousarray(rhs),
                                   np.ascontiguousarray(z), np.ascontiguousarray(y),
                                   state, filters)
    return dv, (float(np.sqrt(norm_r) / np.sqrt(norm_b)) if norm_b > 0 else 0.0)


def warm_up() -> None:
    """Compile or load these kernels on a two-particle system with a free, a
    held and a sliding particle, so no timed solve pays for it."""
    if not _compiled.enabled():
        return
    import scipy.sparse as sp
    from .constraints import Constraints
    blocks = np.stack([np.eye(3) * 2.0, -np.eye(3), -np.eye(3), np.eye(3) * 2.0])
    matrix = sp.bsr_matrix((blocks, np.array([0, 1, 0, 1]), np.array([0, 2, 4])),
                           shape=(6, 6))
    rhs = np.ones((2, 3))
    sliding = np.eye(3) - np.outer([0.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    constraints = Constraints(np.array([0, 1]), np.stack([np.zeros((3, 3)), sliding]),
                              np.zeros((2, 3)))
    _, b, z = projected_data(matrix, rhs, constraints)
    projected_rhs(matrix, rhs, constraints)
    solution(matrix, rhs, constraints, z, b)
