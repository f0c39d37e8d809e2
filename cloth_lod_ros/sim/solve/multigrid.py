"""A geometric multigrid preconditioner from the cloth's own lattice (design §3).

A 4-8 mesh of a rectangular cloth made of square blocks of side ``b`` has, at
every even bisection level ``2p``, its vertices on the square lattice of spacing
``b / 2^p`` (odd levels add the centres of those squares).  Those lattices are
the coarse grids: nothing has to be built or aggregated, and the same lattices
serve any mesh of the cloth, uniform or adaptive, because the prolongation from
a lattice to any set of material points is bilinear interpolation in (u, v) —
the face rule of the bisection (a new particle is the mean of the ends of the
edge it splits) is its restriction to the lattice points.

* :func:`lattice_hierarchy` - prolongations ``P_k`` (fine points to lattice
  nodes, then lattice to lattice), coarsest first dropped when it would not
  coarsen;
* :class:`VCycle` - Galerkin coarse operators ``P_kᵀ A_k P_k`` (3 × 3 blocks:
  ``P ⊗ I₃``), Chebyshev smoothing in the block-Jacobi-scaled operator, a
  sparse LU on the coarsest lattice; one symmetric V-cycle is an SPD
  approximate inverse, so it can precondition CG.

The fine operator is the *projected* system ``S A S + (I − S) D (I − S)`` (D:
the diagonal blocks of A): the same as A in free directions, the scale of A in
held ones, so coarse operators stay positive definite however many particles
are held (pins, grasps, contacts) and the held rows do not swamp the averages.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .sparse import CsrOperator, block_diagonal_matrix

__all__ = ["lattice_hierarchy", "block_transfers", "largest_eigenvalue", "VCycle"]

COARSENING = 0.75        # a coarse lattice has at most this fraction of the finer level's nodes


def _bilinear(points: np.ndarray, spacing: float, nu: int, nv: int) -> sp.csr_matrix:
    """``(len(points), (nu+1)(nv+1))`` bilinear weights of lattice nodes
    (node ``i + j (nu+1)`` at ``(i, j) · spacing``) at ``points`` ``(m, 2)`` m."""
    g = points / spacing
    i = np.clip(np.floor(g[:, 0] + 1e-9).astype(np.int64), 0, nu - 1)
    j = np.clip(np.floor(g[:, 1] + 1e-9).astype(np.int64), 0, nv - 1)
    fu, fv = g[:, 0] - i, g[:, 1] - j
    rows = np.repeat(np.arange(len(points)), 4)
    cols = np.stack([i + j * (nu + 1), i + 1 + j * (nu + 1),
                     i + (j + 1) * (nu + 1), i + 1 + (j + 1) * (nu + 1)], axis=1).ravel()
    weights = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv],
                       axis=1).ravel()
    keep = weights > 1e-12
    return sp.csr_matrix((weights[keep], (rows[keep], cols[keep])),
                         shape=(len(points), (nu + 1) * (nv + 1)))


def lattice_hierarchy(uv: np.ndarray, width: float, height: float, block: float,
                      min_nodes: int = 100) -> list[sp.csr_matrix]:
    """Prolongations from coarse lattices down to the points ``uv``.

    Args:
        uv: ``(n, 2)`` rest material coordinates of the particles, m.
        width, height: the cloth, m; block: side of a level-0 square block, m.
        min_nodes: stop at the first lattice with at most this many nodes (its
            operator is factorised; one level fewer costs less than it saves).

    Returns:
        ``[P_0, P_1, ...]``: ``P_0`` maps the first coarse lattice to the particles
        (``n × N_1``), ``P_k`` lattice ``k+1`` to lattice ``k``.  The first
        lattice is the finest one with fewer than :data:`COARSENING` ``· n`` nodes
        (so every level coarsens); empty if even the base lattice is not coarser.
    """
    prolongations = []
    points = np.asarray(uv, dtype=float)
    count = len(points)

    def nodes(p: int) -> int:
        spacing = block / 2 ** p
        return (int(round(width / spacing)) + 1) * (int(round(height / spacing)) + 1)

    p = 0
    while nodes(p + 1) < COARSENING * count:
        p += 1                       # the finest lattice that still coarsens
    while p >= 0:
        spacing = block / 2 ** p
        nu, nv = int(round(width / spacing)), int(round(height / spacing))
        if (nu + 1) * (nv + 1) >= COARSENING * count:
            break                    # would not coarsen
        weights = _bilinear(points, spacing, nu, nv)
        # On an adaptive mesh a lattice may be finer than the mesh somewhere:
        # its nodes there carry no fine point and are left out.
        supported = np.flatnonzero(np.asarray(weights.sum(axis=0)).ravel() > 0)
        if len(supported) < weights.shape[1]:
            weights = weights[:, supported].tocsr()
        prolongations.append(weights)
        if weights.shape[1] <= min_nodes:
            break
        gu, gv = np.meshgrid(np.arange(nu + 1) * spacing, np.arange(nv + 1) * spacing)
        points = np.stack([gu.ravel(), gv.ravel()], axis=1)[supported]
        count = len(points)
        p -= 1
    return prolongations


def block_transfers(prolongations: list[sp.csr_matrix]) -> list[tuple]:
    """``[(P ⊗ I₃, (P ⊗ I₃)ᵀ)]`` as CSR: the prolongations acting on 3-vectors
    (once per topology)."""
    identity3 = sp.identity(3, format="csr")
    out = []
    for p in prolongations:
        p3 = sp.kron(p, identity3, format="csr")
        out.append((p3, p3.T.tocsr()))
    return out


def _block_diagonal_inverse(matrix: sp.csr_matrix) -> sp.csr_matrix:
    """Block-diagonal CSR of the inverses of the 3 × 3 diagonal blocks of ``matrix``."""
    n = matrix.shape[0] // 3
    bsr = sp.bsr_matrix(matrix, blocksize=(3, 3))
    rows = np.repeat(np.arange(n), np.diff(bsr.indptr))
    diagonal = np.zeros((n, 3, 3))
    on_diagonal = rows == bsr.indices
    diagonal[rows[on_diagonal]] = bsr.data[on_diagonal]
    return block_diagonal_matrix(np.linalg.inv(diagonal))


def largest_eigenvalue(apply, size: int, bound: float, iterations: int) -> float:
    """The top of the Chebyshev interval of :class:`VCycle`: a power-iteration
    estimate of λmax of ``D⁻¹ A`` (``apply``: ``x (size,) -> D⁻¹ A x``, from a
    fixed random start, ``iterations`` products) with a 20 % margin, never
    above ``bound``, the largest absolute row sum of ``D⁻¹ A``; 1 if neither
    is usable."""
    x = np.random.default_rng(0).standard_normal(size)
    estimate = bound
    for _ in range(iterations):
        y = apply(x)
        norm = float(np.linalg.norm(y))
        if not np.isfinite(norm) or norm == 0.0:
            break
        estimate, x = norm / float(np.linalg.norm(x)), y / norm
    largest = min(1.2 * estimate, bound)
    return largest if np.isfinite(largest) and largest > 0.0 else 1.0


class VCycle:
    """One symmetric V-cycle on ``matrix`` (3 × 3-block SPD), built once per matrix.

    Smoothing is a Chebyshev polynomial in ``D⁻¹ A`` (degree 2, on the upper
    70 % of its spectrum, its top estimated by power iteration): on a flat,
    unstretched cloth the operator is anisotropic
    (stretch couples each displacement component along one fibre direction only,
    shear is 10x softer), where damped block-Jacobi needs ~30 CG iterations at
    level 8 and Chebyshev 9.

    Args:
        matrix: the fine operator (CSR, ``3n × 3n``).
        fine_inverse_diagonal: block-diagonal inverse of its diagonal blocks
            (computed by the caller, who has them already).
        transfers: ``[(P_k ⊗ I₃, its transpose)]`` from :func:`block_transfers`.
        degree: Chebyshev degree (sweeps before and after each coarse correction).
    """

    LOWER = 0.3              # smoothed part of the spectrum: [LOWER λmax, λmax]
    POWER_ITERATIONS = 10

    def __init__(self, matrix: sp.csr_matrix, fine_inverse_diagonal: sp.csr_matrix,
                 transfers: list[tuple[sp.csr_matrix, sp.csr_matrix]], degree: int = 2):
        self.degree = int(degree)
        self.levels = []
        inverse_diagonal = fine_inverse_diagonal
        for p3, r3 in transfers:
            # The cycle's products go through CsrOperator (no scipy dispatch);
            # the Galerkin product needs the scipy matrices.
            self.levels.append([CsrOperator(matrix), CsrOperator(inverse_diagonal),
                                CsrOperator(p3), CsrOperator(r3),
                                self._largest_eigenvalue(matrix, inverse_diagonal)])
            matrix = r3 @ (matrix @ p3)
            inverse_diagonal = _block_diagonal_inverse(matrix)
        self.coarse = spla.splu(matrix.tocsc())

    def _largest_eigenvalue(self, matrix, inverse_diagonal) -> float:
        """λmax of ``D⁻¹ A``: a power-iteration estimate with a 20 % margin,
        never above the largest absolute row sum (a guaranteed bound).

        Chebyshev smoothing amplifies the error in any part of the spectrum
        above its interval, which can make the V-cycle indefinite; the row-sum
        bound alone is safe but about twice too large on a cloth, which halves
        the smoother's effect (18 CG iterations at level 8 instead of 10).  The
        CG caller detects an indefinite preconditioner and falls back.
        """
        scaled = inverse_diagonal @ matrix
        bound = float(np.max(np.asarray(abs(scaled).sum(axis=1)).ravel()))
        return largest_eigenvalue(scaled.__matmul__, matrix.shape[0], bound,
                                  self.POWER_ITERATIONS)

    def update_fine(self, matrix: sp.csr_matrix, inverse_diagonal: sp.csr_matrix) -> None:
        """Smooth with a new fine operator, keeping the coarse ones.

        A V-cycle whose coarse operators come from a nearby matrix (an earlier
        step, another contact round of the same step) is still a symmetric
        positive definite preconditioner for the new one; rebuilding them (the
        Galerkin products) costs about as much as the whole solve.
        """
        self.levels[0][0] = CsrOperator(matrix)
        self.levels[0][1] = CsrOperator(inverse_diagonal)

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """An approximation of ``matrix⁻¹ residual`` (``(3n,)``)."""
        return self._cycle(0, residual)

    def _smooth(self, level, b: np.ndarray, x: np.ndarray | None) -> np.ndarray:
        """Chebyshev iteration for ``A x = b`` preconditioned by ``D⁻¹``."""
        matrix, inverse_diagonal, _, _, largest = level
        low = self.LOWER * largest
        centre, half_width = 0.5 * (largest + low), 0.5 * (largest - low)
        sigma = centre / half_width
        rho = 1.0 / sigma
        r = inverse_diagonal @ (b if x is None else b - matrix @ x)
        d = r / centre
        x = d.copy() if x is None else x + d
        for _ in range(self.degree - 1):
            r = r - inverse_diagonal @ (matrix @ d)
            rho_next = 1.0 / (2.0 * sigma - rho)
            d = rho_next * rho * d + (2.0 * rho_next / half_width) * r
            rho = rho_next
            x = x + d
        return x

    def _cycle(self, k: int, b: np.ndarray) -> np.ndarray:
        if k == len(self.levels):
            return self.coarse.solve(b)
        level = self.levels[k]
        matrix, _, p3, r3, _ = level
        x = self._smooth(level, b, None)
        x = x + p3 @ self._cycle(k + 1, r3 @ (b - matrix @ x))
        return self._smooth(level, b, x)
