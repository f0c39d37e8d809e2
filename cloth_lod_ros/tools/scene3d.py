"""3-D scenes for pictures and animations: view box, axes, obstacles, hidden faces.

Shared by :mod:`~cloth_lod_ros.tools.plotting` (still pictures) and
:mod:`~cloth_lod_ros.tools.view` (animations):

* :func:`view_box`, :func:`cube_box`, :func:`setup_axes`: fixed, equally scaled
  axes around the cloth (obstacles included, clipped to a box around it);
* :func:`draw_obstacles`: planes as a ground grid, spheres, discs/cylinders and
  boxes (with their orientation) as translucent surfaces;
  :class:`ObstacleArtists` the same, moved frame by frame (kinematic obstacles);
* :func:`hidden_points`: which points an obstacle hides from the camera (a ray
  cast against the obstacles' signed distances), so the cloth behind an
  obstacle can be drawn before it (mplot3d sorts polygons within a collection,
  not between collections).
"""

from __future__ import annotations

import numpy as np

from ..sim.contact.obstacles import make_obstacle, quaternion_matrix

__all__ = ["VIEWS", "LIGHT", "Z_ORDER", "view_box", "cube_box", "setup_axes",
           "draw_obstacles", "ObstacleArtists", "obstacle_extent", "hidden_points",
           "camera_direction", "clip_polygon"]

# Views: (elevation, azimuth) in degrees, as mplot3d's view_init takes them.
VIEWS = {"3d": (18.0, -60.0), "top": (90.0, -90.0), "side": (0.0, -90.0)}
LIGHT = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
_OBSTACLE_GREY = np.array([0.55, 0.58, 0.62])
_OBSTACLE_ALPHA = 0.55
# Drawing order (mplot3d with computed_zorder off draws by zorder).
Z_ORDER = dict(plane_behind=1, hidden=2, solid=3, cloth=5, holders=6, plane_front=7)


# -- axes ---------------------------------------------------------------------------
def obstacle_extent(o, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``(k, 3)`` points bounding obstacle ``o``, m (a plane: the corners of the
    cloth box ``lo``, ``hi`` projected onto it; the others do not use the box)."""
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
             pad: float = 0.04, extents=()) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` axis limits (m) holding every point of every set, and the
    obstacles clipped to the cloth's box grown by ``margin`` × its largest side.

    Args:
        point_sets: iterable of ``(n, 3)`` arrays (e.g. each frame's positions,
            or only their bounding corners).
        obstacles: :class:`~cloth_lod_ros.sim.scene.config.ObstacleConfig` sequence.
        extents: iterable of ``(k, 3)`` points bounding obstacles already
            (e.g. :func:`obstacle_extent` over a moving obstacle's poses),
            clipped as the obstacles are.
    """
    points = np.vstack([np.asarray(p, float).reshape(-1, 3) for p in point_sets])
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = max(float((hi - lo).max()), 1e-3)
    clip_lo, clip_hi = lo - margin * size, hi + margin * size
    all_lo, all_hi = lo.copy(), hi.copy()
    extents = [obstacle_extent(o, lo, hi) for o in obstacles] + [
        np.asarray(e, float).reshape(-1, 3) for e in extents]
    for extent in extents:
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


def _obstacle_style(o, box, towards: np.ndarray):
    """What an obstacle looks like from ``towards`` inside ``box``: ``(polygons,
    face RGBA (p, 4), edge RGBA, line width, base zorder)``, or None when
    nothing of it is inside the box (planes: grid cells; solids: the faces
    turned to the camera, shaded by their normal)."""
    if o.type == "plane":
        cells = _plane_cells(o, box)
        if not cells:
            return None
        behind = float(_unit(o.normal) @ towards) >= -1e-9
        return (cells, np.tile((0.82, 0.82, 0.8, 0.35), (len(cells), 1)),
                (0.35, 0.35, 0.35, 0.45), 0.5,
                Z_ORDER['plane_behind'] if behind else Z_ORDER['plane_front'])
    polygons, normals = _solid_polygons(o)
    front = normals @ towards > 1e-9          # faces turned to the camera
    kept = [(clip_polygon(q, box), n) for q, n, f in zip(polygons, normals, front) if f]
    kept = [(q, n) for q, n in kept if q is not None]
    if not kept:
        return None                           # outside the axes box
    normals = np.array([n for _, n in kept])
    shade = 0.55 + 0.45 * np.abs(normals @ LIGHT)
    colours = np.column_stack([_OBSTACLE_GREY * shade[:, None],
                               np.full(len(kept), _OBSTACLE_ALPHA)])
    return [q for q, _ in kept], colours, "none", 0.0, Z_ORDER['solid']


def _depth_ranks(obstacles, towards: np.ndarray) -> dict:
    """Solids' drawing ranks, farther first (they do not overlap each other in
    practice): ``{index in obstacles: rank}``."""
    solids = [k for k, o in enumerate(obstacles) if o.type != "plane"]
    order = sorted(solids, key=lambda k: float(np.asarray(obstacles[k].centre, float) @ towards))
    return {k: rank for rank, k in enumerate(order)}


def draw_obstacles(ax, obstacles, box, view: str = "3d") -> list:
    """Draw ``obstacles`` (:class:`~cloth_lod_ros.sim.scene.config.ObstacleConfig`) on a
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
    ranks = _depth_ranks(obstacles, towards)
    artists = []
    for k, o in enumerate(obstacles):
        style = _obstacle_style(o, box, towards)
        if style is None:
            continue
        polygons, faces, edges, width, zorder = style
        artist = Poly3DCollection(polygons, facecolors=faces, edgecolors=edges,
                                  linewidths=width, zorder=zorder + 0.01 * ranks.get(k, 0))
        artist.set_label(o.name or o.type)
        artist.set_gid(f"obstacle:{o.type}")
        ax.add_collection3d(artist, autolim=False)
        artists.append(artist)
    return artists


class ObstacleArtists:
    """Obstacles drawn as :func:`draw_obstacles` draws them, moved frame by frame.

    One collection per obstacle, made once; :meth:`update` recomputes the
    polygons (``Poly3DCollection.set_verts``) of the obstacles whose config
    changed since the last frame, so a static obstacle costs nothing after the
    first frame.  An obstacle outside the axes box has an empty collection.

    Args:
        ax: a 3-D axes set up by :func:`setup_axes` with the same ``box`` and ``view``.
        obstacles: the first frame's obstacle configs (their number and order
            stay; later frames give the same obstacles at other poses).
    """

    def __init__(self, ax, obstacles, box, view: str = "3d"):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        self.box = box
        self.towards = camera_direction(view)
        self.shown: list = [None] * len(obstacles)
        self.artists = []
        for o in obstacles:
            artist = Poly3DCollection(np.zeros((0, 3, 3)))
            artist.set_label(o.name or o.type)
            artist.set_gid(f"obstacle:{o.type}")
            ax.add_collection3d(artist, autolim=False)
            self.artists.append(artist)
        self.update(obstacles)

    def update(self, obstacles) -> list:
        """Show ``obstacles`` (configs in the order given at creation); returns
        the artists whose polygons changed."""
        if len(obstacles) != len(self.artists):
            raise ValueError(f"{len(obstacles)} obstacles given, {len(self.artists)} drawn")
        ranks = _depth_ranks(obstacles, self.towards)
        changed = []
        for k, (o, artist) in enumerate(zip(obstacles, self.artists)):
            if self.shown[k] is not None and self.shown[k] == o:
                continue
            self.shown[k] = o
            style = _obstacle_style(o, self.box, self.towards)
            if style is None:
                artist.set_verts([])
                artist.set_facecolor(np.zeros((0, 4)))
            else:
                polygons, faces, edges, width, zorder = style
                artist.set_verts(polygons)
                artist.set_facecolor(faces)
                artist.set_edgecolor(edges)
                artist.set_linewidth(width)
                artist.set_zorder(zorder)
            changed.append(artist)
        for k, rank in ranks.items():             # a moved solid may change places
            self.artists[k].set_zorder(Z_ORDER['solid'] + 0.01 * rank)
        return changed


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
