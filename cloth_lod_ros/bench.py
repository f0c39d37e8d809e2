"""``cloth-lod bench``: error against cost, uniform levels and adaptive thresholds.

DESIGN.md §5.  For one scene (default ``hang_two_corners``, 2 s simulated):

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
``python -m cloth_lod_ros.bench`` works too.  Worker processes are started as
``python -m cloth_lod_ros.bench --worker SPEC.json``.
"""

from __future__ import annotations

import argparse
import csv
import datetime as _dt
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time as _time
from collections import deque
from pathlib import Path

import numpy as np

__all__ = ["add_arguments", "run", "main", "BenchError", "PAPER"]

#: The paper's §6 numbers (2003 hardware): mean CPU ms per frame over the first
#: 2 s, adaptive (max level 6, 25-particle start) against uniform 33 × 33.
PAPER = dict(adaptive_ms=284.5, uniform_ms=3012.7, ratio=3012.7 / 284.5, lod_share=0.03)

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


# --------------------------------------------------------------------------
# Worker: one configuration, one process, one core.
# --------------------------------------------------------------------------

def _worker(spec: dict) -> dict:
    """Run one configuration and return its samples and cost counters.

    ``spec`` keys: ``scene`` (name or path), ``overrides`` (list of
    ``key=value``), ``points`` ((m, 2) material points, m), ``times`` (sample
    times, s), ``duration`` (timed window, s), ``rest`` (None, ``{"time": t}``
    to sample at t, or ``{"find": {"threshold", "window", "cap"}}`` to find
    the rest time as described in the module docstring).

    Returns a JSON-ready dict: ``samples`` ((k, m, 3) positions, m, at
    ``times`` then at rest if requested), ``rest_time`` (s), ``at_rest``,
    ``ke_per_mass`` at each sample (J/kg), and ``cost`` (wall/CPU seconds and
    work counters over the timed window).
    """
    from .config import load_scene
    from .sim import ClothSim

    setup_start = _time.perf_counter()
    scene = load_scene(spec["scene"], spec["overrides"])
    sim = ClothSim(scene)
    setup_s = _time.perf_counter() - setup_start
    h = scene.simulation.time_step
    points = np.asarray(spec["points"], dtype=float)
    total_mass = float(sim.masses.sum())
    timed_steps = int(round(spec["duration"] / h))
    wanted = {int(round(t / h)): i for i, t in enumerate(spec["times"])}
    rest = spec.get("rest")
    rest_step = int(round(rest["time"] / h)) if rest and "time" in rest else None
    find = rest.get("find") if rest else None
    last_step = max([timed_steps, *wanted, rest_step or 0])
    if find:
        last_step = max(last_step, int(round(find["cap"] / h)))
        window = deque(maxlen=max(int(round(find["window"] / h)), 1))

    samples: list = [None] * len(spec["times"])
    ke = [None] * len(spec["times"])
    step_wall = np.zeros(timed_steps)
    cpu_s = 0.0
    load_start = os.getloadavg()
    rest_time = at_rest = rest_sample = rest_ke = None
    k = 0
    while k < last_step:
        # Only sim.step() is inside the clock; sampling and bookkeeping are not.
        if k < timed_steps:
            c0, w0 = _time.process_time(), _time.perf_counter()
            stats = sim.step()
            w1, c1 = _time.perf_counter(), _time.process_time()
            step_wall[k] = w1 - w0
            cpu_s += c1 - c0
        else:
            stats = sim.step()
        k += 1
        ke_mass = stats.kinetic_energy / total_mass
        if k in wanted:
            samples[wanted[k]] = sim.sample(points).tolist()
            ke[wanted[k]] = ke_mass
        if rest_step is not None and k == rest_step:
            rest_time = k * h
            rest_sample, rest_ke = sim.sample(points).tolist(), ke_mass
        if find:
            window.append(ke_mass)
            settled = len(window) == window.maxlen and max(window) < find["threshold"]
            if k > timed_steps and (settled or k == last_step):
                rest_time, at_rest = k * h, bool(settled)
                rest_sample, rest_ke = sim.sample(points).tolist(), ke_mass
                break
    load_end = os.getloadavg()

    st = sim.stats[:timed_steps]
    step_ms = np.array([s.step_ms for s in st])
    tris = np.array([s.triangle_count for s in st])
    cost = dict(
        steps=timed_steps, simulated_s=timed_steps * h,
        wall_s=float(step_wall.sum()), cpu_s=float(cpu_s),
        step_wall_ms_median=float(1e3 * np.median(step_wall)),
        step_wall_ms_max=float(1e3 * step_wall.max()),
        internal_step_ms=float(step_ms.sum()),
        lod_ms=float(sum(s.lod_ms for s in st)),
        force_ms=float(sum(s.force_ms for s in st)),
        assembly_ms=float(sum(s.assembly_ms for s in st)),
        solve_ms=float(sum(s.solve_ms for s in st)),
        cg_iterations=int(sum(s.cg_iterations for s in st)),
        cg_iterations_max=int(max(s.cg_iterations for s in st)),
        unconverged_steps=int(sum(not s.converged for s in st)),
        vertex_steps=int(sum(s.vertex_count for s in st)),
        triangle_steps=int(tris.sum()),
        triangles_mean=float(tris.mean()), triangles_max=int(tris.max()),
        triangles_final=int(tris[-1]),
        splits=int(sum(s.refines for s in st)), merges=int(sum(s.merges for s in st)),
        setup_s=setup_s, loadavg_start=load_start[0], loadavg_end=load_end[0])
    if rest_sample is not None:
        samples.append(rest_sample)
        ke.append(rest_ke)
    return dict(samples=samples, ke_per_mass=ke, rest_time=rest_time, at_rest=at_rest,
                time_step=h, cost=cost, cpu=sorted(os.sched_getaffinity(0)))


def _worker_main(spec_path: str) -> int:
    spec = json.loads(Path(spec_path).read_text())
    # Pin before any work: the timed loop must never migrate between cores.
    os.sched_setaffinity(0, {int(spec["cpu"])})
    result = _worker(spec)
    Path(spec["result"]).write_text(json.dumps(result))
    return 0


def _package_root() -> str:
    return str(Path(__file__).resolve().parent.parent)


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
    proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.bench", "--worker",
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

def _time_tag(t: float) -> str:
    return f"{t:.4g}s"


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


def _write_csv(path: Path, rows: list[dict]) -> None:
    fields = list(rows[0])
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            # repr() of a float reads back to the same float.
            writer.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


def _plot(path: Path, rows: list[dict], summary: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("rms_frac_motion", "during motion: RMS over t = "
               + ", ".join(f"{t:.3g}" for t in summary["times"]) + " s"),
              ("rms_frac_rest", f"at rest (t = {summary['rest_time']:.3g} s); "
               "hollow: settled into another shape (†)")]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2), sharey=False)
    ref = next(r for r in rows if r["kind"] == "reference")
    half = next((r for r in rows if r["kind"] == "half_step"), None)
    markers = {6: "s", 8: "^"}
    for ax, (key, title) in zip(axes, panels):
        groups = [("uniform", [r for r in rows if r["kind"] == "uniform"], "k", "o")]
        for level in sorted({r["level"] for r in rows if r["kind"] == "adaptive"}):
            groups.append((f"adaptive, max level {level}",
                           [r for r in rows if r["kind"] == "adaptive" and r["level"] == level],
                           "C0" if level <= 6 else "C3", markers.get(level, "D")))
        for name, group, colour, marker in groups:
            group = sorted((r for r in group if r[key] > 0),
                           key=lambda r: r["wall_per_sim_s_median"])
            if not group:
                continue
            x = np.array([r["wall_per_sim_s_median"] for r in group])
            y = np.array([r[key] for r in group])
            err = np.array([[r["wall_per_sim_s_median"] - r["wall_per_sim_s_min"]
                             for r in group],
                            [r["wall_per_sim_s_max"] - r["wall_per_sim_s_median"]
                             for r in group]])
            hollow = np.array([key == "rms_frac_rest" and _other(r) for r in group])
            ax.errorbar(x, y, xerr=err, color=colour, lw=1.5, capsize=3, zorder=2)
            ax.plot(x[~hollow], y[~hollow], ls="none", marker=marker, ms=6, color=colour,
                    zorder=3, label=name)
            ax.plot(x[hollow], y[hollow], ls="none", marker=marker, ms=6, mfc="white",
                    mec=colour, mew=1.5, zorder=3, label=None if (~hollow).any() else name)
            # Uniform labels below the points, adaptive ones above; the two
            # adaptive curves coincide where the higher maximum level is never
            # reached, so their labels go to opposite sides.
            if group[0]["kind"] == "uniform":
                offset, align = (6, -12), "left"
            elif colour == "C3":
                offset, align = (6, 5), "left"
            else:
                offset, align = (-6, 5), "right"
            for r, xi, yi in zip(group, x, y):
                text = (f"L{r['level']}" if r["kind"] == "uniform"
                        else f"{r['refine_threshold_m'] * 1e3:g} mm")
                ax.annotate(text, (xi, yi), textcoords="offset points", xytext=offset,
                            ha=align, fontsize=8, color=colour)
        ax.axvline(ref["wall_per_sim_s_median"], color="0.4", ls="--", lw=1)
        ax.annotate(f"reference L{ref['level']}\n(error 0)", (ref["wall_per_sim_s_median"], 0.5),
                    xycoords=("data", "axes fraction"), textcoords="offset points",
                    xytext=(-4, 0), ha="right", fontsize=8, color="0.3")
        ax.axvline(1.0, color="0.7", ls=":", lw=1)
        ax.annotate("real time", (1.0, 0.02), xycoords=("data", "axes fraction"),
                    textcoords="offset points", xytext=(3, 0), fontsize=8, color="0.5")
        if half is not None and half[key] > 0:
            ax.axhline(half[key], color="C2", ls="-.", lw=1)
            ax.annotate(f"reference at h vs at h/2: {100 * half[key]:.2g} % of side",
                        (0.02, half[key]), xycoords=("axes fraction", "data"),
                        textcoords="offset points", xytext=(0, 3), fontsize=8, color="C2")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.margins(x=0.12)                  # room for the labels of the end points
        ax.set_xlabel("cost: wall seconds per simulated second (median, bar = min–max), one core")
        ax.set_ylabel("RMS distance from reference / cloth side")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(f"{summary['scene']}: error against cost, {summary['duration']:g} s simulated, "
                 f"h = {summary['time_step']:.4g} s, reference uniform L{ref['level']}",
                 fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------
# Markdown: tables and a paragraph computed from the numbers.
# --------------------------------------------------------------------------

def _pct(x, digits=2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{100 * x:.{digits}g} %" if x < 0.1 else f"{100 * x:.1f} %"


def _cost_text(r: dict) -> str:
    return (f"{r['wall_per_sim_s_median']:.3g} ({r['wall_per_sim_s_min']:.3g}–"
            f"{r['wall_per_sim_s_max']:.3g})")


def _uniform_curve_error(rows: list[dict], key: str, cost: float) -> tuple[float | None, str]:
    """Error of the uniform curve at ``cost`` (s/s), log–log interpolated.

    Between two measured uniform levels (sorted by cost, reference excluded:
    its error is 0) the curve is a straight line in log–log.  Returns
    ``(error, where)``; ``error`` is None outside the measured range.
    """
    pts = sorted((r["wall_per_sim_s_median"], r[key]) for r in rows
                 if r["kind"] == "uniform" and r[key] > 0)
    if not pts:
        return None, "no uniform level with a non-zero error"
    if cost < pts[0][0]:
        return None, "cheaper than every uniform level"
    if cost > pts[-1][0]:
        return None, "dearer than every uniform level but the reference"
    for (c0, e0), (c1, e1) in zip(pts, pts[1:]):
        if c0 <= cost <= c1:
            f = 0.0 if c1 == c0 else math.log(cost / c0) / math.log(c1 / c0)
            return math.exp((1 - f) * math.log(e0) + f * math.log(e1)), "interpolated"
    return pts[0][1], "at a measured level"


def _compare_to_uniform(rows: list[dict], key: str) -> list[dict]:
    """For each adaptive row, its standing against the uniform levels on ``key``.

    Measured points only, for the verdict: ``dominates`` are the uniform levels
    (reference included) that cost at least as much and are less accurate;
    ``dominated_by`` those that cost at most as much and are at least as
    accurate (``within_spread`` when all of those overlap the adaptive run's
    min–max cost, i.e. the timing cannot separate them).  Neither is a
    trade-off.  ``curve_ratio`` is the uniform curve's error at the same cost
    over the adaptive error (> 1: adaptive more accurate at equal cost).
    """
    uniform = [r for r in rows if r["kind"] in ("uniform", "reference")]
    out = []
    for a in sorted((r for r in rows if r["kind"] == "adaptive"),
                    key=lambda r: (r["level"], r["refine_threshold_m"])):
        cost, err = a["wall_per_sim_s_median"], a[key]
        dominates = [u for u in uniform if u["wall_per_sim_s_median"] >= cost and u[key] > err]
        dominated = [u for u in uniform if u["wall_per_sim_s_median"] <= cost and u[key] <= err]

        def overlap(u):
            return (u["wall_per_sim_s_min"] <= a["wall_per_sim_s_max"]
                    and a["wall_per_sim_s_min"] <= u["wall_per_sim_s_max"])
        curve, where = _uniform_curve_error(rows, key, cost)
        out.append(dict(
            row=a, dominates=dominates, dominated_by=dominated,
            within_spread=bool(dominated) and all(overlap(u) for u in dominated),
            curve_error=curve, curve_where=where,
            curve_ratio=(curve / err) if (curve is not None and err > 0) else None))
    return out


def _levels(us: list[dict], key: str = "") -> str:
    mark = lambda u: " †" if key == "rms_frac_rest" and _other(u) else ""  # noqa: E731
    return ", ".join(f"L{u['level']}{mark(u)}" for u in sorted(us, key=lambda u: u["level"]))


def _comparison_table(rows: list[dict], key: str) -> list[str]:
    body = []
    for c in _compare_to_uniform(rows, key):
        a = c["row"]
        if c["dominated_by"]:
            verdict = "dominated by uniform " + _levels(c["dominated_by"], key)
            if c["within_spread"]:
                verdict += " (cost within the timing spread)"
        elif c["dominates"]:
            verdict = "dominates uniform " + _levels(c["dominates"], key)
        else:
            verdict = "trade-off (no uniform level is better in both)"
        curve = (f"{_pct(c['curve_error'])} ({c['curve_ratio']:.2g}×)"
                 if c["curve_ratio"] is not None else c["curve_where"])
        mark = " †" if key == "rms_frac_rest" and _other(a) else ""
        body.append([a["label"] + mark, _cost_text(a), _pct(a[key]), curve, verdict])
    return _table(["adaptive run", "wall s / sim s", "RMS / side",
                   "uniform curve at that cost (its error / adaptive error)", "verdict"], body)


def _verdict_sentences(rows: list[dict], key: str, what: str) -> str:
    comps = _compare_to_uniform(rows, key)
    below = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] > 1]
    above = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] <= 1]
    wins = [c for c in comps if c["dominates"] and not c["dominated_by"]]
    losses = [c for c in comps if c["dominated_by"]]
    name = lambda c: (c["row"]["label"].replace("adaptive ", "")  # noqa: E731
                      + (" †" if key == "rms_frac_rest" and _other(c["row"]) else ""))
    parts = [f"**{what}:** "]
    if wins:
        parts.append("the adaptive mesh dominates some uniform level (cheaper *and* more "
                     "accurate) at " + "; ".join(
                         f"{name(c)} (over uniform {_levels(c['dominates'], key)})" for c in wins)
                     + ". ")
    else:
        parts.append("no adaptive run is both cheaper and more accurate than any uniform "
                     "level. ")
    if losses:
        parts.append("A uniform level is both cheaper and at least as accurate as "
                     + "; ".join(f"{name(c)} (uniform {_levels(c['dominated_by'], key)}"
                                 + (", within the timing spread" if c["within_spread"] else "")
                                 + ")" for c in losses) + ". ")
    if below or above:
        parts.append(f"Against the log–log interpolated uniform curve, {len(below)} of "
                     f"{len(below) + len(above)} adaptive runs inside its cost range lie below "
                     "it (more accurate at equal cost)"
                     + (": " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×" for c in below)
                        if below else "")
                     + ("; above it: " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×"
                                                    for c in above) if above else "")
                     + ".")
    return "".join(parts)


def _why_table(rows: list[dict]) -> list[str]:
    """Triangles bought and cost per triangle-step, adaptive against the uniform
    level of nearest cost: why equal cost buys fewer triangles."""
    uni = [r for r in rows if r["kind"] in ("uniform", "reference")]
    ada = sorted((r for r in rows if r["kind"] == "adaptive"),
                 key=lambda r: (r["level"], r["refine_threshold_m"]))
    if not uni or not ada:
        return []

    def per_tri(r):         # µs of wall time per triangle per step
        return 1e6 * r["wall_per_sim_s_median"] * r["time_step_s"] / max(r["triangles_mean"], 1)
    body = []
    for a in ada:
        near = min(uni, key=lambda u: abs(math.log(u["wall_per_sim_s_median"]
                                                   / a["wall_per_sim_s_median"])))
        body.append([a["label"], f"{a['triangles_mean']:.0f} / {a['triangles_max']}",
                     f"{per_tri(a):.1f}", f"{a['cg_iterations_per_step']:.0f}",
                     _pct(a["lod_share_median"]), _pct(a["unattributed_share_median"]),
                     near["label"], f"{near['triangles_mean']:.0f}", f"{per_tri(near):.1f}",
                     f"{near['cg_iterations_per_step']:.0f}",
                     _pct(near["unattributed_share_median"])])
    return _table(["adaptive run", "triangles mean / max", "µs per triangle-step",
                   "CG it. / step", "LOD share", "unattributed", "uniform of nearest cost",
                   "triangles", "µs per triangle-step", "CG it. / step", "unattributed"], body)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def _other(row: dict) -> bool:
    return row["kind"] != "reference" and bool(row.get("rest_other_shape"))


def _same_computations(rows: list[dict]) -> list[tuple[dict, dict]]:
    """Adaptive pairs (same threshold, different maximum level) that did the
    same work and got the same errors: the higher maximum was never reached."""
    ada = sorted((r for r in rows if r["kind"] == "adaptive"),
                 key=lambda r: (r["refine_threshold_m"], r["level"]))
    pairs = []
    for a, b in zip(ada, ada[1:]):
        if (a["refine_threshold_m"] == b["refine_threshold_m"]
                and a["vertex_steps"] == b["vertex_steps"]
                and a["cg_iterations"] == b["cg_iterations"]
                and a["rms_frac_motion"] == b["rms_frac_motion"]
                and a["rms_frac_rest"] == b["rms_frac_rest"]):
            pairs.append((a, b))
    return pairs


def _rest_shape_section(rows: list[dict]) -> list[str]:
    """Where each run at rest is farthest from the reference, and which way."""
    body = []
    for r in rows:
        if r["kind"] == "reference":
            continue
        body.append([r["label"] + (" †" if _other(r) else ""), _pct(r["rms_frac_rest"]),
                     _pct(r["max_frac_rest"]), _pct(r["max_frac_motion"]),
                     f"({r['rest_worst_u_m']:.3g}, {r['rest_worst_v_m']:.3g})",
                     ", ".join(f"{1e3 * r[f'rest_worst_d{c}_m']:+.1f}" for c in "xyz")])
    others = [r for r in rows if _other(r)]
    text = ("**At rest: which shape.** For each run, the material point (u, v) farthest from "
            "the reference at rest and the offset there. ")
    if others:
        text += (f"{len(others)} run{'s' if len(others) > 1 else ''} (†) "
                 f"{'have' if len(others) > 1 else 'has'} the largest distance at rest over "
                 "twice the largest while moving: not a small drift but a different "
                 "equilibrium (e.g. a fold that buckled the other way; the offsets show where "
                 "and which way). For those, the at-rest verdicts above compare which shape a "
                 "run fell into, not how accurate its mesh is.")
    else:
        text += "No run settled into a visibly different shape."
    return ([text, ""] + _table(["run", "RMS at rest", "max at rest", "max during motion",
                                  "farthest point (u, v) m", "offset there (x, y, z) mm"],
                                 body) + [""])


def _markdown(result: dict) -> str:
    s, m, rows = result["settings"], result["machine"], result["rows"]
    times = s["times"]
    tags = [_time_tag(t) for t in times] + ["rest"]
    ref = next(r for r in rows if r["kind"] == "reference")
    half = next((r for r in rows if r["kind"] == "half_step"), None)
    rest = result["rest"]
    md = [f"# cloth-lod bench: {s['scene']}", ""]
    md += [f"Command: `{s['command']}` (or `python -m cloth_lod_ros.bench` with the same "
           "arguments)  ",
           f"Machine: {m['cpu_model']}, {m['logical_cpus']} logical CPUs (each run pinned to "
           f"CPU {m['pinned_cpu']}, one thread), {m['platform']}; Python {m['python']}, "
           f"numpy {m['numpy']}, scipy {m['scipy']}; commit {m['git_commit'] or '?'}; "
           f"{m['date']}.  ",
           f"Wall time of the whole benchmark: {result['wall_s'] / 60:.1f} min; 1-minute load "
           f"average during the runs {result['load_min']:.2f}–{result['load_max']:.2f} "
           "(the machine is shared; a load above 1 on 2 CPUs means other work competed for "
           "the cores, so compare the min–max ranges, not only the medians).", ""]
    md += ["## Set-up", "",
           f"- Scene `{s['scene']}`, {s['duration']:g} s simulated, h = {s['time_step']:.6g} s; "
           f"cloth side {s['side_m']:g} m (0.1 % of the side = {s['side_m']:g} mm).",
           f"- Reference: uniform level {s['reference_level']}, same h. "
           + s["reference_note"],
           f"- Error: RMS and max distance from the reference over a {s['grid']} × {s['grid']} "
           f"grid of material points, as a fraction of the side, at t = "
           + ", ".join(f"{t:.4g}" for t in times) + " s and at rest. \"During motion\" is the "
           "RMS over all points and those times.",
           f"- At rest: the first time after {s['duration']:g} s at which the reference's "
           f"kinetic energy per unit mass stayed below {s['rest_threshold']:g} J/kg for "
           f"{s['rest_window']:g} s, capped at {s['rest_cap']:g} s: "
           + (f"t = {rest['time']:g} s." if rest["at_rest"] else
              f"**not reached by the cap**; sampled at t = {rest['time']:g} s "
              f"(reference kinetic energy {rest['ke_per_mass']:.2g} J/kg).")
           + " Every run is sampled at that time; its own kinetic energy there is in the "
           "CSV (`ke_per_mass_at_rest`).",
           f"- Cost over the first {s['duration']:g} s only: wall seconds per simulated second "
           f"(median and min–max of {s['repeats']} runs, each a fresh process pinned to one "
           "CPU, all thread pools at 1), vertex-steps, CG iterations, share of wall time in "
           "LOD (criterion, splits/merges, refresh of compact arrays). The reference at h/2 "
           "runs once (it is there for its error, not its cost).",
           f"- Adaptive runs start from level {s['initial_level']} and refine where the "
           "deviation d exceeds the threshold; coarsen threshold = "
           f"{s['coarsen_ratio']:g} × threshold (the scene's ratio)."]
    md.append(f"- The bench's clock around `ClothSim.step()` read at most "
              f"{_pct(max(r['timing_overhead_share_max'] for r in rows))} more than the "
              "step's own clock (`StepStats.step_ms`): sampling and bookkeeping are outside "
              "the timed calls.")
    if any(r["repeat_max_deviation_m"] > 0 for r in rows):
        md.append("- **Repeats differ** (see `repeat_max_deviation_m`): runs are not "
                  "deterministic.")
    else:
        md.append("- Every repeat reproduced the first one's samples bit for bit.")
    md.append("")
    if half is not None:
        md += ["## What \"converged\" means", "",
               f"Distance of the reference (uniform L{ref['level']}, h) from the same mesh at "
               f"h/2 (implicit Euler's numerical damping depends on h):", ""]
        md += _table(["t"] + [t.replace("s", " s") if t != "rest" else "rest" for t in tags],
                     [["RMS / side"] + [_pct(half[f"rms_frac_{t}"]) for t in tags],
                      ["max / side"] + [_pct(half[f"max_frac_{t}"]) for t in tags]])
        md += ["", "Errors below are spatial (mesh) errors at fixed h; where they are smaller "
               "than this row, the time step, not the mesh, limits the accuracy."]
        finest = max((r for r in rows if r["kind"] == "uniform"), key=lambda r: r["level"],
                     default=None)
        if finest is not None and finest["rms_frac_motion"] > 0:
            md[-1] += (f" During motion, halving h moves the reference "
                       f"{half['rms_frac_motion'] / finest['rms_frac_motion']:.3g}× as far as "
                       f"refining from uniform L{finest['level']} to L{ref['level']} does "
                       f"({_pct(half['rms_frac_motion'])} against "
                       f"{_pct(finest['rms_frac_motion'])} RMS); at rest "
                       f"{_pct(half['rms_frac_rest'])} against {_pct(finest['rms_frac_rest'])}.")
        md.append("")
    md += ["## Results", ""]
    header = (["run", "wall s / sim s", "ms / step", "CPU s / sim s", "vertex-steps",
               "CG it. (per step)", "triangles mean / max", "LOD share"]
              + [f"RMS {t.replace('s', ' s') if t != 'rest' else 'at rest'}" for t in tags]
              + ["RMS motion", "max motion", "max at rest"])
    body = []
    for r in rows:
        if r["kind"] == "half_step":
            continue
        body.append([r["label"], _cost_text(r), f"{r['ms_per_step_median']:.3g}",
                     f"{r['cpu_per_sim_s_median']:.3g}", f"{r['vertex_steps']:,}",
                     f"{r['cg_iterations']:,} ({r['cg_iterations_per_step']:.0f})",
                     f"{r['triangles_mean']:.0f} / {r['triangles_max']}",
                     _pct(r["lod_share_median"]) if r["kind"] == "adaptive" else "—"]
                    + [_pct(r[f"rms_frac_{t}"]) + (" †" if t == "rest" and _other(r) else "")
                       for t in tags]
                    + [_pct(r["rms_frac_motion"]), _pct(r["max_frac_motion"]),
                       _pct(r["max_frac_rest"])])
    md += _table(header, body)
    if any(_other(r) for r in rows):
        md += ["", "† settled into another shape than the reference (its largest distance at "
               "rest is more than twice its largest distance during motion); see "
               "\"At rest: which shape\" below."]
    same = _same_computations(rows)
    if same:
        md += ["", "Same computation, different labels: " + "; ".join(
            f"{b['label']} never refined past what {a['label']} did (same vertex-steps, CG "
            f"iterations and errors), so the gap between their costs, "
            f"{a['wall_per_sim_s_median']:.3g} and {b['wall_per_sim_s_median']:.3g} s per "
            f"simulated second, is timing noise" for a, b in same)
            + ". That is how far apart two measurements of one computation came on this "
            "machine."]
    md += ["", "![error against cost](bench.png)", ""]
    paper = result.get("paper")
    md += ["## The paper's comparison on our code", ""]
    if paper:
        md += [f"Mean time per step over the first {s['duration']:g} s (the paper's \"frame\"), "
               f"adaptive (max level {paper['level']}, threshold "
               f"{paper['threshold'] * 1e3:g} mm, as in the scene) against uniform level "
               f"{paper['level']} ({paper['grid']} × {paper['grid']} particles), median "
               "(min–max) of the repeats; the ratio is computed per round (runs back to back).",
               ""]
        md += _table(
            ["", "adaptive ms / step", "uniform ms / step", "ratio", "LOD share",
             "adaptive RMS motion / rest", "uniform RMS motion / rest"],
            [["paper (2003 hardware)", f"{PAPER['adaptive_ms']:.1f}",
              f"{PAPER['uniform_ms']:.1f}", f"{PAPER['ratio']:.1f}×", "~3 %", "not given",
              "not given"],
             ["this code", paper["adaptive_ms_text"], paper["uniform_ms_text"],
              paper["ratio_text"],
              f"{_pct(paper['lod_share'])} (≤ {_pct(paper['lod_share_upper'])})",
              f"{_pct(paper['adaptive_rms_motion'])} / {_pct(paper['adaptive_rms_rest'])}",
              f"{_pct(paper['uniform_rms_motion'])} / {_pct(paper['uniform_rms_rest'])}"]])
        md += ["", "LOD share: as `StepStats.lod_ms` books it; in brackets, plus the "
               "adaptive run's unattributed share beyond the uniform run's (mostly the "
               "criterion's force evaluation on steps where the mesh changes). Errors: RMS "
               "distance from the reference, as a fraction of the side.", ""]
    else:
        md += ["Not available: the run needs the scene's level among `--levels` and "
               "`--max-levels` and its refine threshold among `--thresholds`.", ""]
    md += ["## Does adaptive beat uniform?", "",
           "Verdicts use measured points only; \"dominates\" means cheaper (median wall "
           "time) *and* more accurate. The uniform curve column interpolates between "
           "measured uniform levels in log–log.", ""]
    for key, what in (("rms_frac_motion", "During motion"), ("rms_frac_rest", "At rest")):
        md += [_verdict_sentences(rows, key, what), ""] + _comparison_table(rows, key) + [""]
    md += _rest_shape_section(rows)
    why = _why_table(rows)
    if why:
        md += ["Where the time goes: the triangles each run simulates, and what a "
               "triangle-step costs (wall time per step / mean triangles), against the "
               "uniform level of nearest cost. \"Unattributed\" is step time that "
               "`StepStats` books to none of LOD, forces, assembly and solve: energies and "
               "statistics in every run, and with LOD on also the criterion's force "
               "evaluation on steps where the mesh then changes (the solver evaluates the new "
               "mesh again and books only that one). The LOD share is therefore a lower "
               "bound; LOD share + the adaptive run's extra unattributed share is about the "
               "upper one.", ""] + why + [""]
    if half is not None:
        md += [f"For scale: the reference itself moves {_pct(half['rms_frac_motion'])} RMS "
               "during motion when the time step is halved, "
               f"and {_pct(half['rms_frac_rest'])} at rest.", ""]
    md += ["Files: `bench.csv` (one row per configuration), `bench.json` (the same rows plus "
           "machine, settings and every repeat), `bench.png`.", ""]
    return "\n".join(md)


# --------------------------------------------------------------------------
# Command line.
# --------------------------------------------------------------------------

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
    from .config import SceneError, find_scene_file, load_scene
    from .metrics import material_grid

    args._out_given = args.out is not None
    if args.out is None:
        args.out = "out/bench"
    if getattr(args, "from_json", None):
        return _rerender(Path(args.from_json), args.out if args._out_given else None)
    started = _time.perf_counter()
    say = (lambda *a: None) if getattr(args, "quiet", False) else (
        lambda *a: print(*a, flush=True))
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
            print("usage: python -m cloth_lod_ros.bench --worker SPEC.json", file=sys.stderr)
            return 2
        return _worker_main(argv[1])
    parser = add_arguments(argparse.ArgumentParser(
        prog="python -m cloth_lod_ros.bench", description=__doc__.split("\n\n")[0]))
    args = parser.parse_args(argv)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
