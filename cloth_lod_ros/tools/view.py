"""``cloth-lod view``: an animation of a recorded bag or of a headless run.

    cloth-lod view BAG_OR_SCENE [--out anim.gif] [--fps 15] [--duration S] [--level L]
                   [--set key=value ...] [--every N] [--size WxH] [--view 3d|top|side]

* A bag (a directory or an ``.mcap`` file): every recorded ``cloth/markers``
  frame (or every N-th).  The ``surface`` marker gives the triangle corners and,
  through its colours, each face's level (:func:`~cloth_lod_ros.messages.markers.surface_levels`;
  a session recorded with ``colour_by: shading`` falls back to the level implied
  by each triangle's area); the ``grasps`` marker the closed grasps; the time is
  ``sim_time_s`` of the ``cloth/lod_stats`` message of the same frame; the
  obstacles and the colour scale come from the ``/cloth/session`` scene.
* A scene (built-in name or YAML file, with ``--level``/``--set`` as for
  ``cloth-lod run``): simulated headless, one frame every 1/fps simulated seconds
  from t = 0, so the animation plays in real time.

Frames are drawn with the helpers of :mod:`~cloth_lod_ros.tools.plotting` (the
still pictures' palette and obstacles) on one reused figure, with fixed axes
over the whole animation, and written as a GIF (matplotlib's PillowWriter) or,
when ffmpeg is installed, an MP4.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .plotting import (VIEWS, ClothArtists, ClothFrame, draw_obstacles, frame_from_sim,
                       level_colorbar, setup_axes, view_box)

__all__ = ["Animation", "animation_from_bag", "animation_from_scene", "write_animation",
           "is_bag", "parse_size", "add_arguments", "run"]

FORMATS = (".gif", ".mp4")
ZOOM = 1.05


@dataclass
class Animation:
    """Frames to draw and what stays the same in all of them.

    Attributes:
        name: scene name (titles, default output name).
        frames: :class:`~cloth_lod_ros.tools.plotting.ClothFrame` list, in order.
        obstacles: obstacle configs (:class:`~cloth_lod_ros.sim.config.ObstacleConfig`).
        max_level: top of the level colour scale (None: one cloth colour).
        source_frames: frames available before ``--every`` (bag: recorded markers).
        stopped: why the frames end early (a simulation error), or None.
    """

    name: str
    frames: list[ClothFrame] = field(default_factory=list)
    obstacles: tuple = ()
    max_level: int | None = None
    source_frames: int = 0
    stopped: str | None = None


def is_bag(argument: str) -> bool:
    """A bag is a directory or an ``.mcap`` file; anything else names a scene."""
    path = Path(argument)
    return path.is_dir() or path.suffix == ".mcap"


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` in pixels, e.g. ``"480x360"``.

    Raises:
        ValueError: not two integers between 64 and 4096 joined by ``x``.
    """
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match:
        raise ValueError(f"--size {text!r} must look like WIDTHxHEIGHT in pixels, e.g. 480x360")
    width, height = int(match.group(1)), int(match.group(2))
    if not (64 <= width <= 4096 and 64 <= height <= 4096):
        raise ValueError(f"--size {text!r}: width and height must be 64 to 4096 pixels")
    return width, height


def _title(name: str, t: float, triangles: int) -> str:
    return f"{name}   t = {t:.2f} s   {triangles} triangles"


# -- a headless run -----------------------------------------------------------------
def animation_from_scene(scene, fps: float, every: int = 1, progress=None) -> Animation:
    """Simulate ``scene`` for its duration, keeping a frame every 1/fps simulated
    seconds from t = 0 (at most one per step), then every ``every``-th of those.

    Args:
        scene: a validated :class:`~cloth_lod_ros.sim.config.SceneConfig`.
        progress: optional ``callable(str)`` for a progress line every 10 %.

    A :class:`~cloth_lod_ros.sim.SimulationError` ends the frames early
    (:attr:`Animation.stopped` says why).
    """
    from ..sim import ClothSim, SimulationError
    sim = ClothSim(scene)
    interval = 1.0 / fps
    frames = []

    def take():
        frames.append(frame_from_sim(sim, _title(scene.name, sim.time, sim.mesh.triangle_count)))

    take()
    next_time = interval
    steps = int(round(scene.simulation.duration / scene.simulation.time_step))
    report = max(steps // 10, 1)

    def callback(s, stats):
        nonlocal next_time
        if s.time >= next_time - 1e-9:
            take()
            while next_time <= s.time + 1e-9:
                next_time += interval
        if progress is not None and (stats.step_index + 1) % report == 0:
            progress(f"  simulated t = {s.time:.2f} s, {s.mesh.triangle_count} triangles")

    animation = Animation(scene.name, obstacles=tuple(scene.obstacles),
                          max_level=scene.cloth.level)      # as the node's markers
    try:
        sim.run(scene.simulation.duration, callback=callback)
    except SimulationError as exc:
        animation.stopped = str(exc)
    animation.source_frames = len(frames)
    animation.frames = frames[::every]
    return animation


# -- a recording --------------------------------------------------------------------
def _levels_from_area(corners: np.ndarray, scene) -> np.ndarray:
    """Levels implied by triangle areas: each bisection halves a base triangle's
    area (half a square block); right for strains well below 40 %."""
    cloth = scene.cloth
    base_area = 0.5 * (cloth.width / cloth.base_blocks[0]) ** 2
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                         corners[:, 2] - corners[:, 0]), axis=1)
    levels = np.round(np.log2(base_area / np.maximum(area, 1e-300)))
    return np.clip(levels, 0, cloth.level).astype(np.int64)


def _frame_from_markers(message, t: float, scene, name: str) -> ClothFrame | None:
    """The cloth frame a recorded ``MarkerArray`` shows (None: no surface marker)."""
    from ..messages.markers import ADD, SPHERE_LIST, TRIANGLE_LIST, surface_levels
    surface = grasps = None
    for marker in message.markers:
        if marker.action != ADD:
            continue
        if marker.ns == "surface" and marker.type == TRIANGLE_LIST:
            surface = marker
        elif marker.ns == "grasps" and marker.type == SPHERE_LIST:
            grasps = marker
    if surface is None:
        return None
    corners = np.array([(p.x, p.y, p.z) for p in surface.points], float).reshape(-1, 3, 3)
    colours = np.array([(c.r, c.g, c.b) for c in surface.colors[::3]], float).reshape(-1, 3)
    levels = None
    if len(colours) == len(corners):
        levels = surface_levels(corners, colours, scene.cloth.level)
    if levels is None:
        levels = _levels_from_area(corners, scene)
    points = np.array([(p.x, p.y, p.z) for p in grasps.points], float).reshape(-1, 3) \
        if grasps is not None else np.zeros((0, 3))
    return ClothFrame(corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3),
                      levels, t, points, title=_title(name, t, len(corners)))


def animation_from_bag(path, every: int = 1, duration: float | None = None) -> Animation:
    """The recorded ``cloth/markers`` frames of a bag (every ``every``-th, within
    the first ``duration`` seconds of the recording).

    Raises:
        BagError: not a readable bag, no session or no markers.
    """
    from ..bag.analysis import decode, read_session, topic_named
    from ..bag.rosbag import BagError, BagReader
    from ..sim.config import SceneError, scene_from_dict
    with BagReader(path) as reader:
        session = read_session(reader)
        try:
            scene = scene_from_dict(session["scene"])
        except (SceneError, KeyError, TypeError) as exc:
            raise BagError(f"{path}: the session's scene is unreadable ({exc})") from None
        markers_topic = topic_named(reader, "cloth/markers")
        if markers_topic is None or not reader.topics[markers_topic].message_count:
            raise BagError(f"{path}: no cloth/markers messages to show")
        stats_topic = topic_named(reader, "cloth/lod_stats")
        sim_times = {}                        # log time -> simulated time of that frame
        if stats_topic is not None:
            for m in reader.messages([stats_topic]):
                msg = decode(m.data, m.type_name)
                values = {kv.key: kv.value for kv in msg.status[0].values} if msg.status else {}
                if "sim_time_s" in values:
                    sim_times[m.time_ns] = float(values["sim_time_s"])
        animation = Animation(scene.name, obstacles=tuple(scene.obstacles),
                              max_level=scene.cloth.level)
        first_ns = None
        for index, m in enumerate(reader.messages([markers_topic])):
            first_ns = m.time_ns if first_ns is None else first_ns
            if duration is not None and (m.time_ns - first_ns) * 1e-9 > duration + 1e-9:
                break
            animation.source_frames += 1
            if index % every:
                continue
            t = sim_times.get(m.time_ns, (m.time_ns - first_ns) * 1e-9)
            frame = _frame_from_markers(decode(m.data, m.type_name), t, scene, scene.name)
            if frame is not None:
                animation.frames.append(frame)
    if not animation.frames:
        raise BagError(f"{path}: no cloth surface in the recorded cloth/markers")
    return animation


# -- drawing ------------------------------------------------------------------------
def check_output(path) -> str:
    """The writer for ``path``'s suffix: ``"pillow"`` (.gif) or ``"ffmpeg"`` (.mp4).

    Raises:
        ValueError: another suffix, or .mp4 without ffmpeg.
    """
    from matplotlib import animation
    suffix = Path(path).suffix.lower()
    if suffix == ".gif":
        return "pillow"
    if suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ValueError(f"cannot write {path}: MP4 needs ffmpeg, which is not installed; "
                             "write a GIF instead (--out anim.gif)")
        return "ffmpeg"
    raise ValueError(f"cannot write {path}: the animation must be a .gif (or .mp4 with "
                     "ffmpeg installed)")


def write_animation(path, animation: Animation, fps: float, size=(640, 480),
                    view: str = "3d", progress=None) -> int:
    """Draw every frame of ``animation`` on one figure and write ``path``.

    Returns:
        The number of frames written.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FFMpegWriter, PillowWriter

    if view not in VIEWS:
        raise ValueError(f"--view must be one of {', '.join(VIEWS)}, got {view!r}")
    writer_name = check_output(path)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    frames = animation.frames
    box = view_box([f.positions for f in frames], animation.obstacles)
    width, height = size
    dpi = 100
    fig = plt.figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    # Leave the right edge to the level colour bar (the axes' labels reach past it).
    rect = (0.0, 0.0, 1.0, 1.0) if animation.max_level is None else (-0.04, 0.0, 0.86, 1.0)
    ax = fig.add_axes(rect, projection="3d")
    setup_axes(ax, box, view, zoom=ZOOM)
    ax.tick_params(labelsize=7, pad=0)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.label.set_size(8)
    draw_obstacles(ax, animation.obstacles, box, view)
    cloth = ClothArtists(ax, animation.max_level, animation.obstacles, view, ambient=0.35,
                         edge_alpha=0.2, linewidth=0.25,
                         reach=float(np.linalg.norm(box[1] - box[0])), title_size=9)
    if animation.max_level is not None:
        bar_ax = fig.add_axes((0.92, 0.25, 0.02, 0.5))
        bar = level_colorbar(fig, None, animation.max_level, cax=bar_ax)
        bar.ax.tick_params(labelsize=7)
        bar.set_label("")
        bar.ax.set_title("level", fontsize=8)
    writer = PillowWriter(fps=fps) if writer_name == "pillow" else FFMpegWriter(fps=fps)
    report = max(len(frames) // 10, 1)
    with writer.saving(fig, str(path), dpi=dpi):
        for k, frame in enumerate(frames):
            cloth.update(frame)
            writer.grab_frame()
            if progress is not None and (k + 1) % report == 0:
                progress(f"  drew {k + 1} / {len(frames)} frames")
    plt.close(fig)
    return len(frames)


# -- the command --------------------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("source", metavar="BAG_OR_SCENE",
                        help="a bag (directory or .mcap) to animate, or a scene to simulate "
                             "(built-in name or YAML file)")
    parser.add_argument("--out", help="animation file, .gif (or .mp4 with ffmpeg); "
                                      "default out/<scene>.gif")
    parser.add_argument("--fps", type=float, default=15.0,
                        help="frames per second of the animation; a scene is sampled at this "
                             "rate of simulated time (default 15)")
    parser.add_argument("--duration", type=float,
                        help="seconds: a scene's simulated time, or the first seconds of a bag")
    parser.add_argument("--level", type=int, help="scene only: (maximum) refinement level")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="scene only: override a scene field (repeatable)")
    parser.add_argument("--every", type=int, default=1,
                        help="keep every N-th frame (default 1: all)")
    parser.add_argument("--size", default="640x480",
                        help="WIDTHxHEIGHT in pixels (default 640x480)")
    parser.add_argument("--view", default="3d", choices=tuple(VIEWS),
                        help="camera: 3d (default), top (looking down z) or side (looking along y)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args) -> int:
    """``cloth-lod view``: 0 on success, 3 if the simulation stopped early (the
    frames before are written); errors raise (the CLI turns them into exit 2)."""
    from ..sim import config
    if args.fps <= 0:
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    if args.every < 1:
        raise ValueError(f"--every must be at least 1, got {args.every}")
    if args.duration is not None and args.duration <= 0:
        raise ValueError(f"--duration must be > 0 s, got {args.duration}")
    size = parse_size(args.size)
    say = (lambda text: None) if args.quiet else (lambda text: print(text, flush=True))
    bag = is_bag(args.source)
    if bag and (args.level is not None or args.set):
        raise ValueError("--level and --set change a scene; a recorded bag is shown as it is")
    if not bag:
        source = Path(args.source)
        if not source.exists() and len(source.parts) > 1 and source.suffix not in (".yaml", ".yml"):
            raise FileNotFoundError(f"{args.source}: no such bag directory, .mcap file "
                                    "or scene file")
        overrides = list(args.set or [])
        if args.level is not None:
            overrides.append(f"cloth.level={args.level}")
        if args.duration is not None:
            overrides.append(f"simulation.duration={args.duration}")
        scene = config.load_scene(args.source, overrides)
    name = Path(args.source).name.removesuffix(".mcap") if bag else scene.name
    out = Path(args.out) if args.out else Path("out") / f"{name}.gif"
    check_output(out)                                  # fail before the work
    start = time.perf_counter()
    if bag:
        animation = animation_from_bag(args.source, args.every, args.duration)
        say(f"{args.source}: {animation.source_frames} recorded frames, drawing "
            f"{len(animation.frames)}")
    else:
        say(f"simulating {scene.name} for {scene.simulation.duration:g} s, a frame every "
            f"{1 / args.fps:.3g} s")
        animation = animation_from_scene(scene, args.fps, args.every, say)
    count = write_animation(out, animation, args.fps, size, args.view, say)
    wall = time.perf_counter() - start
    span = animation.frames[-1].time - animation.frames[0].time
    speed = (f", {span / ((count - 1) / args.fps):.2g}x real time"
             if count > 1 and span > 0 else "")
    print(f"  wrote {out}: {count} frames at {args.fps:g} fps ({count / args.fps:.1f} s"
          f"{speed}), {size[0]}x{size[1]}, {out.stat().st_size / 1e3:.0f} kB, "
          f"in {wall:.1f} s")
    if animation.stopped:
        import sys
        print(f"cloth-lod: simulation stopped: {animation.stopped}", file=sys.stderr)
        return 3
    return 0
