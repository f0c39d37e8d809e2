"""``cloth-lod bench --scenes``: what each built-in scene costs, and where it goes.

Every case (each built-in scene with LOD on and off, and a few with
self-collision off where the cloth never meets itself) runs in a fresh
process pinned to one CPU with one thread, in rounds (every case once, then
again), so that ratios between cases come from one run.  Reported per case:
milliseconds per frame (median over the repeats), the real-time factor
(frame period / wall time per frame), the shares of the frame spent on LOD
bookkeeping, forces and assembly, linear solves and self-collision, solves
and integrator steps per frame, mean triangles (these of the repeat with the
median time); and for a case measured
against another (``vs``), the ratio of their times - how much self-collision
(on by default: ``auto``) costs a scene without self-contact, measured on the same
frames in the same run (and the optional ``cholmod`` backend's cases,
where it is installed, against the default's).  Writes ``scenes.json`` and
``scenes.md`` in ``--out``.  Speed only: the error against the converged motion is what the
default mode measures (contact scenes are too sensitive to small changes
for a converged reference to mean much: see the README).
"""

from __future__ import annotations

import os
import tempfile
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["SceneCase", "SCENE_CASES", "QUICK_SCENE_CASES", "run_scenes", "markdown"]

SELF = "self_collision.enabled=true"
#: The base of a self-collision comparison (the scenes' default is auto: on).
SELF_OFF = "self_collision.enabled=false"
LOD_OFF = "lod.enabled=false"
#: The optional backend: its cases run only where it is installed.
CHOLMOD = "solver.method=cholmod"


@dataclass(frozen=True)
class SceneCase:
    """One benchmarked run: ``label``, built-in ``scene``, ``overrides``,
    simulated ``duration`` (s) and ``vs``: the label of the case its time is
    compared with (None: none)."""

    label: str
    scene: str
    overrides: list = field(default_factory=list)
    duration: float = 2.0
    vs: str | None = None


SCENE_CASES = (
    SceneCase("hang_two_corners", "hang_two_corners", [], 3.0),
    SceneCase("hang_two_corners, self-collision off", "hang_two_corners", [SELF_OFF], 3.0,
              vs="hang_two_corners"),
    SceneCase("hang_two_corners, LOD off", "hang_two_corners", [LOD_OFF], 3.0),
    SceneCase("hang_two_corners, LOD off, self-collision off", "hang_two_corners",
              [LOD_OFF, SELF_OFF], 3.0, vs="hang_two_corners, LOD off"),
    SceneCase("hang_two_corners, cholmod", "hang_two_corners", [CHOLMOD], 3.0,
              vs="hang_two_corners"),
    SceneCase("grasp_lift", "grasp_lift", [], 3.0),
    SceneCase("grasp_lift, cholmod", "grasp_lift", [CHOLMOD], 3.0, vs="grasp_lift"),
    SceneCase("grasp_lift, LOD off", "grasp_lift", [LOD_OFF], 3.0),
    SceneCase("grasp_lift, LOD off, self-collision off", "grasp_lift", [LOD_OFF, SELF_OFF],
              3.0, vs="grasp_lift, LOD off"),
    SceneCase("table_drape", "table_drape", [], 2.0),
    SceneCase("drop_on_sphere", "drop_on_sphere", [], 2.0),
    SceneCase("drop_on_disc", "drop_on_disc", [], 2.0),
    SceneCase("push_with_box", "push_with_box", [], 3.0),
    SceneCase("push_with_box, LOD off", "push_with_box", [LOD_OFF], 3.0),
    SceneCase("fold_in_half", "fold_in_half", [], 3.5),
    SceneCase("fold_in_half, LOD off", "fold_in_half", [LOD_OFF], 3.5),
    SceneCase("drop_crumple", "drop_crumple", [], 2.5),
    SceneCase("drop_crumple, LOD off", "drop_crumple", [LOD_OFF], 2.5),
)
QUICK_SCENE_CASES = (
    SceneCase("hang_two_corners L3", "hang_two_corners", ["cloth.level=3"], 0.3),
    SceneCase("hang_two_corners L3, self-collision off", "hang_two_corners",
              ["cloth.level=3", SELF_OFF], 0.3, vs="hang_two_corners L3"),
    SceneCase("fold_in_half L3", "fold_in_half", ["cloth.level=3"], 0.3),
)


def run_scenes(out: Path, repeats: int = 3, quick: bool = False, cpu: int | None = None,
               cases=None, progress=print) -> dict:
    """Run every case ``repeats`` times in rounds; write and return the table."""
    from .process import run_in_process     # pinned single-thread workers
    from .machine import write_suite
    from ...sim.solve.backends import available_methods
    cases = cases or (QUICK_SCENE_CASES if quick else SCENE_CASES)
    if "cholmod" not in available_methods():
        cases = [c for c in cases if CHOLMOD not in c.overrides]
    labels = [c.label for c in cases]
    for case in cases:
        if case.vs is not None and case.vs not in labels:
            raise ValueError(f"case {case.label!r} is compared with {case.vs!r}, "
                             "which is not run")
    cpu = sorted(os.sched_getaffinity(0))[-1] if cpu is None else cpu
    out.mkdir(parents=True, exist_ok=True)
    runs: dict = {}
    start = _time.time()
    with tempfile.TemporaryDirectory(prefix="cloth_scenes_") as tmp:
        for round_index in range(repeats):
            for index, case in enumerate(cases):
                spec = dict(scene=case.scene, overrides=list(case.overrides), points=[],
                            times=[], duration=case.duration, rest=None, cpu=cpu)
                result = run_in_process(spec, Path(tmp), f"{index}_{round_index}")
                runs.setdefault(case.label, []).append(result["cost"])
                c = result["cost"]
                progress(f"  {case.label:48s} {1e3 * c['wall_s'] / c['steps']:8.1f} ms/frame"
                         f"  round {round_index + 1}/{repeats}")
    rows = [_row(case, runs[case.label]) for case in cases]
    by_label = {r["case"]: r for r in rows}
    for case, row in zip(cases, rows):
        if case.vs is not None:
            row["vs"] = case.vs
            row["ratio_to_vs"] = row["ms_per_frame"] / by_label[case.vs]["ms_per_frame"]
    return write_suite(out, "scenes", rows, repeats, cpu, start, markdown)


def _row(case: SceneCase, costs: list[dict]) -> dict:
    """One table row from the repeats' cost counters (the worker's ``cost``):
    the median time per frame, and the shares and counts of the repeat with
    that time (of two middle ones, the faster), so that a row's shares come
    from one run and a single slow or fast run moves neither."""
    times = [1e3 * c["wall_s"] / c["steps"] for c in costs]
    ms = float(np.median(times))
    c = costs[int(np.argsort(times, kind="stable")[(len(times) - 1) // 2])]
    frame = c["simulated_s"] / c["steps"]
    internal = max(c["internal_step_ms"], 1e-12)
    return dict(
        case=case.label, scene=case.scene, overrides=list(case.overrides),
        lod="off" if LOD_OFF in case.overrides else "on",
        frames=c["steps"], frame_period_s=frame, ms_per_frame=ms, real_time_factor=1e3 * frame / ms,
        lod_share=c["lod_ms"] / internal,
        force_share=(c["force_ms"] + c["assembly_ms"]) / internal,
        solve_share=c["solve_ms"] / internal,
        self_collision_share=c.get("self_collision_ms", 0.0) / internal,
        solves_per_frame=c["solves"] / c["steps"],
        substeps_per_frame=c["substeps"] / c["steps"],
        rejected_steps=c["rejected_steps"], unconverged_steps=c["unconverged_steps"],
        triangles_mean=c["triangles_mean"], solvers=c.get("solvers", []),
        vs=None, ratio_to_vs=None)


def markdown(result: dict) -> str:
    lines = [f"Built-in scenes, {result['repeats']} repeats each, one pinned thread "
             f"({result['machine']['platform']}); ms per frame is the median wall time, the "
             "real-time factor the frame period over it; shares (of the simulator's own step "
             "time) and counts are the median-time repeat's; \"× vs\" is the ratio to the "
             "case named (same run).", "",
             "| case | LOD | ms / frame | real-time factor | × vs | LOD | forces + assembly "
             "| solves | self-collision | solves / frame | steps / frame | triangles |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        versus = "" if r["ratio_to_vs"] is None else f"{r['ratio_to_vs']:.3f} × {r['vs']}"
        lines.append(
            f"| {r['case']} | {r['lod']} | {r['ms_per_frame']:.1f} | "
            f"{r['real_time_factor']:.2f} | {versus} | {100 * r['lod_share']:.1f} % | "
            f"{100 * r['force_share']:.0f} % | {100 * r['solve_share']:.0f} % | "
            f"{100 * r['self_collision_share']:.1f} % | {r['solves_per_frame']:.1f} | "
            f"{r['substeps_per_frame']:.2f} | {r['triangles_mean']:.0f} |")
    return "\n".join(lines) + "\n"
