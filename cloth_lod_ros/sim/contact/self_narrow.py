"""The narrow phase of self-collision (design §3): closest points and
continuous (swept) tests, vectorised over many pairs (the candidates come
from :mod:`.self_broad`).

* :func:`point_triangle` and :func:`segment_segment` - closest points
  (Ericson, *Real-Time Collision Detection*, §5.1.5 and §5.1.9).
* :func:`vf_crossing` and :func:`ee_crossing` - continuous tests over a step
  in which every particle moves on a straight line from ``x0`` to ``x1``:
  the time of coplanarity of the four points is a root of a cubic in t
  (Provot 1997; Bridson et al. 2002), found by splitting [0, 1] at the roots
  of the derivative into monotonic pieces and bisecting each piece whose ends
  differ in sign (32 halvings: the root to 2e-10 of the step, far below
  ``eta`` for any motion a step makes); at each root
  the two primitives are tested for proximity (``eta``, m).  A crossing of a
  layer (a vertex through a triangle or an edge through an edge) changes the
  sign of that cubic, so every crossing is found; a grazing touch that does
  not change sides may be missed, and that is not a crossing.  Four points
  that stay coplanar for the whole step (|f| never above rounding) are not
  reported: their order is not a side.

Positions in m, times as fractions of the step.
"""

from __future__ import annotations

import numpy as np


__all__ = ["point_triangle", "segment_segment", "vf_crossing", "ee_crossing"]


def _dot(a, b):
    return np.einsum("kd,kd->k", a, b)


def point_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(k, 3)`` of the point of triangle ``abc``
    nearest ``p`` (all ``(k, 3)``, m); Ericson §5.1.5, region by region."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        total = va + vb + vc
        v = np.where(total != 0, vb / total, 1.0 / 3.0)
        w = np.where(total != 0, vc / total, 1.0 / 3.0)
        bary = np.stack([1.0 - v - w, v, w], axis=1)
        # Later assignments win: this is Ericson's order of tests, reversed.
        e_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        s = (d4 - d3) / np.where(e_bc, (d4 - d3) + (d5 - d6), 1.0)
        bary[e_bc] = np.stack([np.zeros_like(s), 1 - s, s], axis=1)[e_bc]
        e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        s = d2 / np.where(e_ac, d2 - d6, 1.0)
        bary[e_ac] = np.stack([1 - s, np.zeros_like(s), s], axis=1)[e_ac]
        bary[(d6 >= 0) & (d5 <= d6)] = (0.0, 0.0, 1.0)
        e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        s = d1 / np.where(e_ab, d1 - d3, 1.0)
        bary[e_ab] = np.stack([1 - s, s, np.zeros_like(s)], axis=1)[e_ab]
        bary[(d3 >= 0) & (d4 <= d3)] = (0.0, 1.0, 0.0)
        bary[(d1 <= 0) & (d2 <= 0)] = (1.0, 0.0, 0.0)
    return bary


def segment_segment(p1, q1, p2, q2) -> tuple[np.ndarray, np.ndarray]:
    """Parameters ``(s, t)`` ``(k,)`` in [0, 1] of the closest points
    ``p1 + s (q1 − p1)`` and ``p2 + t (q2 − p2)`` (Ericson §5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    tiny = 1e-30
    a_safe, e_safe = np.maximum(a, tiny), np.maximum(e, tiny)
    denom = a * e - b * b
    s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / np.where(
        denom > 1e-12 * a * e, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    low, high = t < 0.0, t > 1.0
    s = np.where(low, np.clip(-c / a_safe, 0.0, 1.0), s)
    s = np.where(high, np.clip((b - c) / a_safe, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    return s, t


def _cubic(b0, db, c0, dc, d0, dd):
    """Coefficients ``(4, k)`` of ``((b0 + t db) × (c0 + t dc)) · (d0 + t dd)``."""
    bc0 = np.cross(b0, c0)
    bc1 = np.cross(b0, dc) + np.cross(db, c0)
    bc2 = np.cross(db, dc)
    return np.stack([_dot(bc0, d0), _dot(bc0, dd) + _dot(bc1, d0),
                     _dot(bc1, dd) + _dot(bc2, d0), _dot(bc2, dd)])


def _roots01(coef: np.ndarray) -> np.ndarray:
    """Roots in [0, 1] of cubics ``(4, k)`` at which the sign changes,
    ``(k, 3)`` (NaN: none in that monotonic piece)."""
    c0, c1, c2, c3 = coef
    k = coef.shape[1]
    w0, w1, w2, w3 = (c[:, None] for c in coef)

    def f(t):                               # t: (k, 3)
        return ((w3 * t + w2) * t + w1) * t + w0

    # Pieces: [0, 1] split at the derivative's roots 3c3 t² + 2c2 t + c1 = 0.
    qa, qb, qc = 3 * c3, 2 * c2, c1
    disc = qb * qb - 4 * qa * qc
    sq = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = np.abs(qa) > 1e-300
        r1 = np.where(quad, (-qb - sq) / (2 * qa), np.where(qb != 0, -qc / qb, np.nan))
        r2 = np.where(quad, (-qb + sq) / (2 * qa), np.nan)
    r1 = np.where(disc >= 0, r1, np.nan)
    r2 = np.where(disc >= 0, r2, np.nan)
    crit = np.sort(np.stack([r1, r2], axis=1), axis=1)            # NaN last
    crit = np.where((crit > 0) & (crit < 1), crit, np.nan)
    crit = np.sort(crit, axis=1)
    bounds = np.column_stack([np.zeros(k), crit, np.ones(k)])    # (k, 4) with NaN gaps
    # Fill gaps so each piece [lo, hi] is valid (empty pieces have lo == hi).
    for col in (1, 2):
        bounds[:, col] = np.where(np.isnan(bounds[:, col]), bounds[:, col - 1], bounds[:, col])
    bounds[:, 1:3] = np.maximum.accumulate(bounds[:, 1:3], axis=1)
    lo, hi = bounds[:, :3], bounds[:, 1:]
    flo, fhi = f(lo), f(hi)
    scale = np.abs(coef).sum(axis=0)[:, None]
    noise = 1e-12 * scale                  # coplanar throughout: no sign to change
    change = (hi > lo) & (((flo <= 0) & (fhi >= 0)) | ((flo >= 0) & (fhi <= 0))) \
        & ((np.abs(flo) > noise) | (np.abs(fhi) > noise))
    # Bisect only the pieces that hold a root (few: most pairs never meet).
    rows, cols = np.nonzero(change)
    a, b = lo[rows, cols], hi[rows, cols]
    rising = fhi[rows, cols] > flo[rows, cols]
    p0, p1, p2, p3 = c0[rows], c1[rows], c2[rows], c3[rows]
    for _ in range(32):
        m = 0.5 * (a + b)
        fm = ((p3 * m + p2) * m + p1) * m + p0
        right = (fm < 0) == rising          # the root is in the right half
        a = np.where(right, m, a)
        b = np.where(right, b, m)
    out = np.full((k, 3), np.nan)
    out[rows, cols] = 0.5 * (a + b)
    return out


def vf_crossing(x0: np.ndarray, x1: np.ndarray, verts: np.ndarray, tris: np.ndarray,
                eta: float) -> np.ndarray:
    """Which vertex–triangle pairs meet during the step, ``(k,)`` bool.

    Args:
        x0, x1: ``(n, 3)`` positions at the start and end of the step, m.
        verts: ``(k,)`` vertex indices; tris: ``(k, 3)`` triangle corners.
        eta: a vertex within ``eta`` m of the triangle at a coplanarity time meets it.
    """
    if not len(verts):
        return np.zeros(0, dtype=bool)
    p0, a0, b0, c0 = x0[verts], x0[tris[:, 0]], x0[tris[:, 1]], x0[tris[:, 2]]
    dp, da, db, dc = (x1[verts] - p0, x1[tris[:, 0]] - a0, x1[tris[:, 1]] - b0,
                      x1[tris[:, 2]] - c0)
    roots = _roots01(_cubic(b0 - a0, db - da, c0 - a0, dc - da, p0 - a0, dp - da))

    def gap(ok, tt):
        p, a, b, c = (p0[ok] + tt * dp[ok], a0[ok] + tt * da[ok], b0[ok] + tt * db[ok],
                      c0[ok] + tt * dc[ok])
        w = point_triangle(p, a, b, c)
        return p - (w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c)
    return _meets_at_roots(roots, gap, eta)


def ee_crossing(x0: np.ndarray, x1: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                eta: float) -> np.ndarray:
    """Which edge–edge pairs (``(k, 2)`` each) meet during the step, ``(k,)`` bool
    (see :func:`vf_crossing`)."""
    if not len(e1):
        return np.zeros(0, dtype=bool)
    p0, q0, r0, s0 = x0[e1[:, 0]], x0[e1[:, 1]], x0[e2[:, 0]], x0[e2[:, 1]]
    dp, dq, dr, ds = (x1[e1[:, 0]] - p0, x1[e1[:, 1]] - q0, x1[e2[:, 0]] - r0,
                      x1[e2[:, 1]] - s0)
    roots = _roots01(_cubic(q0 - p0, dq - dp, s0 - r0, ds - dr, r0 - p0, dr - dp))

    def gap(ok, tt):
        p, q, r, s = (p0[ok] + tt * dp[ok], q0[ok] + tt * dq[ok], r0[ok] + tt * dr[ok],
                      s0[ok] + tt * ds[ok])
        u, v = segment_segment(p, q, r, s)
        return (p + u[:, None] * (q - p)) - (r + v[:, None] * (s - r))
    return _meets_at_roots(roots, gap, eta)


def _meets_at_roots(roots: np.ndarray, gap, eta: float) -> np.ndarray:
    """``(k,)`` bool: a pair meets if, at one of its coplanarity times ``roots``
    ``(k, 3)`` (NaN: none), the closest points are within ``eta`` m.  ``gap(ok,
    t)`` gives the ``(m, 3)`` vector between the closest points of the pairs
    selected by ``ok`` at their times ``t`` ``(m, 1)``."""
    hit = np.zeros(len(roots), dtype=bool)
    for j in range(3):                      # the cubic's (up to) three roots in [0, 1]
        t = roots[:, j]
        ok = ~np.isnan(t)
        if ok.any():
            hit[np.flatnonzero(ok)[np.linalg.norm(gap(ok, t[ok, None]), axis=1) <= eta]] = True
    return hit
