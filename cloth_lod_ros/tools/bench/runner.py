"""``cloth-lod bench``: error against cost, uniform levels and adaptive thresholds.

Design §5.  For one scene (default ``hang_two_corners``, 2 s simulated):

* **Reference**: the uniform mesh at the finest level benchmarked, same time
  step.  It is also run once at half the step, and the distance between the
  two is reported, so the reader sees what "converged" means.
* **Runs**: the uniform mesh at each of ``--levels``; the adaptive mesh at each
  of ``--max-levels`` × ``--thresholds`` (refine threshold, m; the coarsen
  threshold keeps the scene's coarsen/refine ratio).  Each configuration runs
  ``--repeats`` times, each time in a fresh Python process pinned to one CPU
  with every BLAS/OpenMP pool limited to one thread.  Repeats are run in
  rounds (every configuration once, then again), so a burst of load from
  another process spreads over configurations instead of hitting one.
* **Error**: RMS and maximum 3-D distance from the reference at a fixed grid
  of material (u, v) points, as a fraction of the cloth's larger side, at
  ¼, ½ and all of the duration (0.5, 1 and 2 s by default) and **at rest**.
  "At rest" is the first time after the duration at which the reference's
  kinetic energy per unit mass has stayed below ``--rest-threshold`` (J/kg)
  for a whole ``--rest-window`` (s; longer than half a swing, so a turning
  point of the swing, where the kinetic energy passes through zero, does not
  count), or ``--rest-cap`` if that comes first (then the table says so).
  Every other run is sampled at that same time.
* **Cost** (over the first ``duration`` seconds only): wall seconds per
  simulated second (median and min–max over the repeats), CPU seconds per
  simulated second, vertex-steps, CG iterations, and the share of the step
  time spent in LOD operations (criterion, splits/merges, refresh of compact
  arrays: ``StepStats.lod_ms``).

Outputs in ``--out``: ``bench.csv`` and ``bench.json`` (the same rows; the
JSON adds the machine, the settings and per-repeat numbers), ``bench.png``
(error against cost, log–log) and ``bench.md`` (tables, the paper's
comparison, and a paragraph written from the numbers).  ``--from-json
bench.json`` rewrites the CSV, plot and summary of a finished run without
running anything.

Module API for the command line: :func:`add_arguments` and :func:`run`;
``python -m cloth_lod_ros.tools.bench`` works too.  Worker processes are started as
``python -m cloth_lod_ros.tools.bench --worker SPEC.json``.
"""


import argparse
import datetime as _dt
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time as _time
from pathlib import Path

import numpy as np

from .report import PAPER, _markdown, _plot, _time_tag, _write_csv
from .worker import run_spec_file

__all__ = ["add_arguments", "run", "main", "BenchError", "PAPER"]

DEFAULT_SCENE = "hang_two_corners"
FULL = dict(duration=2.0, levels=[2, 3, 4, 5, 6, 7, 8], max_levels=[6, 8],
            thresholds=[0.00025, 0.0005, 0.001, 0.002, 0.004], repeats=3,
            rest_threshold=1e-6, rest_window=1.0, rest_cap=20.0)
# --quick: a smoke test of the whole pipeline in well under a minute.  The
# cloth is not at rest by the cap; the table says so.
QUICK = dict(duration=0.5, levels=[2, 3, 4], max_levels=[4],
             thresholds=[0.001, 0.004], repeats=3,
             rest_threshold=1e-6, rest_window=0.25, rest_cap=1.0)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


class BenchError(RuntimeError):
    """Bad arguments or a failed worker; the message says which."""


def _package_root() -> str:
    """The directory that holds the ``cloth_lod_ros`` package (the repository root
    for a source tree), so workers import the same code as this process."""
    return str(Path(__file__).resolve().parents[3])


def _run_worker(spec: dict, workdir: Path, tag: str) -> dict:
    """Run ``spec`` in a fresh single-threaded process; return its result."""
    spec_path = workdir / f"{tag}.spec.json"
    result_path = workdir / f"{tag}.result.json"
    spec = dict(spec, result=str(result_path))
    spec_path.write_text(json.dumps(spec))
    env = dict(os.environ)
    for name in THREAD_VARIABLES:
        env[name] = "1"
    env["PYTHONPATH"] = os.pathsep.join(
        [_package_root()] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.bench", "--worker",
                           str(spec_path)], env=env, capture_output=True, text=True)
    if proc.returncode != 0 or not result_path.exists():
        tail = "\n".join(proc.stderr.strip().splitlines()[-15:])
        raise BenchError(f"worker {tag} failed (exit {proc.returncode}):\n{tail}")
    return json.loads(result_path.read_text())


# --------------------------------------------------------------------------
# Plan: configurations and their scene overrides.
# --------------------------------------------------------------------------

def _configurations(args, scene) -> list[dict]:
    """The configurations to run, reference first.

    Each is a dict with ``key`` (unique tag), ``kind`` (``reference``,
    ``half_step``, ``uniform``, ``adaptive``), ``level`` (uniform level or
    adaptive maximum), ``threshold``/``coarsen`` (m, adaptive only),
    ``time_step`` (s) and ``overrides``.
    """
    base = list(args.set or [])
    h = scene.simulation.time_step
    ref = args.reference_level
    uniform = lambda level: base + ["lod.enabled=false", f"cloth.level={level}"]  # noqa: E731
    configs = [dict(key=f"uniform_L{ref}", kind="reference", level=ref, threshold=None,
                    coarsen=None, time_step=h, overrides=uniform(ref))]
    if not args.no_half_step:
        configs.append(dict(key=f"uniform_L{ref}_half_step", kind="half_step", level=ref,
                            threshold=None, coarsen=None, time_step=h / 2,
                            overrides=uniform(ref) + [f"simulation.time_step={h / 2!r}"]))
    for level in sorted(set(args.levels) - {ref}):
        configs.append(dict(key=f"uniform_L{level}", kind="uniform", level=level,
                            threshold=None, coarsen=None, time_step=h,
                            overrides=uniform(level)))
    for level in sorted(set(args.max_levels)):
        for thr in sorted(set(args.thresholds)):
            coarsen = thr * args.coarsen_ratio
            configs.append(dict(
                key=f"adaptive_L{level}_{thr * 1e3:g}mm", kind="adaptive", level=level,
                threshold=thr, coarsen=coarsen, time_step=h,
                overrides=base + ["lod.enabled=true", f"cloth.level={level}",
                                  f"lod.refine_threshold={thr!r}",
                                  f"lod.coarsen_threshold={coarsen!r}"]))
    return configs


def _label(cfg: dict) -> str:
    if cfg["kind"] == "adaptive":
        return f"adaptive max L{cfg['level']}, {cfg['threshold'] * 1e3:g} mm"
    if cfg["kind"] == "half_step":
        return f"uniform L{cfg['level']}, h/2"
    suffix = " (reference)" if cfg["kind"] == "reference" else ""
    return f"uniform L{cfg['level']}{suffix}"


# --------------------------------------------------------------------------
# Rows: aggregate the repeats of one configuration.
# --------------------------------------------------------------------------

def _row(cfg: dict, runs: list[dict], reference: np.ndarray, times: list[float],
         side: float, points: np.ndarray) -> dict:
    """One table row: cost over the repeats and error of the first repeat.

    ``reference``: (k, m, 3) reference samples at ``times`` and at rest (m);
    ``points``: (m, 2) their material coordinates (m).
    """
    first = runs[0]
    sampled = np.asarray(first["samples"], dtype=float)
    sim_s = first["cost"]["simulated_s"]
    walls = np.array([r["cost"]["wall_s"] for r in runs]) / sim_s
    cpus = np.array([r["cost"]["cpu_s"] for r in runs]) / sim_s
    lod = np.array([r["cost"]["lod_ms"] / (1e3 * r["cost"]["wall_s"]) for r in runs])
    # Step time that StepStats gives to none of LOD, forces, assembly, solve
    # (energies and statistics; with LOD on also the criterion's force
    # evaluation on steps whose mesh then changed, which the solver redoes).
    other = np.array([1.0 - (r["cost"]["lod_ms"] + r["cost"]["force_ms"] + r["cost"]["assembly_ms"]
                             + r["cost"]["solve_ms"]) / r["cost"]["internal_step_ms"]
                      for r in runs])
    # The bench's clock around sim.step() against the step's own clock.
    overhead = np.array([1.0 - r["cost"]["internal_step_ms"] / (1e3 * r["cost"]["wall_s"])
                         for r in runs])
    c = first["cost"]
    row = dict(
        config=cfg["key"], label=_label(cfg), kind=cfg["kind"], level=cfg["level"],
        refine_threshold_m=cfg["threshold"], coarsen_threshold_m=cfg["coarsen"],
        time_step_s=cfg["time_step"], repeats=len(runs),
        wall_per_sim_s_median=float(np.median(walls)), wall_per_sim_s_min=float(walls.min()),
        wall_per_sim_s_max=float(walls.max()),
        cpu_per_sim_s_median=float(np.median(cpus)),
        ms_per_step_median=float(np.median(walls) * cfg["time_step"] * 1e3),
        lod_share_median=float(np.median(lod)),
        unattributed_share_median=float(np.median(other)),
        timing_overhead_share_max=float(overhead.max()),
        vertex_steps=c["vertex_steps"], triangle_steps=c["triangle_steps"],
        cg_iterations=c["cg_iterations"],
        cg_iterations_per_step=c["cg_iterations"] / c["steps"],
        solves_per_step=c.get("solves", c["steps"]) / c["steps"],
        solver="+".join(c.get("solvers", [])),
        unconverged_steps=c["unconverged_steps"],
        triangles_mean=c["triangles_mean"], triangles_max=c["triangles_max"],
        triangles_final=c["triangles_final"], splits=c["splits"], merges=c["merges"])
    # Same inputs, same single thread: every repeat must give the same cloth.
    deviation = 0.0
    for r in runs[1:]:
        other = np.asarray(r["samples"], dtype=float)
        n = min(len(other), len(sampled))
        deviation = max(deviation, float(np.abs(other[:n] - sampled[:n]).max()))
    row["repeat_max_deviation_m"] = deviation
    tags = [_time_tag(t) for t in times] + ["rest"]
    rms_all, worst_all = [], []
    for i, tag in enumerate(tags):
        dist = np.linalg.norm(sampled[i] - reference[i], axis=1)
        rms, worst = float(np.sqrt(np.mean(dist**2))), float(dist.max())
        row[f"rms_frac_{tag}"] = rms / side
        row[f"max_frac_{tag}"] = worst / side
        if tag != "rest":
            rms_all.append(rms)
            worst_all.append(worst)
    # One number for "during motion": the RMS over every point and sample time.
    row["rms_frac_motion"] = float(np.sqrt(np.mean(np.square(rms_all)))) / side
    row["max_frac_motion"] = max(worst_all) / side
    row["ke_per_mass_at_rest"] = first["ke_per_mass"][-1]
    # Where the cloth at rest is farthest from the reference, and which way.
    offset = sampled[-1] - reference[-1]
    worst = int(np.argmax(np.linalg.norm(offset, axis=1)))
    row["rest_worst_u_m"], row["rest_worst_v_m"] = (float(c) for c in points[worst])
    row["rest_worst_dx_m"], row["rest_worst_dy_m"], row["rest_worst_dz_m"] = (
        float(c) for c in offset[worst])
    # A run whose largest distance at rest is over twice its largest distance
    # while moving has settled into another shape (e.g. a fold that buckled
    # the other way), which is not "less accurate" in the usual sense.
    row["rest_other_shape"] = bool(row["max_frac_rest"] > 2.0 * row["max_frac_motion"])
    return row


# --------------------------------------------------------------------------
# Machine, outputs.
# --------------------------------------------------------------------------

def _machine(cpu: int) -> dict:
    import scipy
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=_package_root(),
                                capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                    cwd=_package_root(), capture_output=True, text=True,
                                    timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        commit, dirty = "", False
    return dict(cpu_model=model, logical_cpus=os.cpu_count(), pinned_cpu=cpu,
                platform=platform.platform(), python=platform.python_version(),
                numpy=np.__version__, scipy=scipy.__version__,
                date=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                git_commit=commit + ("+dirty" if dirty else ""),
                threads={name: "1" for name in THREAD_VARIABLES})


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``bench`` options to ``parser`` (for ``cloth-lod bench``)."""
    parser.add_argument("scene", nargs="?", default=DEFAULT_SCENE,
                        help=f"built-in scene name or YAML path (default {DEFAULT_SCENE})")
    parser.add_argument("--quick", action="store_true",
                        help="smoke test: short run, levels 2-4, under a minute")
    parser.add_argument("--repeats", type=int, help="timed runs per configuration (default 3)")
    parser.add_argument("--out", help="output directory (default out/bench)")
    parser.add_argument("--levels", type=int, nargs="+", metavar="L",
                        help="uniform levels (default 2 3 4 5 6 7 8; quick: 2 3 4)")
    parser.add_argument("--max-levels", type=int, nargs="+", metavar="L",
                        help="adaptive maximum levels (default 6 8; quick: 4)")
    parser.add_argument("--thresholds", type=float, nargs="+", metavar="M",
                        help="adaptive refine thresholds in m (default 0.00025 0.0005 0.001 "
                             "0.002 0.004; quick: 0.001 0.004)")
    parser.add_argument("--reference-level", type=int,
                        help="uniform level of the reference (default: the finest level asked)")
    parser.add_argument("--duration", type=float,
                        help="simulated seconds timed and sampled at 1/4, 1/2, 1 of it "
                             "(default 2; quick 0.5)")
    parser.add_argument("--coarsen-ratio", type=float,
                        help="coarsen threshold / refine threshold (default: the scene's)")
    parser.add_argument("--rest-threshold", type=float,
                        help="'at rest': kinetic energy per unit mass below this, J/kg "
                             "(default 1e-6)")
    parser.add_argument("--rest-window", type=float,
                        help="... for this long, s (default 1.0; quick 0.25)")
    parser.add_argument("--rest-cap", type=float,
                        help="... or at this time at the latest, s (default 20; quick 1)")
    parser.add_argument("--grid", type=int, default=21,
                        help="material sample points per side (default 21)")
    parser.add_argument("--no-half-step", action="store_true",
                        help="skip the reference run at half the time step")
    parser.add_argument("--cpu", type=int,
                        help="CPU to pin every run to (default: the last one allowed)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="scene override for every run (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--solvers", action="store_true",
                        help="compare the linear-solver backends instead (uniform L4-L8, the "
                             "adaptive default, grasp_lift with LOD on and off; quick: two "
                             "small cases); writes solvers.json and solvers.md")
    parser.add_argument("--from-json", metavar="BENCH_JSON",
                        help="run nothing: rewrite the CSV, plot and summary of a finished "
                             "run from its bench.json (into --out, default beside it)")
    return parser


def _resolve(args) -> None:
    """Fill unset options from the full or quick defaults; validate them."""
    defaults = QUICK if args.quick else FULL
    for name, value in defaults.items():
        if getattr(args, name, None) is None:
            setattr(args, name, list(value) if isinstance(value, list) else value)
    if args.repeats < 1:
        raise BenchError("--repeats must be at least 1")
    if not args.duration > 0:
        raise BenchError("--duration must be positive")
    if args.grid < 2:
        raise BenchError("--grid must be at least 2")
    if any(t <= 0 or not math.isfinite(t) for t in args.thresholds):
        raise BenchError("--thresholds must be positive lengths in metres")
    if args.rest_threshold <= 0 or args.rest_window <= 0:
        raise BenchError("--rest-threshold and --rest-window must be positive")
    if args.rest_cap <= args.duration:
        raise BenchError(f"--rest-cap ({args.rest_cap:g} s) must exceed --duration "
                         f"({args.duration:g} s)")
    args._reference_level_given = args.reference_level is not None
    args._coarsen_ratio_given = args.coarsen_ratio is not None
    if args.reference_level is None:
        args.reference_level = max(list(args.levels) + list(args.max_levels))
    bad = [lv for lv in list(args.levels) + list(args.max_levels) + [args.reference_level]
           if lv < 0]
    if bad:
        raise BenchError(f"level {bad[0]} is below the base mesh (level 0)")
    finer = [lv for lv in list(args.levels) + list(args.max_levels) if lv > args.reference_level]
    if finer:
        raise BenchError(f"level {finer[0]} is finer than the reference level "
                         f"{args.reference_level}; the reference must be the finest")
    cpus = sorted(os.sched_getaffinity(0))
    if args.cpu is None:
        args.cpu = cpus[-1]
    elif args.cpu not in cpus:
        raise BenchError(f"--cpu {args.cpu} is not available; allowed CPUs: {cpus}")


def _command_line(args) -> str:
    """A command that reproduces this run: the options that differ from the defaults."""
    defaults = QUICK if args.quick else FULL
    parts = ["cloth-lod bench", str(args.scene)] + (["--quick"] if args.quick else [])
    for name in ("repeats", "levels", "max_levels", "thresholds", "duration", "rest_threshold",
                 "rest_window", "rest_cap"):
        value = getattr(args, name)
        if value != defaults[name]:
            value = " ".join(f"{v:g}" for v in value) if isinstance(value, list) else f"{value:g}"
            parts.append(f"--{name.replace('_', '-')} {value}")
    if getattr(args, "_reference_level_given", False):
        parts.append(f"--reference-level {args.reference_level}")
    if getattr(args, "_coarsen_ratio_given", False):
        parts.append(f"--coarsen-ratio {args.coarsen_ratio:g}")
    if args.grid != 21:
        parts.append(f"--grid {args.grid}")
    if args.no_half_step:
        parts.append("--no-half-step")
    parts += [f"--set {item}" for item in (args.set or [])]
    parts.append(f"--out {args.out}")
    return " ".join(parts)


def run(args) -> int:
    """Run the benchmark described by ``args`` (from :func:`add_arguments`).

    Returns 0 on success, 2 for bad arguments or scenes, 3 if a run failed.
    """
    from ...sim.config import SceneError, find_scene_file, load_scene
    from ...sim.metrics import material_grid

    args._out_given = args.out is not None
    if args.out is None:
        args.out = "out/bench"
    if getattr(args, "from_json", None):
        return _rerender(Path(args.from_json), args.out if args._out_given else None)
    started = _time.perf_counter()
    say = (lambda *a: None) if getattr(args, "quiet", False) else (
        lambda *a: print(*a, flush=True))
    if getattr(args, "solvers", False):
        from .backends import run_backends
        try:
            result = run_backends(Path(args.out), repeats=args.repeats or 3, quick=args.quick,
                                  cpu=args.cpu, progress=say)
        except BenchError as exc:
            print(f"cloth-lod bench: {exc}", file=sys.stderr)
            return 3
        say(f"wrote {Path(args.out) / 'solvers.md'} ({result['minutes']:.1f} min)")
        return 0
    try:
        _resolve(args)
        scene_path = find_scene_file(args.scene)
        scene_arg = str(scene_path.resolve()) if scene_path.exists() else args.scene
        scene = load_scene(scene_arg, list(args.set or []))
        if args.coarsen_ratio is None:
            args.coarsen_ratio = scene.lod.coarsen_threshold / scene.lod.refine_threshold
        low = [lv for lv in args.max_levels if lv < scene.lod.initial_level]
        if low:
            raise BenchError(f"adaptive max level {low[0]} is below the level the adaptive "
                             f"run starts from (lod.initial_level = {scene.lod.initial_level})")
        configs = _configurations(args, scene)
        for cfg in configs:                 # every scene must load before hours of work
            load_scene(scene_arg, cfg["overrides"])
    except SceneError as exc:
        print(f"cloth-lod bench: scene error: {exc}", file=sys.stderr)
        return 2
    except (BenchError, ValueError, OSError) as exc:
        print(f"cloth-lod bench: error: {exc}", file=sys.stderr)
        return 2

    h = scene.simulation.time_step
    side = max(scene.cloth.width, scene.cloth.height)
    duration = round(args.duration / h) * h
    times = [round(duration * f / h) * h for f in (0.25, 0.5, 1.0)]
    times = sorted({t for t in times if t > 0})
    points = material_grid(scene.cloth.width, scene.cloth.height, args.grid)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base_spec = dict(scene=scene_arg, points=points.tolist(), times=times, duration=duration,
                     cpu=args.cpu)
    runs: dict[str, list[dict]] = {c["key"]: [] for c in configs}
    loads = []
    say(f"cloth-lod bench: {len(configs)} configurations x {args.repeats} repeats on CPU "
        f"{args.cpu}, reference uniform L{args.reference_level}")
    try:
        with tempfile.TemporaryDirectory(prefix="cloth_lod_bench_") as tmp:
            workdir = Path(tmp)
            rest_time = None
            for rnd in range(args.repeats):
                for cfg in configs:
                    if cfg["kind"] == "half_step" and rnd > 0:
                        continue
                    spec = dict(base_spec, overrides=cfg["overrides"])
                    if rnd == 0 and cfg["kind"] == "reference":
                        spec["rest"] = dict(find=dict(threshold=args.rest_threshold,
                                                      window=args.rest_window,
                                                      cap=args.rest_cap))
                    elif rnd == 0:
                        spec["rest"] = dict(time=rest_time)
                    t0 = _time.perf_counter()
                    result = _run_worker(spec, workdir, f"{cfg['key']}_r{rnd}")
                    if rnd == 0 and cfg["kind"] == "reference":
                        rest_time = result["rest_time"]
                        rest_info = dict(time=rest_time, at_rest=result["at_rest"],
                                         ke_per_mass=result["ke_per_mass"][-1])
                    runs[cfg["key"]].append(result)
                    c = result["cost"]
                    loads += [c["loadavg_start"], c["loadavg_end"]]
                    say(f"  [{rnd + 1}/{args.repeats}] {_label(cfg):34s} "
                        f"{c['wall_s'] / c['simulated_s']:7.3f} s/s  "
                        f"{c['cg_iterations'] / c['steps']:6.1f} CG/step  "
                        f"(process {_time.perf_counter() - t0:5.1f} s)")
    except BenchError as exc:
        print(f"cloth-lod bench: {exc}", file=sys.stderr)
        return 3

    reference = np.asarray(runs[configs[0]["key"]][0]["samples"], dtype=float)
    rows = [_row(cfg, runs[cfg["key"]], reference, times, side, points) for cfg in configs]
    # Table order: uniform by level (reference included), then adaptive.
    order = {"uniform": 0, "reference": 0, "half_step": 2, "adaptive": 1}
    rows.sort(key=lambda r: (order[r["kind"]], r["level"], r["refine_threshold_m"] or 0))

    settings = dict(
        scene=scene.name, command=_command_line(args), duration=duration, time_step=h,
        times=times, side_m=side, grid=args.grid, repeats=args.repeats,
        reference_level=args.reference_level, levels=sorted(set(args.levels)),
        max_levels=sorted(set(args.max_levels)), thresholds=sorted(set(args.thresholds)),
        coarsen_ratio=args.coarsen_ratio, initial_level=scene.lod.initial_level,
        rest_threshold=args.rest_threshold, rest_window=args.rest_window,
        rest_cap=args.rest_cap, overrides=list(args.set or []), quick=bool(args.quick),
        reference_note=_reference_note(args, runs, configs))
    result = dict(settings=settings, machine=_machine(args.cpu), rest=rest_info, rows=rows,
                  paper=_paper_row(rows, runs, configs, scene),
                  runs={k: [dict(v, samples=None) for v in vs] for k, vs in runs.items()},
                  load_min=min(loads), load_max=max(loads))
    result["wall_s"] = _time.perf_counter() - started
    _render(result, out)
    say(f"  wrote {out}/bench.csv, bench.json, bench.png, bench.md "
        f"({result['wall_s']:.0f} s in all)")
    return 0


def _render(result: dict, out: Path) -> None:
    """Write bench.csv, bench.png, bench.md and bench.json from ``result``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = result["rows"]
    _write_csv(out / "bench.csv", rows)
    _plot(out / "bench.png", rows, dict(result["settings"], rest_time=result["rest"]["time"]))
    (out / "bench.md").write_text(_markdown(result))
    (out / "bench.json").write_text(json.dumps(result, indent=1))


def _rerender(path: Path, out: Path | None) -> int:
    """``--from-json``: rewrite the tables, plot and summary of a finished run."""
    try:
        result = json.loads(Path(path).read_text())
        rows = result["rows"]
        # Rows written before a column existed get it from what is stored.
        for row in rows:
            row.setdefault("rest_other_shape",
                           bool(row["max_frac_rest"] > 2.0 * row["max_frac_motion"]))
    except (OSError, ValueError, KeyError) as exc:
        print(f"cloth-lod bench: cannot read {path}: {exc}", file=sys.stderr)
        return 2
    _render(result, Path(out) if out else Path(path).parent)
    return 0


def _reference_note(args, runs, configs) -> str:
    ref = runs[configs[0]["key"]]
    cost = np.array([r["cost"]["wall_s"] / r["cost"]["simulated_s"] for r in ref])
    c = ref[0]["cost"]
    return (f"Its own cost: {np.median(cost):.3g} s per simulated second (median of "
            f"{len(cost)}; {c['cg_iterations'] / c['steps']:.0f} CG iterations per step). It "
            "is the finest level benchmarked, so every level and every adaptive maximum level "
            "is compared with a mesh at least as fine; the h/2 check is one run of the same "
            "mesh.")


def _paper_row(rows, runs, configs, scene) -> dict | None:
    """Adaptive (scene's level and threshold) against uniform at that level."""
    level, thr = scene.cloth.level, scene.lod.refine_threshold
    uni = next((r for r in rows if r["kind"] in ("uniform", "reference")
                and r["level"] == level), None)
    ada = next((r for r in rows if r["kind"] == "adaptive" and r["level"] == level
                and math.isclose(r["refine_threshold_m"], thr)), None)
    if uni is None or ada is None:
        return None
    ms = lambda key: np.array([1e3 * r["cost"]["wall_s"] / r["cost"]["steps"]  # noqa: E731
                               for r in runs[key]])
    a_ms, u_ms = ms(ada["config"]), ms(uni["config"])
    n = min(len(a_ms), len(u_ms))
    ratios = u_ms[:n] / a_ms[:n]
    text = lambda x: f"{np.median(x):.1f} ({x.min():.1f}–{x.max():.1f})"  # noqa: E731
    blocks_u, blocks_v = scene.cloth.base_blocks
    grid = (blocks_u * 2 ** (level // 2) + 1) if level % 2 == 0 else None
    return dict(level=level, threshold=thr, grid=grid if grid else "—",
                adaptive_ms=float(np.median(a_ms)), uniform_ms=float(np.median(u_ms)),
                ratio=float(np.median(ratios)), adaptive_ms_text=text(a_ms),
                uniform_ms_text=text(u_ms),
                ratio_text=f"{np.median(ratios):.2f}× ({ratios.min():.2f}–{ratios.max():.2f})",
                lod_share=ada["lod_share_median"],
                lod_share_upper=ada["lod_share_median"] + max(
                    ada["unattributed_share_median"] - uni["unattributed_share_median"], 0.0),
                adaptive_rms_motion=ada["rms_frac_motion"], adaptive_rms_rest=ada["rms_frac_rest"],
                uniform_rms_motion=uni["rms_frac_motion"], uniform_rms_rest=uni["rms_frac_rest"])


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--worker"]:
        if len(argv) != 2:
            print("usage: python -m cloth_lod_ros.tools.bench --worker SPEC.json", file=sys.stderr)
            return 2
        return run_spec_file(argv[1])
    parser = add_arguments(argparse.ArgumentParser(
        prog="python -m cloth_lod_ros.tools.bench", description=__doc__.split("\n\n")[0]))
    args = parser.parse_args(argv)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
