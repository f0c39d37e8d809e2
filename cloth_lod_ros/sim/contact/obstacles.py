"""Analytic obstacles: plane, sphere, cylinder (disc), box; their signed
distance, normal and surface velocity, and their poses (BW §5.3, §6;
design §3).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["Obstacle", "Plane", "Sphere", "Cylinder", "Box", "make_obstacle", "quaternion_matrix",
           "quaternion_from_z"]


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


def quaternion_from_z(axis) -> np.ndarray:
    """Unit quaternion ``[x, y, z, w]`` of the shortest turn taking +z onto ``axis`` (3,)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    w = 1.0 + a[2]
    if w < 1e-12:                                   # axis = -z: half turn about x
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.array([-a[1], a[0], 0.0, w])
    return q / np.linalg.norm(q)


@dataclass
class Obstacle:
    """Base: name and Coulomb friction coefficient (dimensionless).

    A moving obstacle also has ``velocity`` ``(3,)`` m/s (of :attr:`origin`)
    and ``angular_velocity`` ``(3,)`` rad/s over the current step; both None
    for a static one.  Its *pose* is ``(origin (3,) m, quaternion [x, y, z, w])``:
    the frame whose z axis is a plane's normal or a cylinder's axis, a box's
    own frame, a sphere's (identity) - the pose of its marker.
    """

    name: str
    friction: float
    velocity: np.ndarray | None = field(default=None, kw_only=True)
    angular_velocity: np.ndarray | None = field(default=None, kw_only=True)

    def distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(φ (m,), normal (m, 3))`` for points ``x`` ``(m, 3)`` in m."""
        raise NotImplementedError

    @property
    def moving(self) -> bool:
        return self.velocity is not None

    @property
    def origin(self) -> np.ndarray:
        """``(3,)`` m: the reference point of the pose (centre, or a plane's point)."""
        return self.centre

    def orientation_quaternion(self) -> np.ndarray:
        """``(4,)`` unit quaternion [x, y, z, w] of the pose."""
        return np.array([0.0, 0.0, 0.0, 1.0])

    def _posed(self, position: np.ndarray, rotation: np.ndarray | None) -> dict:
        """Fields of this shape at ``position`` (3,) m, turned by ``rotation``
        (3, 3) relative to its present orientation (None: not turned, so its
        directions stay exactly as they are)."""
        return {"centre": position}

    def moved(self, position, rotation: np.ndarray | None, velocity=None,
              angular_velocity=None) -> "Obstacle":
        """A copy with its origin at ``position`` ``(3,)`` m, turned by
        ``rotation`` ``(3, 3)`` relative to this one (None: not turned), with
        the given velocities (``(3,)`` m/s and rad/s; None: static)."""
        fields = self._posed(np.asarray(position, dtype=float), rotation)
        return replace(self, **fields, velocity=velocity, angular_velocity=angular_velocity)

    def surface_velocity(self, points: np.ndarray) -> np.ndarray:
        """``(m, 3)`` m/s: velocity of the obstacle's material at ``points`` ``(m, 3)``
        (m), ``v + ω × (p − origin)``; zeros for a static obstacle."""
        if self.velocity is None:
            return np.zeros_like(points)
        u = np.broadcast_to(self.velocity, points.shape).copy()
        if self.angular_velocity is not None and np.any(self.angular_velocity):
            u += np.cross(self.angular_velocity, points - self.origin)
        return u


@dataclass
class Plane(Obstacle):
    """Half-space below the plane through ``point`` with outward ``normal``."""

    point: np.ndarray
    normal: np.ndarray

    def distance(self, x):
        n = self.normal / np.linalg.norm(self.normal)
        return (x - self.point) @ n, np.broadcast_to(n, x.shape)

    @property
    def origin(self):
        return self.point

    def orientation_quaternion(self):
        return quaternion_from_z(self.normal)

    def _posed(self, position, rotation):
        if rotation is None:
            return {"point": position}
        return {"point": position, "normal": rotation @ self.normal}


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

    def orientation_quaternion(self):
        return quaternion_from_z(self.axis)

    def _posed(self, position, rotation):
        if rotation is None:
            return {"centre": position}
        return {"centre": position, "axis": rotation @ self.axis}


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

    def orientation_quaternion(self):
        return np.asarray(self.orientation, float) / np.linalg.norm(self.orientation)

    def _posed(self, position, rotation):
        if rotation is None:
            return {"centre": position}
        turned = rotation @ quaternion_matrix(self.orientation)
        return {"centre": position, "orientation": _matrix_quaternion(turned)}


def _matrix_quaternion(m: np.ndarray) -> np.ndarray:
    """Unit quaternion [x, y, z, w] of a rotation matrix (3, 3) (w ≥ 0)."""
    q = Rotation.from_matrix(m).as_quat()
    return -q if q[3] < 0 else q


def _any_perpendicular(a: np.ndarray) -> np.ndarray:
    helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    p = np.cross(a, helper)
    return p / np.linalg.norm(p)


def make_obstacle(cfg) -> Obstacle:
    """Build an obstacle from :class:`cloth_lod_ros.sim.scene.config.ObstacleConfig`."""
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
