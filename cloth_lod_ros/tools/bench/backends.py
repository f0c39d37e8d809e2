"""``cloth-lod bench --solvers``: the linear-solver backends on the same steps.

For each case (uniform ``hang_two_corners`` at levels 4-8, the adaptive default,
``grasp_lift`` with LOD on and off) every backend runs the same steps in a fresh
process pinned to one CPU with one thread, in rounds (every case and backend
once, then again), so the ratios come from one run.  Reported per run: ms per
step (median over the repeats), the solve share of the step, CG iterations and
solves per step, and the largest distance of the final cloth from the ``pcg``
run of the same case (what the backends' differences within the solver
tolerance add up to).  Writes ``solvers.json`` and ``solvers.md`` in ``--out``.
"""

from __future__ import annotations

import os
import tempfile
import time as _time
from pathlib import Path

import numpy as np

from ...sim.mesh.sampling import material_grid

__all__ = ["CASES", "BACKENDS", "run_backends"]

#: (label, scene, overrides, simulated seconds)
CASES = (
    ("uniform L4", "hang_two_corners", ["lod.enabled=false", "cloth.level=4"], 1.0),
    ("uniform L5", "hang_two_corners", ["lod.enabled=false", "cloth.level=5"], 1.0),
    ("uniform L6", "hang_two_corners", ["lod.enabled=false", "cloth.level=6"], 1.0),
    ("uniform L7", "hang_two_corners", ["lod.enabled=false", "cloth.level=7"], 0.5),
    ("uniform L8", "hang_two_corners", ["lod.enabled=false", "cloth.level=8"], 0.5),
    ("adaptive max L6 (default scene)", "hang_two_corners", [], 2.0),
    ("grasp_lift, LOD on", "grasp_lift", [], 2.0),
    ("grasp_lift, LOD off (L5)", "grasp_lift", ["lod.enabled=false"], 2.0),
)
BACKENDS = ("pcg", "multigrid", "direct", "block_ldl", "cholmod", "superlu", "auto")
#: SuperLU re-analyses every solve and grows as n^3.6 (6 s per solve at level 8).
SUPERLU_SKIPPED = ("uniform L7", "uniform L8")
QUICK_CASES = (("uniform L3", "hang_two_corners", ["lod.enabled=false", "cloth.level=3"], 0.2),
               ("grasp_lift L3", "grasp_lift", ["cloth.level=3"], 0.3))


def run_backends(out: Path, repeats: int = 3, quick: bool = False, cpu: int | None = None,
                 backends=BACKENDS, progress=print) -> dict:
    """Run every case with every backend; return and write the results."""
    from .process import run_in_process     # pinned single-thread workers
    from .machine import write_suite
    from ...sim.solve.backends import available_methods
    backends = [b for b in backends if b in available_methods()]    # optional ones
    cases = QUICK_CASES if quick else CASES
    cpu = sorted(os.sched_getaffinity(0))[-1] if cpu is None else cpu
    out.mkdir(parents=True, exist_ok=True)
    points = material_grid(1.0, 1.0, 11).tolist()
    runs: dict = {}
    start = _time.time()
    with tempfile.TemporaryDirectory(prefix="cloth_solvers_") as tmp:
        for round_index in range(repeats):
            for label, scene, overrides, duration in cases:
                for backend in backends:
                    if backend == "superlu" and label in SUPERLU_SKIPPED:
                        continue              # seconds per solve: the growth is the point
                    spec = dict(scene=scene, overrides=overrides + [f"solver.method={backend}"],
                                points=points, times=[duration], duration=duration, rest=None,
                                cpu=cpu)
                    tag = f"{len(runs)}_{round_index}"
                    result = run_in_process(spec, Path(tmp), tag.replace(" ", "_"))
                    runs.setdefault((label, backend), []).append(result)
                    c = result["cost"]
                    progress(f"  {label:32s} {backend:9s} {1e3 * c['wall_s'] / c['steps']:8.1f} "
                             f"ms/step  round {round_index + 1}/{repeats}")
    rows = []
    for label, _, _, _ in cases:
        reference = np.asarray(runs[(label, "pcg")][0]["samples"][0]) \
            if (label, "pcg") in runs else None
        pcg_ms = None
        for backend in backends:
            if (label, backend) not in runs:
                continue
            results = runs[(label, backend)]
            c = results[0]["cost"]
            ms = float(np.median([1e3 * r["cost"]["wall_s"] / r["cost"]["steps"]
                                  for r in results]))
            if backend == "pcg":
                pcg_ms = ms
            final = np.asarray(results[0]["samples"][0])
            rows.append(dict(
                case=label, backend=backend, solver="+".join(c.get("solvers", [])),
                ms_per_step=ms, ratio_to_pcg=ms / pcg_ms if pcg_ms else None,
                solve_share=c["solve_ms"] / c["internal_step_ms"],
                cg_iterations_per_step=c["cg_iterations"] / c["steps"],
                solves_per_step=c.get("solves", c["steps"]) / c["steps"],
                unconverged_steps=c["unconverged_steps"],
                triangles_mean=c["triangles_mean"],
                max_distance_from_pcg_m=(float(np.linalg.norm(final - reference, axis=1).max())
                                         if reference is not None else None)))
    return write_suite(out, "solvers", rows, repeats, cpu, start, markdown)


def markdown(result: dict) -> str:
    lines = [f"Linear-solver backends, {result['repeats']} repeats each, one pinned thread "
             f"({result['machine']['platform']}); ms per step is the median, the ratio is to "
             "`pcg` on the same case in the same run.", "",
             "| case | backend (ran) | ms / step | × pcg | solve share | CG it. / step | "
             "solves / step | max distance from pcg |",
             "|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        ratio = "" if r["ratio_to_pcg"] is None else f"{r['ratio_to_pcg']:.2f}"
        distance = ("" if r["max_distance_from_pcg_m"] is None
                    else f"{1e3 * r['max_distance_from_pcg_m']:.3f} mm")
        lines.append(f"| {r['case']} | {r['backend']} ({r['solver']}) | {r['ms_per_step']:.1f} | "
                     f"{ratio} | {100 * r['solve_share']:.0f} % | "
                     f"{r['cg_iterations_per_step']:.0f} | {r['solves_per_step']:.1f} | "
                     f"{distance} |")
    return "\n".join(lines) + "\n"
