"""Contact rounds on one factorisation: the constrained particles eliminated last
(design §3, "Linear solvers").

A contact solve
(:meth:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver._solve_with_contacts`)
solves ``Â y = b̂`` with ``Â = S A S + (I − S) D (I − S)`` several times on
the same ``A``: every contact held, then the pulling ones released, then
rounds in which more of them slide (six solves per Newton iteration in
``grasp_lift``'s hold phase).  Only the filters ``S_C`` of the constrained
particles ``C`` change between them; every other particle is free
(``S_I = I``).  With ``C`` ordered last,

    Â = [L_I 0; S_C L_CI I] [D_I 0; 0 M] [L_Iᵀ L_CIᵀ S_C; 0 I],
    M = S_C T S_C + (I − S_C) D_C (I − S_C),   T = A_CC − L_CI D_I L_CIᵀ,

where ``L_I D_I L_Iᵀ = A_II`` and ``L_CI = A_CI L_I⁻ᵀ D_I⁻¹`` do not depend on
``S`` at all: they are factorised once per ``A`` (:func:`.block_ldl.factor_rows`,
the up-looking factorisation of :mod:`.block_ldl` that stops at ``C`` and
leaves its unfiltered Schur complement ``T``, dense), and each round only
filters ``T`` and factorises the dense ``M`` (``3|C|`` unknowns, Cholesky),
all in one compiled call (:func:`round_kernel`).
``D_C`` are ``A``'s diagonal blocks (any SPD block gives the same ``Δv``:
held directions are prescribed).

The elimination order is the topology's AMD order with ``C`` moved to the
end: more fill than AMD's (1.6× the block updates on a ``grasp_lift``
hold-phase system with 51 contacts), paid once instead of at every round.
:class:`TrailingRounds` decides when that pays.
"""

from __future__ import annotations

import numba
import numpy as np

from ..runtime import compiled  # noqa: F401  (keys the kernels' cache: before they are decorated)
from .block_ldl import back_part, factor_rows, forward_part
from .constraints import SolveResult
from .factorisation import _FactoredSystem, _block_ldl_module
from .projection_kernels import (FREE, HELD, _filtered_residual, _particle_filters, _solution,
                                 _start, _usable, particle_filters)

__all__ = ["TrailingFactor", "TrailingRounds", "dense_round_updates", "filtered_schur",
           "round_kernel"]


@numba.njit(cache=True)
def filtered_schur(schur, state, filters, diagonal, out):
    """``M = S T S + (I − S) D (I − S)`` ``(3c, 3c)`` into ``out`` from ``T``
    ``schur`` ``(c, c, 3, 3)``, the trailing particles' filter states
    ``(c,)`` and filters ``(c, 3, 3)`` and ``A``'s diagonal blocks ``D``
    ``(c, 3, 3)``; also returns the filters as ``(c, 3, 3)`` matrices."""
    c = len(state)
    s = np.zeros((c, 3, 3))
    for i in range(c):
        if state[i] == FREE:
            for a in range(3):
                s[i, a, a] = 1.0
        elif state[i] != HELD:
            s[i] = filters[i]
    left = np.empty((3, 3))
    for i in range(c):
        si = s[i]
        for j in range(i + 1):
            t = schur[i, j]
            sj = s[j]
            for a in range(3):
                for e in range(3):
                    left[a, e] = si[a, 0] * t[0, e] + si[a, 1] * t[1, e] + si[a, 2] * t[2, e]
            for a in range(3):
                for d in range(3):
                    v = left[a, 0] * sj[d, 0] + left[a, 1] * sj[d, 1] + left[a, 2] * sj[d, 2]
                    out[3 * i + a, 3 * j + d] = v
                    out[3 * j + d, 3 * i + a] = v
        # (I − S) D (I − S) on the diagonal block.
        free = np.eye(3) - si
        for a in range(3):
            for d in range(3):
                v = 0.0
                for e in range(3):
                    for f in range(3):
                        v += free[a, e] * diagonal[i, e, f] * free[d, f]
                out[3 * i + a, 3 * i + d] += v
    return s


@numba.njit(cache=True)
def round_kernel(indptr, indices, data, rhs, constrained, projectors, prescribed, perm,
                 pointers, rows, factor, inverse_diagonal, first, trailing, schur, diagonal,
                 member):
    """One contact round on a trailing factor, compiled end to end: the
    filters of the constraints ``(constrained (k,), projectors (k, 3, 3),
    prescribed (k, 3))``, the projected right-hand side ``S (b − A z)``, the
    solve (forward part, the dense ``M`` by Cholesky, back part) and ``Δv = z
    + S y`` with the squared norms of ``S (b − A Δv)`` and ``S b``.

    Returns ``(status, Δv (n, 3), norm_r², norm_b²)``: status 0, or 1 where a
    constrained particle is not in the trailing block (``member`` ``(n,)``
    bool), 2 where a constraint names no particle.
    """
    n = len(indptr) - 1
    ok, state, filters = _particle_filters(n, constrained, projectors)
    empty = np.zeros((0, 3))
    if not ok:
        return 2, empty, 0.0, 0.0
    for i in range(n):
        if state[i] != FREE and not member[i]:
            return 1, empty, 0.0, 0.0
    z = _start(n, constrained, projectors, prescribed)
    b = _filtered_residual(indptr, indices, data, rhs, z, state, filters)
    c = len(trailing)
    dense = np.empty((3 * c, 3 * c))
    s = filtered_schur(schur, state[trailing], filters[trailing], diagonal, dense)
    x = forward_part(perm, pointers, rows, factor, inverse_diagonal, first, b)
    tail = np.empty(3 * c)
    for k in range(c):
        for a in range(3):
            tail[3 * k + a] = s[k, a, 0] * x[first + k, 0] + s[k, a, 1] * x[first + k, 1] \
                + s[k, a, 2] * x[first + k, 2]
    low = np.linalg.cholesky(dense)                  # raises LinAlgError if not definite
    m = 3 * c
    for i in range(m):                               # L w = tail
        v = tail[i]
        for j in range(i):
            v -= low[i, j] * tail[j]
        tail[i] = v / low[i, i]
    for i in range(m - 1, -1, -1):                   # Lᵀ y = w
        v = tail[i]
        for j in range(i + 1, m):
            v -= low[j, i] * tail[j]
        tail[i] = v / low[i, i]
    for k in range(c):
        for a in range(3):
            x[first + k, a] = s[k, a, 0] * tail[3 * k] + s[k, a, 1] * tail[3 * k + 1] \
                + s[k, a, 2] * tail[3 * k + 2]
    y = back_part(perm, pointers, rows, factor, first, x)
    dv, norm_r, norm_b = _solution(indptr, indices, data, rhs, z, y, state, filters)
    return 0, dv, norm_r, norm_b


def dense_round_updates(count: int) -> float:
    """A round's dense work for ``count`` trailing particles, in 3 × 3 block
    updates (27 multiply-adds): the Cholesky of ``M`` (``(3c)³/6``) at twice
    the sparse kernels' rate (LAPACK on a dense block) and as much again for
    filtering ``T`` and the triangular solves."""
    return (3.0 * count) ** 3 / 6.0 / 27.0 / 2.0


class TrailingFactor:
    """One ``A`` factorised with the particles ``trailing`` last (module docstring).

    Args:
        indptr, indices: A's block pattern (int64).  order: ``(n,)`` the
            topology's elimination order (AMD).  trailing: ``(c,)`` sorted
            particles whose filters the rounds may change.
        symbolic: :func:`~cloth_lod_ros.sim.solve.block_ldl.symbolic`.
        diagonal_slots: ``(n,)`` the block of each particle's diagonal in A.
    """

    def __init__(self, indptr, indices, order, trailing, symbolic, diagonal_slots):
        n = len(order)
        self.n = n
        self.trailing = trailing
        last = np.zeros(n, dtype=bool)
        last[trailing] = True
        self.perm = np.concatenate([order[~last[order]], trailing]).astype(np.int64)
        self.pinv = np.empty(n, dtype=np.int64)
        self.pinv[self.perm] = np.arange(n)
        self.first = n - len(trailing)
        self.indptr, self.indices = indptr, indices
        self.parent, self.pointers = symbolic(indptr, indices, self.perm, self.pinv)
        self.rows = np.empty(self.pointers[-1], dtype=np.int64)
        self.factor = np.empty((self.pointers[-1], 3, 3))
        self.inverse_diagonal = np.empty((n, 3, 3))
        self.member = last
        # A's diagonal block of each trailing particle.
        self.diagonal_slots = diagonal_slots[trailing]
        self._dense = np.empty((3 * len(trailing), 3 * len(trailing)))
        counts = np.diff(self.pointers)[:self.first]
        #: Block updates of :meth:`refactor` (the up-looking count of its columns).
        self.updates = float(np.sum(counts * (counts + 1) // 2))
        self._key = None
        self._free = np.zeros(n, dtype=bool)     # A itself: no held particle to skip

    def refactor(self, matrix, data) -> bool:
        """Factorise ``A`` (``data`` ``(blocks, 3, 3)``); False if a pivot
        before the trailing block is singular (the caller refactorises the
        projected system and reports)."""
        c = len(self.trailing)
        schur = np.zeros((c, c, 3, 3))      # pairs outside each row's reach stay 0
        failed = factor_rows(self.indptr, self.indices, data, self.perm, self.pinv,
                             self.parent, self.pointers, self.rows, self.factor,
                             self.inverse_diagonal, self._free, self.first, schur)
        if failed >= 0:
            self._key = None
            return False
        self.schur = schur
        self.diagonal = np.ascontiguousarray(data[self.diagonal_slots])
        self._key = (matrix, data.copy(), data.ravel()[::97].copy())
        return True

    def holds(self, matrix) -> bool:
        """Whether this is the factorisation of ``matrix``'s current numbers."""
        key = self._key
        return (key is not None and key[0] is matrix
                and np.array_equal(key[2], matrix.data.ravel()[::97])    # cheap test first
                and np.array_equal(key[1], matrix.data))

    def covers(self, state) -> bool:
        """Whether every constrained particle (``state`` ``(n,)`` int8) is trailing."""
        return not np.any((state != FREE) & ~self.member)

    def round(self, matrix, rhs, constraints):
        """``(status, Δv, relative residual)`` of one round (:func:`round_kernel`;
        status 1: a constraint outside the trailing block, nothing solved)."""
        status, dv, norm_r, norm_b = round_kernel(
            self.indptr, self.indices, self._key[1], np.ascontiguousarray(rhs),
            np.ascontiguousarray(constraints.indices),
            np.ascontiguousarray(constraints.projectors),
            np.ascontiguousarray(constraints.prescribed), self.perm, self.pointers, self.rows,
            self.factor, self.inverse_diagonal, self.first, self.trailing, self.schur,
            self.diagonal, self.member)
        residual = float(np.sqrt(norm_r) / np.sqrt(norm_b)) if norm_b > 0 else 0.0
        return status, dv, residual


class TrailingRounds:
    """When a :class:`~cloth_lod_ros.sim.solve.backends.BlockLdl` solves on a
    trailing factorisation, and the one it keeps (one per topology).

    A trailing factorisation pays when the rounds it serves save more
    ordinary factorisations than it costs.  With ``r`` the filters solved per
    matrix lately (running mean; fewer if the last trailing factorisations
    served fewer, e.g. new contacts part way) it is taken where

        U_trailing + r · U_round  <  gain · r · U_ordinary,

    in block updates, which time both factorisations alike (7.2-7.9 ns each
    on the CI VM); a round costs its dense Cholesky (:func:`dense_round_updates`)
    plus about 20,000 updates' worth of its own passes over the system (one
    compiled round, measured: 0.15 ms at 25 trailing particles, 0.27 at 51,
    0.73 at 100; the model says 0.16, 0.23, 0.78).  Counts, not timings: the
    choice, and so the trajectory to round-off, is the same on every machine
    and in a bag's re-simulation.
    """

    #: The saving asked for.
    gain = 0.8
    #: Most constrained particles: a cloth lying on a table, or the 50-100
    #: contacts of ``drop_on_disc``, whose dense rounds took 0.7-1.4 ms in a
    #: step (cache misses) against the 0.3-0.5 the counts foretell.
    limit = 60
    #: Smaller systems factorise faster than a trailing round's own overhead:
    #: block updates of one ordinary factorisation.
    min_updates = 30_000
    #: A round's work besides its dense Cholesky, in block updates.
    round_overhead = 20_000.0

    def __init__(self):
        self.factor: TrailingFactor | None = None
        self._rounds = 0.0            # filters solved per matrix, running mean
        self._this_matrix = None      # (matrix, filters solved on it so far)
        self._served = np.inf         # solves per trailing factorisation, running mean
        self._serving = None

    def reset_topology(self) -> None:
        """Forget the factorisation (the particles are renumbered); the rounds
        per matrix are the scene's contacts', and carry over."""
        self.factor = None
        self._this_matrix = None

    def _count(self, matrix) -> bool:
        """Count a solve on ``matrix``; whether it was declined for it already.
        The assembly reuses the matrix's storage: a new linearisation is told
        by its numbers (a sample of them: this only counts and declines)."""
        sample = matrix.data.ravel()[::97].copy()
        seen = self._this_matrix
        if seen is not None and seen[0] is matrix and np.array_equal(seen[1], sample):
            self._this_matrix = (matrix, sample, seen[2] + 1, seen[3])
            return seen[3]
        if seen is not None:
            self._rounds = 0.5 * self._rounds + 0.5 * seen[2]
        self._this_matrix = (matrix, sample, 1, False)
        return False

    def _decline(self) -> None:
        """The ordinary factorisation for the rest of this matrix's rounds."""
        seen = self._this_matrix
        self._this_matrix = (seen[0], seen[1], seen[2], True)

    def _pays(self, trailing_updates: float, count: int, updates: float,
              rounds: float) -> bool:
        one_round = self.round_overhead + dense_round_updates(count)
        return trailing_updates + rounds * one_round < self.gain * rounds * updates

    def solve(self, backend, matrix, rhs, constraints):
        """The backend's solve on a trailing factorisation, or None where it
        takes its ordinary factorisation instead (few rounds lately, too
        small, too many or no constraints, a constraint outside the trailing
        block, no compiled kernels)."""
        if self._count(matrix):
            return None                 # declined for this matrix already
        factor = self.factor
        if not _usable(matrix, rhs, constraints):
            return None                 # dtypes the compiled round does not take
        held = factor is not None and factor.holds(matrix)
        if held:
            status, result = self._round(factor, matrix, rhs, constraints, backend.tolerance)
            if status == 0:
                return result if result.converged else None
            if status != 1:
                return None             # another trailing factorisation would fail alike
        if not held and backend._symbolic is None and self._rounds >= 1.5:
            backend._analyse(matrix)        # a new topology's first solve
        if not held and (self._rounds < 1.5 or backend._symbolic is None
                         or backend._updates() < self.min_updates):
            self._decline()
            return None                 # the usual case: a small or contact-free system
        filters = particle_filters(matrix, rhs, constraints)
        if filters is None:
            return None
        state = filters[0]
        if not held or not factor.covers(state):
            constrained = np.flatnonzero(state != FREE)
            rounds = min(self._rounds, self._served)
            updates = backend._updates()
            # Moving C last costs 1.4-1.6x the fill on a cloth's hem (more
            # where C is scattered): if even that would not pay, no ordering
            # is worked out for it.
            if (not len(constrained) or len(constrained) > self.limit
                    or not self._pays(1.4 * updates, len(constrained), updates, rounds)):
                self._decline()
                return None
            if factor is None or not np.array_equal(factor.trailing, constrained):
                indptr, indices, perm = backend._symbolic[:3]
                factor = TrailingFactor(indptr, indices, perm, constrained,
                                        _block_ldl_module().symbolic,
                                        backend.pattern.diagonal_block)
                self.factor = factor        # its ordering, for the next matrix too
            if not self._pays(factor.updates, len(constrained), updates, rounds):
                self._decline()
                return None
            if self._serving is not None:
                self._served = 0.5 * self._served + 0.5 * self._serving
            self._serving = 0
            if not factor.refactor(matrix, np.ascontiguousarray(matrix.data)):
                return None
            _FactoredSystem.factorisations += 1
        status, result = self._round(factor, matrix, rhs, constraints, backend.tolerance)
        return result if status == 0 and result.converged else None

    def _round(self, factor, matrix, rhs, constraints, tolerance):
        """``(status, result)`` of a round on ``factor``: status 0 and a
        SolveResult (converged: within ``tolerance`` or 1e-8, as a
        factorisation's); 1 where a constraint lies outside its block; 2
        where a constraint names no particle or the dense block is not
        definite (result None)."""
        try:
            status, dv, residual = factor.round(matrix, rhs, constraints)
        except np.linalg.LinAlgError:
            return 2, None
        if status != 0:
            return status, None
        converged = bool(np.isfinite(residual) and residual <= max(tolerance, 1e-8))
        if converged:
            self._serving += 1
        return 0, SolveResult(dv=dv, iterations=0, residual=residual, converged=converged)


def warm_up() -> None:
    """Compile or load these kernels on a four-particle chain with two
    trailing particles (one held, one sliding), so no timed solve pays for it."""
    import scipy.sparse as sp
    from .block_ldl import symbolic
    n = 4
    rows, cols, blocks = [], [], []
    for i in range(n):
        for j in range(max(0, i - 1), min(n, i + 2)):
            rows.append(i)
            cols.append(j)
            blocks.append(np.eye(3) * (4.0 if i == j else -1.0))
    indptr = np.searchsorted(np.array(rows), np.arange(n + 1)).astype(np.int64)
    matrix = sp.bsr_matrix((np.array(blocks), np.array(cols), indptr), shape=(3 * n, 3 * n))
    indices = matrix.indices.astype(np.int64)
    diagonal = np.array([indptr[i] + list(cols[indptr[i]:indptr[i + 1]]).index(i)
                         for i in range(n)], dtype=np.int64)
    factor = TrailingFactor(indptr, indices, np.arange(n, dtype=np.int64),
                            np.array([2, 3], dtype=np.int64), symbolic, diagonal)
    factor.refactor(matrix, np.ascontiguousarray(matrix.data))
    from .constraints import Constraints
    constraints = Constraints(np.array([2, 3], dtype=np.int64),
                              np.stack([np.zeros((3, 3)), np.diag([1.0, 1.0, 0.0])]),
                              np.zeros((2, 3)))
    factor.round(matrix, np.ones((n, 3)), constraints)
