"""Linear-solver backends behind one interface (design §3).

Every backend solves the filtered system of one implicit step - ``A Δv = b``
with per-particle constraints (filters ``S_i``, prescribed ``z_i``) - and
returns a :class:`~cloth_lod_ros.sim.solve.constraints.SolveResult` whose ``residual`` is
the same measure for all of them, ``|S(b − A Δv)| / |S b|``:

* ``pcg`` - the paper's method (BW §5.3): filtered CG, block-Jacobi
  preconditioner, warm start.  The reference.
* ``multigrid`` - the same filtered CG preconditioned by one V-cycle on the
  cloth's own lattices (:mod:`~cloth_lod_ros.sim.solve.multigrid`): 5-8 iterations
  whatever the mesh size, where block-Jacobi needs hundreds.
* ``direct`` - a sparse LDLᵀ factorisation (QDLDL) of the projected system
  ``S A S + (I − S) D (I − S)``, whose sparsity pattern is the topology's, so
  the symbolic analysis (ordering, elimination tree) is done once per topology
  and each solve - contact and friction re-solves included - refactors only
  the numbers.
* ``block_ldl`` - the same factorisation on 3 × 3 blocks, compiled with numba
  (:mod:`~cloth_lod_ros.sim.solve.block_ldl`): 0.3-0.4x QDLDL's time, about CHOLMOD's.
* ``cholmod`` - the same as ``direct`` with CHOLMOD's supernodal Cholesky
  (through cvxopt, an optional extra: ``pip install .[cholmod]``; GPL-3.0),
  single-threaded: 0.4x QDLDL's numeric factorisation on the scenes'
  systems.
* ``superlu`` - scipy's SuperLU on the same projected system, re-analysed every
  solve: the earlier direct baseline.
* ``auto`` (the default) - a direct factorisation on small systems (adaptive
  meshes, contact scenes at moderate levels): ``cholmod`` if installed, else
  ``block_ldl``, else ``direct``; ``multigrid`` on large ones (the size limit
  is each factorisation's own, :attr:`LdlDirect.auto_limits`); ``pcg`` where
  no factorisation is installed.
  :attr:`LinearSolver.name` says what ran.
"""

from __future__ import annotations

import os

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from ..runtime.blas_threads import forget_libraries
from .constraints import Constraints, SolveResult
from .pattern import SparsePattern
from .sparse import block_diagonal_matrix
from .pcg import filtered_pcg
from .projection import (project_system, projected_data, projected_rhs, relative_residual,
                         solve_projected_direct)
from ..runtime import compiled as _compiled
from . import multigrid_kernels as _mg_kernels
from . import projection_kernels as _projection
from .multigrid import VCycle, block_transfers, lattice_hierarchy
from .factorisation import _FactoredSystem, _block_ldl_module

__all__ = ["LinearSolver", "make_solver", "METHODS", "available_methods"]

METHODS = ("auto", "pcg", "multigrid", "direct", "block_ldl", "cholmod", "superlu")
#: ``auto`` factorises up to this many particles and uses multigrid above, on
#: uniform meshes (uniform L6, 1,089 particles: multigrid 0.71x pcg, QDLDL 0.79x) ...
AUTO_DIRECT_LIMIT = 700
#: ... and up to this many on graded (adaptive) meshes, where the lattice
#: V-cycle is weaker (default scene, adaptive to L6: LDLT 0.60x pcg, multigrid
#: 0.83x; with the 700 limit auto switched between them and made 0.85x).
AUTO_DIRECT_LIMIT_GRADED = 1200
#: The same limits for the block LDLᵀ and CHOLMOD, ~2.5x faster than QDLDL.
#: ``bench --solvers`` (ms per step, sdirk2, compiled V-cycle): uniform L6
#: (1,089 particles) block LDLT 25.1, multigrid 33.6; L7 (2,113) 72.7 against
#: 66.0, a tie; L8 (4,225) 202 against 99 - so up to L7 on uniform meshes,
#: further on graded ones (default scene: 6.0 against 13.5).
AUTO_FAST_DIRECT_LIMIT = 2500
AUTO_FAST_DIRECT_LIMIT_GRADED = 5000

try:                                   # an optional dependency: see available_methods()
    import qdldl as _qdldl
except ImportError:                    # pragma: no cover - installed with the package
    _qdldl = None


_CHOLMOD: tuple | None = None


def _cholmod_modules():
    """``(cvxopt, cvxopt.cholmod)``, or None when cvxopt is not installed.

    cvxopt ships its own OpenBLAS, which reads its thread count when it is
    loaded: it is loaded with one thread (unless the caller set
    OPENBLAS_NUM_THREADS), because its threads spin between the small dense
    blocks of each factorisation - on two cores twice the CPU and a slower
    factorisation than QDLDL's."""
    global _CHOLMOD
    if _CHOLMOD is None:
        saved = os.environ.get("OPENBLAS_NUM_THREADS")
        os.environ["OPENBLAS_NUM_THREADS"] = saved or "1"
        try:
            import cvxopt
            import cvxopt.cholmod as cholmod
            _CHOLMOD = (cvxopt, cholmod)
            forget_libraries()          # one_blas_thread lists its OpenBLAS too
        except ImportError:
            _CHOLMOD = ()
        finally:
            if saved is None:
                del os.environ["OPENBLAS_NUM_THREADS"]
    return _CHOLMOD or None


def available_methods() -> tuple[str, ...]:
    return tuple(m for m in METHODS if (m != "direct" or _qdldl is not None)
                 and (m != "cholmod" or _cholmod_modules() is not None)
                 and (m != "block_ldl" or _block_ldl_module() is not None))


class LinearSolver:
    """Base: a backend for one topology at a time.

    Args:
        tolerance: relative residual ``|S(b − A Δv)| / |S b|``.
        max_iterations: CG iteration cap (iterative backends).
        geometry: ``(width, height, block)`` of the cloth, m (for multigrid).
    """

    name = "base"

    def __init__(self, tolerance: float, max_iterations: int, geometry=None):
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.geometry = geometry
        self.pattern: SparsePattern | None = None
        self.uv: np.ndarray | None = None

    def reset_topology(self, pattern: SparsePattern | None, uv: np.ndarray | None,
                       graded: bool = False) -> None:
        """Forget what belonged to the previous topology (``uv``: ``(n, 2)`` m;
        ``graded``: the mesh mixes levels, a hint for :class:`Auto`)."""
        self.pattern, self.uv = pattern, uv

    def solve(self, matrix: sp.bsr_matrix, rhs: np.ndarray, constraints: Constraints,
              guess: np.ndarray | None) -> SolveResult:
        raise NotImplementedError


class BlockJacobiPcg(LinearSolver):
    name = "pcg"

    def solve(self, matrix, rhs, constraints, guess):
        return filtered_pcg(matrix, rhs, constraints, self.pattern.diagonal_blocks(matrix),
                            guess=guess, tolerance=self.tolerance,
                            max_iterations=self.max_iterations)


class SuperLu(LinearSolver):
    name = "superlu"

    def solve(self, matrix, rhs, constraints, guess):
        try:
            return solve_projected_direct(matrix, rhs, constraints, self.pattern)
        except RuntimeError as exc:         # SuperLU: "Factor is exactly singular"
            raise np.linalg.LinAlgError(f"LU factorisation failed: {exc}") from exc


class LdlDirect(LinearSolver):
    """QDLDL on the projected system; symbolic analysis once per topology."""

    name = "direct"
    #: Particles up to which ``auto`` factorises: (uniform, graded) meshes.
    auto_limits = (AUTO_DIRECT_LIMIT, AUTO_DIRECT_LIMIT_GRADED)

    def reset_topology(self, pattern, uv, graded=False):
        super().reset_topology(pattern, uv)
        self._factor = None
        self._upper = None
        self._factored = _FactoredSystem()

    def _upper_layout(self, projected: sp.bsr_matrix):
        """The permutation from BSR data to the upper triangle in CSC order (once
        per topology: the projected system has the topology's pattern).

        By symmetry the upper triangle's column ``3J + b`` holds, top to
        bottom, ``A[3J + b, 3I + a]`` for the blocks ``(J, I)`` of block row J
        with ``I ≤ J`` (BSR stores them in increasing I) and ``a = 0..2``
        (``a ≤ b`` on the diagonal block): entry ``9k + 3b + a`` of the data.
        So the order is pure arithmetic on the pattern, no sort.
        """
        n = projected.shape[0] // 3
        indptr, cols_b = projected.indptr, projected.indices
        block_rows = np.repeat(np.arange(n), np.diff(indptr))
        # Blocks on or below the diagonal: a prefix of each block row.
        lower_count = np.bincount(block_rows[cols_b <= block_rows], minlength=n)
        # Layout (J, b, k, a): each row J spans 3 · lower_count[J] blocks.
        span = 3 * lower_count
        row_of = np.repeat(np.arange(n), span)
        within = np.arange(len(row_of)) - np.repeat(np.cumsum(span) - span, span)
        b = within // lower_count[row_of]
        k = indptr[row_of] + within % lower_count[row_of]
        a = np.arange(3)
        data_index = (9 * k + 3 * b)[:, None] + a                  # (m, 3)
        rows = 3 * cols_b[k][:, None] + a
        cols = (3 * row_of + b)[:, None]
        keep = rows <= cols                  # the diagonal block's upper part
        order = data_index[keep]
        counts = np.bincount(np.broadcast_to(cols, rows.shape)[keep], minlength=3 * n)
        col_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        return order, rows[keep].astype(np.int32), col_ptr

    def solve(self, matrix, rhs, constraints, guess):
        if self._factor is not None and self._factored.holds(matrix, constraints):
            b, z = projected_rhs(matrix, rhs, constraints)
        else:
            data, b, z = projected_data(matrix, rhs, constraints, self.pattern)
            if self._upper is None:
                self._upper = self._upper_layout(matrix)       # Â has A's pattern
            order, indices, indptr = self._upper
            self._factored.forget()
            self._numeric(data.ravel()[order], indices, indptr, matrix.shape)
            self._factored.remember(matrix, constraints)
        y = self._backsolve(b.ravel()).reshape(-1, 3)
        return _factorised_result(matrix, rhs, constraints, z, y, self.tolerance)

    def _numeric(self, upper_data, indices, indptr, shape) -> None:
        """Factorise the projected system given by its upper triangle in CSC
        order (``upper_data`` on the pattern ``indices``/``indptr``)."""
        upper = sp.csc_matrix((upper_data, indices, indptr), shape=shape)
        try:
            if self._factor is None:
                self._factor = _qdldl.Solver(upper, upper=True)     # ordering + analysis
            else:
                self._factor.update(upper, upper=True)              # numbers only
        except RuntimeError as exc:         # QDLDL: not quasi-definite (absurd inputs)
            self._factor = None
            raise np.linalg.LinAlgError(f"LDLT factorisation failed: {exc}") from exc

    def _backsolve(self, b: np.ndarray) -> np.ndarray:
        return self._factor.solve(b)


class BlockLdl(LinearSolver):
    """LDLᵀ on 3 × 3 blocks compiled with numba (:mod:`cloth_lod_ros.sim.solve.block_ldl`) of the
    projected system; ordering (AMD on the particle graph, by QDLDL) and
    elimination tree once per topology, numbers only at every solve."""

    name = "block_ldl"
    auto_limits = (AUTO_FAST_DIRECT_LIMIT, AUTO_FAST_DIRECT_LIMIT_GRADED)

    #: Contact rounds on one factorisation with the constrained particles
    #: last, where that is expected to pay (:mod:`cloth_lod_ros.sim.solve.trailing_ldl`).
    trailing_rounds = True

    def reset_topology(self, pattern, uv, graded=False):
        super().reset_topology(pattern, uv)
        self._symbolic = None
        self._factored = _FactoredSystem()
        self._symbolic_updates = None
        if getattr(self, "_trailing", None) is None:
            from .trailing_ldl import TrailingRounds
            self._trailing = TrailingRounds()
        self._trailing.reset_topology()     # its rounds per matrix carry over

    def _analyse(self, matrix) -> None:
        kernels = _block_ldl_module()
        n = matrix.shape[0] // 3
        indptr = matrix.indptr.astype(np.int64)
        indices = matrix.indices.astype(np.int64)
        perm = particle_ordering(indptr, indices, n)
        pinv = np.empty(n, dtype=np.int64)
        pinv[perm] = np.arange(n)
        parent, pointers = kernels.symbolic(indptr, indices, perm, pinv)
        self._symbolic = (indptr, indices, perm, pinv, parent, pointers)
        self._rows = np.empty(pointers[-1], dtype=np.int64)
        self._factor = np.empty((pointers[-1], 3, 3))
        self._inverse_diagonal = np.empty((n, 3, 3))
        self._projected = np.empty_like(matrix.data)        # Â's blocks, every solve

    def solve(self, matrix, rhs, constraints, guess):
        kernels = _block_ldl_module()
        if self._factored.holds(matrix, constraints):
            b, z = projected_rhs(matrix, rhs, constraints)
            perm, pointers = self._symbolic[2], self._symbolic[5]
        else:
            trailing = (self._trailing.solve(self, matrix, rhs, constraints)
                        if self.trailing_rounds else None)
            if trailing is not None:
                return trailing
            if self._symbolic is None:
                self._analyse(matrix)                       # Â has A's pattern
            data, b, z = projected_data(matrix, rhs, constraints, self.pattern,
                                        out=self._projected)
            indptr, indices, perm, pinv, parent, pointers = self._symbolic
            self._factored.forget()
            failed = kernels.numeric(indptr, indices, np.ascontiguousarray(data), perm, pinv,
                                     parent, pointers, self._rows, self._factor,
                                     self._inverse_diagonal,
                                     _held_particles(matrix, rhs, constraints))
            if failed >= 0:
                raise np.linalg.LinAlgError(f"block LDLT factorisation failed: singular "
                                            f"pivot block at particle {int(perm[failed])}")
            self._factored.remember(matrix, constraints)
        y = kernels.solve(perm, pointers, self._rows, self._factor, self._inverse_diagonal,
                          np.ascontiguousarray(b))
        return _factorised_result(matrix, rhs, constraints, z, y, self.tolerance)

    def _updates(self) -> float:
        """Block updates of one ordinary factorisation of this topology."""
        if self._symbolic_updates is None:
            counts = np.diff(self._symbolic[5])
            self._symbolic_updates = float(np.sum(counts * (counts + 1) // 2))
        return self._symbolic_updates


def _held_particles(matrix, rhs, constraints) -> np.ndarray:
    """``(n,)`` bool: the particles the constraints hold in every direction
    (their projected rows and columns are zero off the diagonal)."""
    filters = _projection.particle_filters(matrix, rhs, constraints)
    if filters is not None:
        return filters[0] == _projection.HELD
    # Without the kernels: held where every entry of the particle holds it all
    # (a particle listed twice may end up held or not; only the surely held skip).
    n = rhs.shape[0]
    listed = np.zeros(n, dtype=bool)
    partly = np.zeros(n, dtype=bool)
    listed[constraints.indices] = True
    partly[constraints.indices[np.any(constraints.projectors != 0.0, axis=(1, 2))]] = True
    return listed & ~partly


def _factorised_result(matrix, rhs, constraints, z, y, tolerance) -> SolveResult:
    """``Δv = z + S y`` from a factorisation's solution ``y`` ``(n, 3)`` of the
    projected system, with its residual (converged: within ``tolerance``, or
    1e-8 for a tolerance below what round-off allows)."""
    fast = _projection.solution(matrix, rhs, constraints, z, y)
    if fast is not None:
        dv, rel = fast
    else:
        dv = z + constraints.filter(y)
        rel = relative_residual(matrix, rhs, constraints, dv)
    return SolveResult(dv=dv, iterations=0, residual=rel,
                       converged=bool(np.isfinite(rel) and rel <= max(tolerance, 1e-8)))


def particle_ordering(indptr: np.ndarray, indices: np.ndarray, n: int) -> np.ndarray:
    """A fill-reducing elimination order of the particle graph, ``(n,)`` int64.

    AMD, from QDLDL's analysis of a diagonally dominant matrix on the graph
    (its permutation is all that is kept); reverse Cuthill–McKee (more fill)
    where QDLDL is not installed.  ``indptr``/``indices``: the symmetric block
    pattern, each row's columns sorted (a :class:`SparsePattern`'s).
    """
    if _qdldl is None:
        graph = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
        return np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True), dtype=np.int64)
    # The upper triangle in CSC order is, column by column, the sorted prefix
    # i <= j of row j (the pattern is symmetric): built by arithmetic, as scipy's
    # triu and format conversions cost twice QDLDL's own analysis here.
    degree = np.diff(indptr)
    rows = np.repeat(np.arange(n), degree)
    keep = indices <= rows
    lower_rows, lower_cols = rows[keep], indices[keep]
    pointers = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(lower_rows, minlength=n), out=pointers[1:])
    values = np.where(lower_cols == lower_rows, degree.take(lower_rows) + 1.0, -1.0)
    upper = sp.csc_matrix((values, lower_cols, pointers), shape=(n, n))
    return np.asarray(_qdldl.Solver(upper, upper=True).factors()[2], dtype=np.int64)


class CholmodDirect(LdlDirect):
    """CHOLMOD's supernodal Cholesky of the projected system (optional, cvxopt):
    the symbolic analysis once per topology, a numeric factorisation per solve."""

    name = "cholmod"
    auto_limits = (AUTO_FAST_DIRECT_LIMIT, AUTO_FAST_DIRECT_LIMIT_GRADED)

    def _numeric(self, upper_data, indices, indptr, shape) -> None:
        cvxopt, cholmod = _cholmod_modules()
        values = cvxopt.matrix(np.ascontiguousarray(upper_data, dtype=float))
        if self._factor is None:
            columns = np.repeat(np.arange(shape[1], dtype=np.int64), np.diff(indptr))
            self._system = cvxopt.spmatrix(values, cvxopt.matrix(indices.astype(np.int64)),
                                           cvxopt.matrix(columns), size=shape)
            if self._system.V.size[0] != len(upper_data):
                raise RuntimeError("cvxopt changed the sparsity pattern")   # a defect
            saved = cholmod.options.get("supernodal")
            cholmod.options["supernodal"] = 2            # always supernodal
            try:
                self._factor = cholmod.symbolic(self._system, uplo="U")
            finally:
                if saved is None:
                    del cholmod.options["supernodal"]
                else:
                    cholmod.options["supernodal"] = saved
        else:
            self._system.V = values                       # same pattern, new numbers
        try:
            cholmod.numeric(self._system, self._factor)
        except ArithmeticError as exc:       # not positive definite (absurd inputs)
            self._factor = None
            raise np.linalg.LinAlgError(f"Cholesky factorisation failed: {exc}") from exc

    def _backsolve(self, b: np.ndarray) -> np.ndarray:
        cvxopt, cholmod = _cholmod_modules()
        x = cvxopt.matrix(np.ascontiguousarray(b, dtype=float))
        cholmod.solve(self._factor, x)
        return np.frombuffer(x, dtype=float).copy()


class Multigrid(LinearSolver):
    """Filtered CG preconditioned by a lattice V-cycle (prolongations per topology)."""

    name = "multigrid"

    #: Rebuild the coarse operators after this many solves, or when a solve
    #: needs more than REBUILD_GROWTH times the iterations of the first solve
    #: after the last rebuild (plus 2).
    REBUILD_EVERY = 20
    REBUILD_GROWTH = 1.5

    def reset_topology(self, pattern, uv, graded=False):
        super().reset_topology(pattern, uv)
        self._prolongations = self._transfers = None     # scalar P_k; P_k ⊗ I₃ (numpy path)
        self._cycle = None

    def solve(self, matrix, rhs, constraints, guess):
        if self._prolongations is None:
            width, height, block = self.geometry
            self._prolongations = lattice_hierarchy(self.uv, width, height, block)
        projected, _, _ = project_system(matrix, rhs, constraints, self.pattern)
        compiled = _compiled.enabled()
        diagonal = self.pattern.diagonal_blocks(projected)
        inverse_blocks = _mg_kernels.inverse_blocks(diagonal) if compiled \
            else np.linalg.inv(diagonal)
        if compiled:
            # The same cycle on 3 × 3 blocks (multigrid_kernels): no CSR copies.
            fine = _mg_kernels.block_arrays(projected)
            operator, smoother = _mg_kernels.BlockOperator(fine), inverse_blocks
        else:
            fine = operator = projected.tocsr()
            smoother = block_diagonal_matrix(inverse_blocks)
        if not self._prolongations:
            cycle = block_diagonal_matrix(inverse_blocks).__matmul__  # too small to coarsen
        elif self._cycle is None or self._stale() or self._compiled != compiled:
            if compiled:
                cycle = _mg_kernels.BlockVCycle(fine, smoother, self._prolongations)
            else:
                if self._transfers is None:
                    self._transfers = block_transfers(self._prolongations)
                cycle = VCycle(fine, smoother, self._transfers)
            self._cycle, self._compiled = cycle, compiled
            self._uses, self._baseline = 0, None
        else:
            cycle = self._cycle
            cycle.update_fine(fine, smoother)
        result = filtered_pcg(matrix, rhs, constraints, self.pattern.diagonal_blocks(matrix),
                              guess=guess, tolerance=self.tolerance,
                              max_iterations=self.max_iterations, preconditioner=cycle,
                              filtered_matrix=operator)
        if not result.converged:
            # Never worse than the reference: finish with block-Jacobi PCG from
            # where the multigrid iteration stopped, and rebuild next time.
            start = result.dv if np.all(np.isfinite(result.dv)) else guess
            finish = filtered_pcg(matrix, rhs, constraints,
                                  self.pattern.diagonal_blocks(matrix), guess=start,
                                  tolerance=self.tolerance,
                                  max_iterations=self.max_iterations)
            finish.iterations += result.iterations
            self._cycle = None
            return finish
        if self._cycle is not None:
            self._uses += 1
            self._last = result.iterations
            if self._baseline is None:
                self._baseline = result.iterations
        return result

    def _stale(self) -> bool:
        return (self._uses >= self.REBUILD_EVERY
                or self._last > self.REBUILD_GROWTH * self._baseline + 2)


class Auto(LinearSolver):
    """Picks a backend per topology by size; :attr:`name` is what ran last."""

    def __init__(self, tolerance, max_iterations, geometry=None):
        super().__init__(tolerance, max_iterations, geometry)
        # The block LDLᵀ before CHOLMOD: it alone shares a factorisation
        # between contact rounds, and it is the faster on graded meshes
        # (bench --solvers, README: default scene 5.0 against 6.4 ms per
        # step, grasp_lift 15.6 against 22.0; CHOLMOD is ahead only on
        # uniform meshes from L6, 14.7 against 15.8 there, 39.5 against 46.3 at L7).
        direct = (BlockLdl if _block_ldl_module() is not None
                  else CholmodDirect if _cholmod_modules() is not None
                  else LdlDirect if _qdldl is not None else None)
        self._large = Multigrid(tolerance, max_iterations, geometry)
        self._small = (direct(tolerance, max_iterations, geometry) if direct is not None
                       else BlockJacobiPcg(tolerance, max_iterations, geometry))
        self.limits = (direct or LdlDirect).auto_limits
        self._current: LinearSolver = self._small

    @property
    def name(self) -> str:
        return self._current.name

    def reset_topology(self, pattern, uv, graded=False):
        super().reset_topology(pattern, uv)
        count = pattern.vertex_count if pattern is not None else 0
        limit = self.limits[1] if graded else self.limits[0]
        self._current = self._small if count <= limit else self._large
        self._current.reset_topology(pattern, uv)

    def solve(self, matrix, rhs, constraints, guess):
        return self._current.solve(matrix, rhs, constraints, guess)


def make_solver(method: str, tolerance: float, max_iterations: int,
                geometry=None) -> LinearSolver:
    """The backend named ``method`` (one of :data:`METHODS`).

    Raises:
        ValueError: unknown method, or ``direct`` without QDLDL installed.
    """
    classes = {"auto": Auto, "pcg": BlockJacobiPcg, "multigrid": Multigrid,
               "direct": LdlDirect, "block_ldl": BlockLdl, "cholmod": CholmodDirect,
               "superlu": SuperLu}
    if method not in classes:
        raise ValueError(f"unknown solver method {method!r}; one of {', '.join(METHODS)}")
    if method == "direct" and _qdldl is None:
        raise ValueError("solver.method 'direct' needs the qdldl package (pip install qdldl)")
    if method == "block_ldl" and _block_ldl_module() is None:
        raise ValueError("solver.method 'block_ldl' needs numba (pip install numba)")
    if method == "cholmod" and _cholmod_modules() is None:
        raise ValueError("solver.method 'cholmod' needs cvxopt (pip install '.[cholmod]'; "
                         "GPL-3.0)")
    return classes[method](tolerance, max_iterations, geometry)
