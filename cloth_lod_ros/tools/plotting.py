"""Pictures of a cloth state (matplotlib, headless Agg backend).

The drawing helpers here are shared by the still pictures of ``cloth-lod run``
and the animations of ``cloth-lod view`` (:mod:`cloth_lod_ros.tools.view`):

* :func:`face_colours`: faces coloured by level on a fixed 0..max_level viridis
  scale (:func:`level_cmap`) and shaded by their normal against a fixed light;
* :class:`ClothArtists`: the cloth, the closed grasps and held particles on a
  3-D axes, updated frame by frame;
* the 3-D scene around them (view box, axes, obstacles, hidden faces) from
  :mod:`~cloth_lod_ros.tools.scene3d`, re-exported here.

Depth order: mplot3d sorts the polygons of one collection by depth, but draws
collections whole.  So the cloth is split each frame into the faces an obstacle
hides from the camera and the others; the hidden faces are drawn before the
(translucent) obstacles and the rest after them.  A plane seen from its outer
side is drawn first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .scene3d import (LIGHT, VIEWS, Z_ORDER, ObstacleArtists, camera_direction, clip_polygon,
                      cube_box, draw_obstacles, hidden_points, obstacle_extent, setup_axes,
                      view_box)

__all__ = ["render_cloth", "render_frames", "render_levels", "render_lod_history",
           "ClothFrame", "ClothArtists", "frame_from_sim", "face_colours", "level_cmap",
           "level_colorbar", "view_box", "cube_box", "setup_axes", "draw_obstacles", "hidden_points",
           "camera_direction", "clip_polygon", "ObstacleArtists", "obstacle_extent", "VIEWS"]

_CLOTH_COLOUR = np.array([0.85, 0.45, 0.25])


# -- colours ------------------------------------------------------------------------
def level_cmap(max_level: int):
    """The level palette: viridis with one colour per level 0..max_level."""
    import matplotlib.pyplot as plt
    return plt.get_cmap("viridis", max_level + 1)


def _shade(corners: np.ndarray, ambient: float) -> np.ndarray:
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return ambient + (1.0 - ambient) * np.abs(normals @ LIGHT)


def face_colours(corners: np.ndarray, levels: np.ndarray | None = None,
                 max_level: int | None = None, ambient: float = 0.35) -> np.ndarray:
    """``(t, 3)`` RGB of triangles ``corners`` ``(t, 3, 3)``.

    With ``max_level``, faces take their level's colour on the fixed
    0..max_level scale (so frames and pictures compare); with levels but no
    ``max_level``, a tint relative to the levels present; otherwise one cloth
    colour.  Each face is shaded by its normal against a fixed light, from
    ``ambient`` (edge-on) to 1.
    """
    corners = np.asarray(corners, float)
    if levels is not None and max_level is not None:
        base = level_cmap(max_level)(np.asarray(levels) / max(max_level, 1))[:, :3]
    elif levels is not None and len(np.unique(levels)) > 1:
        import matplotlib.pyplot as plt
        levels = np.asarray(levels)
        span = max(int(levels.max() - levels.min()), 1)
        base = plt.get_cmap("viridis")((levels - levels.min()) / span)[:, :3]
    else:
        base = np.tile(_CLOTH_COLOUR, (len(corners), 1))
    return np.clip(base * _shade(corners, ambient)[:, None], 0, 1)


def level_colorbar(fig, ax, max_level: int, **kwargs):
    """A colour bar of the level palette beside ``ax``."""
    import matplotlib.pyplot as plt
    mappable = plt.cm.ScalarMappable(cmap=level_cmap(max_level),
                                     norm=plt.Normalize(-0.5, max_level + 0.5))
    bar = fig.colorbar(mappable, ax=ax, ticks=range(max_level + 1), **kwargs)
    bar.set_label("level")
    return bar


# -- frames -------------------------------------------------------------------------
@dataclass
class ClothFrame:
    """One picture of the cloth.

    Attributes:
        positions: ``(n, 3)`` m; triangles: ``(t, 3)`` indices into it.
        levels: ``(t,)`` bisection levels, or None.
        time: simulated time, s.
        grasps: ``(k, 3)`` points of the closed grasps, m.
        pins: ``(p, 3)`` held particles, m.
        title: text above the picture.
        obstacles: the obstacle configs at this frame's poses (kinematic
            obstacles move), or None: the ones the drawing was made with.
    """

    positions: np.ndarray
    triangles: np.ndarray
    levels: np.ndarray | None = None
    time: float = 0.0
    grasps: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    pins: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    title: str = ""
    obstacles: tuple | None = None

    @property
    def corners(self) -> np.ndarray:
        """``(t, 3, 3)`` triangle corners, m."""
        return np.asarray(self.positions, float)[np.asarray(self.triangles)]


def frame_from_sim(sim, title: str = "") -> ClothFrame:
    """A copy of a :class:`~cloth_lod_ros.sim.ClothSim`'s state: the mesh, the
    closed grasps' points, the particles held by active pins and the obstacles
    where they are now."""
    pins = [p.vertex for p in sim.pins if p.active(sim.time)]
    grasps = [g.position for g in sim.grasps if g.closed]
    return ClothFrame(sim.positions.copy(), sim.triangles.copy(),
                      sim.triangle_levels.copy(), float(sim.time),
                      np.array(grasps, float).reshape(-1, 3),
                      sim.positions[np.array(pins, dtype=np.int64)].copy(), title,
                      tuple(sim.obstacle_configs()))


# -- the cloth ----------------------------------------------------------------------
class ClothArtists:
    """The cloth, its closed grasps and held particles on a 3-D axes.

    Created once per axes; :meth:`update` redraws them for a frame (the
    animation reuses one figure).

    Args:
        ax: a 3-D axes set up by :func:`setup_axes` (same ``view``).
        max_level: colour faces by level on 0..max_level (None: cloth colour,
            or a relative tint when the frame's levels differ).
        obstacles: obstacle configs that may hide parts of the cloth.
        ambient: darkest shade of a face (edge-on to the light).
        reach: length of the visibility rays, m (the axes box diagonal).
    """

    def __init__(self, ax, max_level: int | None = None, obstacles=(), view: str = "3d",
                 ambient: float = 0.35, edge_alpha: float = 0.25, linewidth: float = 0.3,
                 reach: float = 10.0, title_size: float = 10):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        self.max_level = max_level
        self.obstacles = [o for o in obstacles if o.type != "plane"]
        self.towards = camera_direction(view)
        self.ambient = ambient
        self.reach = reach
        style = dict(edgecolors=(0, 0, 0, edge_alpha), linewidths=linewidth)
        self.behind = Poly3DCollection(np.zeros((0, 3, 3)), zorder=Z_ORDER['hidden'], **style)
        self.front = Poly3DCollection(np.zeros((0, 3, 3)), zorder=Z_ORDER['cloth'], **style)
        for collection in (self.behind, self.front):
            ax.add_collection3d(collection, autolim=False)
        self.pins, = ax.plot([], [], [], "o", color="crimson", ms=5, zorder=Z_ORDER['holders'],
                             label="held particles")
        self.grasps, = ax.plot([], [], [], "o", mfc="crimson", mec="k", mew=0.8, ms=8,
                               zorder=Z_ORDER['holders'], label="closed grasps")
        self.title = ax.text2D(0.5, 0.97, "", transform=ax.transAxes, ha="center",
                               fontsize=title_size)

    def update(self, frame: ClothFrame) -> list:
        """Show ``frame`` (with its obstacles, if it has them, hiding faces);
        returns the artists it changed."""
        if frame.obstacles is not None:
            self.obstacles = [o for o in frame.obstacles if o.type != "plane"]
        corners = frame.corners
        colours = face_colours(corners, frame.levels, self.max_level, self.ambient)
        hidden = np.zeros(len(corners), dtype=bool)
        if self.obstacles and len(corners):
            # Each distinct point once (a recorded surface repeats every shared
            # corner, about six times).
            points, inverse = np.unique(np.asarray(frame.positions, float).reshape(-1, 3),
                                        axis=0, return_inverse=True)
            at_point = hidden_points(points, self.obstacles, self.towards, self.reach)
            per_corner = at_point[inverse.reshape(-1)][np.asarray(frame.triangles)]
            hidden = per_corner.sum(axis=1) >= 2
        self.behind.set_verts(corners[hidden])
        self.behind.set_facecolor(colours[hidden])
        self.front.set_verts(corners[~hidden])
        self.front.set_facecolor(colours[~hidden])
        for line, points in ((self.pins, frame.pins), (self.grasps, frame.grasps)):
            p = np.asarray(points, float).reshape(-1, 3)
            line.set_data_3d(p[:, 0], p[:, 1], p[:, 2])
        self.title.set_text(frame.title)
        return [self.behind, self.front, self.pins, self.grasps, self.title]


def _draw_scene(ax, frame: ClothFrame, box, max_level, obstacles, view="3d",
                ambient=0.35, edge_alpha=0.25) -> ClothArtists:
    setup_axes(ax, box, view)
    draw_obstacles(ax, obstacles, box, view)
    cloth = ClothArtists(ax, max_level, obstacles, view, ambient=ambient, edge_alpha=edge_alpha,
                         reach=float(np.linalg.norm(box[1] - box[0])))
    cloth.update(frame)
    return cloth


# -- still pictures -----------------------------------------------------------------
def render_cloth(path, positions: np.ndarray, triangles: np.ndarray,
                 levels: np.ndarray | None = None, pinned: np.ndarray | None = None,
                 title: str = "", obstacles=(), grasps: np.ndarray | None = None) -> None:
    """Write a PNG of the cloth surface.

    Faces are shaded by their normal against a fixed light (so folds read),
    and tinted by refinement level when ``levels`` has more than one value.

    Args:
        path: output PNG path (its directory is created).
        positions: ``(n, 3)`` particle positions, m.
        triangles: ``(t, 3)`` vertex indices.
        levels: ``(t,)`` bisection level per triangle (optional).
        pinned: ``(k,)`` indices of held particles, drawn as markers.
        obstacles: obstacle configs to draw; grasps: ``(g, 3)`` closed grasp points, m.
    """
    positions = np.asarray(positions, float)
    pins = positions[np.asarray(pinned, dtype=np.int64)] if pinned is not None else None
    frame = ClothFrame(positions, triangles, levels, title=title,
                       grasps=np.zeros((0, 3)) if grasps is None else grasps,
                       pins=np.zeros((0, 3)) if pins is None else pins)
    render_frames(path, [frame], obstacles=obstacles)


def render_frames(path, frames: list[ClothFrame], max_level: int | None = None,
                  obstacles=()) -> None:
    """Write a PNG with one 3-D panel per frame, on common axes.

    Args:
        frames: :class:`ClothFrame` list (each with its title, grasps and pins).
        max_level: colour faces by level on a fixed 0..max_level scale (adaptive
            runs); None shades a single colour (or a relative level tint).
        obstacles: obstacle configs drawn in every panel.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    box = cube_box(view_box([f.positions for f in frames], obstacles))
    fig = plt.figure(figsize=(5.5 * len(frames), 5.5), dpi=100)
    for k, frame in enumerate(frames):
        ax = fig.add_subplot(1, len(frames), k + 1, projection="3d")
        _draw_scene(ax, frame, box, max_level, obstacles)
    fig.subplots_adjust(left=0.02, right=0.95, bottom=0.05, top=0.98, wspace=0.1)
    fig.savefig(path)
    plt.close(fig)


def render_levels(path, positions: np.ndarray, triangles: np.ndarray, uv: np.ndarray,
                  levels: np.ndarray, max_level: int, title: str = "", obstacles=(),
                  grasps: np.ndarray | None = None,
                  grasp_uv: np.ndarray | None = None) -> None:
    """Final mesh coloured by bisection level: 3-D view and rest (u, v) view.

    Args:
        positions: ``(n, 3)`` m; uv: ``(n, 2)`` rest coordinates, m;
        triangles: ``(t, 3)``; levels: ``(t,)``; max_level: colour scale top.
        obstacles: obstacle configs drawn in the 3-D view.
        grasps: ``(g, 3)`` closed grasp points (3-D view); grasp_uv: ``(g, 2)``
            their material points (rest view).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    frame = ClothFrame(np.asarray(positions, float), triangles, levels,
                       grasps=np.zeros((0, 3)) if grasps is None else grasps)
    fig = plt.figure(figsize=(12, 5.5), dpi=100)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    _draw_scene(ax, frame, cube_box(view_box([frame.positions], obstacles)), max_level,
                obstacles, ambient=0.45, edge_alpha=0.3)
    ax2 = fig.add_subplot(1, 2, 2)
    colours = level_cmap(max_level)(np.asarray(levels) / max(max_level, 1))[:, :3]
    ax2.add_collection(PolyCollection(uv[triangles], facecolors=colours,
                                      edgecolors="k", linewidths=0.3))
    if grasp_uv is not None and len(grasp_uv):
        g = np.asarray(grasp_uv, float).reshape(-1, 2)
        ax2.plot(g[:, 0], g[:, 1], "o", mfc="crimson", mec="k", ms=8, label="closed grasps")
    ax2.set_xlim(uv[:, 0].min(), uv[:, 0].max())
    ax2.set_ylim(uv[:, 1].min(), uv[:, 1].max())
    ax2.set_aspect("equal")
    ax2.set_xlabel("u [m]")
    ax2.set_ylabel("v [m]")
    ax2.set_title("rest (u, v) mesh", fontsize=10)
    level_colorbar(fig, ax2, max_level, fraction=0.046)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.savefig(path)
    plt.close(fig)


def render_lod_history(path, stats, title: str = "") -> None:
    """Triangle count (per level) and the share of step time spent in LOD, over time.

    Args:
        stats: sequence of :class:`cloth_lod_ros.sim.StepStats` (empty: a picture
            that says no step was taken).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not len(stats):
        fig, ax = plt.subplots(figsize=(8, 3), dpi=100)
        ax.text(0.5, 0.5, "no steps taken: no adaptive-mesh history", ha="center",
                va="center", transform=ax.transAxes)
        ax.set_axis_off()
        if title:
            fig.suptitle(title, fontsize=11)
        fig.savefig(path)
        plt.close(fig)
        return
    time = np.array([s.time for s in stats])
    per_level = np.array([s.triangles_per_level for s in stats]).T
    lod_ms = np.array([s.lod_ms for s in stats])
    step_ms = np.array([s.step_ms for s in stats])
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6.5), dpi=100, sharex=True)
    ax1.stackplot(time, per_level, labels=[f"level {k}" for k in range(len(per_level))],
                  alpha=0.85, colors=level_cmap(len(per_level) - 1)(
                      np.arange(len(per_level))))
    ax1.plot(time, [s.vertex_count for s in stats], "k--", lw=1, label="particles")
    ax1.set_ylabel("triangles")
    ax1.legend(loc="upper right", fontsize=7, ncol=2)
    window = max(len(time) // 30, 1)
    kernel = np.ones(window) / window
    share = 100 * np.convolve(lod_ms, kernel, "same") / np.maximum(
        np.convolve(step_ms, kernel, "same"), 1e-12)
    ax2.plot(time, 100 * lod_ms / np.maximum(step_ms, 1e-12), color="0.7", lw=0.6,
             label="per step")
    ax2.plot(time, share, color="C3", lw=1.5, label=f"moving mean ({window} steps)")
    overall = 100 * lod_ms.sum() / max(step_ms.sum(), 1e-12)
    ax2.axhline(overall, color="k", ls=":", lw=1, label=f"whole run: {overall:.1f} %")
    ax2.set_ylabel("LOD share of step time [%]")
    ax2.set_xlabel("simulation time [s]")
    ax2.set_ylim(0, 100)
    ax2.legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
