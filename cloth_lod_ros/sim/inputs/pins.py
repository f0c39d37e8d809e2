"""Pins: particles held at a scripted target (BW §5.3 constraints; design §2-§3).

A pin is a material point or a *patch*: with ``radius`` 0 it holds the one
particle nearest its (u, v); with ``radius`` > 0 it holds every active particle
within that (u, v) distance, each at its offset from the patch's centre
particle, so the whole patch follows the pin's target as one rigid translation.
A point pin puts a point load on a membrane, whose strain and sag grow without
bound as the mesh is refined (design §2); a patch spreads the load over a fixed
material area, so the drape converges with refinement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Pin"]


@dataclass
class Pin:
    """A particle, or a rigid patch of particles, held at a target.

    Attributes:
        name: label.
        uv: requested material point (m); ``vertex`` is the (compact) index of
            the particle nearest it (the patch's centre particle), ``node`` its
            permanent id (pool id with LOD on; equal to ``vertex`` otherwise),
            and ``snap_distance`` (m) how far that particle's rest point is.
        anchor: ``(3,)`` target of the centre particle when there are no
            waypoints (m).
        waypoints: ``(w, 4)`` rows ``[t, x, y, z]``; linear in between, held at
            the ends.
        release_time: time (s) after which the pin no longer holds, or None.
        radius: patch radius in (u, v), m (0: the centre particle only).
        nodes: ``(k,)`` permanent ids of every held particle (the centre
            included); ``vertices``: their compact indices, kept current by
            :class:`~cloth_lod_ros.sim.cloth.ClothSim` when the topology changes.
        offsets: ``(k, 3)`` each held particle's offset from the centre
            particle (m), 0 for the centre itself.
    """

    name: str
    uv: np.ndarray
    vertex: int
    snap_distance: float
    node: int
    anchor: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    release_time: float | None = None
    radius: float = 0.0
    nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self):
        if len(self.nodes) == 0:                 # a point pin: its one particle
            self.nodes = np.array([self.node], dtype=np.int64)
            self.vertices = np.array([self.vertex], dtype=np.int64)
            self.offsets = np.zeros((1, 3))

    def active(self, time: float) -> bool:
        return self.release_time is None or time < self.release_time

    def target(self, time: float) -> np.ndarray:
        """Target position (m) of the centre particle at simulation time ``time`` (s)."""
        if len(self.waypoints) == 0:
            return self.anchor
        t = self.waypoints[:, 0]
        return np.array([np.interp(time, t, self.waypoints[:, d]) for d in (1, 2, 3)])

    def held_targets(self, time: float) -> np.ndarray:
        """``(k, 3)`` targets (m) of the held particles ``vertices`` at ``time`` (s):
        the centre's target plus each offset (the centre's is exactly its target)."""
        return self.target(time) + self.offsets

    def hold_more(self, nodes: np.ndarray, positions: np.ndarray,
                  centre: np.ndarray) -> None:
        """Also hold particles ``nodes`` now at ``positions`` ``(m, 3)`` (m), e.g.
        made by a split inside the patch, while the centre particle is at
        ``centre`` ``(3,)`` (m).  Their offsets are taken where they are, so
        nothing jumps; ``vertices`` is refreshed by the caller."""
        self.nodes = np.concatenate([self.nodes, np.asarray(nodes, dtype=np.int64)])
        offsets = np.asarray(positions, dtype=float).reshape(-1, 3) - centre
        self.offsets = np.concatenate([self.offsets, offsets])
