"""``cloth-lod bench``: speed against error, the error measured from the converged motion.

Design §5.  For one scene (default ``hang_two_corners``, 2 s simulated):

* **Configurations** (:mod:`.plan`): integrator *families* (``--schemes``: the
  paper's ``baraff_witkin`` step, ``sdirk2`` with one step per frame and with
  error control at a few tolerances), each on the uniform mesh at
  ``--levels`` and on the adaptive mesh at ``--max-levels`` × ``--thresholds``
  (default: the scene's level and thresholds).  Each configuration runs
  ``--repeats`` times, each time in a fresh Python process pinned to one CPU
  with every BLAS/OpenMP pool limited to one thread, in rounds (every
  configuration once, then again), so a burst of load from another process
  spreads over configurations instead of hitting one.
* **Reference** (:mod:`cloth_lod_ros.tools.reference`): by default the
  *converged* motion - the scene uniform at ``--reference-level`` (default:
  the finest level asked), ``sdirk2`` at ``h/--reference-divisor`` (default
  8) with 3 Newton iterations to 1e-8 m - plus its own error: a run at twice
  its step (time) and, unless ``--no-mesh-check``, one level coarser (mesh).
  ``--reference same-step`` compares each family with its own uniform run at
  the reference level instead (mesh error only; every output says so).
* **Error**: RMS and maximum 3-D distance from the reference at a fixed grid
  of material (u, v) points, as a fraction of the cloth's larger side, at
  ¼, ½ and all of the duration (0.5, 1 and 2 s by default) and **at rest**:
  the first time after the duration at which the reference's kinetic energy
  per unit mass has stayed below ``--rest-threshold`` (J/kg) for a whole
  ``--rest-window`` (s; longer than half a swing), or ``--rest-cap``.
* **Cost** (over the first ``duration`` seconds only): wall and CPU seconds per
  simulated second (median and min–max over the repeats), and per frame the
  integrator steps, rejected steps, Newton iterations, linear solves, CG
  iterations, and the LOD share of the step time.

Outputs in ``--out``: ``bench.csv`` and ``bench.json`` (the same rows; the
JSON adds the machine, the settings, the reference's runs and own error and
per-repeat numbers), ``bench.png`` (error against cost, log–log) and
``bench.md`` (tables and paragraphs written from the numbers).
``--from-json bench.json`` rewrites the CSV, plot and summary of a finished
run without running anything; ``--report MD`` writes one page from the
``bench.json``, ``scenes.json`` and ``solvers.json`` in ``--out``
(:mod:`.performance`), also without running anything.

Module API for the command line: :func:`add_arguments` and :func:`run`;
``python -m cloth_lod_ros.tools.bench`` works too.  Worker processes are started as
``python -m cloth_lod_ros.tools.bench --worker SPEC.json``.
"""


import argparse
import json
import math
import os
import sys
import tempfile
import time as _time
from pathlib import Path

import numpy as np

from ...sim.integrate.step_control import effective_tolerance
from ..reference import MODES, SAME_STEP_LABEL, ConvergedReference
from .plan import (FULL, QUICK, REFERENCE_KINDS, BenchError, configurations, family_label,
                   parse_scheme)
from .plot import plot, write_csv
from .report import PAPER, markdown
from .rows import config_row, flag_other_shapes, paper_row, reference_summary
from .pools import make_pool
from .worker import run_spec_file
from .machine import _machine, _version, write_suite  # noqa: F401  (re-exported for the suites)

__all__ = ["add_arguments", "run", "main", "BenchError", "PAPER"]

DEFAULT_SCENE = "hang_two_corners"
def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``bench`` options to ``parser`` (for ``cloth-lod bench``)."""
    parser.add_argument("scene", nargs="?", default=DEFAULT_SCENE,
                        help=f"built-in scene name or YAML path (default {DEFAULT_SCENE})")
    parser.add_argument("--quick", action="store_true",
                        help="smoke test: 0.5 s, levels 2 and 4, three families, about a minute")
    parser.add_argument("--repeats", type=int, help="timed runs per configuration (default 3; "
                                                    "quick 2)")
    parser.add_argument("--out", help="output directory (default out/bench)")
    parser.add_argument("--schemes", nargs="+", metavar="INTEGRATOR[@TOL]",
                        help="integrator families: simulation.integrator, and after @ the "
                             "simulation.error_tolerance in m (none: one step per frame); "
                             "default " + " ".join(FULL["schemes"]) + "; quick "
                             + " ".join(QUICK["schemes"]))
    parser.add_argument("--levels", type=int, nargs="+", metavar="L",
                        help="uniform levels (default 2 4 6; quick: 2 4)")
    parser.add_argument("--max-levels", type=int, nargs="+", metavar="L",
                        help="adaptive maximum levels (default: the scene's level; quick: 4)")
    parser.add_argument("--thresholds", type=float, nargs="+", metavar="M",
                        help="adaptive refine thresholds in m (default: the scene's)")
    parser.add_argument("--reference", choices=MODES, default="converged",
                        help="converged (default): the scene uniform at --reference-level, "
                             "sdirk2 at h/--reference-divisor, 3 Newton iterations, and its "
                             f"own error estimated; same-step: {SAME_STEP_LABEL}")
    parser.add_argument("--reference-level", type=int,
                        help="uniform level of the reference (default: the finest level asked)")
    parser.add_argument("--reference-divisor", type=int,
                        help="converged reference step h_ref = h / this (default 8)")
    parser.add_argument("--no-mesh-check", dest="mesh_check", action="store_false",
                        help="skip the converged reference's run one level coarser (its mesh "
                             "error estimate)")
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
    parser.add_argument("--cpu", type=int,
                        help="CPU to pin every run to (default: the last one allowed)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="scene override for every run, the reference's included "
                             "(repeatable)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on the Dask workers of this scheduler (tcp://HOST:8786), "
                             "each run in a fresh process pinned to its worker's core, one "
                             "timed run per core at a time (needs the cluster extra)")
    parser.add_argument("--workers", type=int,
                        help="run on a local Dask cluster of this many workers, one per core "
                             "(default without it or --scheduler: one run at a time on --cpu)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the runs (label, repeats, scene overrides) and stop")
    parser.add_argument("--solvers", action="store_true",
                        help="compare the linear-solver backends instead (uniform L4-L8, the "
                             "adaptive default, grasp_lift with LOD on and off; quick: two "
                             "small cases); writes solvers.json and solvers.md")
    parser.add_argument("--scenes", action="store_true",
                        help="time every built-in scene instead (LOD on and off, "
                             "self-collision's cost where the cloth never meets itself; "
                             "quick: three small cases); writes scenes.json and scenes.md")
    parser.add_argument("--contact", action="store_true",
                        help="the contact scenes (drop_on_sphere, table_drape, grasp_lift) at "
                             "default settings against their converged motion at 1, 2, 3 s, "
                             "with the reference's own error (references cached under "
                             "$CLOTH_LOD_CACHE, default /tmp/cloth_lod_bench_cache); writes "
                             "contact.json and contact.md")
    parser.add_argument("--local", action="store_true",
                        help="adaptivity where detail is local instead: lifted_corner, "
                             "table_corner, small_ball (config/bench/), uniform levels against "
                             "adaptive settings from a converged reference cached in "
                             "/tmp/cloth_lod_local; writes local.json, local.md, local_*.png "
                             "(quick: one scene, small levels)")
    parser.add_argument("--local-scenes", nargs="+", metavar="NAME",
                        help="with --local: these of its scenes only")
    parser.add_argument("--from-json", metavar="BENCH_JSON",
                        help="run nothing: rewrite the CSV, plot and summary of a finished "
                             "run from its bench.json (into --out, default beside it)")
    parser.add_argument("--report", metavar="MD",
                        help="run nothing: write one Markdown page (tables, plot, machine and "
                             "command of each) from the bench.json, scenes.json and "
                             "solvers.json in --out, e.g. --report docs/performance.md "
                             "--out resource/readme/bench")
    return parser


def _resolve(args) -> None:
    """Fill unset options from the full or quick defaults; validate what needs no scene."""
    defaults = QUICK if args.quick else FULL
    args._given = {name for name in defaults if getattr(args, name, None) is not None}
    for name, value in defaults.items():
        if getattr(args, name, None) is None:
            setattr(args, name, list(value) if isinstance(value, list) else value)
    if args.repeats < 1:
        raise BenchError("--repeats must be at least 1")
    if not args.duration > 0:
        raise BenchError("--duration must be positive")
    if args.grid < 2:
        raise BenchError("--grid must be at least 2")
    if args.thresholds is not None and any(t <= 0 or not math.isfinite(t)
                                           for t in args.thresholds):
        raise BenchError("--thresholds must be positive lengths in metres")
    if args.rest_threshold <= 0 or args.rest_window <= 0:
        raise BenchError("--rest-threshold and --rest-window must be positive")
    if args.rest_cap <= args.duration:
        raise BenchError(f"--rest-cap ({args.rest_cap:g} s) must exceed --duration "
                         f"({args.duration:g} s)")
    if args.reference_divisor < 1:
        raise BenchError("--reference-divisor must be at least 1")
    args._families = [parse_scheme(text) for text in args.schemes]
    keys = [f["key"] for f in args._families]
    if len(set(keys)) != len(keys):
        raise BenchError(f"--schemes: a family is given twice ({' '.join(args.schemes)})")
    cpus = sorted(os.sched_getaffinity(0))
    if args.cpu is None:
        args.cpu = cpus[-1]
    elif args.cpu not in cpus:
        raise BenchError(f"--cpu {args.cpu} is not available; allowed CPUs: {cpus}")


def _resolve_scene(args, scene) -> None:
    """Defaults that come from the scene (maximum level, thresholds, coarsen
    ratio, reference level) and the checks that need them."""
    args._reference_level_given = args.reference_level is not None
    args._coarsen_ratio_given = args.coarsen_ratio is not None
    if args.max_levels is None:
        args.max_levels = [scene.cloth.level]
    if args.thresholds is None:
        args.thresholds = [scene.lod.refine_threshold]
    if args.coarsen_ratio is None:
        args.coarsen_ratio = scene.lod.coarsen_threshold / scene.lod.refine_threshold
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
    low = [lv for lv in args.max_levels if lv < scene.lod.initial_level]
    if low:
        raise BenchError(f"adaptive max level {low[0]} is below the level the adaptive "
                         f"run starts from (lod.initial_level = {scene.lod.initial_level})")


def _command_line(args) -> str:
    """A command that reproduces this run: the options that differ from the defaults."""
    parts = ["cloth-lod bench", str(args.scene)] + (["--quick"] if args.quick else [])
    for name in ("repeats", "schemes", "levels", "max_levels", "thresholds", "duration",
                 "rest_threshold", "rest_window", "rest_cap", "reference_divisor"):
        if name in args._given:
            value = getattr(args, name)
            text = (" ".join(v if isinstance(v, str) else f"{v:g}" for v in value)
                    if isinstance(value, list) else f"{value:g}")
            parts.append(f"--{name.replace('_', '-')} {text}")
    if args.reference != "converged":
        parts.append(f"--reference {args.reference}")
    for name in ("scheduler", "workers"):         # where it ran (Dask)
        if getattr(args, name, None):
            parts.append(f"--{name} {getattr(args, name)}")
    if args._reference_level_given:
        parts.append(f"--reference-level {args.reference_level}")
    if not args.mesh_check:
        parts.append("--no-mesh-check")
    if args._coarsen_ratio_given:
        parts.append(f"--coarsen-ratio {args.coarsen_ratio:g}")
    if args.grid != 21:
        parts.append(f"--grid {args.grid}")
    parts += [f"--set {item}" for item in (args.set or [])]
    parts.append(f"--out {args.out}")
    return " ".join(parts)


def _rest_spec(cfg: dict, finder: dict, rest_time, args, frame: float) -> dict:
    """What a first-round run does after the timed window."""
    if cfg is finder:
        spec = dict(rest=dict(find=dict(threshold=args.rest_threshold,
                                        window=args.rest_window, cap=args.rest_cap)))
    elif cfg["kind"] == "reference_2h":
        return dict(rest=None)          # its time-error estimate is for the motion only
    else:
        spec = dict(rest=dict(time=rest_time))
    if cfg["kind"] in REFERENCE_KINDS:
        spec["rest_time_step"] = frame
    return spec


def run(args) -> int:
    """Run the benchmark described by ``args`` (from :func:`add_arguments`).

    Returns 0 on success, 2 for bad arguments or scenes, 3 if a run failed.
    """
    from ...sim.scene.config import SceneError, find_scene_file, load_scene
    from ...sim.mesh.sampling import material_grid

    args._out_given = args.out is not None
    if args.out is None:
        args.out = "out/bench"
    if getattr(args, "from_json", None):
        return _rerender(Path(args.from_json), args.out if args._out_given else None)
    if getattr(args, "report", None):
        from .performance import write_report
        try:
            write_report(Path(args.report), Path(args.out))
        except (OSError, ValueError) as exc:
            print(f"cloth-lod bench: cannot write the report: {exc}", file=sys.stderr)
            return 2
        say = (lambda *a: None) if getattr(args, "quiet", False) else print
        say(f"wrote {args.report}")
        return 0
    started = _time.perf_counter()
    say = (lambda *a: None) if getattr(args, "quiet", False) else (
        lambda *a: print(*a, flush=True))
    for flag, module, function, table in (("solvers", "backends", "run_backends", "solvers.md"),
                                          ("scenes", "scenes", "run_scenes", "scenes.md"),
                                          ("contact", "contact", "run_contact", "contact.md"),
                                          ("local", "local", "run_local", "local.md")):
        if getattr(args, flag, False):
            import importlib
            suite = getattr(importlib.import_module(f"{__package__}.{module}"), function)
            try:
                repeats = args.repeats or (1 if flag == "local" else 3)
                extra = ({"scenes": tuple(args.local_scenes)}
                         if flag == "local" and getattr(args, "local_scenes", None) else {})
                result = suite(Path(args.out), repeats=repeats, quick=args.quick,
                               cpu=args.cpu, progress=say, **extra)
            except BenchError as exc:
                print(f"cloth-lod bench: {exc}", file=sys.stderr)
                return 3
            # The command that reproduces the suite, for the report (--report).
            result["command"] = " ".join(
                ["cloth-lod bench", f"--{flag}"] + (["--quick"] if args.quick else [])
                + ([f"--repeats {args.repeats}"] if args.repeats else [])
                + ([f"--local-scenes {' '.join(args.local_scenes)}"]
                   if flag == "local" and getattr(args, "local_scenes", None) else [])
                + [f"--out {args.out}"])
            stem = table.removesuffix(".md")
            (Path(args.out) / f"{stem}.json").write_text(json.dumps(result, indent=1))
            say(f"wrote {Path(args.out) / table} ({result['minutes']:.1f} min)")
            return 0
    try:
        _resolve(args)
        scene_path = find_scene_file(args.scene)
        scene_arg = str(scene_path.resolve()) if scene_path.exists() else args.scene
        scene = load_scene(scene_arg, list(args.set or []))
        _resolve_scene(args, scene)
        h = scene.simulation.time_step
        reference = (ConvergedReference(args.reference_level, h, args.reference_divisor)
                     if args.reference == "converged" else None)
        configs = configurations(args, scene, args._families, reference)
        for cfg in configs:                 # every scene must load before hours of work
            load_scene(scene_arg, cfg["overrides"])
    except SceneError as exc:
        print(f"cloth-lod bench: scene error: {exc}", file=sys.stderr)
        return 2
    except (BenchError, ValueError, OSError) as exc:
        print(f"cloth-lod bench: error: {exc}", file=sys.stderr)
        return 2

    if getattr(args, "dry_run", False):
        for cfg in configs:
            repeats = 1 if cfg["kind"] in REFERENCE_KINDS else args.repeats
            print(f"{cfg['key']}\t{cfg['kind']}\t{repeats}\t{cfg['label']}\t"
                  + " ".join(cfg["overrides"]))
        return 0
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
    finder = configs[0]
    say(f"cloth-lod bench: {len(configs)} runs x {args.repeats} repeats on CPU {args.cpu}; "
        + (reference.describe() if reference else SAME_STEP_LABEL))
    by_key = {c["key"]: c for c in configs}
    try:
        pool = make_pool(args)
    except RuntimeError as exc:                 # no cluster, or workers that cannot run
        print(f"cloth-lod bench: {exc}", file=sys.stderr)
        return 2
    if pool.workers:
        say(f"  on {len(pool.workers)} Dask worker(s): " + ", ".join(
            f"{w['host']} cpu {w['cpu']}" for w in pool.workers.values()))
    try:
        with tempfile.TemporaryDirectory(prefix="cloth_lod_bench_") as tmp:
            pool.workdir = Path(tmp)
            rest_time = rest_info = None
            for rnd in range(args.repeats):
                # The converged reference runs once; in the first round the run
                # that finds the rest time goes alone, the others sample at it.
                batch = [c for c in configs if not (c["kind"] in REFERENCE_KINDS and rnd > 0)]
                for part in ([batch[:1], batch[1:]] if rnd == 0 else [batch]):
                    jobs = []
                    for cfg in part:
                        spec = dict(base_spec, overrides=cfg["overrides"])
                        if rnd == 0:
                            spec.update(_rest_spec(cfg, finder, rest_time, args, h))
                        jobs.append((cfg["key"], spec, f"{cfg['key']}_r{rnd}"))
                    for key, result in pool.map(jobs):
                        cfg = by_key[key]
                        if rnd == 0 and cfg is finder:
                            rest_time = result["rest_time"]
                            rest_info = dict(time=rest_time, at_rest=result["at_rest"],
                                             ke_per_mass=result["ke_per_mass"][-1])
                        runs[cfg["key"]].append(result)
                        c = result["cost"]
                        loads += [c["loadavg_start"], c["loadavg_end"]]
                        say(f"  [{rnd + 1}/{args.repeats}] {cfg['label'][:58]:58s} "
                            f"{c['wall_s'] / c['simulated_s']:7.3f} s/s  "
                            f"{c['solves'] / c['steps']:5.2f} solves/step  "
                            f"(process {result['process_s']:5.1f} s)"
                            + (f"  [{result['host']} cpu {result['cpu']}]"
                               if "host" in result else ""))
    except BenchError as exc:
        print(f"cloth-lod bench: {exc}", file=sys.stderr)
        return 3
    finally:
        pool.close()

    fams = {f["key"]: f for f in args._families}
    for f in fams.values():
        f["label"] = family_label(f, h)
    rows = []
    for cfg in configs:
        if cfg["kind"] in REFERENCE_KINDS:
            continue
        ref_key = (configs[0]["key"] if reference else
                   next(c["key"] for c in configs
                        if c["kind"] == "same_step" and c["family"] == cfg["family"]))
        ref_samples = np.asarray(runs[ref_key][0]["samples"], dtype=float)
        rows.append(config_row(cfg, runs[cfg["key"]], ref_samples, times, side, points,
                               fams[cfg["family"]],
                               "converged" if reference else SAME_STEP_LABEL))
        if pool.workers:                    # what ran where (host/CPU of each repeat)
            rows[-1]["ran_on"] = " ".join(f"{r['host']}/cpu{r['cpu']}"
                                          for r in runs[cfg["key"]])
    if reference:
        ref_info = dict(reference.as_dict(), mesh_check=bool(args.mesh_check),
                        **reference_summary(configs, runs, times, side))
    else:
        ref_info = dict(mode="same-step", label=SAME_STEP_LABEL, level=args.reference_level)
    settings = dict(
        scene=scene.name, command=_command_line(args), duration=duration, time_step=h,
        times=times, side_m=side, grid=args.grid, repeats=args.repeats,
        reference_level=args.reference_level, levels=sorted(set(args.levels)),
        max_levels=sorted(set(args.max_levels)), thresholds=sorted(set(args.thresholds)),
        families=list(fams.values()),
        scene_default=dict(integrator=scene.simulation.integrator,
                           error_tolerance=effective_tolerance(scene.simulation)),
        coarsen_ratio=args.coarsen_ratio, initial_level=scene.lod.initial_level,
        rest_threshold=args.rest_threshold, rest_window=args.rest_window,
        rest_cap=args.rest_cap, overrides=list(args.set or []), quick=bool(args.quick))
    if pool.workers:
        settings["dask_workers"] = pool.workers
    result = dict(settings=settings, machine=_machine(args.cpu), reference=ref_info,
                  rest=rest_info, rows=rows, paper=paper_row(rows, runs, scene),
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
    flag_other_shapes(result)
    label = "converged" if result["reference"]["mode"] == "converged" else SAME_STEP_LABEL
    for row in result["rows"]:          # files written before the column existed
        row.setdefault("reference", label)
    write_csv(out / "bench.csv", result["rows"])
    plot(out / "bench.png", result)
    (out / "bench.md").write_text(markdown(result))
    (out / "bench.json").write_text(json.dumps(result, indent=1))


def _rerender(path: Path, out: Path | None) -> int:
    """``--from-json``: rewrite the tables, plot and summary of a finished run."""
    try:
        result = json.loads(Path(path).read_text())
        for key in ("settings", "reference", "rows", "rest"):
            result[key]
    except (OSError, ValueError, KeyError) as exc:
        print(f"cloth-lod bench: cannot read {path}: {exc}", file=sys.stderr)
        return 2
    _render(result, Path(out) if out else Path(path).parent)
    return 0


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
