"""``cloth-lod view``: a video of a recorded bag or of a headless run.

    cloth-lod view BAG_OR_SCENE [--out video.mp4|anim.gif|sheet.png] [--fps 15]
                   [--speed 1] [--duration S] [--size WxH] [--view 3d|top|side]
                   [--tiles N] [--level L] [--set key=value ...] [--quiet]

* A bag (a directory or an ``.mcap`` file): frames chosen by the bag's log
  time at ``--fps`` (:mod:`~cloth_lod_ros.tools.view_bag`), so the video lasts
  as long as the session (divided by ``--speed``); obstacles at their recorded
  pose in each frame, closed grasps, faces coloured by level.  The bag is read
  twice, message by message: once for the time span and the axes' extent,
  once to draw.  A recorded frame is parsed only if it is shown.
* A scene (built-in name or YAML file, with ``--level``/``--set`` as for
  ``cloth-lod run``): simulated headless, one frame every ``speed/fps``
  simulated seconds from t = 0.

The format follows the output's suffix: ``.mp4`` (H.264 through the ffmpeg
that the ``imageio-ffmpeg`` package ships; the default when it is installed),
``.gif`` (fallback: at most 10 frames per second, 400x300 unless ``--size``,
64 colours per frame, only the changed rectangle of each frame stored) or
``.png`` (a contact sheet of ``--tiles`` frames evenly spaced in time).

Every frame is drawn on one reused matplotlib figure (artists updated in place,
the Agg canvas's RGBA buffer handed to the encoder) and written at once; no
more than one picture is held (GIF: two, the contact sheet: its tiles).
"""

from __future__ import annotations

import re
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .plotting import (VIEWS, ClothArtists, ClothFrame, ObstacleArtists, frame_from_sim,
                       level_colorbar, setup_axes, view_box)

__all__ = ["Animation", "animation_from_scene", "Renderer", "open_writer", "output_format",
           "ffmpeg_available", "is_bag", "parse_size", "add_arguments", "run"]

FORMATS = (".mp4", ".gif", ".png")
DEFAULT_SIZE = {"mp4": (640, 480), "gif": (400, 300), "png": (320, 240)}
GIF_MAX_FPS = 10.0
GIF_COLOURS = 64
ZOOM = 1.05


@dataclass
class Animation:
    """Frames of a headless run and what stays the same in all of them.

    Attributes:
        name: scene name (titles, default output name).
        frames: :class:`~cloth_lod_ros.tools.plotting.ClothFrame` list, in
            order, one every ``speed/fps`` simulated seconds (each with the
            obstacles where they were).
        obstacles: obstacle configs at the start.
        max_level: top of the level colour scale (None: one cloth colour).
        stopped: why the frames end early (a simulation error), or None.
    """

    name: str
    frames: list[ClothFrame] = field(default_factory=list)
    obstacles: tuple = ()
    max_level: int | None = None
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
def animation_from_scene(scene, fps: float, speed: float = 1.0, progress=None) -> Animation:
    """Simulate ``scene`` for its duration, keeping a frame every ``speed/fps``
    simulated seconds from t = 0 (at most one per step).

    Args:
        scene: a validated :class:`~cloth_lod_ros.sim.scene.config.SceneConfig`.
        progress: optional ``callable(str)`` for a progress line every 10 %.

    A :class:`~cloth_lod_ros.sim.SimulationError` ends the frames early
    (:attr:`Animation.stopped` says why).
    """
    from ..sim import ClothSim, SimulationError
    sim = ClothSim(scene)
    interval = speed / fps
    frames = []

    def take():
        frames.append(frame_from_sim(sim, _title(scene.name, sim.time, sim.mesh.triangle_count)))

    take()
    taken = 1
    steps = int(round(scene.simulation.duration / scene.simulation.time_step))
    report = max(steps // 10, 1)

    def callback(s, stats):
        nonlocal taken
        if s.time >= taken * interval - 1e-9:
            take()
            while taken * interval <= s.time + 1e-9:
                taken += 1
        if progress is not None and (stats.step_index + 1) % report == 0:
            progress(f"  simulated t = {s.time:.2f} s, {s.mesh.triangle_count} triangles")

    animation = Animation(scene.name, obstacles=tuple(scene.obstacles),
                          max_level=scene.cloth.level)      # as the node's markers
    try:
        sim.run(scene.simulation.duration, callback=callback)
    except SimulationError as exc:
        animation.stopped = str(exc)
    animation.frames = frames
    return animation


# -- drawing ------------------------------------------------------------------------
class Renderer:
    """One figure, drawn again for every frame.

    The axes, the colour bar and the obstacles are made once; a frame moves the
    obstacles that moved (:class:`~cloth_lod_ros.tools.scene3d.ObstacleArtists`)
    and replaces the cloth's polygons and colours
    (:class:`~cloth_lod_ros.tools.plotting.ClothArtists`).  What does not
    change - axes, ticks, labels, colour bar, planes seen from above - is drawn
    once and kept as a background (Agg ``copy_from_bbox``); each frame restores
    it and draws only the cloth, grasps, title and solid obstacles on it, in
    their drawing order (blitting; drawing the 3-D axes is most of a full
    draw).  The Agg canvas's RGBA buffer is returned as it is (no PNG round
    trip).  The background is drawn again when a plane moves.

    Args:
        size: ``(width, height)`` pixels; box: fixed axis limits ``(lo, hi)``, m.
        max_level: top of the level colour scale (None: no colour bar).
        obstacles: the obstacle configs of the first frame (the order stays).
    """

    def __init__(self, size, box, max_level: int | None, obstacles, view: str = "3d"):
        import matplotlib
        matplotlib.use("Agg")
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        if view not in VIEWS:
            raise ValueError(f"--view must be one of {', '.join(VIEWS)}, got {view!r}")
        width, height = size
        dpi = 100
        self.size = (width, height)
        self.figure = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.figure)
        font = max(0.6, min(width / 640, height / 480))      # text scaled with the picture
        # Leave the right edge to the level colour bar (the axes' labels reach past it).
        rect = (0.0, 0.0, 1.0, 1.0) if max_level is None else (-0.04, 0.0, 0.86, 1.0)
        ax = self.figure.add_axes(rect, projection="3d")
        setup_axes(ax, box, view, zoom=ZOOM)
        ax.tick_params(labelsize=7 * font, pad=0)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.label.set_size(8 * font)
        self.axes = ax
        self.obstacles = ObstacleArtists(ax, tuple(obstacles), box, view)
        self.cloth = ClothArtists(ax, max_level, obstacles, view, ambient=0.35,
                                  edge_alpha=0.2, linewidth=0.25,
                                  reach=float(np.linalg.norm(box[1] - box[0])),
                                  title_size=9 * font)
        if max_level is not None:
            bar_ax = self.figure.add_axes((0.92, 0.25, 0.02, 0.5))
            bar = level_colorbar(self.figure, None, max_level, cax=bar_ax)
            bar.ax.tick_params(labelsize=7 * font)
            bar.set_label("")
            bar.ax.set_title("level", fontsize=8 * font)

        self._background = None

    def _moving(self) -> list:
        """The artists drawn on the background each frame, in drawing order."""
        from .scene3d import Z_ORDER
        cloth = self.cloth
        artists = [a for a in self.obstacles.artists if a.get_zorder() >= Z_ORDER["hidden"]]
        artists += [cloth.behind, cloth.front, cloth.pins, cloth.grasps]
        return sorted(artists, key=lambda a: a.get_zorder()) + [cloth.title]

    def draw(self, frame: ClothFrame) -> np.ndarray:
        """``(height, width, 4)`` uint8 RGBA picture of ``frame``: a view of the
        canvas's buffer, valid until the next call."""
        changed = self.obstacles.update(frame.obstacles) if frame.obstacles is not None else []
        self.cloth.update(frame)
        moving = self._moving()
        if self._background is None or any(a.get_gid() == "obstacle:plane" for a in changed):
            for a in moving:
                a.set_visible(False)
            self.canvas.draw()
            self._background = self.canvas.copy_from_bbox(self.figure.bbox)
            for a in moving:
                a.set_visible(True)
        else:
            self.canvas.restore_region(self._background)
        renderer = self.canvas.get_renderer()
        for artist in moving:
            if hasattr(artist, "do_3d_projection"):
                artist.do_3d_projection()      # with the axes' projection of the first draw
            artist.draw(renderer)
        return np.asarray(self.canvas.buffer_rgba())


# -- writing ------------------------------------------------------------------------
def ffmpeg_available() -> bool:
    """Whether ``imageio-ffmpeg`` (with its own ffmpeg binary) is installed."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def output_format(path) -> str:
    """``"mp4"``, ``"gif"`` or ``"png"`` from ``path``'s suffix.

    Raises:
        ValueError: another suffix, or .mp4 without imageio-ffmpeg.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"cannot write {path}: the output must be a .mp4 video, a .gif "
                         "animation or a .png contact sheet")
    if suffix == ".mp4" and not ffmpeg_available():
        raise ValueError(f"cannot write {path}: MP4 needs the imageio-ffmpeg package "
                         "(pip install imageio-ffmpeg, or the package's [viewer] extra); "
                         "write a GIF instead (--out anim.gif)")
    return suffix[1:]


class _Mp4:
    """H.264 (yuv420p, CRF 23) through imageio-ffmpeg's ffmpeg, fed raw RGBA frames
    on a pipe: ffmpeg encodes in its own process while the next frame is drawn."""

    def __init__(self, path, size, fps: float):
        import imageio_ffmpeg
        self._gen = imageio_ffmpeg.write_frames(
            str(path), size, pix_fmt_in="rgba", fps=fps, codec="libx264", quality=None,
            macro_block_size=2,                      # yuv420p needs even sides (checked)
            output_params=["-crf", "23", "-preset", "medium", "-movflags", "+faststart"])
        self._gen.send(None)

    def write(self, rgba: np.ndarray) -> None:
        self._gen.send(rgba)

    def close(self) -> None:
        self._gen.close()


class _Gif:
    """An animated GIF (GIF89a) written frame by frame.

    Each frame is quantised to its own palette of ``colours`` (a local colour
    table) without dithering, and only the rectangle that differs from the
    previous frame is stored, drawn over it (disposal 1, "do not dispose").  A
    frame equal to the previous one lengthens its delay instead.  Delays are in
    centiseconds, rounded so that their sum stays within 1 cs of ``k / fps``.
    Holds two pictures: the last one written and the one waiting for its delay.
    """

    def __init__(self, path, size, fps: float, colours: int = GIF_COLOURS):
        self._file = open(path, "wb")
        self.fps, self.colours = fps, colours
        self.count = 0
        self._previous = None              # (h, w, 3) RGB of the last frame
        self._waiting = None               # [encoded chunks, delay cs]
        width, height = size
        # Header, logical screen (no global colour table), loop forever.
        self._file.write(b"GIF89a" + struct.pack("<HHBBB", width, height, 0, 0, 0))
        self._file.write(b"!\xff\x0bNETSCAPE2.0\x03\x01" + struct.pack("<H", 0) + b"\x00")

    def _delay(self) -> int:
        k = self.count
        return round(100 * (k + 1) / self.fps) - round(100 * k / self.fps)

    def write(self, rgba: np.ndarray) -> None:
        from PIL import GifImagePlugin, Image
        rgb = np.array(rgba[:, :, :3])                      # a copy: the buffer is reused
        delay = self._delay()
        self.count += 1
        if self._previous is None:
            top, left, bottom, right = 0, 0, rgb.shape[0], rgb.shape[1]
        else:
            changed = np.any(rgb != self._previous, axis=2)
            rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            if not len(rows):
                self._waiting[1] += delay
                return
            top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        self._flush()
        image = Image.fromarray(rgb[top:bottom, left:right]).quantize(
            colors=self.colours, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
        chunks = GifImagePlugin.getdata(image, (int(left), int(top)), include_color_table=True)
        self._waiting = [b"".join(chunks), delay]
        self._previous = rgb

    def _flush(self) -> None:
        if self._waiting is not None:
            data, delay = self._waiting
            # Graphic control extension: disposal 1, the delay, no transparency.
            self._file.write(b"!\xf9\x04" + struct.pack("<BHBB", 1 << 2, delay, 0, 0) + data)
            self._waiting = None

    def close(self) -> None:
        self._flush()
        self._file.write(b";")
        self._file.close()


class _Sheet:
    """A PNG contact sheet: ``tiles`` pictures in rows of ``columns``."""

    def __init__(self, path, size, tiles: int, columns: int = 4):
        self.path, self.size = path, size
        self.columns = min(columns, tiles)
        rows = -(-tiles // self.columns)
        width, height = size
        self.sheet = np.full((rows * height, self.columns * width, 3), 255, np.uint8)
        self.count = 0

    def write(self, rgba: np.ndarray) -> None:
        width, height = self.size
        row, col = divmod(self.count, self.columns)
        self.sheet[row * height:(row + 1) * height, col * width:(col + 1) * width] = \
            rgba[:, :, :3]
        self.count += 1

    def close(self) -> None:
        from PIL import Image
        Image.fromarray(self.sheet).save(self.path, optimize=True)


def open_writer(path, kind: str, size, fps: float, tiles: int = 12):
    """A writer (``write(rgba)``, ``close()``) of format ``kind`` to ``path``."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if kind == "mp4":
        return _Mp4(path, size, fps)
    if kind == "gif":
        return _Gif(path, size, fps)
    return _Sheet(path, size, tiles)


@dataclass
class _Costs:
    """Wall time spent per stage, s, and frames drawn and written."""

    read: float = 0.0
    draw: float = 0.0
    write: float = 0.0
    drawn: int = 0
    written: int = 0

    def text(self) -> str:
        n = max(self.written, 1)
        return (f"per frame: read {1e3 * self.read / n:.1f} ms, draw "
                f"{1e3 * self.draw / max(self.drawn, 1):.1f} ms ({self.drawn} drawn), "
                f"encode {1e3 * self.write / n:.1f} ms")


def _write_frames(frames, renderer: Renderer, writer, total: int, say) -> _Costs:
    """Draw each frame of the iterator ``frames`` and write it at once; a frame
    that is the same object as the previous one is written again undrawn."""
    costs = _Costs()
    report = max(total // 10, 1)
    last, picture = None, None
    clock = time.perf_counter()
    for frame in frames:
        now = time.perf_counter()
        costs.read += now - clock
        if frame is not last:
            picture = renderer.draw(frame)
            last = frame
            costs.drawn += 1
        clock = time.perf_counter()
        costs.draw += clock - now
        writer.write(picture)
        now, clock = clock, time.perf_counter()
        costs.write += clock - now
        costs.written += 1
        if costs.written % report == 0:
            say(f"  wrote {costs.written} / {total} frames")
    start = time.perf_counter()
    writer.close()
    costs.write += time.perf_counter() - start
    return costs


# -- the command --------------------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("source", metavar="BAG_OR_SCENE",
                        help="a bag (directory or .mcap) to show, or a scene to simulate "
                             "(built-in name or YAML file)")
    parser.add_argument("--out", help="output file: .mp4 (H.264, needs imageio-ffmpeg), .gif or "
                                      ".png (contact sheet); default out/<name>.mp4, or "
                                      ".gif without imageio-ffmpeg")
    parser.add_argument("--fps", type=float, default=15.0,
                        help="frames per second of the video (default 15; a GIF has at most "
                             f"{GIF_MAX_FPS:g})")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="playback speed: 1 = as recorded (the bag's log time) or "
                             "simulated, 2 = twice as fast (default 1)")
    parser.add_argument("--duration", type=float,
                        help="seconds: the first seconds of a bag, or a scene's simulated time")
    parser.add_argument("--size", help="WIDTHxHEIGHT in pixels (default 640x480 for MP4, "
                                       "400x300 for GIF, 320x240 per contact-sheet tile)")
    parser.add_argument("--view", default="3d", choices=tuple(VIEWS),
                        help="camera: 3d (default), top (looking down z) or side (looking along y)")
    parser.add_argument("--tiles", type=int, default=12,
                        help="pictures on a .png contact sheet (default 12, in rows of 4)")
    parser.add_argument("--level", type=int, help="scene only: (maximum) refinement level")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="scene only: override a scene field (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _output(args, name: str, say) -> tuple[Path, str]:
    if args.out:
        return Path(args.out), output_format(args.out)
    if ffmpeg_available():
        return Path("out") / f"{name}.mp4", "mp4"
    say("imageio-ffmpeg is not installed: writing a GIF (pip install imageio-ffmpeg, or the "
        "[viewer] extra, for a smaller MP4)")
    return Path("out") / f"{name}.gif", "gif"


def _evenly(count: int, span_ns: int):
    """``count`` offsets from 0 to ``span_ns`` inclusive, evenly spaced, ns."""
    if count == 1:
        return [0]
    return [int(round(i * span_ns / (count - 1))) for i in range(count)]


def run(args) -> int:
    """``cloth-lod view``: 0 on success, 3 if the simulation stopped early (the
    frames before are written); errors raise (the CLI turns them into exit 2)."""
    from ..sim.scene import config
    for option, value in (("--fps", args.fps), ("--speed", args.speed)):
        if not value > 0:
            raise ValueError(f"{option} must be > 0, got {value}")
    if args.duration is not None and args.duration <= 0:
        raise ValueError(f"--duration must be > 0 s, got {args.duration}")
    if args.tiles < 1:
        raise ValueError(f"--tiles must be at least 1, got {args.tiles}")
    size = parse_size(args.size) if args.size else None
    say = (lambda text: None) if args.quiet else (lambda text: print(text, flush=True))
    bag = is_bag(args.source)
    if bag and (args.level is not None or args.set):
        raise ValueError("--level and --set change a scene; a recorded bag is shown as it is")
    if not bag:
        source = Path(args.source)
        if not source.exists() and len(source.parts) > 1 and source.suffix not in (".yaml", ".yml"):
            raise FileNotFoundError(f"{args.source}: no such bag directory, .mcap file "
                                    "or scene file")
    name = Path(args.source).name.removesuffix(".mcap") if bag else None
    if not bag:
        overrides = list(args.set or [])
        if args.level is not None:
            overrides.append(f"cloth.level={args.level}")
        if args.duration is not None:
            overrides.append(f"simulation.duration={args.duration}")
        scene = config.load_scene(args.source, overrides)
        name = scene.name
    out, kind = _output(args, name, say)               # fail before the work
    size = size or DEFAULT_SIZE[kind]
    if kind == "mp4":
        size = (size[0] - size[0] % 2, size[1] - size[1] % 2)   # yuv420p: even sides
    fps = args.fps
    if kind == "gif" and fps > GIF_MAX_FPS:
        fps = GIF_MAX_FPS
        say(f"GIF: {GIF_MAX_FPS:g} frames per second (use .mp4 for {args.fps:g})")
    start = time.perf_counter()
    if bag:
        costs, count, video_s, session_s, stopped = _from_bag(args, out, kind, size, fps, say)
    else:
        costs, count, video_s, session_s, stopped = _from_scene(args, scene, out, kind, size,
                                                                fps, say)
    wall = time.perf_counter() - start
    length = (f"{video_s:.2f} s at {fps:g} fps for {session_s:.2f} s of "
              f"{'recording (bag log time)' if bag else 'simulated time'}"
              + (f", speed {args.speed:g}" if args.speed != 1 else "")
              if kind != "png" else f"{count} tiles over {session_s:.2f} s")
    say(f"  {costs.text()}")
    print(f"  wrote {out}: {count} frames, {length}, {size[0]}x{size[1]}, "
          f"{out.stat().st_size / 1e3:.0f} kB, in {wall:.1f} s")
    if stopped:
        import sys
        print(f"cloth-lod: simulation stopped: {stopped}", file=sys.stderr)
        return 3
    return 0


def _from_bag(args, out, kind, size, fps, say):
    from ..bag.rosbag import BagReader
    from .view_bag import bag_frames, frame_offsets, open_bag, scan
    duration_ns = None if args.duration is None else int(round(args.duration * 1e9))
    with BagReader(args.source) as reader:
        source = open_bag(reader)
        count = scan(reader, source, frame_offsets(fps, args.speed), duration_ns)
        session_s = (source.end_ns - source.start_ns) * 1e-9
        if kind == "png":
            count = min(args.tiles, source.recorded)
            offsets = _evenly(count, source.end_ns - source.start_ns)
        else:
            offsets = frame_offsets(fps, args.speed)
        say(f"{args.source}: {source.recorded} recorded frames over {session_s:.2f} s "
            f"(bag log time), drawing {count}")
        box = view_box([source.box_points], source.planes, extents=source.obstacle_extents)
        renderer = Renderer(size, box, source.scene.cloth.level, source.scene.obstacles,
                            args.view)
        writer = open_writer(out, kind, size, fps, count)
        frames = (frame for _, _, frame in bag_frames(reader, source, offsets, duration_ns))
        costs = _write_frames(frames, renderer, writer, count, say)
    return costs, costs.written, costs.written / fps, session_s, None


def _from_scene(args, scene, out, kind, size, fps, say):
    say(f"simulating {scene.name} for {scene.simulation.duration:g} s, a frame every "
        f"{args.speed / fps:.3g} s")
    animation = animation_from_scene(scene, fps, args.speed, say)
    frames = animation.frames
    if kind == "png":
        picks = np.unique(np.round(np.linspace(0, len(frames) - 1,
                                               min(args.tiles, len(frames)))).astype(int))
        frames = [frames[i] for i in picks]
    box = view_box([f.positions for f in frames], [o for f in frames for o in f.obstacles])
    renderer = Renderer(size, box, animation.max_level, animation.obstacles, args.view)
    writer = open_writer(out, kind, size, fps, len(frames))
    costs = _write_frames(iter(frames), renderer, writer, len(frames), say)
    span = frames[-1].time - frames[0].time
    return costs, len(frames), len(frames) / fps, span, animation.stopped
