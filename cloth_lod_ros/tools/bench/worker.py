"""One benchmark configuration in one process pinned to one core (``cloth-lod bench``).

:func:`run_spec_file` is what ``python -m cloth_lod_ros.tools.bench --worker
SPEC.json`` runs: it pins the process, simulates the configuration in the spec
and writes the samples and costs next to it as JSON.
"""

from __future__ import annotations

import json
import os
import time as _time
from collections import deque
from pathlib import Path

import numpy as np

__all__ = ["run_spec_file"]


def _worker(spec: dict) -> dict:
    """Run one configuration and return its samples and cost counters.

    ``spec`` keys: ``scene`` (name or path), ``overrides`` (list of
    ``key=value``), ``points`` ((m, 2) material points, m), ``times`` (sample
    times, s, within the timed window), ``duration`` (timed window, s),
    ``rest`` (None, ``{"time": t}`` to sample at t, or ``{"find": {"threshold",
    "window", "cap"}}`` to find the rest time as described in the runner's
    docstring) and ``rest_time_step`` (optional, s: the step taken after the
    timed window, on the way to rest; default the run's own) and ``perturb``
    (optional ``{"size": m, "seed": int}``: every particle's start position
    moved by ``size`` times a standard normal sample per coordinate, to
    measure how far the motion amplifies a change that small,
    :mod:`..sensitivity`).  Steps are
    frames (``ClothSim.step()``: ``simulation.time_step``, substeps inside).

    Returns a JSON-ready dict: ``samples`` ((k, m, 3) positions, m, at
    ``times`` then at rest if requested), ``rest_time`` (s), ``at_rest``,
    ``ke_per_mass`` at each sample (J/kg), and ``cost`` (wall/CPU seconds and
    work counters over the timed window).
    """
    from ...sim.scene.config import load_scene
    from ...sim import ClothSim

    setup_start = _time.perf_counter()
    scene = load_scene(spec["scene"], spec["overrides"])
    sim = ClothSim(scene)
    if spec.get("perturb"):
        from ..sensitivity import perturb
        perturb(sim, spec["perturb"]["size"], spec["perturb"].get("seed", 0))
    setup_s = _time.perf_counter() - setup_start
    h = scene.simulation.time_step
    points = np.asarray(spec["points"], dtype=float)
    total_mass = float(sim.masses.sum())
    timed_steps = int(round(spec["duration"] / h))
    wanted = {int(round(t / h)): i for i, t in enumerate(spec["times"])}
    rest = spec.get("rest")
    rest_h = float(spec.get("rest_time_step") or h)
    find = rest.get("find") if rest else None

    samples: list = [None] * len(spec["times"])
    ke = [None] * len(spec["times"])
    step_wall = np.zeros(timed_steps)
    cpu_s = 0.0
    load_start = os.getloadavg()
    for k in range(1, max([timed_steps, *wanted]) + 1):
        # Only sim.step() is inside the clock; sampling and bookkeeping are not.
        if k <= timed_steps:
            c0, w0 = _time.process_time(), _time.perf_counter()
            stats = sim.step()
            w1, c1 = _time.perf_counter(), _time.process_time()
            step_wall[k - 1] = w1 - w0
            cpu_s += c1 - c0
        else:
            stats = sim.step()
        if k in wanted:
            samples[wanted[k]] = sim.sample(points).tolist()
            ke[wanted[k]] = stats.kinetic_energy / total_mass
    st = sim.stats[:timed_steps]
    rest_time = at_rest = rest_sample = rest_ke = None
    if rest:
        # After the timed window, frames of ``rest_h`` (the converged reference
        # goes on at the frame period: a resting shape is an equilibrium of the
        # model on its mesh, which the step does not change).
        start = sim.step_count * h
        sim.time_step = rest_h
        if find:
            window = deque(maxlen=max(int(round(find["window"] / rest_h)), 1))
            last = max(int(round((find["cap"] - start) / rest_h)), 1)
        else:
            last = max(int(round((rest["time"] - start) / rest_h)), 0)
        ke_mass = sim.stats[-1].kinetic_energy / total_mass if sim.stats else 0.0
        settled = False
        for j in range(1, last + 1):
            ke_mass = sim.step().kinetic_energy / total_mass
            if find:
                window.append(ke_mass)
                settled = len(window) == window.maxlen and max(window) < find["threshold"]
                if settled:
                    break
        rest_time = start + j * rest_h if last else start
        at_rest = bool(settled) if find else None
        rest_sample, rest_ke = sim.sample(points).tolist(), ke_mass
    load_end = os.getloadavg()

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
        self_collision_ms=float(sum(s.self_collision_ms for s in st)),
        cg_iterations=int(sum(s.cg_iterations for s in st)),
        cg_iterations_max=int(max(s.cg_iterations for s in st)),
        solves=int(sum(s.solves for s in st)),
        substeps=int(sum(s.substeps for s in st)),
        substeps_max=int(max(s.substeps for s in st)),
        rejected_steps=int(sum(s.rejected_steps for s in st)),
        newton_iterations=int(sum(s.newton_iterations for s in st)),
        smallest_step=float(min(s.smallest_step for s in st)),
        solvers=sorted({s.solver for s in st}),
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


def run_spec_file(spec_path: str) -> int:
    spec = json.loads(Path(spec_path).read_text())
    # Pin before any work: the timed loop must never migrate between cores.
    os.sched_setaffinity(0, {int(spec["cpu"])})
    result = _worker(spec)
    Path(spec["result"]).write_text(json.dumps(result))
    return 0


