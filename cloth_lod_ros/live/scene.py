"""The live view's messages, built from a running simulator (Foxglove schemas).

Foxglove's 3D panel draws ``foxglove.SceneUpdate`` messages: entities made of
primitives (https://docs.foxglove.dev/docs/visualization/message-schemas/scene-update).
The cloth is one entity with a ``TriangleListPrimitive`` per bisection level,
each in one colour of the level colour map of ``cloth/markers``
(:func:`~cloth_lod_ros.messages.markers.level_colours`, viridis over
0..max_level); the panel shades the faces itself (flat shading, lit), so the
colours carry the level only.  Each primitive holds the vertices its triangles
use and indices into them (``fixed32``), about a third of the bytes of one point
per corner.  Obstacles are converted from the ``cloth/markers`` obstacle markers
(:func:`~cloth_lod_ros.messages.markers.obstacle_markers`, built from the
obstacles' *current* poses), so both views draw the same shapes.

This module needs the ``foxglove`` package (the ``viewer`` extra); import it
only after :func:`cloth_lod_ros.live.server.require_foxglove`.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove.messages import (Color, CubePrimitive, CylinderPrimitive, FrameTransform,
                               FrameTransforms, KeyValuePair, LinePrimitive,
                               LinePrimitiveLineType, Pose, Quaternion, SceneEntity,
                               SceneUpdate, SpherePrimitive, Timestamp, TriangleListPrimitive,
                               Vector3)

from ..messages.markers import CUBE, CYLINDER, SPHERE, level_colours, obstacle_markers
from ..sim.contact.obstacles import quaternion_from_z
from .protobuf import length_delimited, packed_fixed32, repeated_point3

__all__ = ["cloth_entity", "wireframe_entity", "obstacle_entities", "grasp_entities",
           "scene_update", "frame_transforms", "lod_stats", "LOD_STATS_SCHEMA",
           "GRASP_DIAMETER", "WIREFRAME_SHADE"]

# Field numbers in the Foxglove protobuf schemas (foxglove/SceneUpdate.proto and
# the primitives it includes; the test decodes our bytes with the schema the
# server advertises, so a wrong number fails there).
_SCENE_UPDATE_ENTITIES = 2
_ENTITY_LINES, _ENTITY_TRIANGLES = 11, 12
_TRIANGLES_POINTS, _TRIANGLES_INDICES = 2, 5
_LINES_POINTS, _LINES_INDICES = 5, 8

GRASP_DIAMETER = 0.03           # m, as the grasp spheres of cloth/markers
GRASP_COLOUR = (0.85, 0.1, 0.2, 1.0)
TARGET_COLOUR = (0.85, 0.1, 0.2, 0.35)      # where a grasp is heading (translucent)
WIREFRAME_SHADE = 0.6           # edges: the level colour darkened, as in cloth/markers
WIREFRAME_WIDTH = 1.0           # px (scale-invariant lines)


def _timestamp(stamp_ns: int) -> Timestamp:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


def _pose(position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0)) -> Pose:
    p = [float(c) for c in position]
    q = [float(c) for c in orientation]
    return Pose(position=Vector3(x=p[0], y=p[1], z=p[2]),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def _color(rgba) -> Color:
    r, g, b, a = (float(c) for c in rgba)
    return Color(r=r, g=g, b=b, a=a)


def _compact(elements: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertex ids ``elements`` ``(k, m)`` use (ascending), and ``elements``
    renumbered into them, flattened ``(k m,)`` (a scatter, no sort)."""
    used = np.zeros(vertex_count, dtype=bool)
    used[elements] = True
    new_id = np.cumsum(used) - 1
    return np.flatnonzero(used), new_id[elements].reshape(-1)


def _entity(entity_id: str, frame_id: str, stamp_ns: int, bulk: bytes = b"",
            **primitives) -> bytes:
    """Bytes of a ``SceneEntity``: the SDK encodes the header and small primitives,
    ``bulk`` (encoded primitive fields) is appended."""
    head = SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=frame_id, id=entity_id,
                       frame_locked=True, **primitives).encode()
    return head + bulk


def cloth_entity(positions: np.ndarray, triangles: np.ndarray, levels: np.ndarray,
                 max_level: int, frame_id: str, stamp_ns: int,
                 entity_id: str = "cloth") -> bytes:
    """The cloth surface: one ``TriangleListPrimitive`` per level present, in its colour.

    Args:
        positions: ``(n, 3)`` particle positions, m.
        triangles: ``(t, 3)`` vertex ids; levels: ``(t,)`` bisection levels.
        max_level: top of the colour scale.
        stamp_ns: entity timestamp, ns.

    Returns:
        Encoded ``foxglove.SceneEntity`` (see :func:`scene_update`).
    """
    x = np.asarray(positions, float)
    tri = np.asarray(triangles)
    lev = np.asarray(levels)
    present = np.unique(lev)
    palette = level_colours(present, max_level)
    bulk = []
    for level, rgb in zip(present, palette):
        used, local = _compact(tri[lev == level], len(x))
        primitive = (TriangleListPrimitive(pose=_pose(), color=_color([*rgb, 1.0])).encode()
                     + repeated_point3(_TRIANGLES_POINTS, x[used])
                     + packed_fixed32(_TRIANGLES_INDICES, local))
        bulk.append(length_delimited(_ENTITY_TRIANGLES, primitive))
    metadata = [KeyValuePair(key="triangles", value=str(len(tri))),
                KeyValuePair(key="max_level", value=str(int(max_level)))]
    return _entity(entity_id, frame_id, stamp_ns, b"".join(bulk), metadata=metadata)


def wireframe_entity(positions: np.ndarray, edges: np.ndarray, edge_levels: np.ndarray,
                     max_level: int, frame_id: str, stamp_ns: int,
                     entity_id: str = "wireframe") -> bytes:
    """The mesh edges: one ``LinePrimitive`` (line list) per level, darkened level colour.

    Args:
        edges: ``(e, 2)`` vertex ids and ``edge_levels`` ``(e,)`` the finest level
            of each edge's triangles
            (:func:`~cloth_lod_ros.messages.markers.unique_edges`).
    """
    x = np.asarray(positions, float)
    edges = np.asarray(edges)
    edge_levels = np.asarray(edge_levels)
    present = np.unique(edge_levels)
    palette = level_colours(present, max_level) * WIREFRAME_SHADE
    bulk = []
    for level, rgb in zip(present, palette):
        used, local = _compact(edges[edge_levels == level], len(x))
        primitive = (LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose(),
                                   thickness=WIREFRAME_WIDTH, scale_invariant=True,
                                   color=_color([*rgb, 1.0])).encode()
                     + repeated_point3(_LINES_POINTS, x[used])
                     + packed_fixed32(_LINES_INDICES, local))
        bulk.append(length_delimited(_ENTITY_LINES, primitive))
    return _entity(entity_id, frame_id, stamp_ns, b"".join(bulk))


def _obstacle_frame_pose(o) -> tuple[np.ndarray, np.ndarray]:
    """Origin ``(3,)`` m and orientation ``(4,)`` [x, y, z, w] of an obstacle's frame
    (z = a plane's normal, a cylinder's or disc's axis)."""
    if o.type == "plane":
        return np.asarray(o.centre, float), quaternion_from_z(o.normal)
    if o.type in ("cylinder", "disc"):
        return np.asarray(o.centre, float), quaternion_from_z(o.axis)
    if o.type == "box":
        return np.asarray(o.centre, float), np.asarray(o.orientation, float)
    return np.asarray(o.centre, float), np.array([0.0, 0.0, 0.0, 1.0])


def obstacle_entities(obstacles, frame_id: str, stamp_ns: int) -> list:
    """One ``SceneEntity`` per obstacle (id ``obstacle/<name>``), drawn as in ``cloth/markers``.

    Args:
        obstacles: obstacle configs at their current poses
            (``ClothSim.obstacle_configs()``).
    """
    entities = []
    for o, spec in zip(obstacles, obstacle_markers(obstacles, frame_id)):
        pose = _pose(spec.position, spec.orientation)
        size = Vector3(x=float(spec.scale[0]), y=float(spec.scale[1]), z=float(spec.scale[2]))
        colour = _color(spec.color)
        shapes = {}
        if spec.type == CUBE:
            shapes["cubes"] = [CubePrimitive(pose=pose, size=size, color=colour)]
        elif spec.type == SPHERE:
            shapes["spheres"] = [SpherePrimitive(pose=pose, size=size, color=colour)]
        elif spec.type == CYLINDER:
            shapes["cylinders"] = [CylinderPrimitive(pose=pose, size=size, bottom_scale=1.0,
                                                     top_scale=1.0, color=colour)]
        else:                                               # pragma: no cover
            raise ValueError(f"no Foxglove primitive for marker type {spec.type}")
        entities.append(SceneEntity(
            timestamp=_timestamp(stamp_ns), frame_id=frame_id, id=f"obstacle/{o.name}",
            frame_locked=True, metadata=[KeyValuePair(key="type", value=o.type)], **shapes))
    return entities


def grasp_entities(grasps, frame_id: str, stamp_ns: int) -> list:
    """One ``SceneEntity`` per grasp (id ``grasp/<name>``): a sphere where a closed
    grasp holds the cloth, a translucent one at its target when it has one; an
    open grasp without a target is an empty entity (which clears the old one)."""
    size = Vector3(x=GRASP_DIAMETER, y=GRASP_DIAMETER, z=GRASP_DIAMETER)
    entities = []
    for g in grasps:
        spheres = []
        if g.closed:
            spheres.append(SpherePrimitive(pose=_pose(g.position), size=size,
                                           color=_color(GRASP_COLOUR)))
        if g.command_position is not None:
            spheres.append(SpherePrimitive(pose=_pose(g.command_position), size=size,
                                           color=_color(TARGET_COLOUR)))
        entities.append(SceneEntity(
            timestamp=_timestamp(stamp_ns), frame_id=frame_id, id=f"grasp/{g.name}",
            frame_locked=True, spheres=spheres,
            metadata=[KeyValuePair(key="closed", value=str(bool(g.closed)).lower())]))
    return entities


def scene_update(entities: list = (), encoded: list[bytes] = ()) -> bytes:
    """Bytes of a ``foxglove.SceneUpdate`` holding SDK ``entities`` and ``encoded``
    entity bytes (concatenated repeated fields parse as one list)."""
    head = SceneUpdate(entities=list(entities)).encode() if entities else b""
    return head + b"".join(length_delimited(_SCENE_UPDATE_ENTITIES, e) for e in encoded)


def frame_transforms(obstacles, grasps, frame_id: str, stamp_ns: int) -> FrameTransforms:
    """``frame_id`` → ``obstacle/<name>`` for each obstacle (its current pose) and
    → ``grasp/<name>`` for each closed grasp (its grip pose), so a 3D panel can
    follow either."""
    stamp = _timestamp(stamp_ns)
    transforms = []
    for o in obstacles:
        origin, q = _obstacle_frame_pose(o)
        transforms.append(FrameTransform(
            timestamp=stamp, parent_frame_id=frame_id, child_frame_id=f"obstacle/{o.name}",
            translation=Vector3(x=float(origin[0]), y=float(origin[1]), z=float(origin[2])),
            rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))
    for g in grasps:
        if not g.closed:
            continue
        q = g.rotation.as_quat()                           # [x, y, z, w]
        transforms.append(FrameTransform(
            timestamp=stamp, parent_frame_id=frame_id, child_frame_id=f"grasp/{g.name}",
            translation=Vector3(x=float(g.position[0]), y=float(g.position[1]),
                                z=float(g.position[2])),
            rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))
    return FrameTransforms(transforms=transforms)


# -- statistics -----------------------------------------------------------------
# Fields of the last step taken as they are (StepStats, SI units, times in ms).
_STEP_FIELDS = ("step_ms", "lod_ms", "force_ms", "assembly_ms", "solve_ms",
                "self_collision_ms", "cg_iterations", "residual", "solves", "factorisations",
                "substeps", "rejected_steps", "smallest_step", "newton_iterations",
                "kinetic_energy", "gravity_energy", "stretch_energy", "shear_energy",
                "bend_energy", "max_strain", "max_speed", "contact_count", "pinned_count",
                "self_contact_count", "air_power", "refines", "merges")

LOD_STATS_SCHEMA = {
    "title": "cloth_lod.LodStats",
    "description": "LOD statistics of the live cloth simulation (SI units, times in ms)",
    "type": "object",
    "properties": {
        "sim_time_s": {"type": "number", "description": "simulated time, s"},
        "step_count": {"type": "integer", "description": "steps since start or reset"},
        "particles": {"type": "integer"},
        "triangles": {"type": "integer"},
        "max_level": {"type": "integer"},
        "triangles_per_level": {"type": "array", "items": {"type": "integer"},
                                "description": "triangles at each level 0..max_level"},
        "steps": {"type": "integer", "description": "steps since the previous message"},
        "lod_share": {"type": "number",
                      "description": "share of step time in LOD over those steps, 0..1"},
        "total_refines": {"type": "integer"},
        "total_merges": {"type": "integer"},
        "converged": {"type": "integer", "description": "1 if the last linear solve converged"},
        **{name: {"type": "number", "description": "last step (StepStats)"}
           for name in _STEP_FIELDS},
    },
}


def _finite(value):
    """A JSON number (NaN and infinities have none: null)."""
    value = float(value)
    return value if math.isfinite(value) else None


def lod_stats(sim, recent: list, totals: tuple[int, int]) -> dict:
    """The ``/cloth/lod_stats`` message: numbers only, so Foxglove's Plot panel can
    plot any field (e.g. ``/cloth/lod_stats.triangles_per_level[3]``).

    Args:
        sim: the :class:`~cloth_lod_ros.sim.ClothSim`.
        recent: the :class:`~cloth_lod_ros.sim.StepStats` since the previous message.
        totals: ``(refines, merges)`` since start or reset.
    """
    per_level = np.bincount(sim.triangle_levels, minlength=sim.max_level + 1)
    out = {"sim_time_s": float(sim.time), "step_count": int(sim.step_count),
           "particles": int(sim.mesh.vertex_count), "triangles": int(sim.mesh.triangle_count),
           "max_level": int(sim.max_level),
           "triangles_per_level": [int(c) for c in per_level],
           "steps": len(recent), "total_refines": int(totals[0]),
           "total_merges": int(totals[1])}
    step_ms = sum(s.step_ms for s in recent)
    out["lod_share"] = _finite(sum(s.lod_ms for s in recent) / step_ms) if step_ms > 0 else 0.0
    last = sim.stats[-1] if sim.stats else None
    if last is not None:
        for name in _STEP_FIELDS:
            out[name] = _finite(getattr(last, name))
        out["converged"] = int(bool(last.converged))
    return out
