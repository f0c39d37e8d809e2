"""``cloth-lod bench --local``: adaptivity where detail is local (issue 33).

Three scenes at the size where an adaptive mesh should pay (``config/bench/``:
a 2 m cloth on an 8 × 8 base, maximum level 6 and above): ``lifted_corner``
(one corner of a cloth lying on the floor lifted 0.3 m), ``table_corner`` (a
cloth draped over the corner of a table) and ``small_ball`` (a cloth dropped
over a 10 cm ball).  For each:

* a **converged reference**: uniform level ``REFERENCE_LEVEL`` (7) with the
  step's local error held to ``REFERENCE_TOLERANCE`` (1e-4 m), and its own
  mesh error: the same at one level coarser (every run steps at that
  tolerance, so the errors measured are the mesh's; a time error the runs
  share with the reference is not in them).  The
  reference runs are expensive (minutes of CPU each) and are run once and
  cached in ``--cache`` (default ``/tmp/cloth_lod_local``), keyed by the scene
  file's path, overrides, duration and sample times;
* **uniform runs** at ``UNIFORM_LEVELS`` and **adaptive runs** at
  ``ADAPTIVE`` settings (the paper's curvature criterion with the scene's
  absolute thresholds, and the detail criterion at a relative tolerance), each
  at maximum levels 6 and 7, alternated in rounds, each in a fresh process
  pinned to one CPU with one thread (:mod:`.process`).  Every run holds the
  step's local error to the reference's tolerance: at the scenes' default
  (1e-3 m) the time integration alone leaves 0.34 % on ``lifted_corner``
  (more than uniform L4's mesh error), which would hide what the mesh does.
  Every run is cached like the reference (``--cache none``: time them all
  again); a cached run's cost is that of the run that made it;
* **error**: RMS distance from the reference at a 21 × 21 grid of material
  points as a fraction of the side, the larger of its values at half and all
  of ``DURATION``; **cost**: CPU seconds per simulated second (median of the
  repeats);
* **factor below the front**: the uniform runs' cost at the adaptive run's
  error (log-log interpolation between the uniform levels, their end
  segments extended) over the adaptive run's cost: above 1, the adaptive run
  is cheaper than a uniform run of equal error.

Writes ``local.json``, ``local.md`` and one ``local_<scene>.png`` (error
against cost, uniform levels joined, adaptive settings as stars) into
``--out``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time as _time
from pathlib import Path

import numpy as np

__all__ = ["LOCAL_SCENES", "ADAPTIVE", "scene_path", "front_cost", "run_local", "markdown",
           "plot_scene"]

LOCAL_SCENES = ("lifted_corner", "table_corner", "small_ball")
DURATION = 1.0
REFERENCE_LEVEL = 7
REFERENCE_TOLERANCE = 1e-4
UNIFORM_LEVELS = (4, 5, 6)
#: (label, overrides) of the adaptive settings, each run at maximum levels 6 and 7.
ADAPTIVE = (("curvature, 1 mm", ["lod.criterion=curvature"]),
            ("detail, tolerance 4", ["lod.criterion=detail", "lod.tolerance=4.0"]),
            ("detail, tolerance 1", ["lod.criterion=detail", "lod.tolerance=1.0"]))
MAX_LEVELS = (6, 7)
QUICK = dict(scenes=("lifted_corner",), uniform=(4, 5), adaptive=ADAPTIVE[:2], max_levels=(5,),
             reference_level=6, duration=0.3)


def scene_path(name: str) -> Path:
    """The YAML file of local-detail scene ``name`` (``config/bench/NAME.yaml`` of
    the source tree)."""
    from .process import _package_root
    return Path(_package_root()) / "config" / "bench" / f"{name}.yaml"


def _key(scene: str, overrides: list, duration: float, times: list) -> str:
    text = json.dumps([os.path.abspath(scene), sorted(overrides), duration, times, ""])
    return hashlib.sha1(text.encode()).hexdigest()[:12]


def _run(spec: dict, cache: Path | None, workdir: Path, tag: str) -> dict:
    """One run in a pinned process; with ``cache``, read from / written to it."""
    from .process import run_in_process
    path = None
    if cache is not None:
        path = cache / (_key(spec["scene"], spec["overrides"], spec["duration"], spec["times"])
                        + ".json")
        if path.exists():
            return json.loads(path.read_text())
    result = run_in_process(spec, workdir, tag)
    if path is not None:
        cache.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result))
    return result


def _error(samples, reference, side: float) -> float:
    """Largest RMS distance over the sample times, as a fraction of ``side``."""
    d = np.linalg.norm(np.asarray(samples) - np.asarray(reference), axis=-1)
    return float(np.sqrt((d ** 2).mean(axis=-1)).max() / side)


def front_cost(uniform: list[tuple[float, float]], error: float) -> float:
    """The uniform front's cost at ``error``: of ``uniform`` ``[(cost, error), ...]``
    the runs no cheaper run beats in error, joined in log-log, the end segments
    extended (nan with fewer than two)."""
    # The front: the uniform runs no cheaper one beats in error (a finer
    # level whose triangles lie across the reference's can be less accurate).
    points, best = [], np.inf
    for c, e in sorted((c, e) for c, e in uniform if e > 0 and c > 0):
        if e < best:
            points.append((e, c))
            best = e
    points.sort()
    if len(points) < 2 or not error > 0:
        return float("nan")
    le = np.log([p[0] for p in points])
    lc = np.log([p[1] for p in points])
    x = np.log(error)
    i = int(np.clip(np.searchsorted(le, x) - 1, 0, len(le) - 2))
    slope = (lc[i + 1] - lc[i]) / (le[i + 1] - le[i])
    return float(np.exp(lc[i] + slope * (x - le[i])))


def run_local(out: Path, repeats: int = 1, quick: bool = False, cpu: int | None = None,
              progress=print, cache: Path | None = Path("/tmp/cloth_lod_local"),
              scenes=None) -> dict:
    """Run the local-detail suite (``scenes``: names of LOCAL_SCENES, default all);
    write ``local.json``, ``local.md`` and the plots."""
    from ...sim.scene.config import load_scene
    from ...sim.mesh.sampling import material_grid
    from .machine import write_suite
    q = QUICK if quick else {}
    scenes = scenes or q.get("scenes", LOCAL_SCENES)
    unknown = [name for name in scenes if name not in LOCAL_SCENES]
    if unknown:
        from .plan import BenchError
        raise BenchError(f"--local-scenes: unknown {unknown[0]!r} (one of "
                         f"{', '.join(LOCAL_SCENES)})")
    levels = q.get("uniform", UNIFORM_LEVELS)
    adaptive = q.get("adaptive", ADAPTIVE)
    max_levels = q.get("max_levels", MAX_LEVELS)
    ref_level = q.get("reference_level", REFERENCE_LEVEL)
    duration = q.get("duration", DURATION)
    cpu = sorted(os.sched_getaffinity(0))[-1] if cpu is None else cpu
    out.mkdir(parents=True, exist_ok=True)
    start = _time.time()
    rows, references = [], {}
    with tempfile.TemporaryDirectory(prefix="cloth_local_") as tmp:
        for name in scenes:
            path = str(scene_path(name))
            scene = load_scene(path)
            times = [duration / 2, duration]        # (the worker rounds them to frames)
            side = max(scene.cloth.width, scene.cloth.height)
            points = material_grid(scene.cloth.width, scene.cloth.height, 21).tolist()
            base = dict(scene=path, points=points, times=times, duration=duration, cpu=cpu,
                        rest=None)
            tol = f"simulation.error_tolerance={REFERENCE_TOLERANCE!r}"
            ref_over = ["lod.enabled=false", f"cloth.level={ref_level}", tol]
            checks = {"mesh": ["lod.enabled=false", f"cloth.level={ref_level - 1}",
                               f"simulation.error_tolerance={REFERENCE_TOLERANCE!r}"]}
            progress(f"  {name}: reference L{ref_level} (cached in {cache})")
            ref = _run(dict(base, overrides=ref_over), cache, Path(tmp), f"{name}_ref")
            own = {kind: _error(_run(dict(base, overrides=over), cache, Path(tmp),
                                     f"{name}_{kind}")["samples"], ref["samples"], side)
                   for kind, over in checks.items()}
            references[name] = dict(level=ref_level, tolerance=REFERENCE_TOLERANCE,
                                    own_error=own, cpu_s=ref["cost"]["cpu_s"])
            configs = [(f"uniform L{lv}", "uniform", lv,
                        ["lod.enabled=false", f"cloth.level={lv}", tol]) for lv in levels]
            configs += [(f"{label}, max L{lv}", "adaptive", lv,
                         over + [f"cloth.level={lv}", tol])
                        for label, over in adaptive for lv in max_levels]
            costs = {c[0]: [] for c in configs}
            errors, tris = {}, {}
            for rnd in range(repeats):
                for index, (label, kind, lv, over) in enumerate(configs):
                    result = _run(dict(base, overrides=over), cache if rnd == 0 else None,
                                  Path(tmp), f"{name}_{index}_{rnd}")
                    c = result["cost"]
                    costs[label].append(c["cpu_s"] / c["simulated_s"])
                    errors[label] = _error(result["samples"], ref["samples"], side)
                    tris[label] = c["triangles_mean"]
                    progress(f"  {name:14s} {label:34s} {100 * errors[label]:7.4f} %  "
                             f"{costs[label][-1]:8.2f} CPU s/s  [{rnd + 1}/{repeats}]")
            cost = {label: float(np.median(v)) for label, v in costs.items()}
            uniform = [(cost[c[0]], errors[c[0]]) for c in configs if c[1] == "uniform"]
            for label, kind, lv, over in configs:
                front = front_cost(uniform, errors[label]) if kind == "adaptive" else None
                rows.append(dict(scene=name, label=label, kind=kind, level=lv,
                                 overrides=over, error=errors[label], cost=cost[label],
                                 triangles_mean=tris[label], front_cost=front,
                                 factor=None if front is None else front / cost[label]))
    result = write_suite(out, "local", rows, repeats, cpu, start, markdown)
    result.update(references=references, duration=duration)
    result["table"] = markdown(result)
    (out / "local.json").write_text(json.dumps(result, indent=1))
    (out / "local.md").write_text(result["table"])
    for name in scenes:
        plot_scene(out / f"local_{name}.png", name, [r for r in rows if r["scene"] == name],
                   references.get(name))
    return result


def markdown(result: dict) -> str:
    """The table per scene: uniform levels and adaptive settings, error, cost and
    the factor below the uniform front."""
    refs = result.get("references", {})
    lines = [f"Local-detail scenes ({result.get('duration', DURATION):g} s simulated; error: "
             "RMS distance from the converged reference at 21 × 21 material points, % of the "
             "side, the larger of its values at half and all of the run; cost: CPU s per "
             "simulated second, median of "
             f"{result['repeats']} repeat(s), one pinned thread; factor: the uniform cost at "
             "equal error over the run's).", ""]
    for name in dict.fromkeys(r["scene"] for r in result["rows"]):
        ref = refs.get(name, {})
        own = ", ".join(f"{k} {100 * v:.3f} %" for k, v in ref.get("own_error", {}).items())
        lines += [f"**{name}** - reference: uniform L{ref.get('level', '?')}, local error "
                  f"≤ {ref.get('tolerance', 0):g} m per step; its own error: {own}.", "",
                  "| run | error | CPU s / s | triangles | uniform cost at equal error "
                  "| factor below the front |", "|---|---|---|---|---|---|"]
        floor = ref.get("own_error", {}).get("mesh", 0.0)
        for r in (r for r in result["rows"] if r["scene"] == name):
            front = "" if r["front_cost"] is None else f"{r['front_cost']:.2f}"
            factor = "" if r["factor"] is None else f"{r['factor']:.2f}"
            if r["factor"] is not None and r["error"] < floor:
                factor += " (error below the reference's own)"
            lines.append(f"| {r['label']} | {100 * r['error']:.4f} % | {r['cost']:.2f} | "
                         f"{r['triangles_mean']:.0f} | {front} | {factor} |")
        lines.append("")
    return "\n".join(lines)


def plot_scene(path: Path, name: str, rows: list[dict], reference: dict | None) -> None:
    """Error against cost (log-log): uniform levels joined and labelled,
    adaptive settings as stars; the reference's own mesh error dashed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 5))
    uni = sorted((r for r in rows if r["kind"] == "uniform"), key=lambda r: r["level"])
    ax.plot([r["cost"] for r in uni], [100 * r["error"] for r in uni], "o-", color="k",
            label="uniform")
    for r in uni:
        ax.annotate(f"L{r['level']}", (r["cost"], 100 * r["error"]), textcoords="offset points",
                    xytext=(4, 4))
    for i, r in enumerate(r for r in rows if r["kind"] == "adaptive"):
        ax.plot(r["cost"], 100 * r["error"], "*", ms=12, color=f"C{i % 10}", label=r["label"])
    if reference and "mesh" in reference.get("own_error", {}):
        ax.axhline(100 * reference["own_error"]["mesh"], ls="--", color="grey",
                   label="reference's own mesh error")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("CPU s per simulated second")
    ax.set_ylabel("error, % of the side")
    ax.set_title(name)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
