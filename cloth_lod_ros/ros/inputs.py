"""What the node does with an input before the simulator sees it (design §6).

Inputs are judged where they arrive (in the input threads) and queued; the
stepping thread takes the queue before each step and applies it.  Taking an
input never waits for a simulation step, and nothing an input carries can stop
the node: a bad value is a counted rejection with a reason.

* :func:`judge_pose` - accept or reject one grasp pose (frame, finite values,
  orientation, stamp, workspace), returning a unit quaternion when accepted;
* :class:`InputQueue` - thread-safe: the latest target per grasp and per
  obstacle (a newer pose replaces an older one not yet applied) and a bounded FIFO of commands
  (service calls, parameter changes), drained together in arrival order;
* :func:`health` - the diagnostic level and message of a published frame.

No rclpy here: the same logic is tested in-process, fast, with hypothesis.
"""

from __future__ import annotations

import itertools
import math
import threading
from dataclasses import dataclass

import numpy as np

__all__ = ["POSE_REJECTIONS", "PoseLimits", "judge_pose", "InputQueue", "health",
           "OK", "WARN", "ERROR"]

#: Why a pose can be rejected (each is a ``rejected_<reason>`` count in ``lod_stats``).
POSE_REJECTIONS = ("frame", "not_finite", "orientation", "bad_stamp", "stale", "future",
                   "workspace")
OK, WARN, ERROR = 0, 1, 2


@dataclass(frozen=True)
class PoseLimits:
    """What a grasp pose must satisfy.

    Attributes:
        frame_id: accepted header frame ("" is accepted too: "the node's frame").
        stale_timeout: s; a stamp more than this before (``stale``) or after
            (``future``) the node's clock is rejected; 0 = stamps are not judged.
        workspace_min, workspace_max: ``(3,)`` m, the box targets must lie in.
    """

    frame_id: str = "world"
    stale_timeout: float = 1.0
    workspace_min: tuple = (-10.0, -10.0, -10.0)
    workspace_max: tuple = (10.0, 10.0, 10.0)


def judge_pose(frame_id: str, position, orientation, stamp_sec: int, stamp_nanosec: int,
               now_s: float, limits: PoseLimits):
    """Judge one pose (of a grasp or an obstacle).

    Args:
        frame_id: the header's frame.
        position: ``(3,)`` m; orientation: quaternion ``(x, y, z, w)``, any norm.
        stamp_sec, stamp_nanosec: the header stamp; ``(0, 0)`` means "now".
        now_s: the node's clock (s, the clock its outputs are stamped with).
        limits: see :class:`PoseLimits`.

    Returns:
        ``(reason, None, None)`` with ``reason`` in :data:`POSE_REJECTIONS`, or
        ``(None, position (3,), unit quaternion (4,))``.
    """
    if frame_id not in ("", limits.frame_id):
        return "frame", None, None
    p = np.asarray(position, dtype=float)
    q = np.asarray(orientation, dtype=float)
    if p.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(p))
                                                  and np.all(np.isfinite(q))):
        return "not_finite", None, None
    # Normalise without overflow: (1e200, 1e200, 0, 0) has a finite scale but
    # its norm overflows; a zero quaternion has no direction.
    scale = float(np.max(np.abs(q)))
    if scale == 0.0:
        return "orientation", None, None
    q = q / scale
    q = q / np.linalg.norm(q)
    if stamp_sec < 0 or not 0 <= stamp_nanosec < 1_000_000_000:
        return "bad_stamp", None, None
    if limits.stale_timeout > 0 and (stamp_sec or stamp_nanosec):
        age = now_s - (stamp_sec + 1e-9 * stamp_nanosec)
        if age > limits.stale_timeout:
            return "stale", None, None
        if -age > limits.stale_timeout:
            return "future", None, None
    if np.any(p < limits.workspace_min) or np.any(p > limits.workspace_max):
        return "workspace", None, None
    return None, p, q


class InputQueue:
    """Inputs waiting for the next step (thread-safe, never blocks on a step).

    Targets are coalesced per grasp (only the newest pose of a grasp matters
    when several arrive during one step); commands are kept in order, at most
    ``max_commands`` of them: beyond that :meth:`put_command` refuses, so a
    burst of service calls is answered with a refusal instead of piling up.
    """

    def __init__(self, max_commands: int = 256):
        self.max_commands = int(max_commands)
        self._lock = threading.Lock()
        self._order = itertools.count()
        self._targets: dict[str, tuple[int, tuple]] = {}
        self._commands: list[tuple[int, tuple]] = []

    def put_target(self, grasp: str, position: np.ndarray, orientation: np.ndarray,
                   kind: str = "target") -> None:
        """Queue the newest pose of grasp ``grasp`` (``kind`` ``"target"``) or of
        an obstacle of that name (``"obstacle_target"``), replacing an older
        one of the same kind and name."""
        with self._lock:
            self._targets[(kind, grasp)] = (next(self._order),
                                            (kind, grasp, position, orientation))

    def put_command(self, *command) -> bool:
        """Queue ``command`` (a tuple whose first item is its kind); False when full."""
        with self._lock:
            if len(self._commands) >= self.max_commands:
                return False
            self._commands.append((next(self._order), command))
            return True

    def pending_commands(self) -> int:
        with self._lock:
            return len(self._commands)

    def take(self) -> list[tuple]:
        """Everything queued, in arrival order (a target where its latest pose came)."""
        with self._lock:
            items = self._commands + list(self._targets.values())
            self._commands, self._targets = [], {}
        return [item for _, item in sorted(items, key=lambda pair: pair[0])]


def health(*, error: str | None, stats, strain_warn: float, speed_warn: float,
           real_time_factor: float | None, waiting_for_clock: bool = False,
           recording_failed: bool = False, paused: bool = False) -> tuple[int, str]:
    """Level (:data:`OK`, :data:`WARN`, :data:`ERROR`) and message of the simulation.

    ERROR: the simulation stopped, or strain or speed beyond 4x their warning
    bounds (the motion is no longer physical).  WARN: strain (``| |w| - 1 |``)
    above ``strain_warn`` or speed above ``speed_warn`` m/s, an unconverged
    solve, slower than real time (``real_time_factor`` < 0.9; None = not
    measured), waiting for ``/clock``, a failed recording.
    """
    if error is not None:
        return ERROR, (f"simulation stopped: {error}; call cloth/reset (or set auto_reset "
                       "to reset by itself)")
    strain = float(stats.max_strain) if stats is not None else 0.0
    speed = float(stats.max_speed) if stats is not None else 0.0
    if not (math.isfinite(strain) and math.isfinite(speed)):
        return ERROR, "non-finite strain or speed"
    if strain > 4 * strain_warn or speed > 4 * speed_warn:
        return ERROR, (f"unphysical motion: strain {strain:.3g}, speed {speed:.3g} m/s "
                       f"(warning bounds {strain_warn:g}, {speed_warn:g} m/s); move the "
                       "targets back or call cloth/reset (or set auto_reset)")
    if waiting_for_clock:
        return WARN, "waiting for /clock (use_sim_time is true)"
    if strain > strain_warn or speed > speed_warn:
        return WARN, f"large motion: strain {strain:.3g}, speed {speed:.3g} m/s"
    if stats is not None and not stats.converged:
        return WARN, "linear solve did not converge"
    if real_time_factor is not None and real_time_factor < 0.9 and not paused:
        return WARN, f"slower than real time (factor {real_time_factor:.2f})"
    if recording_failed:
        return WARN, "recording failed; simulation running"
    return OK, "paused" if paused else "running"
