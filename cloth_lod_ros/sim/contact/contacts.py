"""Particle contact with the analytic obstacles (BW §5.3, §6; design §3).

Each obstacle (:mod:`.obstacles`) gives, for query points, a signed distance
φ (m, negative inside) and the outward unit normal of the nearest surface
point, vectorised.
Contact is a *velocity constraint* in the filtered PCG: a particle that is, or
would get this step, near a surface (see :func:`find_contacts`) has its normal
velocity prescribed so that it ends the step exactly on the offset surface at
``thickness`` (position correction through the velocity: a penetrating particle
is pushed out at most ``max_correction_speed``).  The
constraint is released when the force it would need pulls the particle in
(the solve is repeated without it).  Coulomb friction is part of the implicit
solve (``implicit_stage.ImplicitStageSolver._solve_with_contacts``): from the frictionless
normal impulse λ, a contact sticks (fully constrained) while its tangential
momentum is within μλ and slips with the impulse −μλ t̂ otherwise, so the rest
of the cloth responds to the friction in the same step.

An obstacle may move (design §3, "Moving obstacles"): it then carries the
rigid velocity of its motion over the current step, ``velocity`` (m/s, of its
reference point :attr:`Obstacle.origin`) and ``angular_velocity`` (rad/s), and
every contact carries the velocity of the surface point it touches
(:attr:`ContactSet.velocity`).  The constraint and friction are relative to
that velocity.  A static obstacle has ``velocity None`` and its contacts
``velocity None``: the code then runs exactly as it did before obstacles could
move.

A particle near two obstacles at once gets both (``ContactSet.second``; the
solve is in :mod:`cloth_lod_ros.sim.contact.contact_rows`).  A scene without obstacles never calls
into this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .obstacles import Obstacle

__all__ = ["ContactSet", "nearest_surface", "find_contacts", "penetrations"]


@dataclass
class ContactSet:
    """Particles in contact this step.

    Attributes:
        indices: ``(k,)`` particle indices; ``normals``: ``(k, 3)`` outward;
        distance: ``(k,)`` φ − thickness (m, negative = inside the offset
        surface) at the start of the step; ``friction``: ``(k,)`` μ of the
        touched obstacle;
        ``hold``: ``(k,)`` contacts that may not be released (the particle was
        found inside the obstacle, so letting go is not an option);
        ``velocity``: ``(k, 3)`` m/s, the velocity of the obstacle's surface
        point the particle touches (None: every one is 0, static obstacles).
        The normal target and the stick condition are relative to it: a
        contact lands on the offset surface where the surface is at the end
        of the stage, a sticking one moves with the surface, a slipping one
        feels friction against its velocity *relative* to the surface.
        ``partners``, ``partner_weights``: ``(k, 3)`` for a contact with
        another layer of the cloth (self-collision), the particles of the
        other side and their barycentric weights (summing to 1): the
        reaction to the impulse this contact applies acts on them.  Zero
        weights (or None for the whole set): an obstacle, which takes the
        reaction itself (kinematic).
        ``second``: a particle near two obstacles at once (wedged between a
        pushing box and the table) is constrained against both: ``second`` is
        a set aligned row by row with this one (same ``indices``) holding the
        other obstacle's normal, distance, friction, hold and surface
        velocity; rows with one obstacle have a zero normal there
        (:attr:`doubled` is False).  None: no row has a second obstacle.
        The solve then keeps the particle out of both (its normal velocity
        prescribed along both normals, free only along their common tangent;
        ``contact_rows``).
    """

    indices: np.ndarray
    normals: np.ndarray
    distance: np.ndarray
    friction: np.ndarray
    hold: np.ndarray | None = None
    velocity: np.ndarray | None = None
    partners: np.ndarray | None = None
    partner_weights: np.ndarray | None = None
    second: "ContactSet | None" = None

    def __post_init__(self):
        if self.hold is None:
            self.hold = np.zeros(len(self.indices), dtype=bool)

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def doubled(self) -> np.ndarray:
        """``(k,)`` bool: rows constrained against a second obstacle too."""
        if self.second is None:
            return np.zeros(len(self), bool)
        return np.any(self.second.normals != 0.0, axis=1)

    def second_or_blank(self) -> "ContactSet":
        """:attr:`second`, or a blank one (zero normals) when there is none."""
        if self.second is not None:
            return self.second
        k = len(self)
        return ContactSet(self.indices, np.zeros((k, 3)), np.zeros(k), np.zeros(k),
                          velocity=None if self.velocity is None else np.zeros((k, 3)))

    def swapped(self, rows: np.ndarray) -> "ContactSet":
        """A copy whose ``rows`` (``(k,)`` bool) take their second obstacle as
        the first and lose the second (the first one's contact was released)."""
        first, second = self.subset(slice(None)), self.second.subset(slice(None))
        for name in ("normals", "distance", "friction", "hold"):
            getattr(first, name)[rows] = getattr(second, name)[rows]
        if first.velocity is not None or second.velocity is not None:
            first.velocity = first.surface_velocity().copy()
            first.velocity[rows] = second.surface_velocity()[rows]
        first.second = second.without(rows)
        return first

    def without_second(self, rows: np.ndarray) -> "ContactSet":
        """A copy whose ``rows`` (``(k,)`` bool) lose their second obstacle."""
        out = self.subset(slice(None))
        out.second = self.second.without(rows)
        return out

    def without(self, rows: np.ndarray) -> "ContactSet":
        """A copy with ``rows`` (``(k,)`` bool) blanked (zero normal: no constraint);
        for :attr:`second` sets."""
        out = self.subset(slice(None))
        out.normals[rows] = 0.0
        out.distance[rows] = 0.0
        out.friction[rows] = 0.0
        out.hold[rows] = False
        if out.velocity is not None:
            out.velocity[rows] = 0.0
        return out

    def normal_speed(self) -> np.ndarray | None:
        """``(k,)`` m/s: the surface's velocity along each normal (None: static)."""
        if self.velocity is None:
            return None
        return np.einsum("kd,kd->k", self.velocity, self.normals)

    def subset(self, keep) -> "ContactSet":
        """The rows ``keep`` (bool mask, indices or a slice: copies)."""
        return ContactSet(self.indices[keep].copy(), self.normals[keep].copy(),
                          self.distance[keep].copy(), self.friction[keep].copy(),
                          self.hold[keep].copy(),
                          None if self.velocity is None else self.velocity[keep].copy(),
                          None if self.partners is None else self.partners[keep],
                          None if self.partners is None else self.partner_weights[keep],
                          None if self.second is None else self.second.subset(keep))

    def partner_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(partners (k, 3), weights (k, 3))``: :attr:`partners` and
        :attr:`partner_weights`, zeros (no other side) where they are ``None``."""
        if self.partners is None:
            return np.zeros((len(self), 3), np.int64), np.zeros((len(self), 3))
        return self.partners, self.partner_weights

    def surface_velocity(self) -> np.ndarray:
        """``(k, 3)`` m/s: :attr:`velocity`, zeros where it is ``None``."""
        return np.zeros((len(self), 3)) if self.velocity is None else self.velocity

    def union(self, other: "ContactSet") -> "ContactSet":
        """Contacts of both; where a particle is in both, ``other`` wins."""
        keep = ~np.isin(self.indices, other.indices)
        velocity = None
        if self.velocity is not None or other.velocity is not None:
            velocity = np.concatenate([self.surface_velocity()[keep],
                                       other.surface_velocity()])
        partners = (None, None)
        if self.partners is not None or other.partners is not None:
            partners = tuple(np.concatenate([mine[keep], theirs]) for mine, theirs
                             in zip(self.partner_arrays(), other.partner_arrays()))
        second = None
        if self.second is not None or other.second is not None:
            second = self.second_or_blank().subset(keep).union(other.second_or_blank())
        return ContactSet(np.concatenate([self.indices[keep], other.indices]),
                          np.concatenate([self.normals[keep], other.normals]),
                          np.concatenate([self.distance[keep], other.distance]),
                          np.concatenate([self.friction[keep], other.friction]),
                          np.concatenate([self.hold[keep], other.hold]), velocity,
                          *partners, second)


def _nearest(obstacles: list[Obstacle], x: np.ndarray):
    """``(φ (m,), normal (m, 3), μ (m,), index of the nearest obstacle (m,))``."""
    best = np.full(len(x), np.inf)
    normal = np.zeros((len(x), 3))
    mu = np.zeros(len(x))
    which = np.full(len(x), -1)
    for k, obstacle in enumerate(obstacles):
        phi, nrm = obstacle.distance(x)
        closer = phi < best
        best[closer] = phi[closer]
        normal[closer] = nrm[closer]
        mu[closer] = obstacle.friction
        which[closer] = k
    return best, normal, mu, which


def nearest_surface(obstacles: list[Obstacle], x: np.ndarray):
    """For points ``(m, 3)``: signed distance (m), outward normal and friction
    coefficient of the nearest obstacle (the one with the smallest φ)."""
    return _nearest(obstacles, x)[:3]


def _surface_velocity(obstacles: list[Obstacle], which: np.ndarray, x: np.ndarray,
                      phi: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """``(k, 3)`` m/s: velocity of obstacle ``which`` ``(k,)`` at the surface
    points ``x − φ n`` nearest points ``x`` ``(k, 3)`` (m); None when no
    obstacle moves."""
    if not any(o.moving for o in obstacles):
        return None
    surface = x - phi[:, None] * normal
    velocity = np.zeros_like(surface)
    for k, obstacle in enumerate(obstacles):
        if obstacle.moving:
            rows = which == k
            velocity[rows] = obstacle.surface_velocity(surface[rows])
    return velocity


#: A second obstacle constrains a particle when its normal is at least this
#: far (|cos| below it, 15°) from the first's: nearly parallel surfaces are
#: covered by the first constraint, nearly opposite ones (a particle squeezed
#: in a gap thinner than the cloth) cannot both be met.
SECOND_NORMAL_COS = float(np.cos(np.radians(15.0)))


def _second(obstacles: list[Obstacle], which: np.ndarray, x: np.ndarray,
            normal: np.ndarray, band: float, velocities: np.ndarray | None = None,
            h: float = 0.0):
    """For ``k`` particles at ``x`` ``(k, 3)`` (m) constrained against obstacle
    ``which`` ``(k,)`` along ``normal`` ``(k, 3)``: the nearest *other*
    obstacle within ``band`` m (after the approach ``h·min((v − u)·n, 0)`` over
    ``h`` s at ``velocities`` ``(k, 3)`` m/s) whose normal is not nearly
    parallel or opposite to ``normal``.  Returns ``(rows (k,) bool, φ (k,),
    normal (k, 3), μ (k,), index (k,))`` (rows False: none)."""
    k = len(x)
    best = np.full(k, np.inf)
    out_normal = np.zeros((k, 3))
    mu = np.zeros(k)
    out_which = np.full(k, -1)
    for j, obstacle in enumerate(obstacles):
        others = np.flatnonzero(which != j)
        if not len(others):
            continue
        phi, nrm = obstacle.distance(x[others])
        gap = phi
        if velocities is not None and h > 0:
            relative = velocities[others] - obstacle.surface_velocity(x[others] - phi[:, None] * nrm)
            gap = phi + h * np.minimum(np.einsum("kd,kd->k", relative, nrm), 0.0)
        cos = np.einsum("kd,kd->k", nrm, normal[others])
        take = (gap < band) & (np.abs(cos) < SECOND_NORMAL_COS) & (phi < best[others])
        rows = others[take]
        best[rows] = phi[take]
        out_normal[rows] = nrm[take]
        mu[rows] = obstacle.friction
        out_which[rows] = j
    return out_which >= 0, best, out_normal, mu, out_which


def _with_second(contacts: ContactSet, found, normal, mu, distance, hold,
                 velocity) -> ContactSet:
    """``contacts`` with the second obstacles :func:`_second` ``found``
    (``(k,)`` bool; ``normal`` ``(k, 3)``, ``mu`` ``(k,)``) attached as
    :attr:`ContactSet.second`, at ``distance`` ``(k,)`` m with ``hold``
    ``(k,)`` and surface ``velocity`` ``(k, 3)`` m/s or None; unchanged when
    none was found."""
    if found.any():
        contacts.second = ContactSet(
            contacts.indices, np.where(found[:, None], normal, 0.0),
            np.where(found, distance, 0.0), np.where(found, mu, 0.0), found & hold,
            None if velocity is None else np.where(found[:, None], velocity, 0.0))
    return contacts


def _second_velocity(obstacles, found, which, x, phi, normal):
    """``(k, 3)`` m/s: the surface velocity at the second obstacles' nearest
    points (zero where none was found), or None when no obstacle moves."""
    return _surface_velocity(obstacles, which, x, np.where(found, phi, 0.0), normal)


def find_contacts(obstacles: list[Obstacle], x: np.ndarray, thickness: float,
                  exclude: np.ndarray | None = None, velocities: np.ndarray | None = None,
                  h: float = 0.0) -> ContactSet:
    """Particles that touch, or would reach this step, an obstacle's offset surface.

    *Speculative* contacts: a particle is a candidate when
    ``φ + h·min((v − u)·n, 0) < 2·thickness`` (``u`` the velocity of the
    surface point, 0 for a static obstacle), so that one moving fast
    towards the surface, or one a surface moves fast towards, is caught
    before it tunnels into a thin obstacle, and one resting on a surface stays
    constrained instead of falling a step (g h²) in and out of the band.  The
    solve then prescribes the normal velocity that lands it exactly on the
    offset surface (or releases it if that would pull).

    Args:
        obstacles: at their poses at the start of the step.
        x: ``(n, 3)`` positions, m; velocities: ``(n, 3)`` m/s; h: step, s.
        thickness: distance kept from surfaces, m.
        exclude: particle indices never constrained by contact (held ones).
    """
    best, normal, mu, which = _nearest(obstacles, x)
    surface_velocity = _surface_velocity(obstacles, which, x, best, normal)
    approach = 0.0
    if velocities is not None and h > 0:
        relative = velocities if surface_velocity is None else velocities - surface_velocity
        approach = h * np.minimum(np.einsum("nd,nd->n", relative, normal), 0.0)
    elif surface_velocity is not None and h > 0:
        approach = h * np.minimum(-np.einsum("nd,nd->n", surface_velocity, normal), 0.0)
    touching = best + approach < 2.0 * thickness
    if exclude is not None and len(exclude):
        touching[exclude] = False
    idx = np.flatnonzero(touching)
    contacts = ContactSet(idx, normal[idx], best[idx] - thickness, mu[idx],
                          velocity=None if surface_velocity is None else surface_velocity[idx])
    if len(obstacles) > 1 and len(idx):
        found, phi, nrm, mu2, which2 = _second(
            obstacles, which[idx], x[idx], normal[idx], 2.0 * thickness,
            None if velocities is None else velocities[idx], h)
        contacts = _with_second(contacts, found, nrm, mu2, phi - thickness,
                                np.zeros(len(idx), bool),
                                _second_velocity(obstacles, found, which2, x[idx], phi, nrm))
    return contacts


def penetrations(obstacles: list[Obstacle], start: np.ndarray, end: np.ndarray,
                 thickness: float, exclude: np.ndarray | None = None,
                 tolerance: float = 0.25, h: float = 0.0) -> ContactSet:
    """Contacts for particles whose end-of-step position is inside the offset surface.

    A particle that ends more than ``tolerance × thickness`` inside gets a
    contact on the tangent plane at the surface point nearest its predicted
    position; ``distance`` is measured from its *start* position to that plane
    as it was at the start of the step (a moving surface point was ``u h``
    back), so the re-solved step lands it on the offset surface where it is
    at the end.

    Args:
        obstacles: at their poses at the *end* of the step.
        start, end: ``(n, 3)`` positions at the start of the step and as
            predicted by the solve, m.
        h: the step, s (how far back a moving surface was).
    """
    best, normal, mu, which = _nearest(obstacles, end)
    inside = best < (1.0 - tolerance) * thickness
    if exclude is not None and len(exclude):
        inside[exclude] = False
    idx = np.flatnonzero(inside)
    surface = end[idx] - best[idx, None] * normal[idx]
    velocity = _surface_velocity(obstacles, which[idx], end[idx], best[idx], normal[idx])
    if velocity is not None:
        surface = surface - h * velocity
    along = np.einsum("kd,kd->k", start[idx] - surface, normal[idx])
    contacts = ContactSet(idx, normal[idx], along - thickness, mu[idx],
                          np.ones(len(idx), dtype=bool), velocity)
    if len(obstacles) > 1 and len(idx):
        # Pushed into one obstacle, it may be next to another (a box pushing
        # it into the table's corner): that one constrains it too.
        found, phi, nrm, mu2, which2 = _second(obstacles, which[idx], end[idx], normal[idx],
                                               2.0 * thickness)
        velocity2 = _second_velocity(obstacles, found, which2, end[idx], phi, nrm)
        surface2 = end[idx] - np.where(found, phi, 0.0)[:, None] * nrm
        if velocity2 is not None:
            surface2 = surface2 - h * velocity2
        along2 = np.einsum("kd,kd->k", start[idx] - surface2, nrm)
        contacts = _with_second(contacts, found, nrm, mu2, along2 - thickness,
                                phi < (1.0 - tolerance) * thickness, velocity2)
    return contacts
