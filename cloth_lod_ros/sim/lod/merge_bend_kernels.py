"""Compiled (numba) bend part of the merge energies: for every candidate, the
stencil energy of its piece of mesh before and after its merge, the numbers
of :func:`cloth_lod_ros.sim.lod.merge_bend.merge_bend_change` (the same
pieces, centres and stencils, :func:`~cloth_lod_ros.sim.physics.bending.bend_stencils`'
formulas written out for one small mesh; rounding differs: the fits' ring
order and LAPACK's pinv in numba's build, compared within
``test/tolerances.py``).

Per candidate: a breadth-first search from m gives the graph distances; the
piece is the triangles touching the ball of radius ``centre radius + 1`` (+ 2
with a clamp within distance 4, where the centre radius is 3 instead of 2),
without m's children and with its parents; the energy after is the sum of
the piece's stencils centred within the centre radius, the energy before
the current stencils' energies summed over the same vertices (given per
vertex).  One loop over candidates in one call, no Python per candidate.
"""

from __future__ import annotations

import math

import numpy as np

from ..runtime import compiled as _compiled
from ..runtime.compiled import _as_float, _as_index, _jit
from .merge_bend import merge_bend_change

__all__ = ["bend_changes"]

_OCT = math.pi / 4.0


#: cos and sin of the 45° classes 0..7.
_COS = np.array([math.cos(k * _OCT) for k in range(8)])
_SIN = np.array([math.sin(k * _OCT) for k in range(8)])


@_jit
def _direction_class(du, dv):
    """45° class 0..7 of the direction (du, dv), -1 off the lattice (within
    1e-7 rad, bending._directions' test; comparisons instead of atan2)."""
    ax, ay = abs(du), abs(dv)
    tol = 1e-7 * max(ax, ay)
    if ay <= tol:
        return 0 if du > 0 else 4
    if ax <= tol:
        return 2 if dv > 0 else 6
    if abs(ax - ay) <= tol:
        if du > 0:
            return 1 if dv > 0 else 7
        return 3 if dv > 0 else 5
    return -1


@_jit
def _least_squares(P, y, m, out):
    """``out[r, d]`` = component 2 + r of the least-squares solution of
    ``P[:m] β = y[:m, d]`` (P ``(m, 5)``), by modified Gram-Schmidt with
    re-orthogonalisation (backward stable).  False where P is rank deficient."""
    Qm = np.empty((m, 5))
    R = np.zeros((5, 5))
    for c in range(5):
        for j in range(m):
            Qm[j, c] = P[j, c]
        for _ in range(2):
            for b in range(c):
                dot = 0.0
                for j in range(m):
                    dot += Qm[j, b] * Qm[j, c]
                R[b, c] += dot
                for j in range(m):
                    Qm[j, c] -= dot * Qm[j, b]
        norm = 0.0
        for j in range(m):
            norm += Qm[j, c] * Qm[j, c]
        norm = math.sqrt(norm)
        R[c, c] = norm
        if not norm > 1e-10 * math.sqrt(m):          # columns of P are O(1)
            return False
        for j in range(m):
            Qm[j, c] /= norm
    z = np.empty(5)
    for d in range(3):
        for c in range(2, 5):
            z[c] = 0.0
            for j in range(m):
                z[c] += Qm[j, c] * y[j, d]
        b4 = z[4] / R[4, 4]
        b3 = (z[3] - R[3, 4] * b4) / R[3, 3]
        b2 = (z[2] - R[2, 3] * b3 - R[2, 4] * b4) / R[2, 2]
        out[0, d], out[1, d], out[2, d] = b2, b3, b4
    return True


@_jit
def _piece_energy(tl, luv, lclamped, lx, centre, lid):
    """Σ |D_s x|² over the stencils of the small mesh ``tl`` ``(t, 3)`` (local
    ids, (apex, left, right)) centred where ``centre`` ``(l,)`` is True
    (bending.bend_stencils' stencils, its clamp rules; ``lid`` ``(l,)`` the
    ids whose order decides a twist's centre, as merge_bend.stencil_centres)."""
    nl, nt = luv.shape[0], tl.shape[0]
    whole = np.zeros(nt, dtype=np.bool_)
    held = np.zeros(nl, dtype=np.bool_)
    for T in range(nt):
        whole[T] = lclamped[tl[T, 0]] and lclamped[tl[T, 1]] and lclamped[tl[T, 2]]
        if whole[T]:
            for j in range(3):
                held[tl[T, j]] = True
    nb = np.full((nl, 8), -1, dtype=np.int64)
    nlen = np.zeros((nl, 8))
    adj = np.full((nl, 8), -1, dtype=np.int64)       # undirected neighbours (valence ≤ 8)
    area = np.empty(nt)
    cls_u = np.empty(nt, dtype=np.int64)
    cls_v = np.empty(nt, dtype=np.int64)
    not_whole_held = np.zeros(nl, dtype=np.bool_)    # in a triangle not all held
    for T in range(nt):
        for j in range(3):
            a = tl[T, j]
            for jj in range(3):
                if jj == j:
                    continue
                b = tl[T, jj]
                du, dv = luv[b, 0] - luv[a, 0], luv[b, 1] - luv[a, 1]
                c = _direction_class(du, dv)
                if c >= 0:
                    nb[a, c] = b
                    nlen[a, c] = math.hypot(du, dv)
                for s in range(8):
                    if adj[a, s] == b:
                        break
                    if adj[a, s] < 0:
                        adj[a, s] = b
                        break
        a0, a1, a2 = tl[T, 0], tl[T, 1], tl[T, 2]
        d1u, d1v = luv[a1, 0] - luv[a0, 0], luv[a1, 1] - luv[a0, 1]
        d2u, d2v = luv[a2, 0] - luv[a0, 0], luv[a2, 1] - luv[a0, 1]
        all_held = held[a0] and held[a1] and held[a2]
        area[T] = 0.0 if all_held else 0.5 * abs(d1u * d2v - d1v * d2u)
        if not all_held:
            not_whole_held[a0] = not_whole_held[a1] = not_whole_held[a2] = True
        cls_u[T] = _direction_class(d1u, d1v) % 4       # legs are on the lattice
        cls_v[T] = _direction_class(d2u, d2v) % 4

    # Corners at the centres: line weights (a line exists) or missing lines (G).
    weight = np.zeros((nl, 4))
    G = np.zeros((nl, 3, 3))
    vec = np.empty(3)
    for T in range(nt):
        for j in range(3):
            q = tl[T, j]
            if not centre[q]:
                continue
            alpha = (0.5 if j == 0 else 0.25) * area[T]
            for c in (cls_u[T], cls_v[T]):
                if nb[q, c] >= 0 and nb[q, c + 4] >= 0:
                    weight[q, c] += alpha
                else:
                    d0, d1 = _COS[c], _SIN[c]
                    vec[0], vec[1], vec[2] = d0 * d0, d1 * d1, 2.0 * d0 * d1
                    for r in range(3):
                        for s in range(3):
                            G[q, r, s] += alpha * vec[r] * vec[s]
    energy = 0.0
    for q in range(nl):
        if not centre[q]:
            continue
        for c in range(4):
            if weight[q, c] <= 0.0:
                continue
            jp, jm = nb[q, c], nb[q, c + 4]
            hp, hm = nlen[q, c], nlen[q, c + 4]
            root = math.sqrt(weight[q, c])
            if held[q] and held[jp] != held[jm]:       # one-sided at a clamp's border
                h_f = hm if held[jp] else hp
                h_c = hp if held[jp] else hm
                c_free = root * 2.0 / (h_f * h_f)
                c_held = root * 2.0 / (h_f * h_c)
                cp = c_held if held[jp] else c_free
                cm = c_free if held[jp] else c_held
            else:
                cp = root * 2.0 / (hp * (hp + hm))
                cm = root * 2.0 / (hm * (hp + hm))
            for d in range(3):
                D = -(cp + cm) * lx[q, d] + cp * lx[jp, d] + cm * lx[jm, d]
                energy += D * D

    # Diamonds: two triangles with the same hypotenuse (left, right).
    key = np.empty(nt, dtype=np.int64)
    for T in range(nt):
        lo, hi = min(tl[T, 1], tl[T, 2]), max(tl[T, 1], tl[T, 2])
        key[T] = lo * nl + hi
    order = np.argsort(key, kind="mergesort")
    in_diamond = np.zeros(nt, dtype=np.bool_)
    for p in range(nt - 1):
        t0, t1 = order[p], order[p + 1]
        if key[t0] != key[t1]:
            continue
        in_diamond[t0] = in_diamond[t1] = True
        e0, e1 = tl[t0, 1], tl[t0, 2]
        owner = e0 if lid[e0] < lid[e1] else e1
        if not centre[owner]:
            continue
        du, dv = luv[e0, 0] - luv[e1, 0], luv[e0, 1] - luv[e1, 1]
        leg2 = 0.5 * (du * du + dv * dv)
        tw = math.sqrt(2.0 * (area[t0] + area[t1])) / leg2
        if (area[t0] == 0.0) != (area[t1] == 0.0):
            tw = 2.0 * tw
        o0, o1 = tl[t0, 0], tl[t1, 0]
        for d in range(3):
            D = tw * (lx[e0, d] + lx[e1, d] - lx[o0, d] - lx[o1, d])
            energy += D * D
    # Missing twists: the corners of triangles without a diamond.
    for T in range(nt):
        if in_diamond[T]:
            continue
        u0, u1 = _COS[cls_u[T]], _SIN[cls_u[T]]
        v0, v1 = _COS[cls_v[T]], _SIN[cls_v[T]]
        vec[0], vec[1], vec[2] = u0 * v0, u1 * v1, u0 * v1 + u1 * v0
        for j in range(3):
            q = tl[T, j]
            if not centre[q]:
                continue
            alpha = (0.5 if j == 0 else 0.25) * area[T]
            for r in range(3):
                for s in range(3):
                    G[q, r, s] += 2.0 * alpha * vec[r] * vec[s]

    # Fits: the least-squares Hessian of the two-ring (usable vertices only).
    usable = np.empty(nl, dtype=np.bool_)
    for v in range(nl):
        usable[v] = (not held[v]) or not_whole_held[v]
    mark = np.full(nl, -1, dtype=np.int64)
    ring = np.empty(nl, dtype=np.int64)
    P = np.empty((nl, 5))
    y = np.empty((nl, 3))
    hess = np.empty((3, 3))              # (H_11, H_22, H_12) × component, in scaled units
    for q in range(nl):
        if not centre[q]:
            continue
        size = 0.0
        for r in range(3):
            for s in range(3):
                size += abs(G[q, r, s])
        if not size > 0.0:
            continue
        m = 0
        mark[q] = q
        for a in range(8):
            b = adj[q, a]
            if b < 0:
                break
            if mark[b] != q:
                mark[b] = q
                if usable[b]:
                    ring[m] = b
                    m += 1
            for aa in range(8):
                c = adj[b, aa]
                if c < 0:
                    break
                if mark[c] != q:
                    mark[c] = q
                    if usable[c]:
                        ring[m] = c
                        m += 1
        mean = 0.0
        for j in range(m):
            du, dv = luv[ring[j], 0] - luv[q, 0], luv[ring[j], 1] - luv[q, 1]
            mean += du * du + dv * dv
        scale = math.sqrt(mean / m)
        for j in range(m):
            su = (luv[ring[j], 0] - luv[q, 0]) / scale
            sv = (luv[ring[j], 1] - luv[q, 1]) / scale
            P[j, 0], P[j, 1] = su, sv
            P[j, 2], P[j, 3], P[j, 4] = 0.5 * su * su, 0.5 * sv * sv, su * sv
        for d in range(3):
            for j in range(m):
                y[j, d] = lx[ring[j], d] - lx[q, d]
        if not _least_squares(P, y, m, hess):
            # Rank deficient (too few or aligned neighbours): the pseudo-inverse.
            pinv = np.linalg.pinv(P[:m])
            for r in range(3):
                for d in range(3):
                    hess[r, d] = 0.0
                    for j in range(m):
                        hess[r, d] += pinv[2 + r, j] * y[j, d]
        # Σ_e w_e (Q_eᵀ H)² over G's eigenpairs is Hᵀ G H (bend_stencils drops
        # eigenvalues below 1e-12 of the largest: rounding noise around 0).
        inv = 1.0 / (scale * scale)
        for d in range(3):
            for r in range(3):
                for s in range(3):
                    energy += hess[r, d] * G[q, r, s] * hess[s, d] * inv * inv
    return energy


@_jit
def _bend_changes(mid, parent_tri, has, tri, uv, clamped, any_clamped, vt_ptr, vt_idx, x,
                  per_vertex, before, after):
    """Energies (Σ|D|², unscaled) before and after each candidate's merge.

    Args:
        mid ``(k,)`` compact m; parent_tri ``(k, 2, 3)`` the parents' compact
        corners, has ``(k, 2)`` which exist; tri ``(t, 3)``, uv ``(n, 2)`` m,
        clamped ``(n,)`` bool, any_clamped: the compact mesh; vt_ptr, vt_idx:
        its vertex → triangle lists (CSR); x ``(n, 3)`` m; per_vertex ``(n,)``
        the current stencils' Σ|D|² per centre.
        before, after: ``(k,)`` outputs.
    """
    n, t = uv.shape[0], tri.shape[0]
    dist = np.full(n, -1, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)
    tri_mark = np.full(t, -1, dtype=np.int64)
    local_of = np.full(n, -1, dtype=np.int64)
    piece = np.empty((t + 2, 3), dtype=np.int64)
    lverts = np.empty(n, dtype=np.int64)
    deepest = 5 if any_clamped else 3
    for i in range(mid.shape[0]):
        m = mid[i]
        head, tail = 0, 1
        queue[0] = m
        dist[m] = 0
        while head < tail:
            v = queue[head]
            head += 1
            if dist[v] >= deepest:
                continue
            for p in range(vt_ptr[v], vt_ptr[v + 1]):
                for j in range(3):
                    w = tri[vt_idx[p], j]
                    if dist[w] < 0:
                        dist[w] = dist[v] + 1
                        queue[tail] = w
                        tail += 1
        rc, radius = 2, 3
        if any_clamped:
            for q in range(tail):
                if dist[queue[q]] <= 4 and clamped[queue[q]]:
                    rc, radius = 3, 5
                    break
        total = 0.0
        for q in range(tail):
            if dist[queue[q]] <= rc:
                total += per_vertex[queue[q]]
        before[i] = total
        # The piece after the merge: the triangles touching the ball, less the
        # children (those with m), and the parents.
        count, nl = 0, 0
        for q in range(tail):
            v = queue[q]
            if dist[v] > radius:
                break                               # (breadth-first: in distance order)
            for p in range(vt_ptr[v], vt_ptr[v + 1]):
                T = vt_idx[p]
                if tri_mark[T] == i:
                    continue
                tri_mark[T] = i
                if tri[T, 0] == m or tri[T, 1] == m or tri[T, 2] == m:
                    continue
                for j in range(3):
                    piece[count, j] = tri[T, j]
                count += 1
        for s in range(2):
            if has[i, s]:
                for j in range(3):
                    piece[count, j] = parent_tri[i, s, j]
                count += 1
        tl = np.empty((count, 3), dtype=np.int64)
        for T in range(count):
            for j in range(3):
                v = piece[T, j]
                if local_of[v] < 0:
                    local_of[v] = nl
                    lverts[nl] = v
                    nl += 1
                tl[T, j] = local_of[v]
        luv = np.empty((nl, 2))
        lx = np.empty((nl, 3))
        lclamped = np.empty(nl, dtype=np.bool_)
        centre = np.empty(nl, dtype=np.bool_)
        lid = np.empty(nl, dtype=np.int64)
        for a in range(nl):
            v = lverts[a]
            luv[a, 0], luv[a, 1] = uv[v, 0], uv[v, 1]
            lx[a, 0], lx[a, 1], lx[a, 2] = x[v, 0], x[v, 1], x[v, 2]
            lclamped[a] = clamped[v]
            centre[a] = dist[v] >= 0 and dist[v] <= rc
            lid[a] = v
        after[i] = _piece_energy(tl, luv, lclamped, lx, centre, lid)
        for a in range(nl):
            local_of[lverts[a]] = -1
        for q in range(tail):
            dist[queue[q]] = -1


@_jit
def _add_per_centre(verts, coef, fitted, x, out):
    """``out[c] += |D_s x|²`` for the stencils ``verts``, ``coef`` ``(s, w)`` of
    one kind, c each one's centre (merge_bend.stencil_centres)."""
    for s in range(verts.shape[0]):
        if fitted:
            c = verts[s, 0]
        elif verts[s, 3] == verts[s, 0] and coef[s, 3] == 0.0:
            c = verts[s, 0]
        else:
            c = min(verts[s, 0], verts[s, 1])
        for d in range(3):
            D = 0.0
            for j in range(verts.shape[1]):
                D += coef[s, j] * x[verts[s, j], d]
            out[c] += D * D


def bend_changes(hierarchy, elements, vertex_ids, vertices, mid, x, bend_stiffness):
    """:func:`~cloth_lod_ros.sim.lod.merge_bend.merge_bend_change` by
    :func:`_bend_changes` (same arguments), or by that numpy reference when
    the kernels are off."""
    k = len(vertices)
    if (not _compiled.enabled() or k == 0 or not elements.bend.kinds
            or elements.rest_uv is None):
        return merge_bend_change(hierarchy, elements, vertex_ids, vertices, mid, x,
                                 bend_stiffness)
    h = hierarchy
    tri = _as_index(elements.triangles)
    n, t = len(x), len(tri)
    parents = h.vertex_parents[vertices]
    has = parents >= 0
    parent_tri = np.searchsorted(vertex_ids, h.tri[np.maximum(parents, 0)])
    order = np.argsort(tri.ravel(), kind="stable")
    vt_idx = order // 3
    vt_ptr = np.concatenate([[0], np.cumsum(np.bincount(tri.ravel(), minlength=n))])
    clamped = (np.zeros(n, dtype=bool) if elements.clamped is None
               else np.ascontiguousarray(elements.clamped, dtype=bool))
    x = _as_float(x)
    per_vertex = np.zeros(n)
    for kind, (verts, coef) in enumerate(elements.bend.kinds):
        _add_per_centre(_as_index(verts), _as_float(coef), kind == 1, x, per_vertex)
    before, after = np.empty(k), np.empty(k)
    _bend_changes(_as_index(mid), _as_index(parent_tri), np.ascontiguousarray(has),
                  tri, _as_float(elements.rest_uv), clamped, bool(clamped.any()),
                  _as_index(vt_ptr), _as_index(vt_idx), x, per_vertex, before, after)
    return 0.5 * bend_stiffness * (after - before)
