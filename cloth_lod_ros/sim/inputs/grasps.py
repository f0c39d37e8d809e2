"""Grasps: grippers that hold the cloth at material points and move it.

A closed grasp holds one particle (``width`` 0) or every particle within
``width/2`` of its material point (a patch).  At closing, each held particle's
offset from the grip point is stored in the grip frame, so a pose
(position + orientation) places all of them rigidly.  The *effective* pose
follows the commanded target at no more than ``max_speed`` (m/s) and
``max_angular_speed`` (rad/s): a target that jumps (a teleport, a dropped
message, a bad clock) is caught up over the following steps instead of making
the cloth explode, and the jump is logged.  Held particles then get the
prescribed velocity that lands them exactly on their targets at the end of the
step (the same exact constraint as pins).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["Grasp"]

log = logging.getLogger(__name__)

#: How far a live target may stretch the cloth between a grasp and another held
#: point (a closed grasp, an active pin): their distance is kept within
#: ``(1 + MAX_REACH_STRAIN)`` times their rest distance in (u, v) (the cloth is a
#: flat rectangle, so the straight line in (u, v) is the shortest path through it).
#: A pose beyond that (a grasp sent to the workspace's edge while another holds the
#: cloth) would stretch it without limit into unphysical motion (issue 34).  0.5: a
#: mean strain along the line of at most half the node's ERROR bound (``strain_warn``
#: 0.3 x 4 = 1.2), leaving a factor of 2 for the strain's concentration at a point hold.
MAX_REACH_STRAIN = 0.5


def checked_pose(position, orientation, what: str) -> tuple[np.ndarray, Rotation | None]:
    """A commanded pose as ``(position (3,) m, Rotation or None)``, checked:
    three finite numbers and, if given, a finite non-zero quaternion
    ``[x, y, z, w]`` (normalised).  ``what`` names the commanded thing.

    Raises:
        ValueError: non-finite or malformed values.
    """
    position = np.asarray(position, dtype=float)
    if position.shape != (3,) or not np.all(np.isfinite(position)):
        raise ValueError(f"{what} target must be 3 finite numbers, got {position!r}")
    if orientation is None:
        return position, None
    q = np.asarray(orientation, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
        raise ValueError(f"{what} orientation must be a quaternion [x, y, z, w], got {q!r}")
    return position, Rotation.from_quat(q / np.linalg.norm(q))


@dataclass
class Grasp:
    """Run-time state of one grasp.

    Attributes:
        name: label; uv: material point (m); width: patch diameter in (u, v), m.
        max_speed: m/s; max_angular_speed: rad/s.
        waypoints: ``(w, 4)`` scripted ``[t, x, y, z]`` targets (empty: none).
        close_time, open_time: scripted events (s) or None.
        closed: whether it holds now.
        nodes: permanent ids of held particles (pool ids with LOD on).
        offsets: ``(k, 3)`` held particles' offsets in the grip frame, m.
        position, rotation: effective pose (m, scipy Rotation).
        command_position, command_rotation: the target pose (None: hold still).
        jumps: how many times the target moved faster than the limits.
    """

    name: str
    uv: np.ndarray
    width: float
    tolerance: float
    max_speed: float
    max_angular_speed: float
    waypoints: np.ndarray
    close_time: float | None = None
    open_time: float | None = None
    closed: bool = False
    nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: Rotation = field(default_factory=Rotation.identity)
    command_position: np.ndarray | None = None
    command_rotation: Rotation | None = None
    jumps: int = 0
    lagging: bool = False
    holding_in_place: bool = False      # the command is "stay where it closed", not a pose
    clamped: bool = False               # the live target is beyond reach (see reachable)

    @classmethod
    def from_config(cls, cfg) -> "Grasp":
        return cls(name=cfg.name, uv=np.asarray(cfg.uv, dtype=float), width=cfg.width,
                   tolerance=cfg.tolerance, max_speed=cfg.max_speed,
                   max_angular_speed=cfg.max_angular_speed,
                   waypoints=np.asarray(cfg.waypoints, dtype=float).reshape(-1, 4),
                   close_time=cfg.close_time, open_time=cfg.open_time)

    def attach(self, nodes: np.ndarray, positions: np.ndarray, grip_point: np.ndarray) -> None:
        """Close on particles ``nodes`` now at ``positions`` ``(k, 3)``; the grip
        frame starts at ``grip_point`` with the commanded (or identity) orientation."""
        self.closed = True
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.position = np.asarray(grip_point, dtype=float).copy()
        self.rotation = self.command_rotation or Rotation.identity()
        self.offsets = self.rotation.inv().apply(positions - self.position)
        if self.command_position is None and len(self.waypoints) == 0:
            self.command_position = self.position.copy()
            self.holding_in_place = True

    def hold_more(self, nodes: np.ndarray, positions: np.ndarray) -> None:
        """Also hold particles ``nodes`` now at ``positions`` ``(k, 3)`` (m), e.g.
        made by a split inside the patch; their offsets are taken where they
        are, so nothing jumps (a midpoint of two held particles is exactly where
        the rigid grip puts it anyway)."""
        self.nodes = np.concatenate([self.nodes, np.asarray(nodes, dtype=np.int64)])
        offsets = self.rotation.inv().apply(np.asarray(positions, dtype=float).reshape(-1, 3)
                                            - self.position)
        self.offsets = np.concatenate([self.offsets, offsets.reshape(-1, 3)])

    def release(self) -> None:
        self.closed = False
        if self.holding_in_place:
            # Closing again later holds the cloth where it is then, instead of
            # carrying it back to where this grip happened to close.
            self.command_position = None
            self.holding_in_place = False
        self.nodes = np.zeros(0, dtype=np.int64)
        self.offsets = np.zeros((0, 3))

    def set_target(self, position, orientation=None) -> None:
        """Command a target pose: position (m) and optional quaternion [x, y, z, w].

        Raises:
            ValueError: non-finite or malformed values (the old target stays).
        """
        position, rotation = checked_pose(position, orientation, "grasp")
        self.waypoints = np.zeros((0, 4))            # a live command replaces the script
        self.command_position = position.copy()
        self.holding_in_place = False
        if rotation is not None:
            self.command_rotation = rotation

    def target_at(self, time: float) -> tuple[np.ndarray, Rotation]:
        """The commanded pose at ``time`` (scripted waypoints or the live command)."""
        if len(self.waypoints):
            t = self.waypoints[:, 0]
            position = np.array([np.interp(time, t, self.waypoints[:, d]) for d in (1, 2, 3)])
        elif self.command_position is not None:
            position = self.command_position
        else:
            position = self.position
        return position, self.command_rotation or self.rotation

    def reachable(self, target: np.ndarray, anchors) -> np.ndarray:
        """``target`` (m) moved into the reach of every anchor: ``anchors`` is a
        list of ``(position (3,) m, rest distance m)`` of the other held points;
        the result lies within ``(1 + MAX_REACH_STRAIN) x`` each rest distance
        of each (alternating projections onto the balls; exact for one anchor)."""
        point = np.asarray(target, dtype=float)
        balls = [(np.asarray(x, dtype=float), (1.0 + MAX_REACH_STRAIN) * d) for x, d in anchors]
        for _ in range(20):
            moved = False
            for centre, radius in balls:
                offset = point - centre
                distance = float(np.linalg.norm(offset))
                if distance > radius * (1 + 1e-12):
                    point = centre + offset * (radius / distance)
                    moved = True
            if not moved:
                break
        return point

    def advance(self, time: float, h: float, anchors=()) -> None:
        """Move the effective pose towards the target of ``time``, speed limited;
        a live target (not a script) is first brought within reach of ``anchors``
        (:meth:`reachable`)."""
        target, target_rotation = self.target_at(time)
        if anchors and not len(self.waypoints) and self.command_position is not None:
            reached = self.reachable(target, anchors)
            if not np.array_equal(reached, target):
                if not self.clamped:
                    log.info("grasp %r: target %.3f m beyond what the cloth reaches from the "
                             "other held points; held at the reach", self.name,
                             float(np.linalg.norm(reached - target)))
                self.clamped = True
                target = reached
            else:
                self.clamped = False
        step = target - self.position
        distance = float(np.linalg.norm(step))
        limit = self.max_speed * h
        if distance > limit:
            if not self.lagging:
                # INFO: catching up is what a target beyond one step's reach means
                # (README, docs/node.md: the README's grasp example's first pose
                # is 0.85 m off), not a fault; counted in jumps.
                self.jumps += 1
                log.info("grasp %r: target is %.3f m away (more than %.3f m/s x %.4g s); "
                         "catching up at the speed limit", self.name, distance,
                         self.max_speed, h)
            self.lagging = True
            step *= limit / distance
        else:
            self.lagging = False
        self.position = self.position + step
        angle = (target_rotation * self.rotation.inv()).magnitude()
        max_angle = self.max_angular_speed * h
        if angle > 1e-12:
            fraction = min(1.0, max_angle / angle)
            slerp = Slerp([0.0, 1.0], Rotation.concatenate([self.rotation, target_rotation]))
            self.rotation = slerp([fraction])[0]

    def held_targets(self) -> np.ndarray:
        """``(k, 3)`` positions the held particles must have (m)."""
        return self.position + self.rotation.apply(self.offsets)
