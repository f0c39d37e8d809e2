"""Self-collision: layers of the cloth kept apart (design §3, "Self-collision").

Three layers, each cheaper than the next and each run only when the one
before it did not suffice:

1. **Proximity constraints** (start of every step).  Vertex–triangle and
   edge–edge pairs that share no particle and are, or would get this step,
   closer than twice ``thickness`` (``d + h·min(v_rel·n, 0) < 2·thickness``,
   the speculative test of obstacle contact) become *contact pairs*: a point of
   side A (the vertex, or a point of an edge) against a point of side B (the
   nearest point of the triangle or of the other edge), with the unit normal
   ``n`` from B to A **at the start of the step** - the side each layer is on
   is taken from the last state known to be free of crossings, never from a
   predicted one.  Candidates come from a spatial hash that first asks which
   cells may hold two layers at all (:func:`~cloth_lod_ros.sim.contact.self_broad.layered_boxes`:
   a cloth without folds stops there) and are kept while the cloth stays
   inside their padded boxes (a Verlet list, :mod:`~cloth_lod_ros.sim.contact.self_broad`;
   compiled when the kernels are).  The particles of side A that
   carry a real share of the contact point (weight ≥ 0.25, or the largest)
   get the per-particle velocity constraint of obstacle contact
   (:class:`~cloth_lod_ros.sim.contact.contacts.ContactSet`): normal ``n``, gap −
   thickness as its distance, and as the *surface velocity* the pair's common
   velocity (the mean of the two sides': equal masses per area) - an
   inelastic contact.  Held particles and particles resting on an obstacle
   count as infinitely heavy (along the surface only if it has friction), so
   a layer falling onto cloth that lies on a table stops on it.  The other
   side's particles (``partners``) take the reaction
   (:mod:`~cloth_lod_ros.sim.contact.layer_reactions`): equal and opposite impulses.
   Side B is constrained too (normal ``−n``) only where A cannot give way
   (held, or on an obstacle) and for pairs found crossing: forcing a
   triangle's corners to the velocity of one point of it dragged them and
   added energy.  The implicit solve lands each constrained particle at
   ``thickness`` from the moving surface, releases the contacts that would
   pull and applies Coulomb friction (``friction``) by rounds as for
   obstacles, on the upper side of a contact only (with friction on both
   mutually constrained sides, both stuck to the pair's start velocity and
   dragged the cloth along).  A particle with several candidate constraints
   keeps a crossing pair's, then the tightest; against an obstacle's the
   obstacle wins unless both push the same way and the self-contact is
   tighter.
2. **Continuous check and re-solve** (after every solve).  Every vertex–
   triangle and edge–edge pair is tested for meeting while the particles
   move on straight lines from the start to the end of the step
   (:func:`~cloth_lod_ros.sim.contact.self_narrow.vf_crossing`); a pair that meets
   becomes a held contact pair (never released), the surface velocities are
   recomputed from the solved velocities, and the step is solved again (up
   to ``max_resolves`` times, shared with the obstacle re-solves).
3. **Refusal, then a stopped zone.**  A step that still has a crossing is
   refused and redone with half the step (the stepper's stretch-growth path).
   At the smallest step allowed, the particles of the crossing pairs and their
   neighbours are put back where the step started, at rest, and the check is
   repeated with the zone grown until no pair meets (:meth:`SelfCollision.stop_zone`).
   The start was free of crossings, so only held particles (a grasp dragging
   cloth through cloth) can defeat it, and that is reported.

A scene with ``self_collision.enabled: false`` never calls into this module.
Positions m, velocities m/s, masses kg.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from ..runtime import compiled as _compiled
from . import self_broad_kernels as _self_broad_kernels
from .contacts import ContactSet
from .layer_reactions import common_velocity
from .self_broad import BroadPhase
from .self_narrow import ee_crossing, point_triangle, segment_segment, vf_crossing

__all__ = ["SelfCollision", "SelfPairs", "SelfCounters", "merge_contacts"]

_MIN_SHARE = 0.25      # a particle carrying less of a contact point is not constrained


@dataclass
class SelfPairs:
    """Contact pairs: a point of side A against a point of side B.

    Attributes:
        a, b: ``(k, 3)`` particle indices of each side (a vertex is
            ``(p, p, p)``, an edge ``(i, j, i)``); wa, wb: ``(k, 3)`` their
            weights (barycentric, summing to 1; unused slots 0).
        normal: ``(k, 3)`` unit vector from B's point to A's at the start.
        gap: ``(k,)`` distance between the points at the start, m.
        hold: ``(k,)`` pairs found crossing (their constraints never let go).
    """

    a: np.ndarray
    wa: np.ndarray
    b: np.ndarray
    wb: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    hold: np.ndarray

    @classmethod
    def empty(cls) -> "SelfPairs":
        i, w = np.zeros((0, 3), np.int64), np.zeros((0, 3))
        return cls(i, w, i, w, w, np.zeros(0), np.zeros(0, bool))

    def __len__(self) -> int:
        return len(self.gap)

    def concat(self, other: "SelfPairs") -> "SelfPairs":
        return SelfPairs(*(np.concatenate([getattr(self, f), getattr(other, f)])
                           for f in ("a", "wa", "b", "wb", "normal", "gap", "hold")))


@dataclass
class SelfCounters:
    """How often each layer worked, summed over every attempted step.

    ``attempts``: steps attempted; ``with_pairs``: attempts that had proximity
    pairs; ``pairs``: proximity pairs found; ``resolves``: re-solves because
    a pair crossed; ``refused``: steps refused for a crossing left after the
    re-solves; ``stopped``: steps that needed the stopped zone (``stopped_particles``
    in all); ``unresolved``: steps whose crossings not even that removed
    (held particles); ``lifted``: particles made by splits moved out of another
    layer; ``broad``: broad phases run (the others reused a cached one);
    ``ms``: time spent in this module (detection, checks), ms.
    """

    attempts: int = 0
    with_pairs: int = 0
    pairs: int = 0
    resolves: int = 0
    refused: int = 0
    stopped: int = 0
    stopped_particles: int = 0
    unresolved: int = 0
    lifted: int = 0
    broad: int = 0
    ms: float = 0.0


def merge_contacts(obstacle: ContactSet | None, own: ContactSet) -> tuple[ContactSet, int]:
    """One constraint per particle from obstacle and self-contact constraints:
    the obstacle's, unless both push the same way (normals within 90°) and the
    self-contact is tighter (smaller distance) - never a held obstacle
    contact for a releasable self-contact (the released particle went on into
    the obstacle).  Returns the merged set and how many of its constraints are self-contacts."""
    if obstacle is None or not len(obstacle):
        return own, len(own)
    if not len(own):
        return obstacle, 0
    common, io, is_ = np.intersect1d(obstacle.indices, own.indices, return_indices=True)
    drop_obstacle = np.zeros(len(obstacle), bool)
    drop_own = np.zeros(len(own), bool)
    if len(common):
        same_way = np.einsum("kd,kd->k", obstacle.normals[io], own.normals[is_]) > 0.0
        tighter = own.distance[is_] < obstacle.distance[io]
        own_wins = same_way & tighter & (own.hold[is_] | ~obstacle.hold[io])
        drop_obstacle[io[own_wins]] = True
        drop_own[is_[~own_wins]] = True
    return (obstacle.subset(~drop_obstacle).union(own.subset(~drop_own)),
            int(len(own) - drop_own.sum()))


class SelfCollision:
    """Self-collision of one cloth (module docstring).

    Args:
        config: :class:`~cloth_lod_ros.sim.scene.config.SelfCollisionConfig`
            (``thickness`` m, ``friction``, ``max_resolves``).
    """

    def __init__(self, config):
        self.config = config
        self.counters = SelfCounters()
        self.last_constraints = 0       # self-contact constraints of the last solve
        self._triangles = None
        #: Candidate pairs and their Verlet cache (:mod:`~cloth_lod_ros.sim.contact.self_broad`).
        self.broad = BroadPhase(config.thickness, self.counters)

    @property
    def triangles(self) -> np.ndarray:
        """``(t, 3)`` the active triangles (compact vertex indices)."""
        return self.broad.triangles

    @property
    def edges(self) -> np.ndarray:
        """``(e, 2)`` the mesh's edges (sorted vertex pairs)."""
        return self.broad.edges

    @property
    def _cache(self):
        return self.broad.cache

    @property
    def eta(self) -> float:
        """Distance (m) at which two primitives meeting at a coplanarity time
        count as touching: a hundredth of the thickness."""
        return 0.01 * self.config.thickness

    def set_topology(self, triangles: np.ndarray, uv: np.ndarray) -> None:
        """Use the active triangles ``(t, 3)`` (compact vertex indices) and the
        particles' rest coordinates ``uv`` ``(n, 2)`` (m); the cached broad
        phase is dropped only when the array is a new one (a topology change)."""
        if triangles is self._triangles:
            return
        start = _time.perf_counter()
        self._triangles = triangles
        self.broad.set_topology(triangles, uv)
        self.counters.ms += 1e3 * (_time.perf_counter() - start)

    # -- pairs ----------------------------------------------------------------
    def _broad(self, x: np.ndarray, y: np.ndarray, need: float) -> dict:
        """Candidates for the boxes spanning ``x`` to ``y`` padded by ``need`` m
        (:meth:`~cloth_lod_ros.sim.contact.self_broad.BroadPhase.query`)."""
        return self.broad.query(x, y, need)

    @staticmethod
    def _vf_pairs(x, verts, tris):
        """Closest points of vertex–triangle pairs: ``(pairs-in-waiting, gap vector)``."""
        w = point_triangle(x[verts], x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]])
        q = np.einsum("kj,kjd->kd", w, x[tris])
        ones = np.zeros((len(verts), 3))
        ones[:, 0] = 1.0
        return (np.repeat(verts[:, None], 3, axis=1), ones, tris, w), x[verts] - q

    @staticmethod
    def _ee_pairs(x, e1, e2):
        s, t = segment_segment(x[e1[:, 0]], x[e1[:, 1]], x[e2[:, 0]], x[e2[:, 1]])
        wa = np.column_stack([1.0 - s, s, np.zeros_like(s)])
        wb = np.column_stack([1.0 - t, t, np.zeros_like(t)])
        a = np.column_stack([e1, e1[:, 0]])
        b = np.column_stack([e2, e2[:, 0]])
        gap = np.einsum("kj,kjd->kd", wa, x[a]) - np.einsum("kj,kjd->kd", wb, x[b])
        return (a, wa, b, wb), gap

    def _narrow(self, c: dict, x: np.ndarray):
        """Sides and gap vectors of ``c``'s candidates at ``x`` (cached for the
        same array: the continuous check of a step reuses its start's)."""
        if c["narrow"] is not None and c["narrow"][0] is x:
            return c["narrow"][1]
        vf = self._vf_pairs(x, c["verts"], c["tris"])
        ee = self._ee_pairs(x, c["e1"], c["e2"])
        c["narrow"] = (x, (vf, ee))
        return vf, ee

    @staticmethod
    def _none(c: dict) -> bool:
        return not len(c["verts"]) and not len(c["e1"])

    @staticmethod
    def _may_touch(c: dict, x: np.ndarray, u: np.ndarray, limit: float, scale: float) -> bool:
        """Whether a candidate of ``c`` may come within ``limit`` m at ``x``
        with ``u`` ``(n, 3)`` times ``scale`` the most its gap can close
        (:func:`~cloth_lod_ros.sim.contact.self_broad_kernels.may_touch`, conservative: a
        False skips a narrow phase that would keep nothing).  Always True on
        the numpy path, which runs every test."""
        if not _compiled.enabled():
            return True
        return _self_broad_kernels.may_touch(np.ascontiguousarray(x), np.ascontiguousarray(u),
                                             c["verts"], c["tris"], c["e1"], c["e2"], limit, scale)

    def proximity(self, x: np.ndarray, v: np.ndarray, h: float) -> SelfPairs:
        """Contact pairs at the start of a step: closer than ``2·thickness``, or
        getting so within ``h`` s at the start velocities.

        Args:
            x, v: ``(n, 3)`` positions (m) and velocities (m/s) at the start.
        """
        start = _time.perf_counter()
        band = 2.0 * self.config.thickness
        # Boxes swept over the predicted motion and padded by the thickness.
        xp = x + h * v
        c = self._broad(x, xp, 0.5 * band)
        counters = self.counters
        counters.attempts += 1
        if self._none(c) or not self._may_touch(c, x, v, band, h):
            counters.ms += 1e3 * (_time.perf_counter() - start)
            return SelfPairs.empty()
        parts = []
        for (a, wa, b, wb), gap in self._narrow(c, x):
            d = np.linalg.norm(gap, axis=1)
            ok = d > 1e-12 * max(1.0, band)
            n = gap / np.where(ok, d, 1.0)[:, None]
            rel = np.einsum("kj,kjd->kd", wa, v[a]) - np.einsum("kj,kjd->kd", wb, v[b])
            approach = h * np.minimum(np.einsum("kd,kd->k", rel, n), 0.0)
            keep = ok & (d + approach < band)
            parts.append(SelfPairs(a[keep], wa[keep], b[keep], wb[keep], n[keep], d[keep],
                                   np.zeros(int(keep.sum()), bool)))
        pairs = parts[0].concat(parts[1])
        counters.with_pairs += bool(len(pairs))
        counters.pairs += len(pairs)
        counters.ms += 1e3 * (_time.perf_counter() - start)
        return pairs

    def crossings(self, x0: np.ndarray, x1: np.ndarray) -> SelfPairs:
        """Pairs that meet while every particle moves straight from ``x0`` to
        ``x1`` (``(n, 3)``, m), as held contact pairs with the side and gap of
        ``x0``.

        The candidates come from the same (cached) broad phase, valid while
        every particle's box from ``x0`` to ``x1`` lies inside the cached
        boxes (then every pair whose swept boxes overlap is among them).  A
        pair is tested only if its gap at ``x0`` can close: by at most the
        largest relative displacement of the pair's corners (0 for a rigid
        motion)."""
        start = _time.perf_counter()
        eta = self.eta
        c = self._broad(x0, x1, 0.5 * eta)
        step = None if self._none(c) else x1 - x0
        if step is None or not self._may_touch(c, x0, step, eta, 1.0):
            self.counters.ms += 1e3 * (_time.perf_counter() - start)
            return SelfPairs.empty()
        move = np.linalg.norm(step, axis=1)
        parts = []
        for kind, ((a, wa, b, wb), gap) in zip(("vf", "ee"), self._narrow(c, x0)):
            d = np.linalg.norm(gap, axis=1)
            # The gap closes by at most the largest |Δa_i − Δb_j| over the
            # corners carrying the points; first the cheaper bound by the sum
            # of the largest moves of each side.
            maybe = np.flatnonzero(d <= move[a].max(axis=1) + move[b].max(axis=1) + eta)
            rel = step[a[maybe]][:, :, None, :] - step[b[maybe]][:, None, :, :]
            reach = np.sqrt(np.max(np.sum(rel * rel, axis=3), axis=(1, 2))) + eta
            maybe = maybe[d[maybe] <= reach]
            if kind == "vf":
                hit = vf_crossing(x0, x1, c["verts"][maybe], c["tris"][maybe], eta)
            else:
                hit = ee_crossing(x0, x1, c["e1"][maybe], c["e2"][maybe], eta)
            k = maybe[hit]
            n = _side_normals(x0, x1, a[k], wa[k], b[k], wb[k], gap[k], d[k])
            parts.append(SelfPairs(a[k], wa[k], b[k], wb[k], n, d[k], np.ones(len(k), bool)))
        self.counters.ms += 1e3 * (_time.perf_counter() - start)
        return parts[0].concat(parts[1])

    # -- constraints ------------------------------------------------------------
    def constraints(self, pairs: SelfPairs, velocities: np.ndarray, masses: np.ndarray,
                    fixed: np.ndarray, exclude: np.ndarray,
                    slides: np.ndarray | None = None,
                    up: np.ndarray | None = None) -> ContactSet:
        """Per-particle constraints (one per particle, the tightest) of ``pairs``.

        Args:
            velocities: ``(n, 3)`` m/s, the latest estimate of the step's velocities.
            masses: ``(n,)`` kg.  fixed: ``(n,)`` bool, particles that count as
                infinitely heavy (held, on an obstacle).
            exclude: particle indices never constrained (held).
            slides: ``(n,)`` bool or None, fixed particles that are so only
                along the normal (on a frictionless obstacle): along the
                surface they move with the pair as the other layer pushes them.
            up: ``(3,)`` unit vector or None: friction acts only on the
                constraints whose normal points along it (the particle lies
                above the other layer; None: on all).
        """
        start = _time.perf_counter()
        if not len(pairs):
            return _empty_contacts()
        va = np.einsum("kj,kjd->kd", pairs.wa, velocities[pairs.a])
        vb = np.einsum("kj,kjd->kd", pairs.wb, velocities[pairs.b])
        u = common_velocity(pairs.a, pairs.wa, va, pairs.b, pairs.wb, vb, fixed)
        if slides is not None and np.any(slides[pairs.a] | slides[pairs.b]):
            # Along the surface only the really immovable count as fixed.
            along = common_velocity(pairs.a, pairs.wa, va, pairs.b, pairs.wb, vb,
                                    fixed & ~slides)
            un = np.einsum("kd,kd->k", u, pairs.normal)
            along_n = np.einsum("kd,kd->k", along, pairs.normal)
            u = along + (un - along_n)[:, None] * pairs.normal
        rows, normals, dist, vel, hold, other, other_w = ([] for _ in range(7))
        distance = pairs.gap - self.config.thickness
        held = np.zeros(len(masses), bool)
        held[exclude] = True
        # Side A (the vertex; the first edge) is constrained against side B's
        # surface.  Side B as well where A cannot give way (held, or resting
        # on an obstacle, whose constraint wins over this one) and for pairs
        # found crossing: otherwise a vertex near the other layer has its
        # own pair there, and constraining a whole triangle to a velocity
        # found at one point of it would drag corners that carry little of
        # the contact (and add energy).
        a_stuck = np.all(fixed[pairs.a] | (pairs.wa <= 0), axis=1)
        both = a_stuck | pairs.hold
        # Each constraint keeps the other side's particles (its partners): the
        # solve applies the reaction to them (equal and opposite impulses).
        for side, weights, far, far_w, sign, use in (
                (pairs.a, pairs.wa, pairs.b, pairs.wb, 1.0, np.ones(len(both), bool)),
                (pairs.b, pairs.wb, pairs.a, pairs.wa, -1.0, both)):
            carries = (weights >= _MIN_SHARE) | (weights == weights.max(axis=1, keepdims=True))
            carries &= (weights > 0) & use[:, None]
            k, j = np.nonzero(carries)
            rows.append(side[k, j])
            normals.append(sign * pairs.normal[k])
            dist.append(distance[k])
            vel.append(u[k])
            hold.append(pairs.hold[k])
            other.append(far[k])
            other_w.append(far_w[k])
        ok = ~held[np.concatenate(rows)]
        rows, normals, dist, vel, hold, other, other_w = (
            np.concatenate(v)[ok] for v in (rows, normals, dist, vel, hold, other, other_w))
        # One per particle: a crossing pair's first, then the tightest.
        order = np.lexsort((dist, ~hold, rows))
        _, first = np.unique(rows[order], return_index=True)
        pick = order[first]
        # Friction on one side of a contact only.  Every vertex near the other
        # layer has its own constraint, so both layers of a contact are
        # constrained against each other; with friction on both, both would
        # stick to the velocity the pair had at the start of the step, the
        # pair would not answer the rest of the cloth pulling on it (as if
        # infinitely heavy) and drag it along: energy from nowhere.  The upper
        # side carries the friction, the lower one takes its reaction
        # (:mod:`~cloth_lod_ros.sim.contact.layer_reactions`).
        friction = np.full(len(pick), self.config.friction)
        if up is not None:
            friction[normals[pick] @ up <= 0.0] = 0.0
        out = ContactSet(rows[pick], normals[pick], dist[pick], friction, hold[pick],
                         vel[pick], other[pick], other_w[pick])
        self.counters.ms += 1e3 * (_time.perf_counter() - start)
        return out

    # -- last resort --------------------------------------------------------------
    def stop_zone(self, x0: np.ndarray, x1: np.ndarray, v1: np.ndarray,
                  held: np.ndarray):
        """Put particles of crossing pairs (and their neighbours) back at ``x0``
        at rest until no pair meets between ``x0`` and the result.

        Returns:
            ``(x, v, stopped, clean)``: new end positions and velocities
            ``(n, 3)``, how many particles were stopped and whether no crossing
            is left.
        """
        x, v = x1.copy(), v1.copy()
        free = np.ones(len(x), bool)
        free[held] = False
        stopped = np.zeros(len(x), bool)
        clean = False
        for _ in range(64):
            cross = self.crossings(x0, x)
            if not len(cross):
                clean = True
                break
            involved = np.zeros(len(x), bool)
            involved[np.concatenate([cross.a.ravel(), cross.b.ravel()])] = True
            # Grow by one ring so the zone does not creep a particle at a time.
            ring = np.any(involved[self.triangles], axis=1)
            involved[self.triangles[ring].ravel()] = True
            new = involved & free & ~stopped
            if not new.any():
                new = free & ~stopped           # all that is left: stop everything free
                if not new.any():
                    break
            stopped |= new
            x[stopped] = x0[stopped]
            v[stopped] = 0.0
        c = self.counters
        c.stopped += 1
        c.stopped_particles += int(stopped.sum())
        c.unresolved += not clean
        return x, v, int(stopped.sum()), clean

    # -- level of detail ----------------------------------------------------------
    def apart(self, n: int) -> bool:
        """Whether the last broad phase (the last step's, over its whole motion,
        on the current ``n`` particles) found no cell that may hold two layers:
        then no layer was within its padding (at least twice the thickness) of
        another, so nothing is near, and a particle a split makes on an edge
        (inside the boxes of its triangles) cannot start inside another layer.
        False when there is no such search (a new topology)."""
        last = self._cache
        return last is not None and not last["layered"] and len(last["lo"]) == n

    def near(self, x: np.ndarray, distance: float) -> np.ndarray:
        """``(n,)`` bool: particles within ``distance`` m of a triangle they are
        not a corner of (another layer), or corners of such a triangle.

        When the last broad phase (the last step's, over its whole motion)
        found no cell that may hold two layers, nothing is near and no new
        search is made: the cloth was farther than its padding from any other
        layer a step ago."""
        start = _time.perf_counter()
        out = np.zeros(len(x), bool)
        last = self._cache
        if last is not None and not last["layered"] and len(last["lo"]) == len(x):
            self.counters.ms += 1e3 * (_time.perf_counter() - start)
            return out
        c = self._broad(x, x, 0.5 * distance)
        if len(c["verts"]):
            (_, _, _, _), gap = self._vf_pairs(x, c["verts"], c["tris"])
            close = np.linalg.norm(gap, axis=1) < distance
            out[c["verts"][close]] = True
            out[c["tris"][close].ravel()] = True
        self.counters.ms += 1e3 * (_time.perf_counter() - start)
        return out

    def separate(self, x: np.ndarray, moved: np.ndarray, v: np.ndarray | None = None,
                 h: float = 0.0) -> np.ndarray:
        """Move particles ``moved`` (indices, e.g. made by a split) that lie within
        ``thickness`` of another layer out to ``thickness`` along the side they
        are on; a move that would make a pair meet is not made.  Returns the
        new positions ``(n, 3)`` (a copy).

        ``v`` ``(n, 3)`` (m/s) and ``h`` (s): the velocities and the longest
        step about to be taken from ``x``.  The broad phase (a new topology
        has none) is then built over that motion, so the step's own detection
        reuses it instead of building another: its boxes, from positions
        moved here by at most ``thickness``, lie inside."""
        start = _time.perf_counter()
        out = x.copy()
        if not len(moved):
            return out
        thickness = self.config.thickness
        ahead = x if v is None else x + h * v
        c = self._broad(x, ahead, 0.5 * thickness)
        mask = np.zeros(len(x), bool)
        mask[moved] = True
        keep = mask[c["verts"]]
        verts, tris = c["verts"][keep], c["tris"][keep]
        if not len(verts):                  # no other layer near any of them
            self.counters.ms += 1e3 * (_time.perf_counter() - start)
            return out
        (_, _, _, _), gap = self._vf_pairs(x, verts, tris)
        d = np.linalg.norm(gap, axis=1)
        inside = (d < thickness) & (d > 1e-12)
        if inside.any():
            # The deepest pair of each particle decides its push.
            verts, gap, d = verts[inside], gap[inside], d[inside]
            order = np.lexsort((d, verts))
            _, first = np.unique(verts[order], return_index=True)
            pick = order[first]
            p = verts[pick]
            out[p] += ((thickness - d[pick]) / d[pick])[:, None] * gap[pick]
            self.counters.ms += 1e3 * (_time.perf_counter() - start)
            cross = self.crossings(x, out)
            if len(cross):
                undo = np.intersect1d(p, np.concatenate([cross.a.ravel(), cross.b.ravel()]))
                out[undo] = x[undo]
            self.counters.lifted += int(len(p))
            return out
        self.counters.ms += 1e3 * (_time.perf_counter() - start)
        return out


def _side_normals(x0, x1, a, wa, b, wb, gap, d):
    """Unit normals (B to A) of crossing pairs from the start geometry; a pair
    that touched at the start (no direction) takes the opposite of its
    relative motion."""
    n = gap / np.where(d > 1e-12, d, 1.0)[:, None]
    flat = d <= 1e-12
    if flat.any():
        rel = (np.einsum("kj,kjd->kd", wa[flat], x1[a[flat]] - x0[a[flat]])
               - np.einsum("kj,kjd->kd", wb[flat], x1[b[flat]] - x0[b[flat]]))
        norm = np.linalg.norm(rel, axis=1)
        n[flat] = -rel / np.where(norm > 0, norm, 1.0)[:, None]
    return n


def _empty_contacts() -> ContactSet:
    return ContactSet(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
                      np.zeros(0, bool), np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                      np.zeros((0, 3)))
