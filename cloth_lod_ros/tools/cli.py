"""``cloth-lod``: the command-line tool.

    cloth-lod run SCENE [--duration S] [--dt H] [--level L] [--set key=value ...]
                        [--out state.npz] [--png picture.png] [--frames N] [--quiet]
                        [--foxglove [PORT]] [--foxglove-host HOST]   served live to Foxglove
    cloth-lod compare SCENE [--level L] [--duration S] [--set key=value ...] [--json F]
                      [--reference converged|same-step] [--mesh-check] ...
    cloth-lod scenes
    cloth-lod bench [SCENE] [--quick] ...        speed against error (cloth_lod_ros.tools.bench)
    cloth-lod stress [--quick] ...               hard-case stability suite (cloth_lod_ros.tools.stress)
    cloth-lod sweep SPEC.yaml [--workers N | --scheduler ADDR] [--resume] ...
                                                 many runs of a scene on Dask (tools.sweep)
    cloth-lod analyze BAG [--png F] [--json [F]] summary and plots of a recorded session
    cloth-lod replay BAG [--json [F]]            re-simulate a recording and compare
    cloth-lod recover BAG [--out DIR]            rebuild an interrupted recording
    cloth-lod play BAG [--rate R] [--loop] [--topics T ...]   republish (a ROS node)
    cloth-lod view BAG_OR_SCENE [--out video.mp4|anim.gif|sheet.png] [--fps 15] [--speed 1]
                   [--duration S] [--size WxH] [--view 3d|top|side] [--tiles N]
                   [--level L] [--set key=value ...]
                                                 a video of a bag (real speed, obstacles where
                                                 they were) or of a headless run (no ROS graph)

``run`` simulates headless and writes the final state (x, v, uv, mass,
triangles, time) and the per-step statistics to an ``.npz`` file, and a PNG of
the final cloth; with ``--bag DIR`` it also records the session as the node does.
The bag commands need the ROS wheels (``pip install ".[ros]"``).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# The simulator (numpy, scipy, numba: 1-3 s) and the bag code (PyYAML) are
# imported where they are used, after main() has printed what the kernels will
# cost (ros/startup.py).
if TYPE_CHECKING:
    from ..sim import ClothSim

__all__ = ["main", "save_state"]


def save_state(path: Path, sim: ClothSim) -> None:
    """Write the final state and every step's statistics to ``path`` (.npz).

    Keys: ``x`` (n,3) m, ``v`` (n,3) m/s, ``uv`` (n,2) m, ``mass`` (n,) kg,
    ``triangles`` (t,3), ``levels`` (t,), ``time`` s, ``pinned`` (k,) (the
    particles active pins hold, every particle of a patch), and
    ``stats_<field>`` (steps,) for each :class:`StepStats` field.
    """
    from ..sim import StepStats
    fields = StepStats.__dataclass_fields__
    stats = {f"stats_{name}": np.array([getattr(s, name) for s in sim.stats])
             for name in fields}
    if not sim.stats:                   # zero steps: empty arrays of the documented shapes
        kinds = {"int": np.int64, "bool": np.bool_, "float": np.float64}
        stats = {f"stats_{name}": np.zeros(0, kinds.get(getattr(f.type, "__name__", f.type),
                                                          np.float64))
                 for name, f in fields.items()}
        stats["stats_triangles_per_level"] = np.zeros((0, sim.max_level + 1), np.int64)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path, x=sim.positions, v=sim.velocities, uv=sim.rest_uv, mass=sim.masses,
        triangles=sim.triangles, levels=sim.triangle_levels, time=sim.time,
        pinned=np.concatenate([np.zeros(0, np.int64)]
                              + [p.vertices for p in sim.pins if p.active(sim.time)]),
        scene=sim.scene.name, **stats)


def _summary(sim: ClothSim, wall: float) -> str:
    st = sim.stats
    if not st:
        return (f"scene {sim.scene.name}: no steps taken (duration 0 s), the initial state "
                f"at t = {sim.time:.3f} s; {sim.mesh.vertex_count} particles, "
                f"{sim.mesh.triangle_count} triangles")
    it = np.array([s.cg_iterations for s in st])
    step_ms = np.array([s.step_ms for s in st])
    unconverged = sum(not s.converged for s in st)
    last = st[-1]
    lines = [
        f"scene {sim.scene.name}: {len(st)} steps of {sim.time_step * 1e3:.3g} ms to "
        f"t = {sim.time:.3f} s; {sim.mesh.vertex_count} particles, "
        f"{sim.mesh.triangle_count} triangles",
        f"  time per step: mean {step_ms.mean():.2f} ms, median {np.median(step_ms):.2f} ms "
        f"(forces {np.mean([s.force_ms for s in st]):.2f}, assembly "
        f"{np.mean([s.assembly_ms for s in st]):.2f}, solve "
        f"{np.mean([s.solve_ms for s in st]):.2f}); real-time factor "
        f"{sim.time / wall:.2f}",
        f"  solver {sim.scene.solver.method}"
        + (f" (ran: {'+'.join(sorted({s.solver for s in st}))})"
           if sim.scene.solver.method == "auto" else "")
        + f", {np.mean([s.solves for s in st]):.1f} solves per step"
        + (f" ({np.mean([s.factorisations for s in st]):.1f} factorisations)"
           if any(s.factorisations for s in st) else "")
        + ": CG iterations mean "
        f"{it.mean():.1f}, "
        f"max {it.max()}; worst residual {max(s.residual for s in st):.2e}; "
        f"{unconverged} unconverged step(s)",
        _lod_line(sim),
        *_self_collision_line(sim),
        f"  final energy [J]: kinetic {last.kinetic_energy:.4g}, stretch "
        f"{last.stretch_energy:.4g}, shear {last.shear_energy:.4g}, bend "
        f"{last.bend_energy:.4g}; max strain {last.max_strain:.4f}, max speed "
        f"{last.max_speed:.3f} m/s",
    ]
    return "\n".join(lines)


def _frame(sim: ClothSim, prefix: str = ""):
    from .plotting import frame_from_sim
    return frame_from_sim(sim, f"{prefix}t = {sim.time:.2f} s, "
                               f"{sim.mesh.triangle_count} triangles")


def _lod_line(sim: ClothSim) -> str:
    st = sim.stats
    if sim.hierarchy is None:
        return f"  uniform mesh at level {sim.max_level} (LOD off)"
    tris = np.array([s.triangle_count for s in st])
    share = 100 * sum(s.lod_ms for s in st) / max(sum(s.step_ms for s in st), 1e-12)
    return (f"  LOD (max level {sim.max_level}): {sum(s.refines for s in st)} splits, "
            f"{sum(s.merges for s in st)} merges; triangles mean {tris.mean():.0f}, "
            f"max {tris.max()}, final {tris[-1]}; {share:.1f} % of step time in LOD")


def _self_collision_line(sim: ClothSim) -> list[str]:
    """One line on self-collision (none when it is off): its share of the step
    time and how often each fail-safe fired."""
    sc = sim.self_collision
    if sc is None:
        return []
    st, c = sim.stats, sim.self_collision.counters
    ms = sum(s.self_collision_ms for s in st)
    share = 100 * ms / max(sum(s.step_ms for s in st), 1e-12)
    return [f"  self-collision: {ms / len(st):.2f} ms per step, {share:.1f} % of step time; "
            f"{c.with_pairs} of {c.attempts} integrator steps had layers in contact; "
            f"{c.resolves} re-solves, {c.refused} steps refused, {c.stopped} stopped zones, "
            f"{c.unresolved} unresolved; {c.lifted} split particles moved out"]


def _cmd_run(args) -> int:
    from ..sim.scene.config import load_scene
    overrides = list(args.set or [])
    if args.dt is not None:
        overrides.append(f"simulation.time_step={args.dt}")
    if args.level is not None:
        overrides.append(f"cloth.level={args.level}")
    if args.duration is not None:
        overrides.append(f"simulation.duration={args.duration}")
    scene = load_scene(args.scene, overrides)     # a scene over budget: refused in < 1 s
    _announce_pending()
    from ..sim import ClothSim, SimulationError
    live = None
    if args.foxglove is not None:       # before the simulator: a viewer can connect while it builds
        from ..live.run import LiveRun
        live = LiveRun(args.foxglove_host, args.foxglove)
    sim = ClothSim(scene)
    out = Path(args.out) if args.out else Path("out") / f"{scene.name}.npz"
    png = Path(args.png) if args.png else out.with_suffix(".png")
    steps = int(round(scene.simulation.duration / scene.simulation.time_step))
    report_every = max(steps // 10, 1)
    # Steps after which a picture panel is taken (the last one is the final state).
    frame_count = max(int(args.frames), 1)
    frame_steps = set(np.linspace(0, steps, frame_count).round().astype(int)[1:-1])
    frames = []
    if frame_count > 1 and steps > 0:          # zero steps: one panel, the initial state
        frames.append(_frame(sim))

    def progress(s, stats):
        if not args.quiet and (stats.step_index + 1) % report_every == 0:
            print(f"  t = {stats.time:6.3f} s  step {stats.step_ms:7.2f} ms  "
                  f"CG {stats.cg_iterations:4d}  KE {stats.kinetic_energy:.3e} J",
                  flush=True)
        if stats.step_index + 1 in frame_steps:
            frames.append(_frame(s))

    start = time.perf_counter()
    recording = _HeadlessRecording(args, sim, overrides, start) if args.bag else None
    callback = progress if recording is None else recording.wrap(progress)
    try:
        if live is not None:
            callback = live.start(sim, callback)    # waits for a viewer; paces to real time
            start = time.perf_counter()
        sim.run(scene.simulation.duration, callback=callback)
    except SimulationError as exc:
        print(f"cloth-lod: simulation stopped: {exc}", file=sys.stderr)
        save_state(out, sim)
        if live is not None:
            live.hold()
        return 3
    except KeyboardInterrupt:
        if live is None:
            raise
        live.close()
        print(f"cloth-lod: stopped at t = {sim.time:.3f} s", file=sys.stderr)
        return 130
    finally:
        if recording is not None:
            recording.close()
    wall = time.perf_counter() - start
    print(_summary(sim, wall))
    save_state(out, sim)
    print(f"  wrote {out}")
    if recording is not None:
        if recording.recorder.failed:
            print(f"cloth-lod: recording failed: {recording.recorder.failed}", file=sys.stderr)
            return 4
        print(f"  wrote {recording.recorder.path} ({recording.recorder.writer.message_count} "
              "messages)")
    if not args.no_png:
        from .plotting import render_frames
        frames.append(_frame(sim, f"{scene.name}, "))
        render_frames(png, frames, max_level=sim.max_level if sim.hierarchy is not None else None,
                      obstacles=scene.obstacles)
        print(f"  wrote {png}")
        if sim.hierarchy is not None:
            from .plotting import render_levels, render_lod_history
            levels_png = png.with_name(png.stem + "_levels.png")
            closed = [g for g in sim.grasps if g.closed]
            render_levels(levels_png, sim.positions, sim.triangles, sim.rest_uv,
                          sim.triangle_levels, sim.max_level,
                          title=f"{scene.name}: final mesh at t = {sim.time:.2f} s, "
                                f"{sim.mesh.triangle_count} triangles",
                          obstacles=sim.obstacle_configs(),      # where they are now
                          grasps=np.array([g.position for g in closed]).reshape(-1, 3),
                          grasp_uv=np.array([g.uv for g in closed]).reshape(-1, 2))
            history_png = png.with_name(png.stem + "_lod.png")
            render_lod_history(history_png, sim.stats,
                               title=f"{scene.name}: adaptive mesh over time")
            print(f"  wrote {levels_png}\n  wrote {history_png}")
    if live is not None:
        live.hold()
    return 0


class _HeadlessRecording:
    """``run --bag``: the node's output frames at ``--bag-rate`` Hz of simulated
    time, stamped start + simulated time (so ``play`` shows physical speed)."""

    def __init__(self, args, sim: ClothSim, overrides: list, wall_start: float):
        from ..bag.recorder import SessionRecorder
        from ..messages.frames import FrameBuilder
        self.sim = sim
        self.recorder = SessionRecorder(args.bag, "/", args.bag_compression,
                                        grasp_names=[g.name for g in sim.grasps])
        self.frames = FrameBuilder("world", 21)
        self.interval = 1.0 / args.bag_rate
        self.start_ns = time.time_ns()
        self.wall_start = wall_start
        self.next_time = 0.0
        self.recorded_step = -1               # sim.step_count of the last recorded frame
        self.recorder.start(sim, {"command": "cloth-lod run", "scene": args.scene,
                                  "overrides": overrides}, 21, self.start_ns)
        self._record()

    def _record(self) -> None:
        sim = self.sim
        wall = time.perf_counter() - self.wall_start
        t_ns = self.start_ns + int(round(sim.time * 1e9))
        values = {"paused": "false", "wall_time_s": f"{wall:.6f}",
                  "real_time_factor": f"{sim.time / max(wall, 1e-9):.3f}",
                  "recording": f"on: {self.recorder.path}"}
        self.recorder.record_frame(self.frames.build(sim, divmod(t_ns, 10**9), values), t_ns)
        self.recorded_step = sim.step_count
        self.next_time += self.interval

    def wrap(self, progress):
        def callback(sim, stats):
            progress(sim, stats)
            if sim.time >= self.next_time - 1e-9:
                self._record()
        return callback

    def close(self) -> None:
        if self.sim.step_count != self.recorded_step:
            self._record()                      # the final state, if not just recorded
        self.recorder.close()


def _cmd_compare(args) -> int:
    import json
    from .compare import compare_adaptive_uniform, format_comparison
    result = compare_adaptive_uniform(args.scene, level=args.level, duration=args.duration,
                                      overrides=args.set, grid=args.grid,
                                      candidate=args.candidate_set,
                                      baseline=args.baseline_set,
                                      reference=args.reference_set, mode=args.reference,
                                      reference_level=args.reference_level,
                                      reference_divisor=args.reference_divisor,
                                      mesh_check=args.mesh_check)
    print(format_comparison(result))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2))
        print(f"  wrote {args.json}")
    return 0


def _cmd_scenes(args) -> int:
    from ..sim.scene.config import builtin_scene_names, load_scene
    for name in builtin_scene_names():
        scene = load_scene(name)
        print(f"{name:24s} {scene.description}")
    return 0


def _write_json(result: dict, target: str) -> None:
    import json
    text = json.dumps(result, indent=2)
    if target == "-":
        print(text)
    else:
        Path(target).parent.mkdir(parents=True, exist_ok=True)
        Path(target).write_text(text)
        print(f"  wrote {target}")


def _cmd_analyze(args) -> int:
    from ..bag.analysis import analyze, format_analysis, plot_analysis
    result = analyze(args.bag)
    if args.json == "-":
        result.pop("series")
        _write_json(result, "-")
        return 0
    print(format_analysis(result))
    if not args.no_png:
        bag = Path(args.bag)
        png = Path(args.png) if args.png else bag.parent / f"{bag.stem}_analysis.png"
        print(f"  wrote {plot_analysis(result, png)}")
    if args.json:
        _write_json(result, args.json)
    return 0


def _cmd_replay(args) -> int:
    from ..bag.replay import format_replay, replay
    result = replay(args.bag)
    if args.json == "-":
        _write_json(result, "-")
    else:
        print(format_replay(result))
        if args.json:
            _write_json(result, args.json)
    return 0 if result["identical"] else 1


def _cmd_recover(args) -> int:
    from ..bag.rosbag import recover
    report = recover(args.bag, args.out)
    print(f"{report.output}: recovered {report.messages} messages on {report.topics} topics "
          f"from {report.chunks} complete chunks (reading stopped at: {report.stopped_because})")
    return 0


def _cmd_play(args) -> int:
    from ..ros.player import play
    return play(args.bag, rate=args.rate, loop=args.loop, topics=args.topics, delay=args.delay)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``cloth-lod`` parser.  With ``command``, the options of the other
    commands that live in their own modules (``view``, ``bench``, ``stress``,
    ``sweep``: each imports the simulator) are left out, so that ``run`` reads
    and checks its scene without waiting for those imports."""
    parser = argparse.ArgumentParser(prog="cloth-lod", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a scene headless and save the final state")
    run.add_argument("scene", help="built-in scene name or path to a scene YAML file")
    run.add_argument("--duration", type=float, help="simulated seconds (default: scene's)")
    run.add_argument("--dt", type=float, help="time step in seconds (default: scene's)")
    run.add_argument("--level", type=int, help="uniform refinement level")
    run.add_argument("--set", action="append", metavar="KEY=VALUE",
                     help="override a scene field, e.g. material.density=0.3 (repeatable)")
    run.add_argument("--out", help="state file (.npz), default out/<scene>.npz")
    run.add_argument("--png", help="picture of the final state, default beside --out")
    run.add_argument("--no-png", action="store_true", help="do not write a picture")
    run.add_argument("--frames", type=int, default=1,
                     help="panels in the picture, evenly spaced in time (default 1: final state)")
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.add_argument("--bag", metavar="DIR",
                     help="record the session to this rosbag2 MCAP bag directory (needs rclpy)")
    run.add_argument("--bag-rate", type=float, default=30.0,
                     help="frames recorded per simulated second (default 30)")
    run.add_argument("--foxglove", nargs="?", type=int, const=8765, metavar="PORT",
                     help="serve the run live to Foxglove (ws://localhost:PORT, default 8765; "
                          "0: any free port): waits for a viewer, runs in real time, then "
                          "shows the final state until Ctrl-C (needs the viewer extra)")
    run.add_argument("--foxglove-host", default="127.0.0.1", metavar="HOST",
                     help="address the live view listens on (default 127.0.0.1, this machine "
                          "only; 0.0.0.0 to watch from another machine)")
    run.add_argument("--bag-compression", default="zstd", choices=("none", "zstd", "lz4"),
                     help="MCAP chunk compression (default zstd)")
    run.set_defaults(func=_cmd_run)
    compare = sub.add_parser(
        "compare", help="adaptive vs uniform at the same level: time per step, and distance "
                        "from the converged motion")
    compare.add_argument("scene", help="built-in scene name or path to a scene YAML file")
    compare.add_argument("--level", type=int, help="maximum (adaptive) and uniform level")
    compare.add_argument("--duration", type=float, help="simulated seconds")
    compare.add_argument("--set", action="append", metavar="KEY=VALUE",
                         help="override a scene field in both runs (repeatable)")
    compare.add_argument("--candidate-set", action="append", metavar="KEY=VALUE",
                         help="override for the compared run only (default run: LOD on)")
    compare.add_argument("--baseline-set", action="append", metavar="KEY=VALUE",
                         help="override for the baseline run only (default run: LOD off, "
                              "same level and step)")
    compare.add_argument("--reference", choices=("converged", "same-step"), default="converged",
                         help="converged (default): both runs against the scene uniform at "
                              "--reference-level, sdirk2 at h/--reference-divisor, 3 Newton "
                              "iterations; same-step: the baseline is the reference (mesh "
                              "error only, labelled so)")
    compare.add_argument("--reference-set", action="append", metavar="KEY=VALUE",
                         help="override for the reference only: the converged runs, or with "
                              "--reference same-step the baseline run")
    compare.add_argument("--reference-level", type=int,
                         help="level of the converged reference (default: --level, the finest "
                              "compared)")
    compare.add_argument("--reference-divisor", type=int, default=8,
                         help="converged reference step h_ref = time_step / this (default 8); "
                              "a second run at 2 h_ref estimates its time error")
    compare.add_argument("--mesh-check", action="store_true",
                         help="also run the converged reference one level coarser (estimate "
                              "of its mesh error; about half the reference's cost)")
    compare.add_argument("--grid", type=int, default=21,
                         help="sample grid points per side (default 21)")
    compare.add_argument("--json", help="also write the result as JSON to this path")
    compare.set_defaults(func=_cmd_compare)
    scenes = sub.add_parser("scenes", help="list the built-in scenes")
    scenes.set_defaults(func=_cmd_scenes)
    analyze = sub.add_parser("analyze", help="summary and plots of a recorded session")
    analyze.add_argument("bag", help="bag directory or .mcap file")
    analyze.add_argument("--png", help="plot file (default <bag>_analysis.png beside the bag)")
    analyze.add_argument("--no-png", action="store_true", help="do not write the plot")
    analyze.add_argument("--json", nargs="?", const="-", metavar="PATH",
                         help="print the result as JSON (or write it to PATH)")
    analyze.set_defaults(func=_cmd_analyze)
    replay = sub.add_parser("replay", help="re-simulate a recorded session and compare")
    replay.add_argument("bag", help="bag directory or .mcap file")
    replay.add_argument("--json", nargs="?", const="-", metavar="PATH",
                        help="print the result as JSON (or write it to PATH)")
    replay.set_defaults(func=_cmd_replay)
    recover = sub.add_parser("recover", help="rebuild a valid bag from an interrupted one")
    recover.add_argument("bag", help="bag directory or .mcap file")
    recover.add_argument("--out", help="new bag directory (default <bag>_recovered)")
    recover.set_defaults(func=_cmd_recover)
    play = sub.add_parser("play", help="republish a recorded session with its original timing")
    play.add_argument("bag", help="bag directory or .mcap file")
    play.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1)")
    play.add_argument("--loop", action="store_true", help="start again at the end")
    play.add_argument("--delay", type=float, default=0.0,
                      help="seconds to wait for subscribers before the first message")
    play.add_argument("--topics", nargs="+", metavar="TOPIC",
                      help="only these topics (default: all recorded topics)")
    play.set_defaults(func=_cmd_play)
    for name, module_name, text in (
            ("view", "view", "a video (MP4, GIF or PNG contact sheet) of a recorded bag at "
                             "its real speed, or of a headless run of a scene"),
            ("bench", "bench", "speed against error from the converged motion: integrators "
                               "x uniform levels and the adaptive mesh"),
            ("stress", "stress", "hard-case stability suite: one table, pass/fail"),
            ("sweep", "sweep", "many runs of a scene (grids, lists, random draws) on Dask: "
                               "one folder per run and one table")):
        subparser = sub.add_parser(name, help=text)
        if command is None or command == name:
            module = importlib.import_module(f"cloth_lod_ros.tools.{module_name}")
            module.add_arguments(subparser)
            subparser.set_defaults(func=module.run)
    return parser


#: Commands that build a simulator, and so need the compiled kernels.
SIMULATING = ("run", "compare", "bench", "stress", "replay", "view")
#: Of these, those that check their scene before the kernel line (a refused scene
#: prints one line only and never waits for numba's imports).
SCENE_FIRST = ("run",)
_pending: list = []


def _announce_pending() -> None:
    """Print the kernel line that :func:`main` deferred, if any."""
    while _pending:
        _pending.pop()()


def _simulates(argv: list[str]) -> bool:
    """Whether the command line asks for a simulation (``view`` of a bag does not)."""
    words = [a for a in argv if not a.startswith("-")]
    if not words or words[0] not in SIMULATING or {"-h", "--help"} & set(argv):
        return False
    if words[0] == "view" and len(words) > 1:
        target = Path(words[1])
        return not (target.suffix == ".mcap" or target.is_dir())
    return True


def main(argv: list[str] | None = None) -> int:
    """``cloth-lod``.  Run as a program (``argv`` None), a command that simulates
    first prints on stderr whether the compiled kernels are compiled (a
    machine's first start) or loaded, before the simulator's imports."""
    if argv is None:
        argv = sys.argv[1:]
        if _simulates(argv):
            from ..ros.startup import announce
            if [a for a in argv if not a.startswith("-")][0] in SCENE_FIRST:
                _pending.append(lambda: announce("cloth-lod"))
            else:
                announce("cloth-lod")
    logging.basicConfig(level=logging.WARNING, format="cloth-lod: %(levelname)s: %(message)s")
    words = [a for a in argv if not a.startswith("-")]
    args = build_parser(words[0] if words and words[0] in SCENE_FIRST else None).parse_args(argv)
    from ..bag.rosbag import BagError
    from ..sim.scene.config import SceneError
    try:
        return args.func(args)
    except SceneError as exc:
        print(f"cloth-lod: scene error: {exc}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"cloth-lod: error: {exc}", file=sys.stderr)
        return 2
    except BagError as exc:
        print(f"cloth-lod: bag error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
