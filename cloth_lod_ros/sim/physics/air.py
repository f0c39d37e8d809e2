"""The air: a force on each face along its normal, quadratic in the normal
speed relative to the wind, and its power (design §2).
"""

from __future__ import annotations

import numpy as np

from .elements import Elements
from .vectors import _corners, _cross_soa, _dot, _dot_soa_02

__all__ = ["air_forces", "air_power"]


def air_forces(elements: Elements, air, x: np.ndarray, v: np.ndarray,
               damping_weight: float = 0.0, with_blocks: bool = False):
    """Forces of the air on each face, along its normal (design §2).

    Per triangle with current area ``A`` (m²) and unit normal ``n``, the relative
    velocity ``v_rel`` = mean of its three corners' velocities − ``air.wind``
    (m/s), ``v_n = n · v_rel``: the face force is ``−½ ρ C_d A |v_n| v_n n`` (N),
    a third to each corner.  It depends on the normal motion only: a sheet
    sliding in its own plane or moving edge-on feels nothing, a flat sheet
    falling face-on reaches ``√(2 ρ_areal g / (ρ C_d))``.  It is a force per unit
    area times the area, so it means the same at every level.  With still air
    its power ``Σ f·v = −Σ ½ ρ C_d A |v_n|³`` is never positive.

    ``∂f_i/∂v_j = −(ρ C_d A |v_n| / 9) n nᵀ`` for every pair of corners (i, j) of
    a face: symmetric negative semi-definite (rank one per face), kept exactly.
    The dependence on x through n and A is dropped, like BW's ``∂f_d/∂x``
    (design §3): it is not symmetric.  No linear term: with this Jacobian the
    implicit step never adds kinetic energy in still air (in still air
    ``f = −½ D v`` with D the PSD matrix above, so each mode of ``M⁻¹D`` keeps
    ``1 − hλ/(2(1 + hλ))`` or more of its speed and never reverses), so the
    quadratic law needs no help to stay stable; and at cloth speeds the air's
    Reynolds number is ~10³ or more, where drag is quadratic.

    Args:
        elements: rest data (only ``triangles`` is used: the area is the current one).
        air: ``density`` (kg/m³), ``drag_coefficient`` (dimensionless),
            ``wind`` ``(3,)`` (m/s).
        x, v: ``(n, 3)`` positions (m) and velocities (m/s).
        damping_weight: the blocks are ``−damping_weight · ∂f/∂v``.
        with_blocks: also return the blocks.

    Returns:
        ``(force (n, 3) N, blocks (t, 3, 3, 3, 3) or None)``, blocks laid out as
        :attr:`Evaluation.triangle_blocks`.
    """
    force, face = _air_face_terms(elements, air, _corners(elements, x), _corners(elements, v),
                                  damping_weight, with_blocks)
    if face is None:
        return force, None
    face = face.transpose(2, 0, 1)                                    # (t, 3, 3)
    return force, np.broadcast_to(face[:, None, :, None, :],
                                  (len(face), 3, 3, 3, 3)).copy()


def _air_face_terms(elements: Elements, air, corners_x: np.ndarray, corners_v: np.ndarray,
                    damping_weight: float, with_blocks: bool):
    """:func:`air_forces` from :func:`_corners` of x and v, with each face's
    block as one 3 × 3 matrix (it is the same for all nine corner pairs),
    component-major ``(3, 3, t)``, or None without blocks."""
    tri = elements.triangles
    n_vertices = elements.vertex_count
    coefficient = 0.5 * air.density * air.drag_coefficient
    if coefficient == 0.0 or not len(tri):
        face = np.zeros((3, 3, len(tri))) if with_blocks else None
        return np.zeros((n_vertices, 3)), face
    # Component-major (3, t): one contiguous loop over the faces per operation.
    x0, x1, x2 = corners_x
    cross = _cross_soa(x1 - x0, x2 - x0)                             # |cross| = 2 A
    twice_area = np.sqrt(_dot_soa_02(cross, cross))
    normal = cross / np.maximum(twice_area, np.finfo(float).tiny)    # 0 if collapsed
    # The corners' mean velocity, relative to the wind.
    v_rel = (corners_v[0] + corners_v[1] + corners_v[2]) / 3.0 \
        - np.asarray(air.wind, dtype=float)[:, None]
    v_n = _dot_soa_02(normal, v_rel)
    k = coefficient * 0.5 * twice_area                               # ½ ρ C_d A, kg/m
    corner = (-k * np.abs(v_n) * v_n / 3.0) * normal                 # N, each corner
    flat = tri.ravel()
    force = np.empty((n_vertices, 3))
    for d in range(3):      # the same weights in the same (face, corner) order as _scatter
        force[:, d] = np.bincount(flat, weights=np.repeat(corner[d], 3), minlength=n_vertices)
    blocks = None
    if with_blocks:
        # −∂f_i/∂v_j = (2 k |v_n| / 9) n nᵀ for every corner pair (i, j).
        blocks = (damping_weight * 2.0 * k * np.abs(v_n) / 9.0) \
            * normal[:, None, :] * normal[None, :, :]                 # (3, 3, t)
    return force, blocks


def air_power(elements: Elements, air, air_drag: float, masses: np.ndarray,
              x: np.ndarray, v: np.ndarray) -> float:
    """Power (W) of the air on the cloth at positions ``x`` (m), velocities ``v``
    (m/s): the face forces of :func:`air_forces` plus the isotropic drag
    ``−air_drag m v`` (``air_drag`` 1/s, ``masses`` ``(n,)`` kg), on every particle.
    Never positive in still air (design §2); wind can make it positive."""
    force, _ = air_forces(elements, air, x, v)
    return float(np.sum(force * v) - air_drag * np.sum(masses * _dot(v, v)))
