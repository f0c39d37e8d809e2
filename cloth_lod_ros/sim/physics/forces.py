"""Baraff–Witkin cloth conditions as resolution-independent energy densities.

Vectorised over triangles and hinges (:mod:`.forces_kernels` compiles the same
maths).  The rest data are :mod:`.elements`', the hinge angles :mod:`.hinges`',
the air :mod:`.air`'; the energies alone, without forces, :mod:`.energies`.
SI units: positions in m, velocities in m/s, forces in N, energies in J.
References: Baraff & Witkin, "Large steps in cloth simulation" (1998), §4.2–4.5
(conditions, forces, damping), §5 (implicit step); the seed paper §5
(bend condition C = θ); design §2 (energies as discretised densities).

Conditions (``A`` = rest area of the triangle in m², ``w_u``/``w_v`` = the
deformation gradient's columns, see :func:`.elements.precompute`):

* stretch  ``C_u = √A (|w_u| − 1)``, ``C_v = √A (|w_v| − 1)``,
  energy ``k_s/2 (C_u² + C_v²)``; ``k_s`` in N/m.  Because ``C² ∝ A`` a uniform
  strain gives the same total energy at every level.
* shear    ``C_s = √A (w_u · w_v)``, energy ``k_sh/2 C_s²``; ``k_sh`` in N/m.
* bend     the quadratic energy ``k_b/2 Σ_s |D_s x|²`` of :mod:`.bending`
  (``k_b`` in N·m): ``D_s`` are second differences of the positions on the
  rest lattice (line stencils along the legs, twist stencils on diamonds,
  fitted stencils where those are missing), so the energy is the continuum's
  ``k_b/2 ∫|∇²x|² dA`` (a cylinder of radius R: ``k_b/2 R⁻² A``; Poisson
  ratio 0), zero for rigid motions, with a constant Hessian.  The hinge
  angles θ are still computed (the LOD criterion's curvature measure) but
  carry no energy.

Damping is Rayleigh-like along each condition (BW §4.5):
``f_d = −β k ∇C Ċ`` with ``β`` in seconds; for bending the condition is each
stencil's ``|D_s|`` (objective: a rigid rotation is not damped).  The air (:func:`.air.air_forces`, design
§2) pushes each face along its normal, ``−½ ρ C_d A |v_n| v_n n`` (ρ in kg/m³,
C_d dimensionless, A the current area, v_n the normal component of the face's
velocity relative to the wind), a third to each corner; the integrator adds the
isotropic ``−c_air m v`` of ``material.air_drag`` itself.

Jacobians (what the implicit solve keeps; design §2–3):

* stretch: full ``−k (∇C ∇Cᵀ + C ∇²C)`` but with ``C`` clamped to ``≥ 0`` in the
  second term (a compressed triangle would make it indefinite);
* shear: the Gauss–Newton part ``−k ∇C ∇Cᵀ`` only; ``C ∇²C`` is
  indefinite for any sign of C and is dropped (it vanishes at rest);
* bend: exact, ``−k_b Σ_s c_s c_sᵀ ⊗ I₃`` (the energy is quadratic);
* damping: ``∂f_d/∂v = −β k ∇C ∇Cᵀ`` (exact); ``∂f_d/∂x`` is dropped (BW §5.2,
  it is non-symmetric);
* air: ``∂f/∂v`` exact (``−ρ C_d A |v_n| / 9 · n nᵀ`` between any two corners of
  a face); the dependence on x through n and A is dropped like ``∂f_d/∂x``.

So every kept block is negative semi-definite and the system matrix
``M − h ∂f/∂v − h² ∂f/∂x`` is symmetric positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .air import _air_face_terms
from .elements import Elements
from .hinges import hinge_angles
from .vectors import _corners, _dot_soa

__all__ = ["Evaluation", "evaluate"]


def summarise(material, conditions, bend_sq, theta, hinge_gradient, force, kv,
              triangle_blocks, hinge_blocks) -> "Evaluation":
    """The :class:`Evaluation`; energies (J) and largest strain from the conditions
    ``(c_u, c_v, c_s, len_u, len_v)`` ``(t,)`` and ``Σ_s |D_s x|²`` of the bend
    stencils (J/(N·m)); ``theta`` the hinge angles ``(h,)`` rad."""
    c_u, c_v, c_s, len_u, len_v = conditions
    strain = np.concatenate([np.abs(len_u - 1.0), np.abs(len_v - 1.0)])
    return Evaluation(
        force=force, shear_energy=float(0.5 * material.shear_stiffness * np.sum(c_s**2)),
        stretch_energy=float(0.5 * material.stretch_stiffness * (np.sum(c_u**2) + np.sum(c_v**2))),
        bend_energy=float(0.5 * material.bend_stiffness * bend_sq),
        max_strain=float(strain.max()) if len(strain) else 0.0,
        stiffness_times_velocity=kv, triangle_blocks=triangle_blocks,
        hinge_blocks=hinge_blocks, hinge_angle=theta, hinge_gradient=hinge_gradient)


@dataclass
class Evaluation:
    """Internal forces of the cloth at one state.

    Attributes:
        force: ``(n, 3)`` elastic + damping forces in N, plus the air's face
            forces when ``evaluate`` is given ``air`` (no gravity, no isotropic drag).
        stretch_energy, shear_energy, bend_energy: J.
        max_strain: largest ``| |w| − 1 |`` over triangles and directions.
        stiffness_times_velocity: ``(n, 3)`` ``(∂f/∂x) v`` with the kept
            Jacobian, in N/s (the ``h² K v`` term of the right-hand side).
        triangle_blocks: ``(t, 3, 3, 3, 3)`` entries ``[e, i, a, j, b]`` of
            ``−(stiffness_weight ∂f/∂x + damping_weight ∂f/∂v)`` (row ``3·v_i + a``,
            column ``3·v_j + b``), or ``None``.
        hinge_blocks: list of ``(s, k, 3, k, 3)``, the same layout for each kind
            of bend stencil (``elements.bend.kinds``), or ``None``.
        hinge_angle: ``(h,)`` θ in rad; ``hinge_gradient``: ``(h, 4, 3)`` ∂θ/∂x
            in 1/m (what the LOD criterion needs; it computes them alone with
            :func:`hinge_angles`, the same numbers).
        assembled: ``(blocks, 3, 3)`` the blocks already summed into a
            pattern's BSR data (compiled path, forces_kernels.evaluate) or ``None``.
    """

    force: np.ndarray
    stretch_energy: float
    shear_energy: float
    bend_energy: float
    max_strain: float
    stiffness_times_velocity: np.ndarray
    triangle_blocks: np.ndarray | None
    hinge_blocks: np.ndarray | None
    hinge_angle: np.ndarray
    hinge_gradient: np.ndarray
    assembled: np.ndarray | None = None

    @property
    def blocks(self) -> list:
        """``[triangle_blocks, *hinge_blocks]``: every element kind's blocks, in
        the order of ``Elements.element_vertices``."""
        return [self.triangle_blocks, *self.hinge_blocks]


def evaluate(elements: Elements, material, x: np.ndarray, v: np.ndarray,
             stiffness_weight: float = 0.0, damping_weight: float = 0.0,
             with_blocks: bool = True, air=None) -> Evaluation:
    """Forces, energies and system-matrix blocks of all conditions.

    Args:
        elements: rest data from :func:`precompute`.
        material: object with ``stretch_stiffness``, ``shear_stiffness`` (N/m),
            ``bend_stiffness`` (N·m), ``stretch_damping``, ``shear_damping``,
            ``bend_damping`` (s).
        x, v: ``(n, 3)`` positions (m) and velocities (m/s).
        stiffness_weight, damping_weight: the blocks returned are
            ``−(stiffness_weight·∂f/∂x + damping_weight·∂f/∂v)``; the implicit
            step uses ``h²`` and ``h``.
        with_blocks: skip the blocks (forces and energies only).
        air: the scene's ``air`` section (``density`` kg/m³, ``drag_coefficient``,
            ``wind`` m/s) or None: its face forces (:func:`air_forces`) are added
            to ``force`` and their ``∂f/∂v`` blocks, times ``damping_weight``, to
            ``triangle_blocks``.
    """
    n = elements.vertex_count
    tri = elements.triangles
    ks, ksh, kb = material.stretch_stiffness, material.shear_stiffness, material.bend_stiffness
    bs, bsh, bb = material.stretch_damping, material.shear_damping, material.bend_damping
    cu, cv, area = elements.coef_u, elements.coef_v, elements.area
    sqrt_area = np.sqrt(area)

    # Membrane terms on component-major (3, t) arrays: each operation is one
    # contiguous loop over all triangles (not t loops of length 3).
    cu0, cu1, cu2 = elements.coef_u_cm
    cv0, cv1, cv2 = elements.coef_v_cm
    corners_x, corners_v = _corners(elements, x), _corners(elements, v)
    x0, x1, x2 = corners_x
    v0, v1, v2 = corners_v
    wu = cu0 * x0 + cu1 * x1 + cu2 * x2                     # (3, t)
    wv = cv0 * x0 + cv1 * x1 + cv2 * x2
    wu_dot = cu0 * v0 + cu1 * v1 + cu2 * v2
    wv_dot = cv0 * v0 + cv1 * v1 + cv2 * v2
    len_u = np.sqrt(_dot_soa(wu, wu))
    len_v = np.sqrt(_dot_soa(wv, wv))
    dir_u = wu / len_u
    dir_v = wv / len_v

    # Stretch: C = √A(|w|−1), ∇_k C = √A coef_k ŵ.
    c_u, c_v = sqrt_area * (len_u - 1.0), sqrt_area * (len_v - 1.0)
    along_u, along_v = _dot_soa(dir_u, wu_dot), _dot_soa(dir_v, wv_dot)
    cdot_u, cdot_v = sqrt_area * along_u, sqrt_area * along_v
    # Shear: C = √A w_u·w_v, ∇_k C = √A (coef_u_k w_v + coef_v_k w_u), so
    # Ċ = Σ_k ∇_k C · v_k = √A (w_v · ẇ_u + w_u · ẇ_v).
    c_s = sqrt_area * _dot_soa(wu, wv)
    cdot_s = sqrt_area * (_dot_soa(wv, wu_dot) + _dot_soa(wu, wv_dot))

    # f_k = −k (C + βĊ) ∇_k C for each condition; every term is coef_u_k U +
    # coef_v_k V for two per-triangle vectors U, V (3, t).
    shear_force = -ksh * (c_s + bsh * cdot_s) * sqrt_area
    force_u = (-ks * sqrt_area * (c_u + bs * cdot_u)) * dir_u + shear_force * wv
    force_v = (-ks * sqrt_area * (c_v + bs * cdot_v)) * dir_v + shear_force * wu
    # (∂f/∂x) v with the kept stretch stiffness S = ŵŵᵀ + max(1 − 1/|w|, 0)(I − ŵŵᵀ).
    tens_u = np.maximum(1.0 - 1.0 / len_u, 0.0)
    tens_v = np.maximum(1.0 - 1.0 / len_v, 0.0)
    shear_kv = -ksh * cdot_s * sqrt_area
    kv_u = (-ks * area) * ((1.0 - tens_u) * along_u * dir_u + tens_u * wu_dot) + shear_kv * wv
    kv_v = (-ks * area) * ((1.0 - tens_v) * along_v * dir_v + tens_v * wv_dot) + shear_kv * wu

    # Bending: the quadratic stencil energy k_b/2 Σ|D_s x|² (.bending); the
    # hinge angles are kept for the LOD criterion only.
    hv = elements.hinge_vertices
    if len(hv):
        theta, grad_b = hinge_angles(x, hv, with_gradient=True)
    else:
        theta, grad_b = np.zeros(0), np.zeros((0, 4, 3))
    bend_force, bend_kv, bend_sq, bend_units = _bend_terms(elements.bend, x, v, kb, bb)

    force = _scatter_membrane(tri, cu, cv, force_u, force_v, n) + bend_force
    kv = _scatter_membrane(tri, cu, cv, kv_u, kv_v, n) + bend_kv

    tri_blocks = hinge_blocks = None
    if with_blocks:
        cK, cD = stiffness_weight, damping_weight
        air_face = None
        if air is not None:
            air_force, air_face = _air_face_terms(elements, air, corners_x, corners_v,
                                                  damping_weight, True)
            force += air_force
        tri_blocks = _membrane_blocks(
            elements, ks * area * (cK + cD * bs), ks * area * cK, ((cK + cD * bsh) * ksh) * area,
            (dir_u, tens_u, wv), (dir_v, tens_v, wu), air_face)
        # k_b c_i c_j (cK I + cD β_b D̂D̂ᵀ) for stencil vertices i, j.
        eye = np.eye(3)
        hinge_blocks = [kb * np.einsum("si,sj,sab->siajb", coef, coef,
                                       cK * eye + (cD * bb) * unit[:, :, None] * unit[:, None, :])
                        for (_, coef), unit in zip(elements.bend.kinds, bend_units)]
    elif air is not None:
        force += _air_face_terms(elements, air, corners_x, corners_v, damping_weight, False)[0]

    return summarise(material, (c_u, c_v, c_s, len_u, len_v), bend_sq, theta, grad_b, force,
                     kv, tri_blocks, hinge_blocks)


def _bend_terms(stencils, x: np.ndarray, v: np.ndarray, kb: float, bb: float):
    """Bend force (N), ``(∂f/∂x) v`` (N/s), both ``(n, 3)``, ``Σ_s |D_s x|²``
    (J/(N·m)) and the unit vectors ``D̂_s`` (per kind ``(s, 3)``, 0 where
    ``D_s = 0``).

    Elastic: ``−k_b Σ_s c_s D_s`` (the exact gradient of the quadratic energy).
    Damping: ``−k_b β_b Σ_s c_s (D̂_s · Ḋ_s) D̂_s``, Rayleigh damping along the
    condition ``C_s = |D_s|`` (BW §4.5): it sees the rate of each stencil's
    curvature and not a rigid rotation (``Ḋ = ω × D ⊥ D``), so it exerts no
    net torque; damping ``Ḋ`` itself would brake a rigidly spinning bent sheet.
    """
    n = len(x)
    force, kv = np.zeros((n, 3)), np.zeros((n, 3))
    total = 0.0
    units = []
    for verts, coef in stencils.kinds:
        d = np.einsum("sk,skd->sd", coef, x[verts])
        d_dot = np.einsum("sk,skd->sd", coef, v[verts])
        size = np.sqrt(np.sum(d * d, axis=1))
        unit = d / np.where(size > 0.0, size, 1.0)[:, None]
        rate = np.sum(unit * d_dot, axis=1)
        total += float(np.sum(d * d))
        force += _scatter(verts, -kb * coef[:, :, None] * (d + bb * rate[:, None] * unit)[:, None, :], n)
        kv += _scatter(verts, -kb * coef[:, :, None] * d_dot[:, None, :], n)
        units.append(unit)
    return force, kv, total, units


def _membrane_blocks(elements: Elements, along: np.ndarray, across_scale: np.ndarray,
                     shear_area: np.ndarray, dir_u_terms, dir_v_terms,
                     air_face: np.ndarray | None) -> np.ndarray:
    """Membrane (stretch + shear, plus air) blocks ``(t, 3, 3, 3, 3)``, laid out
    as :attr:`Evaluation.triangle_blocks`.

    Every membrane term has the form
    ``Σ_pq c_p[i] c_q[j] Q_pq[a, b]`` (p, q ∈ {u, v}; ``c_u``, ``c_v`` the
    coefficient vectors of ``w_u``, ``w_v``): the 2 × 2 grid of 3 × 3 matrices
    Q per triangle, then ``R_p[j] = Σ_q c_q[j] Q_pq`` and
    ``B[i, j] = Σ_p c_p[i] R_p[j]`` (+ the air's face block, the same for all
    nine corner pairs).  Every operation runs over all triangles in one
    contiguous loop on component-major ``(…, t)`` arrays, the last one
    storing into the element-major result (the layout whose assembly sums in
    element order, see pattern.SparsePattern): batched 3 × 3 matmuls over
    ``(t, …)`` arrays cost ~4x more.

    Args:
        along: ``(t,)`` ``k_s A (cK + cD β_s)``, N/m times the weights.
        across_scale: ``(t,)`` ``k_s A cK``; times ``max(1 − 1/|w|, 0)``.
        shear_area: ``(t,)`` ``(cK + cD β_sh) k_sh A``.
        dir_u_terms, dir_v_terms: ``(ŵ (3, t), tension (t,), other w (3, t))``
            of each direction (the other direction's w enters the shear).
        air_face: ``(3, 3, t)`` the air's ``−cD ∂f/∂v`` face block or None.
    """
    cu, cv = elements.coef_u_cm, elements.coef_v_cm                  # (3, t)
    eye = np.eye(3)[:, :, None]
    # Shear: ∇C = √A (c_u ⊗ w_v + c_v ⊗ w_u), so ∇C ∇Cᵀ gives Q_uu = A w_v w_vᵀ,
    # Q_uv = A w_v w_uᵀ, Q_vu = A w_u w_vᵀ, Q_vv = A w_u w_uᵀ (times the weight).
    # Stretch along one direction: k_s A [(cK + cD β) ŵŵᵀ + cK max(1 − 1/|w|, 0)(I − ŵŵᵀ)].
    diagonal = []
    for direction, tension, other in (dir_u_terms, dir_v_terms):
        across = across_scale * tension
        diagonal.append((along - across) * direction[:, None] * direction[None, :]
                        + across * eye + shear_area * other[:, None] * other[None, :])  # (3, 3, t)
    q_uu, q_vv = diagonal
    wv, wu = dir_u_terms[2], dir_v_terms[2]
    q_uv = shear_area * wv[:, None] * wu[None, :]
    q_vu = q_uv.transpose(1, 0, 2)
    t_count = cu.shape[1]
    reduced = np.empty((2, 3, 3, 3, t_count))                           # R[p, j, a, b, t]
    for j in range(3):
        np.add(cu[j] * q_uu, cv[j] * q_uv, out=reduced[0, j])
        np.add(cu[j] * q_vu, cv[j] * q_vv, out=reduced[1, j])
    blocks = np.empty((t_count, 3, 3, 3, 3))                            # [t, i, a, j, b]
    # Written through an [i, j, a, b, t] view: the last operation of each row
    # stores into the element-major result directly, its inner loop running
    # over t (a transposing copy afterwards loops over rows of 3: ~4x slower).
    by_row = blocks.transpose(1, 3, 2, 4, 0)
    for i in range(3):
        row = cu[i] * reduced[0]
        row += cv[i] * reduced[1]
        if air_face is None:
            by_row[i] = row
        else:
            np.add(row, air_face, out=by_row[i])
    return blocks


def _scatter_membrane(tri: np.ndarray, coef_u: np.ndarray, coef_v: np.ndarray,
                      along_u: np.ndarray, along_v: np.ndarray, n: int) -> np.ndarray:
    """Sum ``coef_u[e, k] along_u[:, e] + coef_v[e, k] along_v[:, e]`` into corner
    ``tri[e, k]``: ``(n, 3)``.  ``along_u``, ``along_v``: ``(3, t)``."""
    out = np.empty((n, 3))
    flat = tri.ravel()
    for d in range(3):
        values = coef_u * along_u[d][:, None] + coef_v * along_v[d][:, None]   # (t, 3)
        out[:, d] = np.bincount(flat, weights=values.ravel(), minlength=n)
    return out


def _scatter(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum per-element corner vectors ``values[e, k]`` into ``out[index[e, k]]``."""
    out = np.empty((n, 3))
    flat = index.ravel()
    vals = values.reshape(-1, 3)
    for d in range(3):
        out[:, d] = np.bincount(flat, weights=vals[:, d], minlength=n)
    return out
