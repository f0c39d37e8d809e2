"""The energy a merge would add, for all merge candidates at once (design §2, §4).

A merge removes a split particle m and replaces the path ``left – m – right``
by the chord.  Nothing moves, but the restored coarse triangles see the
positions of only three of the diamond's five particles: if m sits off the
chord (in the plane: a stretched or sheared diamond; out of it: a bent one),
the parents' strain differs from their children's and the stretch energy
jumps.  The masses and velocities change too (m's mass goes to the edge ends,
which share the momentum-conserving velocity change), and so do the kinetic
and gravitational energies.  Measured on ``hang_two_corners`` (20 s, max
level 6) before this test existed: 216 of 495 merges added more than 1 µJ,
the largest +0.96 mJ, almost all of it stretch.

:func:`merge_energy_change` evaluates, for every candidate and on the same
state, the change of the cloth's total mechanical energy

    ΔE = Δ(stretch + shear) + Δbend + Δkinetic + Δgravity      (J)

that merging that one candidate alone would make: the membrane energy of its
one or two parents against its two or four children, the bend energy's
change (:mod:`cloth_lod_ros.sim.lod.merge_bend`: the stencil energy of
:mod:`cloth_lod_ros.sim.physics.bending` on a piece of mesh around m, before
and after, clamps included; the merge changes stencils centred up to two
rings from m), the kinetic energy of m and both ends before and after the
velocity change of
:func:`cloth_lod_ros.sim.mesh.hierarchy.merge_velocity_change`, and
``m_mid g · (x_mid − ½(x_left + x_right))``.  It is the exact energy
difference of the merged and unmerged meshes (tested against whole-mesh
energies), vectorised over candidates: no per-candidate Python loop.
Merges applied one after another interact through a shared edge end (its
mass and velocity: the ``kinetic`` part, which :func:`merge_kinetic_change`
recomputes) or a shared outer edge (the triangle across it), which
:meth:`cloth_lod_ros.sim.lod.policy.LodPolicy.apply` deals with, and through
the bending stencils within a few rings of both, which it does not test
again: there a merge's bend part is that of the mesh before the decision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import merge_energy_kernels
from ..physics.elements import Elements, triangle_maps
from ..physics.energies import membrane_energies
from .merge_bend import merge_bend_change
from ..mesh.hierarchy import Hierarchy48, merge_velocity_change

__all__ = ["MergeEnergy", "merge_energy_change", "merge_kinetic_change"]


@dataclass(frozen=True)
class MergeEnergy:
    """Energy changes of merges, ``(k,)`` each.

    Attributes:
        total: ΔE in J; kinetic: its kinetic part, J (the one part an earlier
        merge sharing an edge end changes); area: rest area of the merged
        diamond (its one or two parents), m².
    """

    total: np.ndarray
    kinetic: np.ndarray
    area: np.ndarray


def merge_energy_change(hierarchy: Hierarchy48, elements: Elements, vertex_ids: np.ndarray,
                        triangle_ids: np.ndarray, vertices: np.ndarray, x: np.ndarray,
                        v: np.ndarray, masses: np.ndarray, material,
                        gravity) -> "MergeEnergy":
    """Energy change, J, of merging each split particle in ``vertices`` alone.

    Args:
        hierarchy: the adaptive mesh (read only; its ``x``/``v`` are not used).
        elements: rest data of the active (compact) mesh.
        vertex_ids, triangle_ids: pool ids of the compact vertices/triangles
            (increasing, as :meth:`Hierarchy48.active_mesh` returns them).
        vertices: ``(k,)`` pool ids of split particles whose merge is valid now
            (:meth:`Hierarchy48.split_vertices`).
        x, v: ``(n, 3)`` compact positions (m) and velocities (m/s).
        masses: ``(n,)`` compact masses, kg.
        material: with ``stretch_stiffness``, ``shear_stiffness`` (N/m) and
            ``bend_stiffness`` (N·m).
        gravity: ``(3,)`` m/s².

    Returns:
        :class:`MergeEnergy`: ``total`` ``(k,)`` ΔE in J (positive when the
        merge would add energy), its ``kinetic`` part and the diamonds' ``area``.
    """
    vertices = np.asarray(vertices, dtype=np.int64)
    k = len(vertices)
    if k == 0:
        return MergeEnergy(np.zeros(0), np.zeros(0), np.zeros(0))
    compiled = merge_energy_kernels.merge_energies(hierarchy, elements, vertex_ids, triangle_ids,
                                                   vertices, x, v, masses, material, gravity)
    if compiled is not None:        # one compiled pass: this reference's numbers (bend part to rounding)
        return MergeEnergy(*compiled)
    h = hierarchy
    mid = np.searchsorted(vertex_ids, vertices)                      # compact m
    ends = np.searchsorted(vertex_ids, h.vertex_edge[vertices])      # (k, 2) l, r
    parents = h.vertex_parents[vertices]                             # (k, 2), -1 pad
    has = parents >= 0
    parent_tri = np.searchsorted(vertex_ids, h.tri[np.maximum(parents, 0)])  # (k, 2, 3)

    # Membrane: the parents against their children (the children are active).
    kids = h.children[np.maximum(parents, 0)].reshape(k, 4)
    kid_has = np.repeat(has, 2, axis=1)
    kid_c = np.searchsorted(triangle_ids, kids[kid_has])
    parent_area, cu, cv = triangle_maps(h.uv[h.tri[parents[has]]])
    energy = membrane_energies(
        np.concatenate([cu, elements.coef_u[kid_c]]), np.concatenate([cv, elements.coef_v[kid_c]]),
        np.concatenate([parent_area, elements.area[kid_c]]),
        x[np.concatenate([parent_tri[has], elements.triangles[kid_c]])], material)
    sign = np.ones(len(energy))
    sign[len(parent_area):] = -1.0
    delta = np.bincount(np.concatenate([np.nonzero(has)[0], np.nonzero(kid_has)[0]]),
                        weights=sign * energy, minlength=k)

    delta += merge_bend_change(h, elements, vertex_ids, vertices, mid, x,
                               material.bend_stiffness)

    # Kinetic and gravity: m's mass goes to the ends, which share the velocity change.
    particles = np.column_stack([mid, ends])
    kinetic = merge_kinetic_change(masses[particles], v[particles])
    chord_mid = 0.5 * (x[ends[:, 0]] + x[ends[:, 1]])
    delta += kinetic + masses[mid] * ((x[mid] - chord_mid) @ np.asarray(gravity, dtype=float))
    area = np.bincount(np.nonzero(has)[0], weights=parent_area, minlength=k)
    return MergeEnergy(delta, kinetic, area)


def merge_kinetic_change(masses: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """Kinetic-energy change, J, of merges, ``(k,)``.

    Args:
        masses: ``(k, 3)`` masses of the removed particle and the two edge
            ends (in that order) before the merge, kg.
        velocities: ``(k, 3, 3)`` their velocities, m/s.

    m's mass goes to the ends equally, and both get the velocity change of
    :func:`cloth_lod_ros.sim.mesh.hierarchy.merge_velocity_change`.
    """
    m_mid, m_l, m_r = masses[:, 0], masses[:, 1], masses[:, 2]
    v_mid, v_l, v_r = velocities[:, 0], velocities[:, 1], velocities[:, 2]
    change = merge_velocity_change(m_mid, m_l + m_r + m_mid, v_mid, v_l, v_r)
    before = m_l * _sq(v_l) + m_r * _sq(v_r) + m_mid * _sq(v_mid)
    after = (m_l + 0.5 * m_mid) * _sq(v_l + change) + (m_r + 0.5 * m_mid) * _sq(v_r + change)
    return 0.5 * (after - before)


def _sq(a: np.ndarray) -> np.ndarray:
    return np.einsum("kd,kd->k", a, a)
