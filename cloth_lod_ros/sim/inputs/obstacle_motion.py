"""Kinematic obstacles: obstacles moved by a script or by live targets (design §3).

An obstacle of the scene is *static* until it has somewhere to go: scripted
``waypoints`` (``[t, x, y, z]`` rows, or ``[t, x, y, z, qx, qy, qz, qw]`` with
an orientation) or a live target (:meth:`ObstacleInputs.set_obstacle_target`,
the node's ``obstacle/<name>/pose``).  From then on it is *kinematic*: its
pose follows the target at no more than ``max_speed`` (m/s) and
``max_angular_speed`` (rad/s), like a grasp's grip, and the cloth does not
push back on it.

The pose of an obstacle is that of its frame
(:class:`~cloth_lod_ros.sim.contact.obstacles.Obstacle`): its centre (a plane's point) and the orientation whose z axis is a plane's
normal or a cylinder's axis, a box's own orientation, the identity for a
sphere - the pose of its marker.

Pose changes happen at step boundaries, with the motion over the step known:
from the pose at the step's start to the pose at its end the obstacle moves
with constant velocity ``v = Δp / H`` and angular velocity ``ω = θ / H``
(``θ`` the rotation vector of the turn, H the frame period), turning about its
moving centre.  :class:`ObstacleSweep` gives the obstacles at any fraction of
the frame, so every step of the error-controlled stepper sees them move
continuously, with the velocity field ``u(x) = v + ω × (x − c)`` that enters
contact and friction.  A static obstacle stays the very object built from the
scene, with no velocity: scenes without kinematic obstacles run exactly as
before.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..contact.obstacles import Obstacle, make_obstacle
from .grasps import checked_pose

__all__ = ["ObstacleMotion", "ObstacleSweep", "ObstacleInputs"]

log = logging.getLogger("cloth_lod_ros.sim.cloth")


@dataclass
class ObstacleMotion:
    """Run-time pose of one obstacle and what drives it.

    Attributes:
        name: the obstacle's name.  home: its geometry at the scene's pose.
        waypoints: ``(w, 4)`` or ``(w, 8)`` scripted targets ``[t, x, y, z(,
            qx, qy, qz, qw)]`` (s, m; empty: none).
        max_speed: m/s; max_angular_speed: rad/s.
        position: ``(3,)`` m and rotation: the current pose.
        command_position, command_rotation: the live target (None: none).
        jumps: how many times the target moved faster than the limits.
    """

    name: str
    home: Obstacle
    waypoints: np.ndarray
    max_speed: float
    max_angular_speed: float
    position: np.ndarray
    rotation: Rotation
    command_position: np.ndarray | None = None
    command_rotation: Rotation | None = None
    home_rotation: Rotation | None = None
    jumps: int = 0
    lagging: bool = False

    def __post_init__(self):
        if self.home_rotation is None:
            self.home_rotation = self.rotation

    @classmethod
    def from_config(cls, cfg) -> "ObstacleMotion":
        """From an :class:`~cloth_lod_ros.sim.scene.config.ObstacleConfig`."""
        home = make_obstacle(cfg)
        rows = np.asarray(cfg.waypoints, dtype=float)
        waypoints = rows.reshape(len(rows), -1) if len(rows) else np.zeros((0, 4))
        return cls(name=cfg.name, home=home, waypoints=waypoints, max_speed=cfg.max_speed,
                   max_angular_speed=cfg.max_angular_speed,
                   position=np.asarray(home.origin, dtype=float).copy(),
                   rotation=Rotation.from_quat(home.orientation_quaternion()))

    @property
    def kinematic(self) -> bool:
        """Whether it has a script or a live target (else it is static)."""
        return len(self.waypoints) > 0 or self.command_position is not None

    def set_target(self, position, orientation=None) -> None:
        """Command a pose: position (m) and optional quaternion [x, y, z, w]; a
        live command replaces the script.

        Raises:
            ValueError: non-finite or malformed values (the old target stays).
        """
        position, rotation = checked_pose(position, orientation, "obstacle")
        self.waypoints = np.zeros((0, 4))
        self.command_position = position.copy()
        if rotation is not None:
            self.command_rotation = rotation

    def target_at(self, time: float) -> tuple[np.ndarray, Rotation]:
        """The commanded pose at ``time`` s: the script interpolated (linear in
        position, slerp in orientation; held before the first and after the
        last waypoint), or the live command, or where it is."""
        if len(self.waypoints):
            w = self.waypoints
            t = w[:, 0]
            position = np.array([np.interp(time, t, w[:, d]) for d in (1, 2, 3)])
            rotation = self.command_rotation or self.rotation
            if w.shape[1] == 8:
                keys = Rotation.from_quat(w[:, 4:8])
                rotation = keys[0] if len(w) == 1 else Slerp(t, keys)(
                    float(np.clip(time, t[0], t[-1])))
            return position, rotation
        if self.command_position is not None:
            return self.command_position, self.command_rotation or self.rotation
        return self.position, self.rotation

    def next_pose(self, time: float, h: float) -> tuple[np.ndarray, Rotation]:
        """The pose after ``h`` s, ending at ``time``: towards the target of
        ``time``, at most ``max_speed · h`` and ``max_angular_speed · h`` away
        (nothing is changed; :meth:`commit` takes it)."""
        target, target_rotation = self.target_at(time)
        step = target - self.position
        distance = float(np.linalg.norm(step))
        limit = self.max_speed * h
        self._lagging = distance > limit
        if self._lagging:
            step = step * (limit / distance)
        position = self.position + step
        rotation = self.rotation
        angle = (target_rotation * self.rotation.inv()).magnitude()
        if angle > 1e-12:
            fraction = min(1.0, self.max_angular_speed * h / angle)
            self._lagging = self._lagging or fraction < 1.0
            rotation = Slerp([0.0, 1.0], Rotation.concatenate(
                [self.rotation, target_rotation]))([fraction])[0]
        self._target_distance = distance
        return position, rotation

    def commit(self, position: np.ndarray, rotation: Rotation, h: float) -> None:
        """Take the pose :meth:`next_pose` gave, once the step has succeeded."""
        if self._lagging and not self.lagging:
            self.jumps += 1
            log.info("obstacle %r: target is %.3f m away (more than %.3f m/s x %.4g s) "
                     "or turned faster than %.3g rad/s; catching up at the speed limit",
                     self.name, self._target_distance, self.max_speed, h,
                     self.max_angular_speed)
        self.lagging = self._lagging
        self.position, self.rotation = position, rotation

    def geometry(self, position, rotation: Rotation, velocity=None,
                 angular_velocity=None) -> Obstacle:
        """The obstacle at pose ``(position (3,) m, rotation)`` with the given
        velocities (``(3,)`` m/s, rad/s)."""
        matrix = None
        if rotation is not self.home_rotation:      # never turned: directions exact
            turn = rotation * self.home_rotation.inv()
            matrix = None if turn.magnitude() == 0.0 else turn.as_matrix()
        return self.home.moved(position, matrix, velocity, angular_velocity)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """``(position (3,) m, quaternion [x, y, z, w])`` now."""
        return self.position.copy(), self.rotation.as_quat()


class ObstacleSweep:
    """The obstacles over one frame of ``frame`` s: each kinematic one moves
    from its pose at the frame's start to its pose at the end with constant
    velocity and angular velocity; static ones stay as they are.

    Args:
        current: the current obstacles (static ones are kept as they are).
        motions: ``{index: (ObstacleMotion, end position (3,), end rotation)}``
            of the kinematic ones.
    """

    def __init__(self, current: list[Obstacle], motions: dict, frame: float):
        self.current = current
        self.frame = frame
        self._paths = {}
        for k, (motion, end_position, end_rotation) in motions.items():
            turn = (end_rotation * motion.rotation.inv()).as_rotvec()
            self._paths[k] = (motion, motion.position, end_position - motion.position,
                              motion.rotation, turn)

    def commit(self, obstacles: list[Obstacle]) -> None:
        """The step succeeded: every kinematic obstacle takes its end pose,
        and ``obstacles`` (modified in place) its end geometry."""
        end = self.at(1.0)
        for k, (motion, start, shift, rotation, turn) in self._paths.items():
            if np.any(turn):
                rotation = Rotation.from_rotvec(turn) * rotation
            motion.commit(start + shift, rotation, self.frame)
            obstacles[k] = end[k]

    def at(self, fraction: float) -> list[Obstacle]:
        """The obstacles at ``fraction`` (0 to 1) of the frame, kinematic ones
        with the frame's velocity ``Δp / H`` (m/s) and ``θ / H`` (rad/s)."""
        out = list(self.current)
        for k, (motion, start, shift, rotation, turn) in self._paths.items():
            if np.any(turn):
                rotation = Rotation.from_rotvec(fraction * turn) * rotation
            out[k] = motion.geometry(start + fraction * shift, rotation,
                                     shift / self.frame, turn / self.frame)
        return out


class ObstacleInputs:
    """Kinematic obstacles of a :class:`~cloth_lod_ros.sim.cloth.ClothSim` (mixin):
    relies on its ``scene``, ``obstacles`` (the current geometry, a list the
    time stepper shares) and ``obstacle_motions``."""

    def _make_obstacles(self) -> None:
        self.obstacle_motions = [ObstacleMotion.from_config(o) for o in self.scene.obstacles]
        self.obstacles = [m.home for m in self.obstacle_motions]

    def obstacle(self, name: str) -> ObstacleMotion:
        for m in self.obstacle_motions:
            if m.name == name:
                return m
        raise KeyError(f"no obstacle named {name!r}; obstacles: "
                       f"{[m.name for m in self.obstacle_motions]}")

    def set_obstacle_target(self, name: str, position, orientation=None) -> None:
        """Command obstacle ``name`` to a pose: position (m) of its centre (a
        plane's point), quaternion [x, y, z, w] of its frame (module
        docstring).  It moves there from the next step on at its speed limits.

        Raises:
            KeyError: unknown obstacle; ValueError: non-finite or malformed pose.
        """
        self.obstacle(name).set_target(position, orientation)

    def obstacle_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(position (3,) m, quaternion [x, y, z, w])`` of obstacle ``name`` now."""
        return self.obstacle(name).pose()

    def obstacle_configs(self) -> tuple:
        """The scene's obstacle configs at their current poses (for drawing:
        markers, pictures)."""
        out = []
        for cfg, obstacle, motion in zip(self.scene.obstacles, self.obstacles,
                                         self.obstacle_motions):
            if obstacle is motion.home:
                out.append(cfg)
                continue
            fields = {"centre": tuple(float(c) for c in obstacle.origin)}
            if cfg.type == "plane":
                fields["normal"] = tuple(float(c) for c in obstacle.normal)
            elif cfg.type in ("cylinder", "disc"):
                fields["axis"] = tuple(float(c) for c in obstacle.axis)
            elif cfg.type == "box":
                fields["orientation"] = tuple(float(c) for c in obstacle.orientation)
            out.append(dataclasses.replace(cfg, **fields))
        return tuple(out)

    def _obstacle_sweep(self, time: float, h: float) -> ObstacleSweep | None:
        """The obstacles' motion over the step of ``h`` s ending at ``time``
        (None when every obstacle is static)."""
        motions = {k: (m, *m.next_pose(time, h)) for k, m in enumerate(self.obstacle_motions)
                   if m.kinematic}
        return ObstacleSweep(self.obstacles, motions, h) if motions else None

    def _commit_obstacles(self, sweep: ObstacleSweep | None) -> None:
        """After a successful step: the kinematic obstacles at their end poses
        (with the step's velocities), in the list the stepper shares."""
        if sweep is not None:
            sweep.commit(self.obstacles)
