"""Inputs that hold the cloth: pins (material patches on scripted targets)
and grasps (grips driven at run time), as methods of
:class:`~cloth_lod_ros.sim.cloth.ClothSim` (design §2-§3).

:class:`HeldInputs` keeps this part of the simulator's facade in one place:
which particles a pin or grasp holds (a patch of material within a radius in
(u, v), kept resolved as the LOD changes the mesh), where they must be at the
end of a step, and the scripting calls that move, open and release them.  It
relies on the simulator's ``mesh``, ``vertex_ids``, ``state``, ``hierarchy``,
``scene``, ``pins`` and ``grasps``.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from . import holding_kernels as _holding_kernels
from .grasps import Grasp
from ..mesh.mesh48 import uniform_vertices_within
from ..mesh.sampling import PointLocator
from .pins import Pin

__all__ = ["HeldInputs", "patch_refresh"]

log = logging.getLogger("cloth_lod_ros.sim.cloth")


class HeldInputs:
    """Pins and grasps of a :class:`~cloth_lod_ros.sim.cloth.ClothSim` (mixin)."""

    def _within(self, uv: np.ndarray, radius: float) -> np.ndarray:
        """Permanent ids (sorted) of the active particles within ``radius`` (m) of
        material point ``uv`` ``(2,)`` (m) in (u, v): a holding patch."""
        return self.vertex_ids[self._within_mask(uv, radius)]

    def _within_mask(self, uv: np.ndarray, radius: float) -> np.ndarray:
        """``(n,)`` bool over the compact particles: :meth:`_within` as a mask."""
        # |d| as np.linalg.norm(d, axis=1) computes it (sqrt of d_u² + d_v²),
        # without its reduction along the length-2 axis.
        d = self.mesh.uv - uv
        return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) <= radius + 1e-12

    def _refresh_held(self) -> None:
        """After a topology change: renumber what pins and grasps hold, and let a
        holding patch (pin or grasp) take the material inside it.

        Particles that splits made inside a patch are held too (else a patch on
        a coarse mesh would hold only its first few particles and let the
        refined cloth between them flap).  The policy never merges a held
        particle; a scripted merge (``apply_mesh_operations``) may, and the
        patch lets it go.  Each patch by :func:`patch_refresh` (one compiled
        pass when the kernels are on).
        """
        x, ids, uv = self.state.positions, self.vertex_ids, self.mesh.uv
        for pin in getattr(self, "pins", ()):
            if pin.radius > 0 and pin.active(self.state.time):
                keep, new, vertices, pin.vertex = _patch_refresh(ids, uv, pin.uv, pin.radius,
                                                                 pin.nodes, pin.node)
                if keep is not None:
                    pin.nodes, pin.offsets = pin.nodes[keep], pin.offsets[keep]
                if len(new):
                    pin.hold_more(ids[new], x[new], x[pin.vertex])
                pin.vertices = vertices
            else:
                pin.vertex = int(np.searchsorted(ids, pin.node))
                pin.vertices = np.searchsorted(ids, pin.nodes)
        for g in getattr(self, "grasps", ()):
            if len(g.nodes):
                # A grasp keeps what it holds wherever the material went, except
                # particles a scripted merge (or an undone split) removed.
                _, present = _compact_index(ids, g.nodes)
                if not present.all():
                    g.nodes, g.offsets = g.nodes[present], g.offsets[present]
            if g.closed and g.width > 0:
                _, new, _, _ = _patch_refresh(ids, uv, g.uv, 0.5 * g.width, g.nodes, None)
                if len(new):
                    g.hold_more(ids[new], x[new])

    def _resolve_pin_patches(self) -> None:
        """LOD on, at set-up: refine over every pin patch until it has each particle
        the uniform maximum-level mesh has there, so the patch holds the same
        material, in its rest shape, as on that mesh (a patch first held by a
        coarse mesh would take the particles later splits make wherever the
        motion has put them).  Held particles are never merged, so it stays
        resolved.  Rounds of splits, each of the triangles containing a missing
        lattice point; design §2."""
        self._resolve_patches([(p.uv, p.radius) for p in self.scene.pins if p.radius > 0])

    def _resolve_patches(self, patches) -> bool:
        """Refine the hierarchy until every ``(uv, radius)`` patch (m) has each
        particle of the uniform maximum-level mesh there (see
        :meth:`_resolve_pin_patches`); whether anything was split."""
        h, cloth = self.hierarchy, self.scene.cloth
        block = cloth.width / cloth.base_blocks[0]
        wanted = [uniform_vertices_within(cloth.width, cloth.height, block, cloth.level,
                                          uv, radius) for uv, radius in patches]
        points = np.concatenate([np.zeros((0, 2))] + wanted)
        split = False
        state = getattr(self, "state", None)        # none yet at set-up
        time = state.time if state is not None else 0.0
        tolerance = 1e-9 * max(cloth.width, cloth.height)
        for _ in range(2 * (cloth.level + 2)):
            mesh, _, triangle_ids = h.active_mesh()
            missing = points[cKDTree(mesh.uv).query(points)[0] > tolerance] if len(points) \
                else points
            if not len(missing):
                break
            locator = PointLocator(mesh.uv, mesh.triangles, mesh.width, mesh.height)
            for t in np.unique(triangle_ids[locator.locate(missing)[0]]):
                # one split meanwhile as a neighbour is skipped
                split |= bool(h.refine(int(t), time))
        return split


    def _make_pin(self, cfg) -> Pin:
        uv = np.asarray(cfg.uv, dtype=float)
        dist = np.linalg.norm(self.mesh.uv - uv, axis=1)
        vertex = int(dist.argmin())
        if dist[vertex] > 1e-9 * max(self.mesh.width, self.mesh.height):
            log.warning("pin %r at uv=%s snapped to the nearest particle uv=%s (%.4g m away)",
                        cfg.name, uv.tolist(), self.mesh.uv[vertex].tolist(), dist[vertex])
        node = int(self.vertex_ids[vertex])
        nodes = np.union1d([node], self._within(uv, cfg.radius)) if cfg.radius > 0 \
            else np.array([node], dtype=np.int64)
        vertices = np.searchsorted(self.vertex_ids, nodes)
        x = self.state.positions
        return Pin(name=cfg.name, uv=uv, vertex=vertex, snap_distance=float(dist[vertex]),
                   node=node, anchor=x[vertex].copy(),
                   waypoints=np.asarray(cfg.waypoints, dtype=float).reshape(-1, 4),
                   release_time=cfg.release_time, radius=cfg.radius, nodes=nodes,
                   vertices=vertices, offsets=x[vertices] - x[vertex])

    def pin(self, name: str) -> Pin:
        for p in self.pins:
            if p.name == name:
                return p
        raise KeyError(f"no pin named {name!r}; pins: {[p.name for p in self.pins]}")

    def set_pin_target(self, name: str, position) -> None:
        """Hold pin ``name`` at ``position`` (m) from the next step on.

        The centre particle moves there in one step with the prescribed velocity
        ``(target − x)/h`` (speed limiting belongs to the grasp layer); a patch
        follows as a rigid translation.
        """
        position = np.asarray(position, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ValueError(f"pin target must be 3 finite numbers, got {position!r}")
        pin = self.pin(name)
        pin.anchor = position.copy()
        pin.waypoints = np.zeros((0, 4))

    def release_pin(self, name: str) -> None:
        """Let pin ``name`` go from now on."""
        self.pin(name).release_time = self.state.time

    def _held(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Compact indices and end-of-step targets of every held particle."""
        pins = [p for p in self.pins if p.active(time)]
        indices = [np.zeros(0, dtype=np.int64)] + [p.vertices for p in pins]
        targets = [np.zeros((0, 3))] + [p.held_targets(time) for p in pins]
        for g in self.grasps:
            if g.closed:
                indices.append(np.searchsorted(self.vertex_ids, g.nodes))
                targets.append(g.held_targets())
        return np.concatenate(indices), np.concatenate(targets)

    def _held_nodes(self) -> np.ndarray:
        """Pool ids of the particles pins and grasps hold now, ``(k,)`` int64
        (patch after patch; one concatenation, not a Python int per node)."""
        time = self.state.time
        parts = [np.zeros(0, dtype=np.int64)] + [p.nodes for p in self.pins if p.active(time)]
        parts += [g.nodes for g in self.grasps if g.closed]
        return np.concatenate(parts).astype(np.int64, copy=False)

    # -- grasps -------------------------------------------------------------
    def grasp(self, name: str) -> Grasp:
        for g in self.grasps:
            if g.name == name:
                return g
        raise KeyError(f"no grasp named {name!r}; grasps: {[g.name for g in self.grasps]}")

    def close_grasp(self, name: str) -> None:
        """Close grasp ``name`` on the cloth at its material point.

        With LOD on, the mesh is refined until a particle lies within the
        grasp's ``tolerance`` of its (u, v) (or the maximum level is reached,
        then the nearest particle is used and a warning logged).  With a
        ``width``, every particle within ``width/2`` in (u, v) is held.
        """
        g = self.grasp(name)
        if g.closed:
            return
        if (self.hierarchy is not None and g.width > 0
                and getattr(self.scene.lod, "criterion", "curvature") == "detail"):
            # The detail criterion's grasps: the patch holds what the uniform
            # maximum-level mesh holds (a coarse patch would hold fewer
            # particles, and take the ones later splits make wherever the
            # motion has put them: another boundary condition).
            self._sync_hierarchy()
            if self._resolve_patches([(g.uv, 0.5 * g.width)]):
                if self.obstacles:
                    self._lift_new_particles()
                self._adopt_hierarchy()
        node, _ = self._particle_at(g.uv, g.tolerance, name)
        nodes = np.array([node], dtype=np.int64)
        if g.width > 0:
            nodes = np.union1d(nodes, self._within(g.uv, 0.5 * g.width))
        compact = np.searchsorted(self.vertex_ids, nodes)
        grip = self.positions[np.searchsorted(self.vertex_ids, node)]
        g.attach(nodes, self.positions[compact].copy(), grip)

    def open_grasp(self, name: str) -> None:
        """Release grasp ``name`` (the cloth falls free of it)."""
        self.grasp(name).release()

    def set_grasp_target(self, name: str, position, orientation=None) -> None:
        """Command grasp ``name`` to a pose: position (m), quaternion [x, y, z, w].

        The held particles follow at the grasp's speed limits.

        Raises:
            KeyError: unknown grasp; ValueError: non-finite or malformed pose.
        """
        self.grasp(name).set_target(position, orientation)

    def _particle_at(self, uv, tolerance: float, label: str) -> tuple[int, float]:
        """Permanent id of a particle at material point ``uv`` (refining if LOD is on)."""
        uv = np.asarray(uv, dtype=float)
        for _ in range(4 * (self.max_level + 2)):
            dist = np.linalg.norm(self.rest_uv - uv, axis=1)
            nearest = int(dist.argmin())
            if dist[nearest] <= tolerance or self.hierarchy is None:
                break
            if self._locator is None:
                self._locator = PointLocator(self.mesh.uv, self.mesh.triangles,
                                             self.mesh.width, self.mesh.height)
            tri, _ = self._locator.locate(uv[None, :])
            pool_tri = int(self.triangle_ids[tri[0]])
            if not self.refine(pool_tri):
                break                              # at the maximum level
        if dist[nearest] > tolerance:
            log.warning("%s: no particle within %.3g m of uv=%s; using the nearest, "
                        "%.3g m away", label, tolerance, uv.tolist(), dist[nearest])
        return int(self.vertex_ids[nearest]), float(dist[nearest])

    def _run_grasp_script(self, time: float) -> None:
        for g in self.grasps:
            if g.close_time is None:
                continue
            want = g.close_time <= time and (g.open_time is None or time < g.open_time)
            if want != self._scripted_closed[g.name]:
                self._scripted_closed[g.name] = want
                (self.close_grasp if want else self.open_grasp)(g.name)


def patch_refresh(vertex_ids: np.ndarray, uv: np.ndarray, centre, radius: float,
                  nodes: np.ndarray, node: int | None):
    """What a holding patch keeps and takes after a topology change (the
    reference of :func:`cloth_lod_ros.sim.inputs.holding_kernels.patch_refresh`).

    Args:
        vertex_ids: ``(n,)`` increasing pool ids of the compact particles.
        uv: ``(n, 2)`` their rest coordinates, m.
        centre: ``(2,)`` the patch's material point, m; radius: m.
        nodes: ``(k,)`` pool ids it holds.
        node: a pin's centre particle (pool id; kept whatever happens), or
            None for a grasp (every node is kept).

    Returns:
        ``(keep, new, vertices, vertex)``: ``(k,)`` bool, which nodes stay
        held (active and in reach, or the centre), None when all do or for a
        grasp; ``(m,)`` int64, the compact particles in reach not held yet,
        increasing; for a pin the compact indices (``np.searchsorted``) of
        the nodes it holds then (the kept ones, then the new ones) and of
        its centre particle (None and -1 for a grasp).  Masks over the
        compact particles instead of ``np.isin``/``np.setdiff1d`` (two sorts
        per patch at every topology change): the same sets, in the same order.
    """
    # |d| as np.linalg.norm(d, axis=1) computes it (HeldInputs._within_mask).
    d = uv - centre
    near = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) <= radius + 1e-12
    at, present = _compact_index(vertex_ids, nodes)
    if node is None:
        near[at[present]] = False          # held already
        return None, np.flatnonzero(near), None, -1
    keep = (present & near[at]) | (nodes == node)
    near[at[keep & present]] = False
    new = np.flatnonzero(near)
    kept = nodes[keep]
    vertices = np.searchsorted(vertex_ids, np.concatenate([kept, vertex_ids[new]]))
    return (None if keep.all() else keep), new, vertices, int(np.searchsorted(vertex_ids, node))


def _patch_refresh(vertex_ids, uv, centre, radius, nodes, node):
    """:func:`patch_refresh`, compiled when the kernels are on."""
    compiled = _holding_kernels.patch_refresh(vertex_ids, uv, centre, radius, nodes, node)
    return compiled if compiled is not None else patch_refresh(vertex_ids, uv, centre,
                                                               radius, nodes, node)


def _compact_index(vertex_ids: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compact indices ``(k,)`` of permanent ids ``nodes`` ``(k,)`` and whether each is
    active (``vertex_ids`` increasing; an inactive node's index is meaningless)."""
    if len(vertex_ids) == 0:
        return np.zeros(len(nodes), dtype=np.int64), np.zeros(len(nodes), dtype=bool)
    at = np.minimum(np.searchsorted(vertex_ids, nodes), len(vertex_ids) - 1)
    return at, vertex_ids[at] == nodes
