"""Analytic obstacles and particle contact (BW §5.3, §6; design §3).

Each obstacle gives, for query points, a signed distance φ (m, negative
inside) and the outward unit normal of the nearest surface point, vectorised.
Contact is a *velocity constraint* in the filtered PCG: a particle that is, or
would get this step, near a surface (see :func:`find_contacts`) has its normal
velocity prescribed so that it ends the step exactly on the offset surface at
``thickness`` (position correction through the velocity: a penetrating particle
is pushed out at most ``max_correction_speed``).  The
constraint is released when the force it would need pulls the particle in
(the solve is repeated without it).  Coulomb friction is part of the implicit
solve (``integrator.ImplicitStageSolver._solve_with_contacts``): from the frictionless
normal impulse λ, a contact sticks (fully constrained) while its tangential
momentum is within μλ and slips with the impulse −μλ t̂ otherwise, so the rest
of the cloth responds to the friction in the same step.

A scene without obstacles never calls into this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Obstacle", "Plane", "Sphere", "Cylinder", "Box", "make_obstacle",
           "ContactSet", "nearest_surface", "find_contacts", "penetrations"]


def _normalise(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(norm > 0, norm, 1.0)


def quaternion_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``[x, y, z, w]`` (ROS order)."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@dataclass
class Obstacle:
    """Base: name and Coulomb friction coefficient (dimensionless)."""

    name: str
    friction: float

    def distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(φ (m,), normal (m, 3))`` for points ``x`` ``(m, 3)`` in m."""
        raise NotImplementedError


@dataclass
class Plane(Obstacle):
    """Half-space below the plane through ``point`` with outward ``normal``."""

    point: np.ndarray
    normal: np.ndarray

    def distance(self, x):
        n = self.normal / np.linalg.norm(self.normal)
        return (x - self.point) @ n, np.broadcast_to(n, x.shape)


@dataclass
class Sphere(Obstacle):
    centre: np.ndarray
    radius: float

    def distance(self, x):
        d = x - self.centre
        r = np.linalg.norm(d, axis=1)
        # At (or within rounding of) the centre any direction is nearest; a tiny
        # |d| would also lose precision when squared, so fall back below 1e-12 R.
        safe = r > 1e-12 * self.radius
        normal = np.where(safe[:, None], d / np.where(safe, r, 1.0)[:, None], [0, 0, 1])
        return r - self.radius, normal


@dataclass
class Cylinder(Obstacle):
    """Solid finite cylinder (a disc when ``half_height`` is small): the paper's
    circular table.  ``axis`` is a unit vector, ``centre`` the middle."""

    centre: np.ndarray
    axis: np.ndarray
    radius: float
    half_height: float

    def distance(self, x):
        a = self.axis / np.linalg.norm(self.axis)
        d = x - self.centre
        along = d @ a
        radial_vec = d - along[:, None] * a
        radial = np.linalg.norm(radial_vec, axis=1)
        radial_dir = np.where(radial[:, None] > 1e-12,
                              radial_vec / np.maximum(radial, 1e-300)[:, None],
                              _any_perpendicular(a))
        q_r, q_a = radial - self.radius, np.abs(along) - self.half_height
        axial_dir = np.sign(along)[:, None] * a
        axial_dir[along == 0] = a
        outside_r, outside_a = np.maximum(q_r, 0), np.maximum(q_a, 0)
        outside = np.hypot(outside_r, outside_a)
        phi = outside + np.minimum(np.maximum(q_r, q_a), 0.0)
        # Normal: the gradient of φ (outside: towards the nearest rim/face point).
        grad_out = _normalise(outside_r[:, None] * radial_dir + outside_a[:, None] * axial_dir)
        grad_in = np.where((q_r > q_a)[:, None], radial_dir, axial_dir)
        return phi, np.where((outside > 0)[:, None], grad_out, grad_in)


@dataclass
class Box(Obstacle):
    """Solid box: ``centre``, ``half_extents`` (m), ``orientation`` [x, y, z, w] and
    edge ``rounding`` radius (m).  Rounded edges spread a cloth's wrap (and its
    friction) over an arc; on a sharp edge the particle before the corner sees
    only the top face and friction holds far more than the capstan law allows."""

    centre: np.ndarray
    half_extents: np.ndarray
    orientation: np.ndarray
    rounding: float = 0.0

    def distance(self, x):
        rot = quaternion_matrix(self.orientation)
        local = (x - self.centre) @ rot                      # world -> box frame
        q = np.abs(local) - (self.half_extents - self.rounding)
        outside = np.linalg.norm(np.maximum(q, 0), axis=1)
        phi = outside + np.minimum(q.max(axis=1), 0.0) - self.rounding
        sign = np.where(local < 0, -1.0, 1.0)
        grad_out = _normalise(np.maximum(q, 0) * sign)
        grad_in = np.zeros_like(local)
        k = q.argmax(axis=1)
        grad_in[np.arange(len(x)), k] = sign[np.arange(len(x)), k]
        local_normal = np.where((outside > 0)[:, None], grad_out, grad_in)
        return phi, local_normal @ rot.T


def _any_perpendicular(a: np.ndarray) -> np.ndarray:
    helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    p = np.cross(a, helper)
    return p / np.linalg.norm(p)


def make_obstacle(cfg) -> Obstacle:
    """Build an obstacle from :class:`cloth_lod_ros.sim.config.ObstacleConfig`."""
    kind = cfg.type
    if kind == "plane":
        return Plane(cfg.name, cfg.friction, np.array(cfg.centre), np.array(cfg.normal))
    if kind == "sphere":
        return Sphere(cfg.name, cfg.friction, np.array(cfg.centre), cfg.radius)
    if kind in ("cylinder", "disc"):
        return Cylinder(cfg.name, cfg.friction, np.array(cfg.centre), np.array(cfg.axis),
                        cfg.radius, cfg.half_height)
    if kind == "box":
        return Box(cfg.name, cfg.friction, np.array(cfg.centre),
                   np.array(cfg.half_extents), np.array(cfg.orientation), cfg.rounding)
    raise ValueError(f"unknown obstacle type {kind!r}")


@dataclass
class ContactSet:
    """Particles in contact this step.

    Attributes:
        indices: ``(k,)`` particle indices; ``normals``: ``(k, 3)`` outward;
        distance: ``(k,)`` φ − thickness (m, negative = inside the offset
        surface); ``friction``: ``(k,)`` μ of the touched obstacle;
        ``hold``: ``(k,)`` contacts that may not be released (the particle was
        found inside the obstacle, so letting go is not an option);
        ``velocity``: ``(k, 3)`` m/s, the velocity of the surface point the
        particle touches (the normal target and sticking are relative to it),
        ``None`` = zero (a resting obstacle).
    """

    indices: np.ndarray
    normals: np.ndarray
    distance: np.ndarray
    friction: np.ndarray
    hold: np.ndarray | None = None
    velocity: np.ndarray | None = None

    def __post_init__(self):
        if self.hold is None:
            self.hold = np.zeros(len(self.indices), dtype=bool)

    def __len__(self) -> int:
        return len(self.indices)

    def subset(self, keep: np.ndarray) -> "ContactSet":
        return ContactSet(self.indices[keep], self.normals[keep], self.distance[keep],
                          self.friction[keep], self.hold[keep],
                          None if self.velocity is None else self.velocity[keep])

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
        return ContactSet(np.concatenate([self.indices[keep], other.indices]),
                          np.concatenate([self.normals[keep], other.normals]),
                          np.concatenate([self.distance[keep], other.distance]),
                          np.concatenate([self.friction[keep], other.friction]),
                          np.concatenate([self.hold[keep], other.hold]), velocity)


def nearest_surface(obstacles: list[Obstacle], x: np.ndarray):
    """For points ``(m, 3)``: signed distance (m), outward normal and friction
    coefficient of the nearest obstacle (the one with the smallest φ)."""
    best = np.full(len(x), np.inf)
    normal = np.zeros((len(x), 3))
    mu = np.zeros(len(x))
    for obstacle in obstacles:
        phi, nrm = obstacle.distance(x)
        closer = phi < best
        best[closer] = phi[closer]
        normal[closer] = nrm[closer]
        mu[closer] = obstacle.friction
    return best, normal, mu


def find_contacts(obstacles: list[Obstacle], x: np.ndarray, thickness: float,
                  exclude: np.ndarray | None = None, velocities: np.ndarray | None = None,
                  h: float = 0.0) -> ContactSet:
    """Particles that touch, or would reach this step, an obstacle's offset surface.

    *Speculative* contacts: a particle is a candidate when
    ``φ + h·min(v·n, 0) < 2·thickness``, so that one moving fast is caught
    before it tunnels into a thin obstacle, and one resting on a surface stays
    constrained instead of falling a step (g h²) in and out of the band.  The
    solve then prescribes the normal velocity that lands it exactly on the
    offset surface (or releases it if that would pull).

    Args:
        x: ``(n, 3)`` positions, m; velocities: ``(n, 3)`` m/s; h: step, s.
        thickness: distance kept from surfaces, m.
        exclude: particle indices never constrained by contact (held ones).
    """
    best, normal, mu = nearest_surface(obstacles, x)
    approach = 0.0
    if velocities is not None and h > 0:
        approach = h * np.minimum(np.einsum("nd,nd->n", velocities, normal), 0.0)
    touching = best + approach < 2.0 * thickness
    if exclude is not None and len(exclude):
        touching[exclude] = False
    idx = np.flatnonzero(touching)
    return ContactSet(idx, normal[idx], best[idx] - thickness, mu[idx])


def penetrations(obstacles: list[Obstacle], start: np.ndarray, end: np.ndarray,
                 thickness: float, exclude: np.ndarray | None = None,
                 tolerance: float = 0.25) -> ContactSet:
    """Contacts for particles whose end-of-step position is inside the offset surface.

    A particle that ends more than ``tolerance × thickness`` inside gets a
    contact on the tangent plane at the surface point nearest its predicted
    position; ``distance`` is measured from its *start* position to that plane,
    so the re-solved step lands it on the offset surface.

    Args:
        start, end: ``(n, 3)`` positions at the start of the step and as
            predicted by the solve, m.
    """
    best, normal, mu = nearest_surface(obstacles, end)
    inside = best < (1.0 - tolerance) * thickness
    if exclude is not None and len(exclude):
        inside[exclude] = False
    idx = np.flatnonzero(inside)
    surface = end[idx] - best[idx, None] * normal[idx]
    along = np.einsum("kd,kd->k", start[idx] - surface, normal[idx])
    return ContactSet(idx, normal[idx], along - thickness, mu[idx],
                      np.ones(len(idx), dtype=bool))
