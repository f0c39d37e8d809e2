"""``cloth-lod bench --contact``: the contact scenes against their converged motion.

Issue 31: the default settings must stay close to the converged motion of the
same model on scenes with contact, not only on the no-contact default scene.
For each of :data:`CONTACT_SCENES` (``drop_on_sphere``, ``table_drape``,
``grasp_lift``), over :data:`DURATION` = 3 s:

* **candidate**: the scene as shipped (adaptive, its level, ``sdirk2`` with
  error control), ``repeats`` times, each in a fresh process pinned to one
  CPU with one thread (:func:`.process.run_in_process`), in rounds;
* **reference** (:class:`~cloth_lod_ros.tools.reference.ConvergedReference`):
  the same scene on the uniform mesh at the scene's level, ``sdirk2`` at a
  fixed ``h_ref = H / divisor`` (``H`` the frame period; default divisor 8),
  3 Newton iterations per stage to 1e-8 m, once;
* **the reference's own error**: a second run at ``2 h_ref``.  Contact makes
  the motion non-smooth, so the order of convergence is not assumed: the
  table states the whole difference ``|ref(2 h_ref) - ref(h_ref)|`` (the
  error of the run at ``2 h_ref``, and a bound on the reference's for any
  order >= 1) and, beside it, the second-order (Richardson) estimate, that
  difference / 3.
* **the scene's sensitivity floor**: the reference again with every
  particle's start moved by :data:`PERTURB` (1 nm) in a seeded random
  direction (:mod:`..sensitivity`).  A cloth that buckles into folds over a
  ball or on a floor picks their number and direction from whatever breaks
  its symmetry first, rounding included; the distance between the two runs
  is the scene's own sensitivity, and an error against the reference below
  it cannot be told from it.

Error: RMS (and largest) 3-D distance from the reference over a 21 x 21 grid
of material points, as a fraction of the cloth's larger side, at 1, 2 and
3 s.  Cost: CPU seconds per simulated second of the candidate's steps
(median and min-max over the repeats), and per frame its integrator steps,
rejected steps and linear solves.

References are expensive (a level-6 run at ``H/8`` takes minutes), so each
reference run's result is cached as JSON under ``cache`` (default
``$CLOTH_LOD_CACHE`` or ``/tmp/cloth_lod_bench_cache``), keyed by its whole
run specification and a SHA-256 of the simulator's sources
(``cloth_lod_ros/sim``): a change to the model runs them again.  Writes
``contact.json`` and ``contact.md`` in ``--out``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time as _time
from pathlib import Path

import numpy as np

__all__ = ["CONTACT_SCENES", "DURATION", "TIMES", "run_contact", "markdown", "sim_fingerprint",
           "cache_dir"]

CONTACT_SCENES = ("drop_on_sphere", "table_drape", "grasp_lift")
#: Simulated seconds, and the sample times (s).
DURATION = 3.0
TIMES = (1.0, 2.0, 3.0)
#: --quick: a smoke test (level 3, 0.5 s, h_ref = H/2).
QUICK = dict(level=3, duration=0.5, times=(0.25, 0.5), divisor=2)
#: m: how far the sensitivity run's start positions are moved (RMS per coordinate).
PERTURB = 1e-9


def sim_fingerprint() -> str:
    """SHA-256 (16 hex digits) of the simulator's sources: paths and bytes of
    every ``.py`` under ``cloth_lod_ros/sim``."""
    root = Path(__file__).resolve().parents[2] / "sim"
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def cache_dir() -> Path:
    return Path(os.environ.get("CLOTH_LOD_CACHE") or "/tmp/cloth_lod_bench_cache")


def _cache_key(spec: dict, scene_text: str, fingerprint: str) -> str:
    ident = {k: spec[k] for k in ("scene", "overrides", "points", "times", "duration")}
    if spec.get("perturb"):
        ident["perturb"] = spec["perturb"]
    text = json.dumps(dict(ident, scene_text=scene_text, sim=fingerprint), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _scene_text(scene: str) -> str:
    from ...sim.scene.config import find_scene_file
    path = find_scene_file(scene)
    return path.read_text() if path.exists() else scene


def _reference_run(spec: dict, tmp: Path, tag: str, cache: Path | None, fingerprint: str,
                   progress) -> dict:
    """One reference run's worker result, from the cache when it holds it."""
    from .process import run_in_process
    path = None
    if cache is not None:
        key = _cache_key(spec, _scene_text(spec["scene"]), fingerprint)
        path = cache / f"{Path(spec['scene']).stem}_{key}.json"
        if path.exists():
            progress(f"  {tag:48s} cached: {path}")
            return dict(json.loads(path.read_text()), cached=str(path))
    start = _time.perf_counter()
    result = run_in_process(spec, tmp, tag)
    c = result["cost"]
    progress(f"  {tag:48s} {c['cpu_s']:8.1f} CPU s ({_time.perf_counter() - start:.0f} s)")
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result))
    return result


def _distances(samples, ref_samples, side: float) -> list[dict]:
    from ..reference import point_distances
    out = []
    for a, b in zip(samples, ref_samples):
        d = point_distances(a, b)
        out.append(dict(rms=float(np.sqrt(np.mean(d ** 2))) / side, max=float(d.max()) / side))
    return out


def run_contact(out: Path, repeats: int = 3, quick: bool = False, cpu: int | None = None,
                progress=print, scenes=CONTACT_SCENES, divisor: int | None = None,
                cache: Path | None | bool = True) -> dict:
    """Measure every contact scene (module docstring); write and return the table.

    Args:
        out: directory for ``contact.json`` and ``contact.md``.
        repeats: timed runs of each candidate.
        quick: the smoke-test settings of :data:`QUICK`.
        cpu: the CPU every run is pinned to (default: the last one allowed).
        scenes: built-in scene names or paths.
        divisor: ``h_ref = H / divisor`` (default 8; quick 2).
        cache: the reference cache directory; True: :func:`cache_dir`;
            None/False: no cache.
    """
    from ...sim.scene.config import load_scene
    from ...sim.mesh.sampling import material_grid
    from ..reference import ConvergedReference
    from .process import run_in_process
    from .machine import write_suite
    settings = dict(QUICK) if quick else dict(level=None, duration=DURATION, times=TIMES,
                                              divisor=8)
    if divisor is not None:
        settings["divisor"] = int(divisor)
    cache = cache_dir() if cache is True else (Path(cache) if cache else None)
    cpu = sorted(os.sched_getaffinity(0))[-1] if cpu is None else cpu
    fingerprint = sim_fingerprint()
    Path(out).mkdir(parents=True, exist_ok=True)
    duration, times = settings["duration"], list(settings["times"])
    base = [f"simulation.duration={duration!r}"] + (
        [f"cloth.level={settings['level']}"] if settings["level"] is not None else [])
    start = _time.time()
    plans = []
    for name in scenes:
        scene = load_scene(name, base)
        h = scene.simulation.time_step
        ref = ConvergedReference(scene.cloth.level, h, settings["divisor"])
        points = material_grid(scene.cloth.width, scene.cloth.height, 21)
        spec = dict(scene=name, points=points.tolist(),
                    times=[round(t / h) * h for t in times], duration=round(duration / h) * h,
                    rest=None, cpu=cpu)
        plans.append(dict(name=name, scene=scene, ref=ref, spec=spec,
                          side=max(scene.cloth.width, scene.cloth.height)))
    rows = []
    with tempfile.TemporaryDirectory(prefix="cloth_contact_") as tmp:
        candidates: dict[str, list] = {p["name"]: [] for p in plans}
        for rnd in range(repeats):           # rounds: load spreads over the scenes
            for i, p in enumerate(plans):
                spec = dict(p["spec"], overrides=list(base))
                result = run_in_process(spec, Path(tmp), f"contact{i}_r{rnd}")
                candidates[p["name"]].append(result)
                c = result["cost"]
                progress(f"  {p['name']:48s} {c['cpu_s'] / c['simulated_s']:7.3f} CPU s/s  "
                         f"round {rnd + 1}/{repeats}")
        for i, p in enumerate(plans):
            refs = {}
            for run in p["ref"].runs(mesh_check=False):
                spec = dict(p["spec"], overrides=base + run["overrides"])
                refs[run["kind"]] = _reference_run(spec, Path(tmp), f"{p['name']} {run['key']}",
                                                   cache, fingerprint, progress)
                if run["kind"] == "reference":
                    spec = dict(spec, perturb=dict(size=PERTURB, seed=1))
                    refs["reference_perturbed"] = _reference_run(
                        spec, Path(tmp), f"{p['name']} {run['key']} moved {PERTURB:g} m",
                        cache, fingerprint, progress)
            rows.append(_row(p, candidates[p["name"]], refs, times))
    result = write_suite(out, "contact", rows, repeats, cpu, start, markdown)
    result.update(divisor=settings["divisor"], duration=duration, times=times,
                  sim_fingerprint=fingerprint)
    (out / "contact.json").write_text(json.dumps(result, indent=1))
    (out / "contact.md").write_text(markdown(result))
    return result


def _row(plan: dict, candidates: list[dict], refs: dict, times: list[float]) -> dict:
    """One scene's row: errors per time (the first repeat's samples: the runs are
    deterministic), the reference's own error, and the cost over the repeats."""
    side = plan["side"]
    ref, ref2 = refs["reference"], refs["reference_2h"]
    errors = _distances(candidates[0]["samples"], ref["samples"], side)
    own = _distances(ref2["samples"], ref["samples"], side)
    floor = _distances(refs["reference_perturbed"]["samples"], ref["samples"], side)
    costs = [c["cost"] for c in candidates]
    per_s = sorted(c["cpu_s"] / c["simulated_s"] for c in costs)
    wall = sorted(c["wall_s"] / c["simulated_s"] for c in costs)
    med = costs[int(np.argsort([c["cpu_s"] for c in costs])[(len(costs) - 1) // 2])]
    same = all(np.array_equal(np.asarray(c["samples"]), np.asarray(candidates[0]["samples"]))
               for c in candidates[1:])
    scene = plan["scene"]
    return dict(
        scene=scene.name, scene_arg=plan["name"], level=scene.cloth.level, frame_period_s=scene.simulation.time_step,
        integrator=scene.simulation.integrator, lod=bool(scene.lod.enabled),
        times=times, rms_frac=[e["rms"] for e in errors], max_frac=[e["max"] for e in errors],
        reference=plan["ref"].describe(), reference_time_step=plan["ref"].time_step,
        reference_diff_rms_frac=[e["rms"] for e in own],
        reference_diff_max_frac=[e["max"] for e in own],
        reference_richardson_rms_frac=[e["rms"] / 3.0 for e in own],
        sensitivity_rms_frac=[e["rms"] for e in floor],
        sensitivity_max_frac=[e["max"] for e in floor], sensitivity_perturbation_m=PERTURB,
        reference_cpu_s=ref["cost"]["cpu_s"], reference_2h_cpu_s=ref2["cost"]["cpu_s"],
        reference_cached=bool(ref.get("cached")),
        cpu_per_sim_s_median=float(np.median(per_s)), cpu_per_sim_s_min=per_s[0],
        cpu_per_sim_s_max=per_s[-1], wall_per_sim_s_median=float(np.median(wall)),
        substeps_per_frame=med["substeps"] / med["steps"],
        rejected_steps=med["rejected_steps"], solves_per_frame=med["solves"] / med["steps"],
        unconverged_steps=med["unconverged_steps"], triangles_mean=med["triangles_mean"],
        repeats_identical=bool(same), load=[min(c["loadavg_start"] for c in costs),
                                            max(c["loadavg_end"] for c in costs)])


def markdown(result: dict) -> str:
    """The contact table (``contact.md``, and the report's section)."""
    from .performance import contact_table
    return contact_table(result)
