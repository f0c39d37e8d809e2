"""Contacts between layers act on both layers (self-collision, design §3).

:func:`common_velocity`: the velocity a contact between layers moves its
particle with (the pair's common velocity, the mean of the two sides').

A contact with another layer of the cloth is a per-particle velocity
constraint against that layer as a moving surface
(:meth:`~cloth_lod_ros.sim.contact.self_contact.SelfCollision.constraints`): it moves
its own particle, and on its own nothing acts on the other layer.  Here the
other layer takes the reaction, so that the layers exchange equal and
opposite impulses: in a contact between two free layers momentum is
conserved, and friction only dissipates (on its own, a sticking particle
pulled to the other layer's velocity gained energy nobody paid for).

:func:`layer_reactions`, called by
:meth:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver._solve_with_contacts`
once its contacts and friction are settled:

* Each contact with a layer (``ContactSet.partners``: the other side's
  particles ``j`` and barycentric weights ``w_j``) applied an impulse ``P``
  to its particle; ``j`` takes ``T_j = −Σ w_j P``.  ``P`` is, along the
  normal, the reaction less the landing (``m · relative_vn``: covering the
  gap, or pushing a penetration out, is a position correction, removed from
  the particle's velocity after the step) and never a pull; along the
  surface, a sticking contact's whole tangential reaction, a sliding one's
  friction impulse.
* ``P`` comes from the solve without ``T``; the caller solves once more with
  ``T`` as a load and the same constraints (so that the other layer answers
  through the cloth in the same step), or adds ``M⁻¹ T`` directly when no
  particle would change by more than ``transfer_speed``.  The reactions are
  not solved for again with ``T``: a partner joined to the contact's particle
  through the cloth would push its share back onto the contact, which would
  pass it back again, without end.
* A partner that is constrained itself (on an obstacle, or against a layer)
  moves only along the directions its own constraint leaves free; the rest
  of its share goes to that constraint (a table carries the layers above).
  Held particles take nothing (infinitely heavy).
* A partner's share may bring it up to the velocity of the contacts pushing
  it (plus ``slack``), never faster relative to them than it was (plus
  ``slack``) (:func:`_limit`).  A constraint holds its particle against the
  rest of the cloth too: the first particle of a falling sheet to touch the
  layer below catches the whole sheet (tens of m/s times its own mass in one
  stage), and passing all of that to the few particles under it threw them
  out of their layer at tens of m/s.  What is cut stays with the constraint,
  as before this module (the layers then do not exchange exactly opposite
  impulses).

Positions m, velocities m/s, masses kg, impulses N·s.
"""

from __future__ import annotations

import numpy as np

from ..solve.sparse import bsr_product

__all__ = ["common_velocity", "layer_reactions", "receivers", "spread"]


def common_velocity(a: np.ndarray, wa: np.ndarray, va: np.ndarray, b: np.ndarray,
                    wb: np.ndarray, vb: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``(k, 3)`` m/s: the common velocity of ``k`` contact pairs, the points
    of side A (particles ``a``, weights ``wa``, ``(k, 3)``) and side B moving
    at ``va``, ``vb`` ``(k, 3)`` m/s; particles ``fixed`` (``(n,)`` bool) count
    as infinitely heavy.

    Two layers of one cloth have the same mass per area, so a point of one
    meets as much mass of the other as it carries itself, however either is
    meshed: the common velocity of two free sides is the mean ``(v_a + v_b)/2``.
    (A point's own effective mass ``1 / Σ w_j²/m_j`` gave each pair of an
    overlap its own target - 3x heavier at a triangle's middle than at a
    corner - and the constraints of neighbouring particles fought through the
    cloth.)  A side whose particles are partly fixed moves by the free
    fraction ``φ`` of its weight: ``u = (φ_b v_a + φ_a v_b)/(φ_a + φ_b)``."""
    free_a = np.einsum("kj,kj->k", wa, ~fixed[a])
    free_b = np.einsum("kj,kj->k", wb, ~fixed[b])
    total = free_a + free_b
    share_a = np.where(total > 0, free_b / np.where(total > 0, total, 1.0), 0.0)
    return share_a[:, None] * va + (1.0 - share_a)[:, None] * vb


def layer_reactions(matrix, rhs, v, dv, contacts, held, masses, sliding, friction_impulse,
                    relative_vn, projectors, slack):
    """The impulses the other side of each contact between layers takes.

    Args:
        matrix: the system matrix ``A`` of the last solve; rhs: ``(n, 3)`` N·s
            its right-hand side (friction included); v: ``(n, 3)`` m/s the
            iterate it started from; dv: ``(n, 3)`` m/s its solution.
        contacts: its :class:`~cloth_lod_ros.sim.contact.contacts.ContactSet` (``k``
            contacts); held: ``(p,)`` indices of held particles.
        masses: ``(n,)`` kg.  sliding: ``(k,)`` bool, contacts free along their
            surface; friction_impulse: ``(k, 3)`` N·s, theirs.
        relative_vn: ``(k,)`` m/s, the normal velocity each contact prescribed
            relative to its surface (the landing).
        projectors: ``(k, 3, 3)`` the contacts' filters (the directions each
            particle was free to move).
        slack: m/s, see :func:`_limit`.

    Returns:
        ``(T, free)``: ``(n, 3)`` N·s the impulses on the other sides' particles
        and their parts along the directions those particles are free to move
        (a particle sticking to an obstacle passes its share on to it, one
        sliding on it moves only along the surface); ``(None, None)`` when no
        contact is with a layer.
    """
    n = len(dv)
    takes = receivers(contacts, held, n)
    if takes is None:
        return None, None
    rows, normals = contacts.indices, contacts.normals
    reaction = (bsr_product(matrix, dv) - rhs)[rows]
    normal_reaction = np.einsum("kd,kd->k", reaction, normals)
    load = np.maximum(normal_reaction - masses[rows] * relative_vn, 0.0)
    along = np.where(sliding[:, None], friction_impulse,
                     reaction - normal_reaction[:, None] * normals)
    transfer = spread(contacts, load[:, None] * normals + along, takes)
    free = transfer.copy()
    free[rows] = np.einsum("kij,kj->ki", projectors, free[rows])
    # The velocity of the contacts pushing each particle (after the solve,
    # less the landing), relative to its own.
    end = v + dv
    pusher = end[rows] - relative_vn[:, None] * normals
    partners, weights = contacts.partner_arrays()
    share = np.where(takes[partners], weights, 0.0).ravel()
    flat = partners.ravel()
    total = np.bincount(flat, share, minlength=n)
    towards = np.column_stack([np.bincount(flat, share * np.repeat(pusher[:, d], 3), minlength=n)
                               for d in range(3)])
    pushed = total > 0
    towards[pushed] = towards[pushed] / total[pushed, None] - end[pushed]
    scale = _limit(free / masses[:, None], towards, slack)
    return scale[:, None] * transfer, scale[:, None] * free


def receivers(contacts, held: np.ndarray, n: int) -> np.ndarray | None:
    """``(n,)`` bool: the particles on the other side of a contact between
    layers (weight > 0) that are not held (``held``: ``(p,)`` indices); None
    when ``contacts`` has no contact with a layer."""
    partners, weights = contacts.partner_arrays()
    if not weights.any():
        return None
    out = np.zeros(n, bool)
    out[partners[weights > 0]] = True
    out[held] = False
    return out


def spread(contacts, applied: np.ndarray, takes: np.ndarray) -> np.ndarray:
    """``(n, 3)`` N·s: ``−Σ w_j P`` on each other-side particle ``j`` that
    ``takes`` (``(n,)`` bool), ``P`` ``(k, 3)`` N·s being the impulse each of
    the ``k`` contacts applied to its own particle (an obstacle contact, with
    zero weights, passes nothing)."""
    partners, weights = contacts.partner_arrays()
    share = np.where(takes[partners], weights, 0.0).ravel()
    flat = partners.ravel()
    return -np.column_stack([np.bincount(flat, share * np.repeat(applied[:, d], 3),
                                         minlength=len(takes)) for d in range(3)])


def _limit(change: np.ndarray, towards: np.ndarray, slack: float) -> np.ndarray:
    """``(n,)`` the largest ``s`` in [0, 1] per particle for which the velocity
    change ``s ΔV`` (``change``, ``(n, 3)`` m/s) neither makes the particle
    faster relative to the contacts pushing it (their velocity relative to
    its own: ``d``, ``towards``, ``(n, 3)`` m/s) than it was, ``|s ΔV − d| ≤
    |d| + slack``, nor is larger than bringing it to their velocity,
    ``|s ΔV| ≤ |d| + slack`` (``slack`` m/s).  Between two layers that slide
    or stick on each other nothing is cut; a share that would throw a
    particle past the layer pushing it, or away from it, is."""
    a = np.einsum("nd,nd->n", change, change)
    b = np.einsum("nd,nd->n", change, towards)
    reach = np.linalg.norm(towards, axis=1) + slack
    c = np.einsum("nd,nd->n", towards, towards) - reach * reach     # ≤ 0
    safe = np.where(a > 0, a, 1.0)
    past = (b + np.sqrt(np.maximum(b * b - a * c, 0.0))) / safe
    size = reach / np.sqrt(safe)
    return np.where(a > 0, np.clip(np.minimum(past, size), 0.0, 1.0), 1.0)
