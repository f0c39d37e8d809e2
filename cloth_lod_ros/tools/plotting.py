"""Pictures of a cloth state (matplotlib, headless Agg backend).

The drawing helpers here are shared by the still pictures of ``cloth-lod run``
and the animations of ``cloth-lod view`` (:mod:`cloth_lod_ros.tools.view`):

* :func:`face_colours`: faces coloured by level on a fixed 0..max_level viridis
  scale (:func:`level_cmap`) and shaded by their normal against a fixed light;
* :class:`ClothArtists`: the cloth, the closed grasps and held particles on a
  3-D axes, updated frame by frame;
* :func:`draw_obstacles`: planes as a ground grid, spheres, discs/cylinders and
  boxes (with their orientation) as surfaces;
* :func:`view_box` and :func:`setup_axes`: fixed, equally scaled axes around the
  cloth (obstacles included, clipped to a box around it).

Depth order: mplot3d sorts the polygons of one collection by depth, but draws
collections whole.  So the cloth is split each frame into the faces an obstacle
hides from the camera (a ray cast against the obstacles' signed distances) and
the others; the hidden faces are drawn before the (translucent) obstacles and
the rest after them.  A plane seen from its outer side is drawn first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..sim.contact import make_obstacle, quaternion_matrix

__all__ = ["render_cloth", "render_frames", "render_levels", "render_lod_history",
           "ClothFrame", "ClothArtists", "frame_from_sim", "face_colours", "level_cmap",
           "level_colorbar", "view_box", "cube_box", "setup_axes", "draw_obstacles", "hidden_points",
           "camera_direction", "clip_polygon", "VIEWS"]

# Views: (elevation, azimuth) in degrees, as mplot3d's view_init takes them.
VIEWS = {"3d": (18.0, -60.0), "top": (90.0, -90.0), "side": (0.0, -90.0)}
_LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
_CLOTH_COLOUR = np.array([0.85, 0.45, 0.25])
_OBSTACLE_GREY = np.array([0.55, 0.58, 0.62])
_OBSTACLE_ALPHA = 0.55
# Drawing order (mplot3d with computed_zorder off draws by zorder).
_Z_PLANE_BEHIND, _Z_HIDDEN, _Z_SOLID, _Z_CLOTH, _Z_HOLDERS, _Z_PLANE_FRONT = 1, 2, 3, 5, 6, 7


# -- colours ------------------------------------------------------------------------
def level_cmap(max_level: int):
    """The level palette: viridis with one colour per level 0..max_level."""
    import matplotlib.pyplot as plt
    return plt.get_cmap("viridis", max_level + 1)


def _shade(corners: np.ndarray, ambient: float) -> np.ndarray:
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return ambient + (1.0 - ambient) * np.abs(normals @ _LIGHT)


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
    """

    positions: np.ndarray
    triangles: np.ndarray
    levels: np.ndarray | None = None
    time: float = 0.0
    grasps: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    pins: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    title: str = ""

    @property
    def corners(self) -> np.ndarray:
        """``(t, 3, 3)`` triangle corners, m."""
        return np.asarray(self.positions, float)[np.asarray(self.triangles)]


def frame_from_sim(sim, title: str = "") -> ClothFrame:
    """A copy of a :class:`~cloth_lod_ros.sim.ClothSim`'s state: the mesh, the
    closed grasps' points and the particles held by active pins."""
    pins = [p.vertex for p in sim.pins if p.active(sim.time)]
    grasps = [g.position for g in sim.grasps if g.closed]
    return ClothFrame(sim.positions.copy(), sim.triangles.copy(),
                      sim.triangle_levels.copy(), float(sim.time),
                      np.array(grasps, float).reshape(-1, 3),
                      sim.positions[np.array(pins, dtype=np.int64)].copy(), title)


# -- axes ---------------------------------------------------------------------------
def _obstacle_extent(o, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Points bounding obstacle ``o`` (a plane: the cloth box projected onto it)."""
    centre = np.asarray(o.centre, float)
    if o.type == "plane":
        n = np.asarray(o.normal, float) / np.linalg.norm(o.normal)
        corners = _box_corners(lo, hi)
        return corners - ((corners - centre) @ n)[:, None] * n
    if o.type == "sphere":
        return np.array([centre - o.radius, centre + o.radius])
    if o.type in ("cylinder", "disc"):
        a = np.asarray(o.axis, float) / np.linalg.norm(o.axis)
        half = np.abs(a) * o.half_height + o.radius * np.sqrt(np.clip(1 - a * a, 0, 1))
        return np.array([centre - half, centre + half])
    rot = quaternion_matrix(o.orientation)                          # box
    signs = _box_corners(-np.ones(3), np.ones(3))
    return centre + (signs * np.asarray(o.half_extents, float)) @ rot.T


def _box_corners(lo, hi) -> np.ndarray:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                     for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def view_box(point_sets, obstacles=(), margin: float = 0.3,
             pad: float = 0.04) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` axis limits (m) holding every point of every set, and the
    obstacles clipped to the cloth's box grown by ``margin`` × its largest side.

    Args:
        point_sets: iterable of ``(n, 3)`` arrays (e.g. each frame's positions).
        obstacles: :class:`~cloth_lod_ros.sim.config.ObstacleConfig` sequence.
    """
    points = np.vstack([np.asarray(p, float).reshape(-1, 3) for p in point_sets])
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = max(float((hi - lo).max()), 1e-3)
    clip_lo, clip_hi = lo - margin * size, hi + margin * size
    all_lo, all_hi = lo.copy(), hi.copy()
    for o in obstacles:
        extent = _obstacle_extent(o, lo, hi)
        all_lo = np.minimum(all_lo, extent.min(axis=0))
        all_hi = np.maximum(all_hi, extent.max(axis=0))
    lo = np.clip(all_lo, clip_lo, clip_hi) - pad * size
    hi = np.clip(all_hi, clip_lo, clip_hi) + pad * size
    thin = 0.1 * size                      # a flat cloth still gets some height
    short = (hi - lo) < thin
    centre = (lo + hi) / 2
    lo[short], hi[short] = centre[short] - thin / 2, centre[short] + thin / 2
    return lo, hi


def camera_direction(view: str = "3d") -> np.ndarray:
    """Unit vector from the scene towards the camera of ``view`` (orthographic)."""
    elev, azim = np.radians(VIEWS[view])
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


def cube_box(box) -> tuple[np.ndarray, np.ndarray]:
    """The cube with ``box``'s centre whose side is ``box``'s largest side."""
    lo, hi = np.asarray(box[0], float), np.asarray(box[1], float)
    centre, half = (lo + hi) / 2, float((hi - lo).max()) / 2
    return centre - half, centre + half


def setup_axes(ax, box, view: str = "3d", zoom: float = 1.0) -> None:
    """Fixed limits ``box``, equal scale on every axis, orthographic ``view``;
    fewer ticks on the shorter sides."""
    from matplotlib.ticker import MaxNLocator
    lo, hi = box
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo), zoom=zoom)
    longest = float((hi - lo).max())
    for axis, extent in zip((ax.xaxis, ax.yaxis, ax.zaxis), hi - lo):
        axis.set_major_locator(MaxNLocator(nbins=max(2, round(6 * extent / longest))))
    ax.set_proj_type("ortho")
    ax.view_init(*VIEWS[view])
    ax.computed_zorder = False                # draw by zorder (see the module doc)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    if view == "top":
        ax.set_zticks([])
        ax.set_zlabel("")
    elif view == "side":
        ax.set_yticks([])
        ax.set_ylabel("")


# -- obstacles ----------------------------------------------------------------------
def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _perpendiculars(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``n`` to a right-handed frame (x and y for +z)."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = _unit(np.cross(helper, n))
    return t1, np.cross(n, t1)


def _solid_polygons(o) -> tuple[list, np.ndarray]:
    """Surface polygons of a sphere, cylinder/disc or box and their outward normals."""
    centre = np.asarray(o.centre, float)
    if o.type == "sphere":
        theta = np.linspace(0, np.pi, 13)                    # from the north pole
        phi = np.linspace(0, 2 * np.pi, 25)
        th, ph = np.meshgrid(theta, phi, indexing="ij")
        dirs = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
        quads = np.stack([dirs[:-1, :-1], dirs[1:, :-1], dirs[1:, 1:], dirs[:-1, 1:]], 2)
        quads = quads.reshape(-1, 4, 3)
        normals = np.array([_unit(q.mean(axis=0)) for q in quads])
        return list(centre + o.radius * quads), normals
    if o.type in ("cylinder", "disc"):
        a = _unit(o.axis)
        t1, t2 = _perpendiculars(a)
        angle = np.linspace(0, 2 * np.pi, 49)[:-1]
        radial = np.cos(angle)[:, None] * t1 + np.sin(angle)[:, None] * t2
        top = centre + o.half_height * a + o.radius * radial
        bottom = centre - o.half_height * a + o.radius * radial
        nxt = np.roll(np.arange(len(angle)), -1)
        sides = [np.array([bottom[i], bottom[j], top[j], top[i]])
                 for i, j in zip(range(len(angle)), nxt)]
        side_normals = _unit_rows(radial + radial[nxt])
        return sides + [top, bottom[::-1]], np.vstack([side_normals, a, -a])
    rot = quaternion_matrix(o.orientation)                          # box
    half = np.asarray(o.half_extents, float)
    polygons, normals = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [k for k in range(3) if k != axis]
            local = np.zeros((4, 3))
            local[:, axis] = sign * half[axis]
            local[:, u] = np.array([-1, 1, 1, -1]) * half[u]
            local[:, v] = np.array([-1, -1, 1, 1]) * half[v]
            polygons.append(centre + local @ rot.T)
            normals.append(sign * rot[:, axis])
    return polygons, np.array(normals)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def _nice_step(extent: float) -> float:
    """A round grid spacing giving about eight cells over ``extent``."""
    raw = extent / 8
    base = 10.0 ** np.floor(np.log10(raw))
    return float(min((s * base for s in (1, 2, 2.5, 5, 10)), key=lambda s: abs(s - raw)))


def clip_polygon(polygon: np.ndarray, box) -> np.ndarray | None:
    """The part of a convex polygon ``(k, 3)`` inside the axis-aligned ``box``
    ``(lo, hi)`` (Sutherland-Hodgman), or None if nothing of it is inside."""
    poly = np.asarray(polygon, float)
    for axis in range(3):
        for bound, sign in ((box[0][axis], 1.0), (box[1][axis], -1.0)):
            inside = sign * (poly[:, axis] - bound) >= 0
            if inside.all():
                continue
            kept = []
            for i in range(len(poly)):
                j = (i + 1) % len(poly)
                if inside[i]:
                    kept.append(poly[i])
                if inside[i] != inside[j]:
                    t = (bound - poly[i, axis]) / (poly[j, axis] - poly[i, axis])
                    kept.append(poly[i] + t * (poly[j] - poly[i]))
            if len(kept) < 3:
                return None
            poly = np.array(kept)
    return poly


def _plane_cells(o, box) -> list:
    """Ground-grid cells of plane ``o`` inside the axes box (none if it misses it)."""
    lo, hi = box
    n = _unit(o.normal)
    p = np.asarray(o.centre, float)
    corners = _box_corners(lo, hi)
    t1, t2 = _perpendiculars(n)
    a, b = (corners - p) @ t1, (corners - p) @ t2
    step = _nice_step(max(a.max() - a.min(), b.max() - b.min()))

    def edges(low, high):
        inner = np.arange(np.floor(low / step) + 1, np.ceil(high / step)) * step
        return np.concatenate([[low], inner[(inner > low) & (inner < high)], [high]])

    ea, eb = edges(a.min(), a.max()), edges(b.min(), b.max())
    cells = []
    for a0, a1 in zip(ea[:-1], ea[1:]):
        for b0, b1 in zip(eb[:-1], eb[1:]):
            cells.append(p + np.outer([a0, a1, a1, a0], t1) + np.outer([b0, b0, b1, b1], t2))
    return [c for c in (clip_polygon(cell, box) for cell in cells) if c is not None]


def draw_obstacles(ax, obstacles, box, view: str = "3d") -> list:
    """Draw ``obstacles`` (:class:`~cloth_lod_ros.sim.config.ObstacleConfig`) on a
    3-D axes set up by :func:`setup_axes`.

    Planes are a ground grid over the axes box (drawn first when the camera sees
    their outer side); spheres, cylinders/discs and boxes are translucent,
    shaded surfaces whose faces turned away from the camera are left out (box
    rounding is not drawn).

    Returns:
        The artists added, one per drawn obstacle, in the order of ``obstacles``
        (an obstacle outside the axes box adds none; the others are clipped to
        it).  Each has the obstacle's ``name`` as its label and
        ``obstacle:<type>`` as its ``gid``.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    towards = camera_direction(view)
    artists = []
    solids = [o for o in obstacles if o.type != "plane"]
    # Farther solids first (they do not overlap each other in practice).
    depth_rank = {id(o): k for k, o in enumerate(
        sorted(solids, key=lambda o: float(np.asarray(o.centre, float) @ towards)))}
    for o in obstacles:
        if o.type == "plane":
            cells = _plane_cells(o, box)
            if not cells:
                continue
            behind = float(_unit(o.normal) @ towards) >= -1e-9
            artist = Poly3DCollection(cells, facecolors=(0.82, 0.82, 0.8, 0.35),
                                      edgecolors=(0.35, 0.35, 0.35, 0.45), linewidths=0.5,
                                      zorder=_Z_PLANE_BEHIND if behind else _Z_PLANE_FRONT)
        else:
            polygons, normals = _solid_polygons(o)
            front = normals @ towards > 1e-9          # faces turned to the camera
            kept = [(clip_polygon(q, box), n) for q, n, f in zip(polygons, normals, front) if f]
            kept = [(q, n) for q, n in kept if q is not None]
            if not kept:
                continue                              # outside the axes box
            normals = np.array([n for _, n in kept])
            shade = 0.55 + 0.45 * np.abs(normals @ _LIGHT)
            colours = np.column_stack([_OBSTACLE_GREY * shade[:, None],
                                       np.full(len(kept), _OBSTACLE_ALPHA)])
            artist = Poly3DCollection([q for q, _ in kept], facecolors=colours,
                                      edgecolors="none",
                                      zorder=_Z_SOLID + 0.01 * depth_rank[id(o)])
        artist.set_label(o.name or o.type)
        artist.set_gid(f"obstacle:{o.type}")
        ax.add_collection3d(artist, autolim=False)
        artists.append(artist)
    return artists


def hidden_points(points: np.ndarray, obstacles, towards: np.ndarray, reach: float,
                  eps: float = 1e-3, iterations: int = 64) -> np.ndarray:
    """``(n,)`` True where the ray from a point towards the camera meets a solid.

    Sphere tracing along ``towards`` with the obstacles' signed distances
    (planes are left out: :func:`draw_obstacles` orders them).  A point within
    ``2 eps`` of a surface (a cloth lying on it) first steps off it along the ray.
    Rays still open after ``iterations`` (grazing ones) count as not hidden.

    Args:
        points: ``(n, 3)`` m; obstacles: obstacle configs;
        towards: unit vector to the camera; reach: m, length of the rays.
    """
    points = np.asarray(points, float).reshape(-1, 3)
    hidden = np.zeros(len(points), dtype=bool)
    solids = [make_obstacle(o) for o in obstacles if o.type != "plane"]
    if not solids or not len(points):
        return hidden

    def distance(x):
        return np.min([s.distance(x)[0] for s in solids], axis=0)

    start = distance(points)
    t = np.where(start < 2 * eps, 2 * eps - np.minimum(start, 0.0), 0.0)
    active = np.arange(len(points))
    for _ in range(iterations):
        phi = distance(points[active] + t[active, None] * towards)
        hit = phi < eps
        hidden[active[hit]] = True
        t[active] += phi
        active = active[~hit & (t[active] < reach)]
        if not len(active):
            break
    return hidden


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
        self.behind = Poly3DCollection(np.zeros((0, 3, 3)), zorder=_Z_HIDDEN, **style)
        self.front = Poly3DCollection(np.zeros((0, 3, 3)), zorder=_Z_CLOTH, **style)
        for collection in (self.behind, self.front):
            ax.add_collection3d(collection, autolim=False)
        self.pins, = ax.plot([], [], [], "o", color="crimson", ms=5, zorder=_Z_HOLDERS,
                             label="held particles")
        self.grasps, = ax.plot([], [], [], "o", mfc="crimson", mec="k", mew=0.8, ms=8,
                               zorder=_Z_HOLDERS, label="closed grasps")
        self.title = ax.text2D(0.5, 0.97, "", transform=ax.transAxes, ha="center",
                               fontsize=title_size)

    def update(self, frame: ClothFrame) -> list:
        """Show ``frame``; returns the artists it changed."""
        corners = frame.corners
        colours = face_colours(corners, frame.levels, self.max_level, self.ambient)
        hidden = np.zeros(len(corners), dtype=bool)
        if self.obstacles and len(corners):
            per_corner = hidden_points(corners.reshape(-1, 3), self.obstacles, self.towards,
                                       self.reach).reshape(-1, 3)
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
