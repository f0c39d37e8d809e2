"""Compiled (numba) kernels for the force evaluation and the sparse assembly.

The numpy code in :mod:`~cloth_lod_ros.sim.physics.forces` and
:meth:`~cloth_lod_ros.sim.solve.pattern.SparsePattern.assemble` is the reference
implementation; this module computes the same quantities with one compiled
loop per element kind (triangles, hinges) instead of dozens of numpy passes
over ``(3, t)`` temporaries.  The maths is exactly the reference's (BW §4.2–4.5
conditions, forces, damping and the kept Jacobians of the docstring of
:mod:`~cloth_lod_ros.sim.physics.forces`; Bridson et al. 2003 for the hinge
gradient, :mod:`.hinges_kernels`), written per element.  Units are SI:
positions m, velocities m/s, forces N, stiffness blocks N/m times the
weights.

The per-step measures have compiled twins of their own:
:mod:`.hinges_kernels` (the hinge angles: the LOD criterion, merge energies)
and :mod:`.energies_kernels` (the step's strain test, the statistics).

Selection: these functions use the kernels when
:func:`~cloth_lod_ros.sim.runtime.compiled.enabled` (numba imports and
``CLOTH_LOD_KERNELS`` is not ``numpy``); without numba everything falls back
to the numpy reference, which stays the definition.  ``error_model="numpy"``
(:mod:`~cloth_lod_ros.sim.runtime.compiled`): a degenerate element (a
zero-length edge or normal) gives inf/nan like the numpy code instead of
raising.
"""

from __future__ import annotations

import numpy as np

from . import forces as _forces
from ..runtime.compiled import _as_index, _jit, enabled
from . import hinges_kernels as _hinges_kernels


__all__ = ["evaluate", "assemble"]


@_jit
def _membrane(tri, cu, cv, area, x, v, ks, ksh, bs, bsh, c_k, c_d, air_coef, wind,
              force, kv, air_force, conditions, blocks, slots, data, mode):
    """Stretch + shear (+ air) of every triangle (BW §4.2, §4.5; design §2).

    Args:
        tri ``(t, 3)`` int64; cu, cv ``(t, 3)`` 1/m; area ``(t,)`` m²; x, v
        ``(n, 3)`` m, m/s; ks, ksh N/m; bs, bsh s; c_k, c_d the block weights
        (``γh²``, ``γh``); air_coef ``½ ρ C_d`` kg/m³ (0: no air); wind ``(3,)``
        m/s.
        force, kv, air_force: ``(n, 3)`` zeroed outputs: the membrane force (N),
            ``(∂f/∂x) v`` (N/s) and the air's face force (N), each summed in
            (triangle, corner) order like the reference's ``np.bincount``.
        conditions: ``(5, t)`` output ``C_u, C_v, C_s`` (m) and ``|w_u|, |w_v|``.
        blocks: ``(t, 81)`` output in the layout ``[e, i, a, j, b]`` of
            ``Evaluation.triangle_blocks`` (mode 1).
        slots, data: ``(t, 3, 3)`` the flat BSR data index of entry (0, 0) of
            each corner pair's block (SparsePattern.block_slots) and the flat
            data to add the blocks into (mode 2).  Adding in element order
            gives every entry the same sum as the reference's ``np.bincount``.
        mode: 0 forces only, 1 blocks into ``blocks``, 2 blocks into ``data``.
    """
    t_count = tri.shape[0]
    q = np.empty((4, 3, 3))         # Q_uu, Q_uv, Q_vu, Q_vv of one triangle
    reduced = np.empty((2, 3, 3, 3))   # R[p, j, a, b]
    face = np.zeros((3, 3))         # the air's block (the same for all nine corner pairs)
    normal = np.empty(3)
    wu = np.empty(3)
    wv = np.empty(3)
    wu_dot = np.empty(3)
    wv_dot = np.empty(3)
    du = np.empty(3)
    dv = np.empty(3)
    fu = np.empty(3)
    fv = np.empty(3)
    ku = np.empty(3)
    kvv = np.empty(3)
    for e in range(t_count):
        i0, i1, i2 = tri[e, 0], tri[e, 1], tri[e, 2]
        cu0, cu1, cu2 = cu[e, 0], cu[e, 1], cu[e, 2]
        cv0, cv1, cv2 = cv[e, 0], cv[e, 1], cv[e, 2]
        a_e = area[e]
        sa = np.sqrt(a_e)
        for d in range(3):
            wu[d] = cu0 * x[i0, d] + cu1 * x[i1, d] + cu2 * x[i2, d]
            wv[d] = cv0 * x[i0, d] + cv1 * x[i1, d] + cv2 * x[i2, d]
            wu_dot[d] = cu0 * v[i0, d] + cu1 * v[i1, d] + cu2 * v[i2, d]
            wv_dot[d] = cv0 * v[i0, d] + cv1 * v[i1, d] + cv2 * v[i2, d]
        len_u = np.sqrt(wu[0] * wu[0] + wu[1] * wu[1] + wu[2] * wu[2])
        len_v = np.sqrt(wv[0] * wv[0] + wv[1] * wv[1] + wv[2] * wv[2])
        for d in range(3):
            du[d] = wu[d] / len_u
            dv[d] = wv[d] / len_v
        # Stretch C = √A(|w| − 1), ∇_k C = √A coef_k ŵ; shear C = √A w_u·w_v.
        c_u = sa * (len_u - 1.0)
        c_v = sa * (len_v - 1.0)
        along_u = du[0] * wu_dot[0] + du[1] * wu_dot[1] + du[2] * wu_dot[2]
        along_v = dv[0] * wv_dot[0] + dv[1] * wv_dot[1] + dv[2] * wv_dot[2]
        cdot_u = sa * along_u
        cdot_v = sa * along_v
        c_s = sa * (wu[0] * wv[0] + wu[1] * wv[1] + wu[2] * wv[2])
        cdot_s = sa * ((wv[0] * wu_dot[0] + wv[1] * wu_dot[1] + wv[2] * wu_dot[2])
                       + (wu[0] * wv_dot[0] + wu[1] * wv_dot[1] + wu[2] * wv_dot[2]))
        conditions[0, e] = c_u
        conditions[1, e] = c_v
        conditions[2, e] = c_s
        conditions[3, e] = len_u
        conditions[4, e] = len_v
        # f_k = −k (C + βĊ) ∇_k C = coef_u_k F_u + coef_v_k F_v.
        shear_force = -ksh * (c_s + bsh * cdot_s) * sa
        s_u = -ks * sa * (c_u + bs * cdot_u)
        s_v = -ks * sa * (c_v + bs * cdot_v)
        # Kept stretch stiffness S = ŵŵᵀ + max(1 − 1/|w|, 0)(I − ŵŵᵀ); a NaN
        # stays NaN (as np.maximum), it is not clamped to 0.
        tens_u = 1.0 - 1.0 / len_u
        if tens_u < 0.0:
            tens_u = 0.0
        tens_v = 1.0 - 1.0 / len_v
        if tens_v < 0.0:
            tens_v = 0.0
        shear_kv = -ksh * cdot_s * sa
        k_area = -ks * a_e
        for d in range(3):
            fu[d] = s_u * du[d] + shear_force * wv[d]
            fv[d] = s_v * dv[d] + shear_force * wu[d]
            ku[d] = k_area * ((1.0 - tens_u) * along_u * du[d] + tens_u * wu_dot[d]) \
                + shear_kv * wv[d]
            kvv[d] = k_area * ((1.0 - tens_v) * along_v * dv[d] + tens_v * wv_dot[d]) \
                + shear_kv * wu[d]
        for k in range(3):
            node = tri[e, k]
            for d in range(3):
                force[node, d] += cu[e, k] * fu[d] + cv[e, k] * fv[d]
                kv[node, d] += cu[e, k] * ku[d] + cv[e, k] * kvv[d]
        if air_coef != 0.0:
            # Face drag along the normal, a third to each corner (air.air_forces).
            e1x = x[i1, 0] - x[i0, 0]
            e1y = x[i1, 1] - x[i0, 1]
            e1z = x[i1, 2] - x[i0, 2]
            e2x = x[i2, 0] - x[i0, 0]
            e2y = x[i2, 1] - x[i0, 1]
            e2z = x[i2, 2] - x[i0, 2]
            cx = e1y * e2z - e1z * e2y
            cy = e1z * e2x - e1x * e2z
            cz = e1x * e2y - e1y * e2x
            twice_area = np.sqrt((cx * cx + cz * cz) + cy * cy)     # reference's sum order
            denom = max(twice_area, 2.2250738585072014e-308)      # 0 normal if collapsed
            nx, ny, nz = cx / denom, cy / denom, cz / denom
            rx = (v[i0, 0] + v[i1, 0] + v[i2, 0]) / 3.0 - wind[0]
            ry = (v[i0, 1] + v[i1, 1] + v[i2, 1]) / 3.0 - wind[1]
            rz = (v[i0, 2] + v[i1, 2] + v[i2, 2]) / 3.0 - wind[2]
            v_n = (nx * rx + nz * rz) + ny * ry
            k_face = air_coef * 0.5 * twice_area
            corner = -k_face * np.abs(v_n) * v_n / 3.0
            for k in range(3):
                node = tri[e, k]
                air_force[node, 0] += corner * nx
                air_force[node, 1] += corner * ny
                air_force[node, 2] += corner * nz
            if mode != 0:
                scale = c_d * 2.0 * k_face * np.abs(v_n) / 9.0
                normal[0], normal[1], normal[2] = nx, ny, nz
                for a in range(3):
                    for b in range(3):
                        face[a, b] = scale * normal[a] * normal[b]
        if mode == 0:
            continue
        # Blocks Σ_pq c_p[i] c_q[j] Q_pq (forces._membrane_blocks): stretch
        # k_s A [(cK + cD β) ŵŵᵀ + cK max(1 − 1/|w|, 0)(I − ŵŵᵀ)], shear
        # (cK + cD β_sh) k_sh A ∇C ∇Cᵀ / A, in the reference's operation order.
        along = ks * a_e * (c_k + c_d * bs)
        across_scale = ks * a_e * c_k
        shear_area = (c_k + c_d * bsh) * ksh * a_e
        across_u = across_scale * tens_u
        across_v = across_scale * tens_v
        for a in range(3):
            for b in range(3):
                eye = 1.0 if a == b else 0.0
                q[0, a, b] = ((along - across_u) * du[a] * du[b] + across_u * eye) \
                    + shear_area * wv[a] * wv[b]
                q[3, a, b] = ((along - across_v) * dv[a] * dv[b] + across_v * eye) \
                    + shear_area * wu[a] * wu[b]
                q[1, a, b] = shear_area * wv[a] * wu[b]
        for a in range(3):
            for b in range(3):
                q[2, a, b] = q[1, b, a]
        # R_p[j] = Σ_q c_q[j] Q_pq, then B[i, j] = Σ_p c_p[i] R_p[j] + the air's.
        for j in range(3):
            cuj, cvj = cu[e, j], cv[e, j]
            for a in range(3):
                for b in range(3):
                    reduced[0, j, a, b] = cuj * q[0, a, b] + cvj * q[1, a, b]
                    reduced[1, j, a, b] = cuj * q[2, a, b] + cvj * q[3, a, b]
        for i in range(3):
            cui, cvi = cu[e, i], cv[e, i]
            for j in range(3):
                start = 0 if mode == 1 else slots[e, i, j]
                for a in range(3):
                    for b in range(3):
                        value = (cui * reduced[0, j, a, b] + cvi * reduced[1, j, a, b]) \
                            + face[a, b]
                        if mode == 1:
                            blocks[e, 27 * i + 9 * a + 3 * j + b] = value
                        else:
                            data[start + 3 * a + b] += value


@_jit
def _stencils(sv, sc, x, v, kb, bb, c_k, c_d, force, kv, blocks, slots, data, mode):
    """Bend of every stencil of one kind, ``E = k_b/2 |D_s x|²`` with
    ``D_s x = Σ_j c_sj x_{v_sj}`` (physics.bending; forces._bend_terms: the
    elastic force ``−k_b c D``, damping ``−k_b β_b c (D̂·Ḋ) D̂``).

    Args:
        sv ``(s, k)`` int64 vertices, sc ``(s, k)`` coefficients; x, v ``(n, 3)``;
        kb N·m; bb s; c_k, c_d block weights.
        force, kv: ``(n, 3)`` outputs to add into (N, N/s).
        blocks: ``(s, 9 k²)`` output ``[e, i, a, j, b]`` (mode 1); slots
            ``(s, k, k)`` and data: as :func:`_membrane`'s (mode 2).  Block
            ``k_b c_i c_j (c_k I + c_d β_b D̂D̂ᵀ)``.

    Returns ``Σ_s |D_s x|²``.
    """
    s_count, k_count = sv.shape
    d = np.empty(3)
    d_dot = np.empty(3)
    unit = np.empty(3)
    block = np.empty((3, 3))
    total = 0.0
    for s in range(s_count):
        for a in range(3):
            d[a] = 0.0
            d_dot[a] = 0.0
        for k in range(k_count):
            c, node = sc[s, k], sv[s, k]
            for a in range(3):
                d[a] += c * x[node, a]
                d_dot[a] += c * v[node, a]
        size2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        total += size2
        size = np.sqrt(size2)
        inv = 1.0 / size if size > 0.0 else 0.0
        rate = 0.0
        for a in range(3):
            unit[a] = d[a] * inv
            rate += unit[a] * d_dot[a]
        for k in range(k_count):
            c, node = sc[s, k], sv[s, k]
            for a in range(3):
                force[node, a] -= kb * c * (d[a] + bb * rate * unit[a])
                kv[node, a] -= kb * c * d_dot[a]
        if mode == 0:
            continue
        for a in range(3):
            for b in range(3):
                block[a, b] = kb * ((c_k if a == b else 0.0) + c_d * bb * unit[a] * unit[b])
        for i in range(k_count):
            for j in range(k_count):
                cc = sc[s, i] * sc[s, j]
                if mode == 1:
                    base = 9 * k_count * i + 3 * j
                    for a in range(3):
                        for b in range(3):
                            blocks[s, base + 3 * k_count * a + b] = cc * block[a, b]
                else:
                    start = slots[s, i, j]
                    for a in range(3):
                        for b in range(3):
                            data[start + 3 * a + b] += cc * block[a, b]
    return total


def evaluate(elements, material, x: np.ndarray, v: np.ndarray,
             stiffness_weight: float = 0.0, damping_weight: float = 0.0,
             with_blocks: bool = True, air=None, pattern=None):
    """:func:`cloth_lod_ros.sim.physics.forces.evaluate` with the compiled kernels when
    :func:`enabled` (else the reference itself): the same arguments and result.

    ``pattern``: the topology's :class:`~cloth_lod_ros.sim.solve.pattern.SparsePattern`.
    Given it (and blocks wanted), the kernels add the blocks straight into the
    pattern's BSR data instead of returning ``triangle_blocks``/``hinge_blocks``
    (None then): the result's ``assembled`` is that ``(blocks, 3, 3)`` data
    without the diagonal, for :func:`assemble`.
    """
    if not enabled():
        return _forces.evaluate(elements, material, x, v, stiffness_weight, damping_weight,
                         with_blocks, air)
    n = elements.vertex_count
    x = np.ascontiguousarray(x, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    tri, hv = _as_index(elements.triangles), _as_index(elements.hinge_vertices)
    t_count, h_count = len(tri), len(hv)
    fused = with_blocks and pattern is not None
    mode = 0 if not with_blocks else (2 if fused else 1)
    air_coef = 0.0 if air is None else 0.5 * air.density * air.drag_coefficient
    wind = np.zeros(3) if air is None else np.asarray(air.wind, dtype=np.float64)
    cK, cD = float(stiffness_weight), float(damping_weight)
    scratch = np.empty(0)
    data = np.zeros(9 * pattern.block_count) if fused else scratch
    kinds = elements.bend.kinds
    if fused:
        wanted = [tuple(v.shape) for v in elements.element_vertices]
        if [tuple(shape) for shape in pattern._element_shapes] != wanted:
            raise ValueError("the pattern was not built from these elements' triangles "
                             "and bend stencils")
        tri_slots, *bend_slots = pattern.block_slots
    else:
        tri_slots = np.empty((0, 3, 3), dtype=np.int64)
        bend_slots = [np.empty((0, sv.shape[1], sv.shape[1]), dtype=np.int64)
                      for sv, _ in kinds]
    tri_blocks = np.empty((t_count, 81)) if mode == 1 else np.empty((0, 81))

    force, kv, air_force = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    conditions = np.empty((5, t_count))
    _membrane(tri, elements.coef_u, elements.coef_v, elements.area, x, v,
              float(material.stretch_stiffness), float(material.shear_stiffness),
              float(material.stretch_damping), float(material.shear_damping),
              cK, cD, air_coef, wind, force, kv, air_force, conditions,
              tri_blocks, tri_slots, data, mode)
    # The hinge angles: the LOD criterion's curvature measure (no force).
    theta, grad = _hinges_kernels.hinge_angles(x, hv, with_gradient=True) if h_count else (
        np.empty(0), np.empty((0, 4, 3)))
    kb = float(material.bend_stiffness)
    bend_sq = 0.0
    bend_blocks = []
    for (sv, sc), slots in zip(kinds, bend_slots):
        k = sv.shape[1]
        blocks = np.empty((len(sv), 9 * k * k)) if mode == 1 else np.empty((0, 9 * k * k))
        bend_sq += _stencils(sv, sc, x, v, kb, float(material.bend_damping), cK, cD,
                             force, kv, blocks, slots, data, mode)
        if mode == 1:
            bend_blocks.append(blocks.reshape(len(sv), k, 3, k, 3))
    if air is not None:
        force += air_force

    result = _forces.summarise(
        material, conditions, bend_sq, theta, grad, force, kv,
        tri_blocks.reshape(t_count, 3, 3, 3, 3) if mode == 1 else None,
        bend_blocks if mode == 1 else None)
    result.assembled = data.reshape(-1, 3, 3) if fused else None
    return result


def assemble(pattern, evaluation, diagonal: np.ndarray):
    """The system matrix of ``evaluation`` on ``pattern`` plus ``diagonal[i] I₃``
    per vertex (``diagonal`` ``(n,)``): :meth:`SparsePattern.assemble` of its
    blocks, or its already assembled data (:func:`evaluate` with a pattern)."""
    data = getattr(evaluation, "assembled", None)
    if data is None:
        return pattern.assemble(evaluation.blocks, diagonal)
    # A copy: the evaluation may be reused (a contact re-solve of the same
    # state) and finish() adds the diagonal in place.
    return pattern.finish(data.copy(), diagonal)
