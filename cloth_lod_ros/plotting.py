"""Pictures of a cloth state (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["render_cloth", "render_frames"]


def _face_colours(positions, triangles, levels):
    import matplotlib.pyplot as plt
    corners = positions[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    light = np.array([0.3, -0.5, 0.8])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.abs(normals @ light)
    if levels is not None and len(np.unique(levels)) > 1:
        cmap = plt.get_cmap("viridis")
        span = max(int(levels.max() - levels.min()), 1)
        base = cmap((levels - levels.min()) / span)[:, :3]
    else:
        base = np.tile([0.85, 0.45, 0.25], (len(triangles), 1))
    return corners, np.clip(base * shade[:, None], 0, 1)


def _draw(ax, positions, triangles, levels, pinned, bounds, title):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    corners, colours = _face_colours(positions, triangles, levels)
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


def render_frames(path, frames, pinned: np.ndarray | None = None) -> None:
    """Write a PNG with one 3-D panel per frame, on common axes.

    Args:
        frames: list of ``(positions (n,3), triangles (t,3), levels (t,) or None,
            title)``.
        pinned: indices of held particles (same in every frame), or None.
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
        _draw(ax, positions, triangles, levels, pinned, bounds, title)
    fig.subplots_adjust(left=0.02, right=0.95, bottom=0.05, top=0.98, wspace=0.1)
    fig.savefig(path)
    plt.close(fig)
