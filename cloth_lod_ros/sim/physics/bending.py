"""Quadratic bending energy of a 4-8 mesh: the squared Hessian of the
embedding, integrated over the rest sheet (design §2, model.md "Bending").

Continuum: for a sheet with flat rest metric, ``x(u, v)`` its embedding,
``E = B/2 ∫ |∇²x|² dA`` with ``|∇²x|² = |x_uu|² + 2|x_uv|² + |x_vv|²`` (3-vectors,
Frobenius norm; B in N·m).  For an isometric deformation the Christoffel
symbols of the flat metric vanish, so ``x_αβ = II_αβ n`` and the density is
``κ₁² + κ₂²``: the Kirchhoff plate with Poisson ratio 0 (a cylinder of radius
R costs ``B/2 R⁻² A``, a twist ``z = c u v`` costs ``B c² A``).  Every affine
map (rigid motions included) has zero energy, at free edges too, and the
natural condition at a free edge is ``x_nn = 0`` (no bending moment across it).
The quadratic-energy idea (a constant Hessian, forces ``−Q x``) is Bergou et
al., "A quadratic bending model for inextensible surfaces" (SGP 2006) and
Wardetzky et al., "Discrete quadratic curvature energies" (CAGD 2007); the
per-vertex Laplacian form of those papers is ``(Δx)²``, i.e. Poisson ratio 1,
whose free-edge condition ``Δx = 0`` lets the row next to a free edge fold
anticlastically for free; the Hessian form here has no such mode.

Discretisation (finite differences on the 4-8 lattice, in rest coordinates):

* **line stencils** ``D x = 2/(h₊+h₋) [(x₊ − x)/h₊ − (x − x₋)/h₋]`` at vertex
  x with its neighbours x₊, x₋ along one straight line (rest spacings h₊, h₋):
  the second derivative along that line, exact on quadratics.  Every corner of
  a triangle T at vertex i has the (Voronoi) area α (½ A_T at the right angle,
  ¼ A_T at each 45° corner: right isosceles triangles, so these are the
  Voronoi areas and sum to the vertex's dual area) and asks for the line
  stencils at i along T's two leg directions, weight α each;
* **twist stencils** on every diamond (two triangles sharing their
  hypotenuse, a square of side a): ``(x_e0 + x_e1 − x_o0 − x_o1)/a²`` is the
  mixed derivative along the legs at its centre, weight 2·(diamond area);
* where such a stencil does not exist (at a free edge a line leaves the
  sheet, a triangle with its hypotenuse on the border or on a coarser leg has
  no diamond) the corner's missing terms are taken from the least-squares
  quadratic fit of the vertex's two-ring (exact on quadratics, zero on
  affine maps): ``α (dᵀ H_i d)²`` per missing line d and ``2 α (uᵀ H_i v)²``
  per missing twist (the triangle's area shared among its corners as above).

On a uniform mesh away from the border this is the classical 5-point/4-point
scheme: the sum of each kind of stencil over the vertices telescopes (summing
by parts), so a smooth cylinder or saddle is the discrete energy's minimum
(the hinge sum ``Σ c_e θ²`` it replaces measured second differences centred
only at the valence-4 vertices: a zig-zag of the valence-8 ones lowered a
bent sheet's energy by ¼, issue 32).

Energy ``E = k_b/2 Σ_s |Σ_k c_sk x_{v_sk}|²`` over stencils s (3-vectors), with
``√weight`` (m) folded into the coefficients ``c`` (1/m), so ``D_s`` is
dimensionless and E is in J with k_b in N·m.  Hessian
``Q = k_b Σ_s c_s c_sᵀ ⊗ I₃``: constant per topology, forces ``f = −Q x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["BendStencils", "bend_stencils", "bend_energy", "bend_matrix"]

_OCT = np.pi / 4.0


@dataclass(frozen=True)
class BendStencils:
    """The bending stencils of one topology.

    Attributes:
        kinds: tuple of ``(vertices (s, k) int64, coef (s, k) float)`` pairs:
            stencil s is ``D_s = Σ_j coef[s, j] x[vertices[s, j]]`` (coef in
            1/m, D_s dimensionless); padding entries repeat a
            vertex of the stencil with coefficient 0.  Kind 0 has k = 4 (lines
            and twists), kind 1 the fitted stencils (k the largest two-ring).
    """

    kinds: tuple


def _directions(uv: np.ndarray, tri: np.ndarray):
    """Directed edges ``(i, j)`` of the triangles and their 45° class 0..7
    (-1 when not on the 45° lattice), rest length h (m)."""
    i = tri[:, [0, 1, 2, 1, 2, 0]].ravel()
    j = tri[:, [1, 2, 0, 0, 1, 2]].ravel()
    key = np.unique(i * (len(uv) + 1) + j)
    i, j = key // (len(uv) + 1), key % (len(uv) + 1)
    d = uv[j] - uv[i]
    angle = np.arctan2(d[:, 1], d[:, 0])
    k = np.rint(angle / _OCT)
    on = np.abs(angle - k * _OCT) < 1e-7
    cls = np.where(on, k.astype(np.int64) % 8, -1)
    return i, j, cls, np.hypot(d[:, 0], d[:, 1])


def bend_stencils(uv: np.ndarray, tri: np.ndarray,
                  clamped: np.ndarray | None = None,
                  fit: np.ndarray | None = None) -> BendStencils:
    """Stencils of the squared-Hessian energy (module docstring) of the mesh
    with rest coordinates ``uv`` ``(n, 2)`` m and triangles ``tri`` ``(t, 3)``
    ``(apex, left, right)`` (apex at the right angle).

    ``clamped``: ``(n,)`` bool, vertices held (pins, grasps), or None.  Where
    they hold whole triangles (a clamp: a patch held rigidly) the sheet's
    energy is that of the free part with a clamped border: those triangles
    carry no area, and a line
    stencil centred on a clamped vertex with one clamped neighbour becomes
    the one-sided second difference from the free side with the clamp's
    tangent, ``2/h₊ [(x₊ − x)/h₊ − (x − x₋)/h₋]`` (second order at the
    border, where the curvature jumps; the central one there measures half
    of it, which makes a clamped strip behave as if clamped half a cell
    inside the clamp: ``2a/l`` too soft for overhang l); a diamond with one
    triangle clamped (the twist across the border) likewise counts twice its
    central value over its free half.

    ``fit``: ``(n,)`` bool, the vertices whose fitted stencils are made
    (None: all that need one).  For a piece of a mesh cut out around some
    vertices (:mod:`cloth_lod_ros.sim.lod.merge_energy`): the cut's own
    border needs fits nobody reads.
    """
    uv = np.asarray(uv, dtype=np.float64)
    tri = np.asarray(tri, dtype=np.int64)
    n, t = len(uv), len(tri)
    held = np.zeros(n, dtype=bool)
    if clamped is not None:
        # Held particles clamp the sheet where they hold whole triangles (a
        # patch); one held particle alone is a point constraint, not a clamp.
        whole = np.asarray(clamped, dtype=bool)[tri].all(axis=1)
        held[tri[whole].ravel()] = True
    di, dj, dcls, dlen = _directions(uv, tri)
    nb = np.full(8 * n, -1, dtype=np.int64)
    nlen = np.zeros(8 * n)
    ok = dcls >= 0
    nb[8 * di[ok] + dcls[ok]] = dj[ok]
    nlen[8 * di[ok] + dcls[ok]] = dlen[ok]

    apex, left, right = tri[:, 0], tri[:, 1], tri[:, 2]
    d_u = uv[left] - uv[apex]
    d_v = uv[right] - uv[apex]
    area = 0.5 * np.abs(d_u[:, 0] * d_v[:, 1] - d_u[:, 1] * d_v[:, 0])
    area = np.where(held[tri].all(axis=1), 0.0, area)
    cls_u = np.rint(np.arctan2(d_u[:, 1], d_u[:, 0]) / _OCT).astype(np.int64) % 4
    cls_v = np.rint(np.arctan2(d_v[:, 1], d_v[:, 0]) / _OCT).astype(np.int64) % 4
    # Corners (vertex, area α, triangle): right angle ½A, the 45° ones ¼A.
    c_vertex = np.concatenate([apex, left, right])
    c_area = np.concatenate([0.5 * area, 0.25 * area, 0.25 * area])
    c_tri = np.tile(np.arange(t), 3)
    # Each corner asks for the lines along its triangle's two leg classes.
    q_vertex = np.concatenate([c_vertex, c_vertex])
    q_class = np.concatenate([cls_u[c_tri], cls_v[c_tri]])
    q_area = np.concatenate([c_area, c_area])
    plus, minus = nb[8 * q_vertex + q_class], nb[8 * q_vertex + q_class + 4]
    have = (plus >= 0) & (minus >= 0)
    line_key = 4 * q_vertex[have] + q_class[have]
    weight = np.bincount(line_key, weights=q_area[have], minlength=4 * n)
    keys = np.flatnonzero(weight)
    lv, lc = keys // 4, keys % 4
    jp, jm = nb[8 * lv + lc], nb[8 * lv + lc + 4]
    hp, hm = nlen[8 * lv + lc], nlen[8 * lv + lc + 4]
    root = np.sqrt(weight[keys])
    cp = root * 2.0 / (hp * (hp + hm))
    cm = root * 2.0 / (hm * (hp + hm))
    # At a clamp's border: one-sided from the free side (h_f the free spacing).
    side = held[lv] & (held[jp] != held[jm])
    h_f = np.where(held[jp], hm, hp)
    h_c = np.where(held[jp], hp, hm)
    c_free = root * 2.0 / h_f**2
    c_held = root * 2.0 / (h_f * h_c)
    cp = np.where(side, np.where(held[jp], c_held, c_free), cp)
    cm = np.where(side, np.where(held[jp], c_free, c_held), cm)
    line_v = np.column_stack([lv, jp, jm, lv])
    line_c = np.column_stack([-(cp + cm), cp, cm, np.zeros(len(keys))])

    # Diamonds: hypotenuse (left, right) of two triangles.
    lo, hi = np.minimum(left, right), np.maximum(left, right)
    hyp_key = lo * n + hi
    order = np.argsort(hyp_key, kind="stable")
    sk = hyp_key[order]
    pair = np.flatnonzero(sk[1:] == sk[:-1])
    t0, t1 = order[pair], order[pair + 1]
    in_diamond = np.zeros(t, dtype=bool)
    in_diamond[t0] = in_diamond[t1] = True
    a2 = 0.5 * np.sum((uv[left[t0]] - uv[right[t0]]) ** 2, axis=1)     # leg², m²
    tw = np.sqrt(2.0 * (area[t0] + area[t1])) / a2
    # A diamond across a clamp's border (one triangle held) measures the
    # twist across the jump: one-sided, twice the central value.
    tw = np.where((area[t0] == 0.0) != (area[t1] == 0.0), 2.0 * tw, tw)
    twist_v = np.column_stack([left[t0], right[t0], apex[t0], apex[t1]])
    twist_c = np.column_stack([tw, tw, -tw, -tw])

    kinds = [(np.concatenate([line_v, twist_v]), np.concatenate([line_c, twist_c]))]

    # Missing terms: a quadratic form G_i in h = (H_11, H_22, H_12) per vertex.
    G = np.zeros((n, 3, 3))
    miss = ~have
    d = np.stack([np.cos(q_class[miss] * _OCT), np.sin(q_class[miss] * _OCT)], axis=1)
    vec = np.stack([d[:, 0] ** 2, d[:, 1] ** 2, 2 * d[:, 0] * d[:, 1]], axis=1)   # dᵀHd
    np.add.at(G, q_vertex[miss], q_area[miss, None, None] * vec[:, :, None] * vec[:, None, :])
    lonely = np.flatnonzero(~in_diamond)
    if len(lonely):
        cs = np.isin(c_tri, lonely)
        u = np.stack([np.cos(cls_u[c_tri[cs]] * _OCT), np.sin(cls_u[c_tri[cs]] * _OCT)], axis=1)
        v = np.stack([np.cos(cls_v[c_tri[cs]] * _OCT), np.sin(cls_v[c_tri[cs]] * _OCT)], axis=1)
        # uᵀHv = u1 v1 H11 + u2 v2 H22 + (u1 v2 + u2 v1) H12; weight 2α.
        vec = np.stack([u[:, 0] * v[:, 0], u[:, 1] * v[:, 1],
                        u[:, 0] * v[:, 1] + u[:, 1] * v[:, 0]], axis=1)
        np.add.at(G, c_vertex[cs], 2.0 * c_area[cs, None, None]
                  * vec[:, :, None] * vec[:, None, :])
    fitted = np.flatnonzero(np.abs(G).reshape(n, 9).sum(axis=1) > 0)
    if fit is not None:
        fitted = fitted[np.asarray(fit, dtype=bool)[fitted]]
    if len(fitted):
        # Fits see the free sheet and the clamp's border, not the clamp's
        # inside (flat: a fit across the curvature's jump would blur it).
        border = held & np.isin(np.arange(n), tri[~held[tri].all(axis=1)].ravel())
        kinds.append(_fitted(uv, tri, fitted, G[fitted], ~held | border))
    return BendStencils(kinds=tuple(kinds))


def _fitted(uv, tri, vertices, G, usable):
    """Stencils ``R W`` with ``Rᵀ R = G`` and ``W`` the least-squares Hessian
    ``(H_11, H_22, H_12)`` of each vertex's two-ring (rest coordinates).

    ``uv`` ``(n, 2)`` m, ``tri`` ``(t, 3)``, ``vertices`` ``(f,)`` the fitted
    vertices, ``G`` ``(f, 3, 3)`` their forms (m²), ``usable`` ``(n,)`` bool
    the vertices a fit may see.  Returns ``(V, C)`` ``(s, k)``: stencil rows
    in the order of ``vertices``, each vertex's rows in ascending eigenvalue
    order of its ``G`` (k the largest two-ring + 1, padded with the vertex
    itself, coefficient 0).  The fits are batched over vertices with the
    same ring size (one LAPACK call per size instead of one per vertex; the
    results are bit for bit those of fitting one vertex at a time).
    """
    n = len(uv)
    rows = tri[:, [0, 1, 2, 1, 2, 0]].ravel()
    cols = tri[:, [1, 2, 0, 0, 1, 2]].ravel()
    adj = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    adj.data[:] = 1.0
    ring = (adj[vertices] @ adj + adj[vertices]).tocsr()
    owner = np.repeat(np.arange(len(vertices)), np.diff(ring.indptr))
    take = (ring.indices != vertices[owner]) & usable[ring.indices]
    nbr_all, owner = ring.indices[take], owner[take]        # grouped by owner, CSR order
    size = np.bincount(owner, minlength=len(vertices))
    first = np.concatenate([[0], np.cumsum(size)[:-1]])
    w, Q = np.linalg.eigh(G)                                 # (f, 3) ascending, (f, 3, 3)
    # R's rows: the eigenvalues above the cut, the last ``kept`` (ascending order).
    keep = w > 1e-12 * np.maximum(w.max(axis=1), 1e-300)[:, None]
    kept = keep.sum(axis=1)
    width = int(size.max()) + 1
    V = np.repeat(vertices[:, None, None], 3, axis=1).repeat(width, axis=2)  # (f, 3, width)
    C = np.zeros((len(vertices), 3, width))
    for m in np.unique(size):
        r = np.flatnonzero(size == m)
        nbrs = nbr_all[first[r, None] + np.arange(m)]        # (g, m)
        d = uv[nbrs] - uv[vertices[r], None, :]              # (g, m, 2)
        scale = np.sqrt(np.mean(np.sum(d * d, axis=2), axis=1))[:, None, None]
        s = d / scale
        P = np.concatenate([s, 0.5 * s**2, s[:, :, :1] * s[:, :, 1:]], axis=2)   # (g, m, 5)
        pinv = np.linalg.pinv(P)[:, 2:] / scale**2            # (g, 3, m): H from x_j − x_i
        W = np.concatenate([-pinv.sum(axis=2, keepdims=True), pinv], axis=2)    # over [i, nbrs]
        V[r, :, 1:m + 1] = nbrs[:, None, :]
        # Grouped by k too: R W is a (k, 3) @ (3, m + 1) product whose rounding
        # depends on k (one row goes to BLAS's gemv), so the stencils are the
        # same numbers as one vertex at a time (trajectories to the last bit).
        for k in (1, 2, 3):
            sel = np.flatnonzero(kept[r] == k)
            if len(sel):
                rk = r[sel]
                R = np.sqrt(w[rk, 3 - k:])[:, :, None] * np.swapaxes(Q[rk][:, :, 3 - k:], 1, 2)
                C[rk, 3 - k:, :m + 1] = R @ W[sel]          # (g_k, k, m + 1)
    return V[keep], C[keep]


def bend_energy(stencils: BendStencils, bend_stiffness: float, x: np.ndarray) -> float:
    """``k_b/2 Σ_s |D_s x|²`` in J at positions ``x`` ``(n, 3)`` m."""
    total = 0.0
    for verts, coef in stencils.kinds:
        D = np.einsum("sk,skd->sd", coef, x[verts])
        total += float(np.sum(D * D))
    return 0.5 * bend_stiffness * total


def bend_matrix(stencils: BendStencils, n: int) -> sp.csr_matrix:
    """The scalar ``(n, n)`` matrix ``Σ_s c_s c_sᵀ`` (1/m²): the Hessian of the
    bend energy is ``k_b`` times it, ⊗ I₃."""
    mats = []
    for verts, coef in stencils.kinds:
        s, k = verts.shape
        rows = np.repeat(np.arange(s), k)
        mats.append(sp.csr_matrix((coef.ravel(), (rows, verts.ravel())), shape=(s, n)))
    D = sp.vstack(mats).tocsr()
    return (D.T @ D).tocsr()

