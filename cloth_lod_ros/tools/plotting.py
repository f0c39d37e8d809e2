"""Pictures of a cloth state (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["render_cloth", "render_frames", "render_levels", "render_lod_history"]


def _face_colours(positions, triangles, levels, max_level=None):
    import matplotlib.pyplot as plt
    corners = positions[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    light = np.array([0.3, -0.5, 0.8])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.abs(normals @ light)
    if levels is not None and max_level is not None:
        # Absolute scale so that frames and pictures compare (as render_levels).
        cmap = plt.get_cmap("viridis", max_level + 1)
        base = cmap(levels / max(max_level, 1))[:, :3]
    elif levels is not None and len(np.unique(levels)) > 1:
        cmap = plt.get_cmap("viridis")
        span = max(int(levels.max() - levels.min()), 1)
        base = cmap((levels - levels.min()) / span)[:, :3]
    else:
        base = np.tile([0.85, 0.45, 0.25], (len(triangles), 1))
    return corners, np.clip(base * shade[:, None], 0, 1)


def _draw(ax, positions, triangles, levels, pinned, bounds, title, max_level=None):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    corners, colours = _face_colours(positions, triangles, levels, max_level)
    ax.add_collection3d(Poly3DCollection(corners, facecolors=colours,
                                         edgecolors=(0, 0, 0, 0.25), linewidths=0.3))
    if pinned is not None and len(pinned):
        p = positions[pinned]
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], color="crimson", s=30, depthshade=False)
    lo, hi = bounds
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-3)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.view_init(elev=18, azim=-60)
    if title:
        ax.text2D(0.5, 0.97, title, transform=ax.transAxes, ha="center", fontsize=10)


def render_cloth(path, positions: np.ndarray, triangles: np.ndarray,
                 levels: np.ndarray | None = None, pinned: np.ndarray | None = None,
                 title: str = "") -> None:
    """Write a PNG of the cloth surface.

    Faces are shaded by their normal against a fixed light (so folds read),
    and tinted by refinement level when ``levels`` has more than one value.

    Args:
        path: output PNG path (its directory is created).
        positions: ``(n, 3)`` particle positions, m.
        triangles: ``(t, 3)`` vertex indices.
        levels: ``(t,)`` bisection level per triangle (optional).
        pinned: ``(k,)`` indices of held particles, drawn as markers.
    """
    render_frames(path, [(positions, triangles, levels, title)], pinned)


def render_frames(path, frames, pinned: np.ndarray | None = None,
                  max_level: int | None = None) -> None:
    """Write a PNG with one 3-D panel per frame, on common axes.

    Args:
        frames: list of ``(positions (n,3), triangles (t,3), levels (t,) or None,
            title)``.
        pinned: indices of held particles (same in every frame), or None.
        max_level: colour faces by level on a fixed 0..max_level scale (adaptive
            runs); None shades a single colour (or a relative level tint).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    every = np.vstack([f[0] for f in frames])
    bounds = (every.min(axis=0), every.max(axis=0))
    fig = plt.figure(figsize=(5.5 * len(frames), 5.5), dpi=100)
    for k, (positions, triangles, levels, title) in enumerate(frames):
        ax = fig.add_subplot(1, len(frames), k + 1, projection="3d")
        _draw(ax, positions, triangles, levels, pinned, bounds, title, max_level)
    fig.subplots_adjust(left=0.02, right=0.95, bottom=0.05, top=0.98, wspace=0.1)
    fig.savefig(path)
    plt.close(fig)


def render_levels(path, positions: np.ndarray, triangles: np.ndarray, uv: np.ndarray,
                  levels: np.ndarray, max_level: int, title: str = "") -> None:
    """Final mesh coloured by bisection level: 3-D view and rest (u, v) view.

    Args:
        positions: ``(n, 3)`` m; uv: ``(n, 2)`` rest coordinates, m;
        triangles: ``(t, 3)``; levels: ``(t,)``; max_level: colour scale top.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cmap = plt.get_cmap("viridis", max_level + 1)
    colours = cmap(levels / max(max_level, 1))[:, :3]
    corners = positions[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.45 + 0.55 * np.abs(normals @ light)
    fig = plt.figure(figsize=(12, 5.5), dpi=100)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.add_collection3d(Poly3DCollection(corners, facecolors=colours * shade[:, None],
                                         edgecolors=(0, 0, 0, 0.3), linewidths=0.3))
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-3)
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.view_init(elev=18, azim=-60)
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.add_collection(PolyCollection(uv[triangles], facecolors=colours,
                                      edgecolors="k", linewidths=0.3))
    ax2.set_xlim(uv[:, 0].min(), uv[:, 0].max())
    ax2.set_ylim(uv[:, 1].min(), uv[:, 1].max())
    ax2.set_aspect("equal")
    ax2.set_xlabel("u [m]")
    ax2.set_ylabel("v [m]")
    ax2.set_title("rest (u, v) mesh", fontsize=10)
    mappable = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(-0.5, max_level + 0.5))
    bar = fig.colorbar(mappable, ax=ax2, ticks=range(max_level + 1), fraction=0.046)
    bar.set_label("level")
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
                  alpha=0.85, colors=plt.get_cmap("viridis", len(per_level))(
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
