"""Pictures of a cloth state (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["render_cloth"]


def render_cloth(path, positions: np.ndarray, triangles: np.ndarray,
                 levels: np.ndarray | None = None, pinned: np.ndarray | None = None,
                 title: str = "") -> None:
    """Write a PNG of the cloth surface.

    Faces are shaded by their normal against a fixed light (so folds read),
    and tinted by refinement level when ``levels`` has more than one value.

    Args:
        path: output PNG path.
        positions: ``(n, 3)`` particle positions, m.
        triangles: ``(t, 3)`` vertex indices.
        levels: ``(t,)`` bisection level per triangle (optional).
        pinned: ``(k,)`` indices of held particles, drawn as markers.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

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
    colours = np.clip(base * shade[:, None], 0, 1)

    fig = plt.figure(figsize=(6, 6), dpi=110)
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(corners, facecolors=colours,
                                         edgecolors=(0, 0, 0, 0.25), linewidths=0.3))
    if pinned is not None and len(pinned):
        p = positions[pinned]
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], color="crimson", s=30, depthshade=False)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
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
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
