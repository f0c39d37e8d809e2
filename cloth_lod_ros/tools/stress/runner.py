"""Hard-case stability suite: ``cloth-lod stress`` (and ``python -m cloth_lod_ros.tools.stress``).

Each case is a built-in scene plus ``--set``-style overrides and, where needed,
a small scripted driver (a teleported grasp target, a released pin, two grasps
turned against each other).  Every case runs with LOD on and off; every step is
recorded and checked against explicit bounds:

* **finite** — the simulator never refuses a step (:class:`SimulationError`);
* **energy** — measured above the lowest height the cloth can reach,
  ``E_rel = E − M g z_low`` (kinetic + gravity + elastic; ≥ 0, and independent
  of where z = 0 is).  Gravity, damping and inelastic contact cannot raise it,
  so it is bounded by its initial value plus the most work the driver can do
  (``budget``: the lift and speed of a moved grasp, the stretch of a twist).
  Its peak must stay within ``energy_peak × budget`` (1 unless a case
  documents a known transient) and its final value within
  ``energy_final × budget``;
* **strain / speed** — the largest ``| |w| − 1 |`` stays below the case's
  limit; the fastest particle below ``speed_factor × sqrt(2 budget / M)``,
  a multiple of the speed the whole cloth would have with all its energy as
  motion;
* **mass** — with LOD on, the sum of particle masses equals density × area to
  round-off after every topology change (and the hierarchy's exact
  mass-unit and conformity checks hold at the end);
* **holders** — active pins exactly on their targets; closed grasps' particles
  exactly on the grip's targets, and the grip itself on its commanded pose once
  it has had time to catch up (speed limits);
* **contact** — no particle deeper inside an obstacle than its contact
  thickness (no tunnelling);
* **topology** — operations (splits + merges) per second per active particle,
  in any 1 s window after start-up, below the case's bound (thrashing); the
  deepest level reached where a case is about depth;
* **solver** — every linear solve converged;
* **landing** — in the contact cases that say so, no particle leaves an
  obstacle faster (along the normal) than ``landing`` times the speed at
  which it landed there (inelastic contact throws nothing);
* **rest** — from the case's ``rest`` time on, every particle is slower than
  1 cm/s and the strain below 1 % (the scene comes to rest);
* **layers** — in the contact cases (``push_with_box``, and the
  self-collision ones), after every step no two triangles that share no
  vertex intersect (an independent check,
  :mod:`~cloth_lod_ros.tools.stress.intersect`); a self-collision run also
  reports how often each of its fail-safes fired.

Numbers are SI: m, s, m/s, J.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ...sim.scene.config import parse_override, load_scene
from ...sim.mesh.topology import MeshError
from ...sim import ClothSim, SimulationError

from .cases import CASES, EPS, LANDING_SPEED, Bounds, Case, Event, _gravity
from .intersect import intersecting_pairs

__all__ = ["RunResult", "build_scene", "run_case", "run_cases", "format_table",
           "add_arguments", "run", "main"]


@dataclass
class RunResult:
    """Outcome of one case with LOD on or off.

    Per-step arrays (``steps`` long) are in SI units; ``failures`` lists the
    violated checks (empty: pass).
    """

    case: str
    lod: bool
    quick: bool
    steps: int = 0
    time: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_strain: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    energy: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cg_iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    converged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    topology_ops: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    substeps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    rejected: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    smallest_step: np.ndarray = field(default_factory=lambda: np.zeros(0))
    deepest_level: int = 0
    initial_energy: float = 0.0
    budget: float = 0.0
    speed_limit: float = 0.0
    max_ops_per_second: float = 0.0
    max_turnover: float = 0.0
    triangles_final: int = 0
    wall_seconds: float = 0.0
    failures: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    crossed_steps: int = 0          # steps ending with intersecting triangles (layers)
    max_crossing_pairs: int = 0     # most intersecting pairs after one step
    landing_ratio: float = 0.0      # worst leaving / landing normal speed (landing)
    rest_speed: float = 0.0         # fastest particle from the rest time on, m/s
    rest_strain: float = 0.0        # largest strain from the rest time on
    self_collision: dict = field(default_factory=dict)   # SelfCounters, summed

    @property
    def passed(self) -> bool:
        return not self.failures

    def summary(self) -> dict:
        """JSON-ready summary (per-step series included)."""
        def stat(a, fn, default=0.0):
            return float(fn(a)) if len(a) else default
        return dict(
            case=self.case, lod=self.lod, quick=self.quick, steps=self.steps,
            passed=self.passed, failures=list(self.failures), warnings=list(self.warnings),
            max_strain=stat(self.max_strain, np.max), max_speed=stat(self.max_speed, np.max),
            energy_initial=self.initial_energy, energy_budget=self.budget,
            speed_limit=self.speed_limit,
            energy_max=stat(self.energy, np.max, self.initial_energy),
            energy_final=stat(self.energy, lambda a: a[-1], self.initial_energy),
            cg_mean=stat(self.cg_iterations, np.mean), cg_max=stat(self.cg_iterations, np.max),
            unconverged=int(np.sum(~self.converged)),
            topology_ops=int(np.sum(self.topology_ops)),
            max_ops_per_second=self.max_ops_per_second, max_turnover=self.max_turnover,
            split_steps=int(np.sum(self.substeps > 1)),
            max_substeps=int(self.substeps.max()) if len(self.substeps) else 0,
            rejected_steps=int(np.sum(self.rejected)),
            smallest_step=stat(self.smallest_step, np.min),
            deepest_level=self.deepest_level,
            triangles_final=self.triangles_final, wall_seconds=self.wall_seconds,
            crossed_steps=self.crossed_steps, max_crossing_pairs=self.max_crossing_pairs,
            landing_ratio=self.landing_ratio, rest_speed=self.rest_speed,
            rest_strain=self.rest_strain, self_collision=dict(self.self_collision),
            series=dict(time=self.time.tolist(), max_strain=self.max_strain.tolist(),
                        max_speed=self.max_speed.tolist(), energy=self.energy.tolist(),
                        cg_iterations=self.cg_iterations.tolist(),
                        topology_ops=self.topology_ops.tolist(),
                        substeps=self.substeps.tolist()))


def build_scene(case: Case, lod: bool, quick: bool, extra: list[str] | None = None):
    """The :class:`~cloth_lod_ros.sim.scene.config.SceneConfig` of ``case`` (LOD on/off,
    flavour), with ``extra`` ``key=value`` overrides (e.g. a solver backend) on top."""
    variant = case.quick if quick else case.full
    overrides = dict(case.overrides)
    overrides.update(dict(variant.overrides))
    overrides["cloth.level"] = variant.level
    overrides["simulation.duration"] = variant.duration
    overrides["lod.enabled"] = lod
    if lod:
        overrides.setdefault("lod.initial_level", 0)     # unless the case starts finer
    for text in extra or ():
        key, value = parse_override(text)
        overrides[key] = value
    return load_scene(case.scene, overrides)


def _lowest_height(case: Case, sim: ClothSim) -> float:
    """Lowest height (m) any particle can reach: the case's floor, or the
    lowest anchor less the farthest any material point is from its nearest
    anchor (in (u, v)), stretched by the strain bound."""
    if case.floor is not None:
        return case.floor
    anchors = np.asarray(case.anchors, dtype=float)
    cloth = sim.scene.cloth
    # The cloth's material points on a fine grid, the same with LOD on and off
    # (the particles are not: a coarse start has none where the reach is largest).
    u, v = np.meshgrid(np.linspace(0.0, cloth.width, 201), np.linspace(0.0, cloth.height, 201))
    uv = np.column_stack([u.ravel(), v.ravel()])
    reach = np.min(np.linalg.norm(uv[:, None, :] - anchors[None, :, :], axis=2), axis=1).max()
    anchor_z = sim.sample(anchors)[:, 2].min()
    return float(anchor_z - reach * (1.0 + case.bounds.max_strain))


def _apply_event(sim: ClothSim, event: Event) -> None:
    if event.kind == "teleport":
        name, offset = event.args
        g = sim.grasp(name)
        sim.set_grasp_target(name, g.position + np.asarray(offset, dtype=float))
    elif event.kind == "release":
        sim.release_pin(event.args[0])
    elif event.kind == "turn":
        name, axis, angle, offset = event.args
        g = sim.grasp(name)
        turn = Rotation.from_rotvec(angle * np.asarray(axis, dtype=float)) * g.rotation
        sim.set_grasp_target(name, g.position + np.asarray(offset, dtype=float),
                             orientation=turn.as_quat())
    elif event.kind == "velocity":
        sim.state.velocities[:] = np.asarray(event.args[0], dtype=float)
    else:  # pragma: no cover - programming error in a case table
        raise ValueError(f"unknown event kind {event.kind!r}")


class _Collect(logging.Handler):
    """Keeps the simulator's warnings of one run (they go in the result, not
    between the table's rows)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def run_case(case: Case, lod: bool, quick: bool = False,
             extra: list[str] | None = None) -> RunResult:
    """Run ``case`` and check every step against its bounds.

    Returns:
        :class:`RunResult` (never raises for a failing run: a refused step is a
        failure like any other).
    """
    bounds = case.bounds
    result = RunResult(case=case.name, lod=lod, quick=quick)
    sim = ClothSim(build_scene(case, lod, quick, extra))
    h = sim.time_step
    steps = int(round(sim.scene.simulation.duration / h))
    density = sim.scene.material.density
    nominal_mass = density * sim.scene.cloth.width * sim.scene.cloth.height
    failures: dict[str, str] = {}           # first failure of each check

    def fail(check: str, message: str) -> None:
        failures.setdefault(check, message)

    pending = sorted(case.events, key=lambda e: e.time)
    while pending and pending[0].time <= sim.time + 1e-9:
        _apply_event(sim, pending.pop(0))
    z_low = _lowest_height(case, sim)
    mass = float(np.sum(sim.masses))
    offset = mass * _gravity(sim) * z_low
    result.initial_energy = sum(sim.energy().values()) - offset
    work = case.driver_work(sim) if case.driver_work is not None else 0.0
    result.budget = result.initial_energy + work
    result.speed_limit = bounds.speed_factor * math.sqrt(2.0 * max(result.budget, 0.0) / mass)
    thickness = sim.scene.contact.thickness
    catch_up = dict(case.catch_up)

    series = {k: [] for k in ("time", "strain", "speed", "energy", "cg", "conv", "ops",
                              "substeps", "rejected", "smallest", "particles")}
    deepest = 0
    landings = _Landings(thickness) if bounds.landing is not None and sim.obstacles else None
    collector = _Collect()
    sim_log = logging.getLogger("cloth_lod_ros")
    sim_log.addHandler(collector)
    propagate, sim_log.propagate = sim_log.propagate, False
    start = _time.perf_counter()
    try:
        for _ in range(steps):
            while pending and pending[0].time <= sim.time + 1e-9:
                _apply_event(sim, pending.pop(0))
            if landings is not None:
                landings.before(sim)
            try:
                s = sim.step()
            except SimulationError as exc:
                fail("finite", f"step refused: {exc}")
                break
            t = s.time
            ops = s.refines + s.merges
            for key, value in (("time", t), ("strain", s.max_strain), ("speed", s.max_speed),
                               ("energy", s.total_energy - offset), ("cg", s.cg_iterations),
                               ("conv", s.converged), ("ops", ops),
                               ("substeps", s.substeps), ("rejected", s.rejected_steps),
                               ("smallest", s.smallest_step),
                               ("particles", s.vertex_count)):
                series[key].append(value)
            deepest = max(deepest, int(np.flatnonzero(s.triangles_per_level).max()))
            if not all(math.isfinite(v) for v in (s.max_strain, s.max_speed, s.total_energy)):
                fail("finite", f"non-finite statistics at t = {t:.3f} s")
            if ops or not lod:
                # Exact up to the rounding of summing n masses.
                total = float(np.sum(sim.masses))
                if abs(total - nominal_mass) > len(sim.masses) * EPS * nominal_mass:
                    fail("mass", f"mass {total:.15g} kg != {nominal_mass:.15g} kg "
                                 f"at t = {t:.3f} s")
            _check_holders(sim, bounds, catch_up, fail)
            if landings is not None:
                ratio = landings.after(sim)
                if ratio > bounds.landing:
                    fail("landing", f"a particle left an obstacle at {ratio:.2f} x its "
                                    f"landing speed at t = {t:.3f} s")
            if bounds.rest is not None and t >= bounds.rest - 1e-9:
                result.rest_speed = max(result.rest_speed, s.max_speed)
                result.rest_strain = max(result.rest_strain, s.max_strain)
                if s.max_speed >= bounds.rest_speed or s.max_strain >= bounds.rest_strain:
                    fail("rest", f"not at rest at t = {t:.3f} s: {100 * s.max_speed:.1f} "
                                 f"cm/s, strain {100 * s.max_strain:.2f} %")
            if bounds.layers:
                crossing = intersecting_pairs(sim.positions, sim.triangles)
                result.max_crossing_pairs = max(result.max_crossing_pairs, len(crossing))
                if len(crossing):
                    result.crossed_steps += 1
                    fail("layers", f"{len(crossing)} pair(s) of triangles intersect "
                                   f"at t = {t:.3f} s")
            if sim.obstacles:
                depth = -min(float(o.distance(sim.positions)[0].min()) for o in sim.obstacles)
                if depth > bounds.max_penetration * thickness:
                    fail("contact", f"particle {1e3 * depth:.1f} mm inside an obstacle "
                                    f"at t = {t:.3f} s")
        if lod and sim.hierarchy is not None:
            try:
                sim.hierarchy.check()
            except MeshError as exc:
                fail("mesh", f"hierarchy check: {exc}")
    finally:
        result.wall_seconds = _time.perf_counter() - start
        if sim.self_collision is not None:
            result.self_collision = dict(vars(sim.self_collision.counters))
        sim_log.removeHandler(collector)
        sim_log.propagate = propagate

    if landings is not None:
        result.landing_ratio = landings.worst
    result.steps = len(series["time"])
    result.time = np.array(series["time"], dtype=float)
    result.max_strain = np.array(series["strain"], dtype=float)
    result.max_speed = np.array(series["speed"], dtype=float)
    result.energy = np.array(series["energy"], dtype=float)
    result.cg_iterations = np.array(series["cg"], dtype=int)
    result.converged = np.array(series["conv"], dtype=bool)
    result.topology_ops = np.array(series["ops"], dtype=int)
    result.substeps = np.array(series["substeps"], dtype=int)
    result.rejected = np.array(series["rejected"], dtype=int)
    result.smallest_step = np.array(series["smallest"], dtype=float)
    result.deepest_level = deepest
    result.triangles_final = int(sim.mesh.triangle_count)
    result.warnings = collector.messages
    result.max_ops_per_second, result.max_turnover = _max_ops_per_second(
        result.time, result.topology_ops, np.array(series["particles"], dtype=float), h,
        bounds.startup)
    _check_series(result, bounds, fail)
    order = ("finite", "strain", "speed", "energy", "energy_final", "mass", "mesh", "pins",
             "grasps", "catch_up", "contact", "landing", "rest", "layers", "topology", "level",
             "solver")
    result.failures = [f"{k}: {failures[k]}" for k in order if k in failures]
    return result


class _Landings:
    """Landings on obstacles and how fast the particles leave them, followed
    by particle (the hierarchy's pool ids with LOD on: a particle keeps its id
    across topology changes) and by obstacle (in the corner between two, a
    particle lands on one and may slide along the other).

    A particle *touches* an obstacle when it is within 1.5 contact
    thicknesses of it at a step's end.  Each time it starts to touch it
    *lands*, with the normal speed it had at the start of that step (a
    particle a split made during the step had none: 0), along the surface's
    normal there; it *leaves* with its velocity along that landing normal, at
    the end of a step after one in which it touched.  A bounce is a leave
    within :attr:`window` s of the landing: later, the rest of the cloth may
    pull it off at any speed (a hanging cloth swinging away from a table's
    side it brushed), and along the landing normal, as a particle that slides
    round a rounded edge leaves along a normal that has turned with the
    surface.  Only landings at
    :data:`~cloth_lod_ros.tools.stress.cases.LANDING_SPEED` or faster are
    judged."""

    #: s: the landing kick of issue 31 threw particles in the landing frame.
    window = 0.1

    def __init__(self, thickness: float):
        self.thickness = thickness
        self.arrival = np.zeros((0, 0))         # (particles, obstacles), m/s
        self.normal = np.zeros((0, 0, 3))       # the landing normals
        self.landed_at = np.zeros((0, 0))       # s
        self.touching = np.zeros((0, 0), bool)
        self.worst = 0.0
        self._ids = self._v = None

    def _grow(self, size: int, obstacles: int) -> None:
        if size > len(self.arrival) or self.arrival.shape[1] != obstacles:
            size = max(size, len(self.arrival))
            for name, kind, tail in (("arrival", float, ()), ("normal", float, (3,)),
                                     ("landed_at", float, ()), ("touching", bool, ())):
                old = getattr(self, name)
                new = np.zeros((size, obstacles) + tail, kind)
                new[:len(old), :old.shape[1]] = old
                setattr(self, name, new)

    def before(self, sim: ClothSim) -> None:
        self._ids = np.array(sim.vertex_ids, dtype=np.int64)
        self._v = sim.velocities.copy()

    def after(self, sim: ClothSim) -> float:
        """The worst leaving / landing ratio of this step (0: none left)."""
        ids = np.asarray(sim.vertex_ids, dtype=np.int64)
        self._grow(int(max(ids.max(initial=-1), self._ids.max(initial=-1))) + 1,
                   len(sim.obstacles))
        before = np.zeros((len(self.arrival), 3))
        before[self._ids] = self._v
        ratio = 0.0
        touching = np.zeros_like(self.touching)
        for k, obstacle in enumerate(sim.obstacles):
            phi, normal = obstacle.distance(sim.positions)
            was = self.touching[ids, k]
            speed = np.einsum("nd,nd->n", sim.velocities, self.normal[ids, k])
            landed = self.arrival[ids, k]
            leaving = (was & (speed > 0.0) & (landed >= LANDING_SPEED)
                       & (sim.time - self.landed_at[ids, k] <= self.window + 1e-9))
            if leaving.any():
                ratio = max(ratio, float(np.max(speed[leaving] / landed[leaving])))
            now = phi < 1.5 * self.thickness
            first = now & ~was
            self.arrival[ids[first], k] = np.abs(np.einsum("nd,nd->n", before[ids[first]],
                                                           normal[first]))
            self.normal[ids[first], k] = normal[first]
            self.landed_at[ids[first], k] = sim.time
            touching[ids[now], k] = True
        self.touching = touching
        self.worst = max(self.worst, ratio)
        return ratio


def _check_holders(sim: ClothSim, bounds: Bounds, catch_up: dict, fail) -> None:
    """Pins and closed grasps exactly on their targets; grips caught up on time."""
    t = sim.time
    tol = bounds.holder_tolerance
    for p in sim.pins:
        if p.active(t):                 # every particle of a patch
            err = float(np.abs(sim.positions[p.vertices] - p.held_targets(t)).max())
            if err > tol:
                fail("pins", f"pin {p.name} {err:.3g} m off its target at t = {t:.3f} s")
    for g in sim.grasps:
        if not g.closed:
            continue
        held = np.searchsorted(sim.vertex_ids, g.nodes)
        err = float(np.abs(sim.positions[held] - g.held_targets()).max())
        if err > tol:
            fail("grasps", f"grasp {g.name} {err:.3g} m off its target at t = {t:.3f} s")
        if g.name in catch_up and t >= catch_up[g.name]:
            target, rotation = g.target_at(t)
            lag = float(np.linalg.norm(g.position - target))
            turn = float((rotation * g.rotation.inv()).magnitude())
            if lag > tol or turn > 1e-9:
                fail("catch_up", f"grasp {g.name} still {lag:.3g} m / {turn:.3g} rad from "
                                 f"its command at t = {t:.3f} s")


def _max_ops_per_second(time: np.ndarray, ops: np.ndarray, particles: np.ndarray, h: float,
                        startup: float) -> tuple[float, float]:
    """Most operations in any 1 s window starting after ``startup``: ``(per s,
    per s per particle)`` (the latter over the window's mean particle count).
    A run with less than 1 s left after start-up is measured over what is left."""
    after = time > startup + 1e-9
    ops, particles = ops[after], particles[after]
    if not len(ops):
        return 0.0, 0.0
    window = min(int(round(1.0 / h)), len(ops))
    kernel = np.ones(window)
    counts = np.convolve(ops, kernel, mode="valid")
    mean_particles = np.convolve(particles, kernel, mode="valid") / window
    seconds = window * h
    return float(counts.max()) / seconds, float((counts / mean_particles).max()) / seconds


def _check_series(result: RunResult, bounds: Bounds, fail) -> None:
    if not result.steps:
        return
    strain = float(result.max_strain.max())
    if not strain <= bounds.max_strain:
        k = int(np.nanargmax(result.max_strain))
        fail("strain", f"max strain {strain:.4f} > {bounds.max_strain} "
                       f"at t = {result.time[k]:.3f} s")
    speed = float(result.max_speed.max())
    if not speed <= result.speed_limit:
        k = int(np.nanargmax(result.max_speed))
        fail("speed", f"max speed {speed:.3g} m/s > {result.speed_limit:.3g} m/s "
                      f"at t = {result.time[k]:.3f} s")
    budget = result.budget
    peak = float(result.energy.max())
    if not peak <= bounds.energy_peak * budget:
        k = int(np.nanargmax(result.energy))
        fail("energy", f"energy {peak:.4g} J > {bounds.energy_peak} x budget {budget:.4g} J "
                       f"at t = {result.time[k]:.3f} s")
    final = float(result.energy[-1])
    if not final <= bounds.energy_final * budget:
        fail("energy_final", f"final energy {final:.4g} J > {bounds.energy_final} x "
                             f"budget {budget:.4g} J (not settling)")
    if bounds.turnover is not None and result.max_turnover > bounds.turnover:
        fail("topology", f"{result.max_turnover:.1f} operations/s per particle after "
                         f"{bounds.startup} s > {bounds.turnover}/s (thrashing; at most "
                         f"{result.max_ops_per_second:.0f} operations/s)")
    if bounds.min_level is not None and result.deepest_level < bounds.min_level:
        fail("level", f"deepest level {result.deepest_level} < {bounds.min_level}")
    if not result.converged.all():
        k = int(np.argmin(result.converged))
        fail("solver", f"{int(np.sum(~result.converged))} unconverged solve(s), first at "
                       f"t = {result.time[k]:.3f} s")


def run_cases(cases, lod_modes=(True, False), quick: bool = False,
              progress: Callable[[RunResult], None] | None = None,
              extra: list[str] | None = None) -> list[RunResult]:
    """Run every case in every LOD mode, one at a time; ``progress`` sees each result."""
    results = []
    for case in cases:
        for lod in lod_modes:
            result = run_case(case, lod, quick, extra)
            results.append(result)
            if progress is not None:
                progress(result)
    return results


# -- report -----------------------------------------------------------------------

_COLUMNS = (("case", 21, "<"), ("LOD", 3, "<"), ("steps", 5, ">"), ("cut/rej", 7, ">"),
            ("level", 5, ">"), ("strain", 6, ">"), ("speed", 5, ">"),
            ("E init/max/final [J]", 20, ">"), ("CG mean/max", 11, ">"),
            ("ops total/max/s", 15, ">"), ("wall s", 6, ">"), ("result", 0, "<"))


def _row(values) -> str:
    cells = []
    for (_, width, align), value in zip(_COLUMNS, values):
        cells.append(f"{value:{align}{width}}" if width else str(value))
    return "  ".join(cells)


def format_header() -> str:
    return _row([c[0] for c in _COLUMNS]) + "\n" + _row(["-" * (c[1] or 6) for c in _COLUMNS])


def format_row(result: RunResult) -> str:
    s = result.summary()
    energy = f"{s['energy_initial']:.3g}/{s['energy_max']:.3g}/{s['energy_final']:.3g}"
    verdict = "pass" if result.passed else "FAIL " + "; ".join(result.failures)
    return _row([result.case, "on" if result.lod else "off", result.steps,
                 f"{s['split_steps']}/{s['rejected_steps']}",
                 s["deepest_level"], f"{s['max_strain']:.4f}", f"{s['max_speed']:.2f}", energy,
                 f"{s['cg_mean']:.0f}/{s['cg_max']:.0f}",
                 f"{s['topology_ops']}/{s['max_ops_per_second']:.0f}",
                 f"{result.wall_seconds:.1f}", verdict])


def format_table(results) -> str:
    """The report table (header and one row per run)."""
    return "\n".join([format_header()] + [format_row(r) for r in results])


def format_layers(result: RunResult) -> str:
    """One line on a self-collision run: intersecting steps and how often each
    fail-safe fired (empty for a run without self-collision)."""
    c = result.self_collision
    if not c:
        return ""
    return (f"  {result.case} LOD {'on' if result.lod else 'off'}: {result.crossed_steps} "
            f"step(s) with intersecting triangles; {c['attempts']} attempts, "
            f"{c['with_pairs']} with self-contact pairs; {c['resolves']} re-solves, "
            f"{c['refused']} steps refused, {c['stopped']} stopped zones "
            f"({c['stopped_particles']} particles), {c['unresolved']} unresolved; "
            f"{c['lifted']} split particles moved out; {c['ms'] / 1e3:.2f} s in "
            f"self-collision code")


# -- command line -----------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``cloth-lod stress``."""
    parser.add_argument("--quick", action="store_true",
                        help="short, coarse flavour of every case (what the tests run)")
    parser.add_argument("--cases", nargs="+", metavar="NAME",
                        help=f"cases to run (default all: {', '.join(c.name for c in CASES)})")
    parser.add_argument("--lod", choices=("on", "off", "both"), default="both",
                        help="run with LOD on, off or both (default both)")
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="scene override for every case, e.g. solver.method=pcg")


def run(args) -> int:
    """Run the selected cases, print the table; 0 when every run passes, 1 otherwise."""
    by_name = {c.name: c for c in CASES}
    names = args.cases or list(by_name)
    unknown = [n for n in names if n not in by_name]
    if unknown:
        print(f"cloth-lod stress: unknown case(s) {', '.join(unknown)}; cases: "
              f"{', '.join(by_name)}", file=sys.stderr)
        return 2
    lod_modes = {"on": (True,), "off": (False,), "both": (True, False)}[args.lod]
    print(f"stress suite ({'quick' if args.quick else 'full'}): energy E_rel above the lowest "
          "reachable height; cut/rej = frames covered by several steps / steps rejected "
          "(error or stretch-growth control); level = "
          "deepest reached; ops = splits + merges, max per s after start-up")
    print(format_header(), flush=True)
    start = _time.perf_counter()
    def progress(r):
        print(format_row(r), flush=True)
        if r.self_collision:
            print(format_layers(r), flush=True)

    results = run_cases([by_name[n] for n in names], lod_modes, args.quick,
                        progress=progress, extra=list(getattr(args, "set", None) or []))
    wall = _time.perf_counter() - start
    failed = [r for r in results if not r.passed]
    print(f"{len(results) - len(failed)}/{len(results)} runs passed in {wall:.1f} s wall")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(dict(quick=bool(args.quick), wall_seconds=wall,
                                        runs=[r.summary() for r in results]), indent=1))
        print(f"  wrote {path}")
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cloth-lod stress",
                                     description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    logging.basicConfig(level=logging.WARNING, format="cloth-lod: %(levelname)s: %(message)s")
    sys.exit(main())
