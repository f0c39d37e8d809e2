"""Pins: particles held at a scripted target (BW §5.3 constraints; design §3)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Pin"]


@dataclass
class Pin:
    """A particle held at a target.

    Attributes:
        name: label.
        uv: requested material point (m); ``vertex`` is the (compact) index of
            the particle holding it, ``node`` its permanent id (pool id with LOD
            on; equal to ``vertex`` otherwise), and ``snap_distance`` (m) how far
            that particle's rest point is.
        anchor: ``(3,)`` target used when there are no waypoints (m).
        waypoints: ``(w, 4)`` rows ``[t, x, y, z]``; linear in between, held at
            the ends.
        release_time: time (s) after which the pin no longer holds, or None.
    """

    name: str
    uv: np.ndarray
    vertex: int
    snap_distance: float
    node: int
    anchor: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    release_time: float | None = None

    def active(self, time: float) -> bool:
        return self.release_time is None or time < self.release_time

    def target(self, time: float) -> np.ndarray:
        """Target position (m) at simulation time ``time`` (s)."""
        if len(self.waypoints) == 0:
            return self.anchor
        t = self.waypoints[:, 0]
        return np.array([np.interp(time, t, self.waypoints[:, d]) for d in (1, 2, 3)])

