"""Hard-case stability suite: ``cloth-lod stress`` (and ``python -m cloth_lod_ros.stress``).

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
* **solver** — every linear solve converged.

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

from .config import load_scene
from .mesh48 import MeshError
from .sim import ClothSim, SimulationError

__all__ = ["Variant", "Bounds", "Event", "Case", "CASES", "RunResult", "build_scene", "run_case",
           "run_cases", "format_table", "add_arguments", "run", "main"]


EPS = float(np.finfo(float).eps)


def _gravity(sim: ClothSim) -> float:
    """|g| in m/s²; every case has it along −z, so heights are z."""
    return float(np.linalg.norm(sim.scene.simulation.gravity))


# -- declarations ---------------------------------------------------------------

@dataclass(frozen=True)
class Variant:
    """Run length and resolution of one flavour of a case.

    Attributes:
        duration: simulated time, s.
        level: maximum level with LOD on, uniform level with LOD off.
        overrides: extra scene overrides for this flavour only.
    """

    duration: float
    level: int
    overrides: tuple = ()


@dataclass(frozen=True)
class Bounds:
    """Limits a run must respect (SI units).

    Attributes:
        max_strain: largest ``| |w| − 1 |`` allowed at any step.
        speed_factor: the fastest particle may move this many times
            ``sqrt(2 budget / M)``, the speed of the whole cloth if all the
            energy available to it were motion (2: a free edge or corner can
            whip faster than the bulk; measured at most 1.1x, and 1.5x at the
            tip of the falling strip at h/4).
        energy_peak: largest ``E_rel / budget`` at any step (1: nothing beyond
            the initial energy and the driver's work).
        energy_final: largest ``E_rel / budget`` at the last step.
        turnover: most topology operations per second *per active particle*
            in any 1 s window after ``startup`` (None: not checked); the
            operations-per-second bound scales with the mesh it acts on.
        startup: s; before this the mesh is allowed to build up.
        max_penetration: deepest a particle may be inside an obstacle, as a
            multiple of the contact thickness.
        holder_tolerance: m; pins/grasped particles vs their targets.
        min_level: the deepest triangle level the run must reach (None: not
            checked); a case about deep hierarchies must actually get there.
    """

    max_strain: float
    speed_factor: float = 2.0
    energy_peak: float = 1.0
    energy_final: float = 1.0
    turnover: float | None = None
    startup: float = 0.5
    max_penetration: float = 1.0
    holder_tolerance: float = 1e-12
    min_level: int | None = None


@dataclass(frozen=True)
class Event:
    """A scripted action at simulation time ``time`` (s), applied before the
    first step that starts at or after it.

    ``kind`` is one of ``"teleport"`` (``args = (grasp, (dx, dy, dz))``: the
    grasp's target jumps by that offset, m), ``"release"`` (``args = (pin,)``),
    ``"turn"`` (``args = (grasp, (ax, ay, az), angle, (dx, dy, dz))``: target
    orientation = rotation by ``angle`` rad about the world axis, target
    position = current + offset), ``"velocity"`` (``args = ((vx, vy, vz),)``:
    every particle gets this velocity, m/s).
    """

    time: float
    kind: str
    args: tuple


@dataclass(frozen=True)
class Case:
    """One hard case: scene, overrides, driver, energy reference and bounds.

    Attributes:
        name, description: label and one line for the table.
        scene: built-in scene name.
        overrides: ``{dotted.key: value}`` applied to it (both flavours).
        full, quick: the report's and the tests' flavour.
        bounds: :class:`Bounds`.
        events: scripted driver (:class:`Event`), times in s.
        floor: lowest height the cloth can reach, m; None: computed from
            ``anchors`` (material points that hold the cloth at the end).
        anchors: ``((u, v), ...)`` material points, m.
        driver_work: ``callable(sim) -> J``, the most work the driver can do on
            the cloth (None: it does none).
        catch_up: ``((grasp, time), ...)``: from ``time`` (s) on the grip must
            be on its commanded pose.
    """

    name: str
    description: str
    scene: str
    overrides: dict
    full: Variant
    quick: Variant
    bounds: Bounds
    events: tuple = ()
    floor: float | None = None
    anchors: tuple = ()
    driver_work: Callable | None = None
    catch_up: tuple = ()


def _grasp(name: str, uv, **kw) -> dict:
    """A grasp closed from the first step (raw scene mapping)."""
    return dict(name=name, uv=list(uv), close_time=0.0, **kw)


def _lift_and_speed_work(lift: float, speed: float):
    """Driver work bound (J) for a grasp that raises the cloth by ``lift`` m and
    moves at most ``speed`` m/s: the potential energy of lifting all of it
    plus the kinetic energy of all of it moving at that speed."""
    def work(sim: ClothSim) -> float:
        mass = float(np.sum(sim.masses))
        return mass * _gravity(sim) * max(lift, 0.0) + 0.5 * mass * speed ** 2
    return work


def _twist_work(angle: float, speed: float):
    """Driver work bound (J) for two grasps that twist a strip (length L = cloth
    width, half-width b = height/2) by ``angle`` Φ rad and move at most
    ``speed`` m/s.

    Twisted with its ends kept apart, the strip is a helicoid: the fibre at
    distance r from the axis becomes a helix stretched by ε ≈ ½(Φ r / L)², with
    no shear (the helix stays perpendicular to the straight cross-section), so
    it stores ``½ k_s ∫∫ ε² = k_s Φ⁴ b⁵ / (20 L³)``; moving the ends closer
    only relaxes it (bending is ~10⁻⁴ of that).  Plus the kinetic energy of
    all of the cloth at the grips' speed limit.
    """
    def work(sim: ClothSim) -> float:
        cloth, mat = sim.scene.cloth, sim.scene.material
        length, b = cloth.width, 0.5 * cloth.height
        mass = float(np.sum(sim.masses))
        return (mat.stretch_stiffness * angle ** 4 * b ** 5 / (20.0 * length ** 3)
                + 0.5 * mass * speed ** 2)
    return work


_HANG = "hang_two_corners"

# Two 10 cm grippers instead of the two pins of hang_two_corners (closed at
# t = 0).  A gripper holds a patch: a single held particle is a point load whose
# strain grows with refinement (13 % next to it at level 6 during the teleport),
# which would test the discretisation, not the simulator.
_HANG_BY_GRASPS = {"pins": [], "grasps": [_grasp("left", (0.0, 1.0), width=0.1),
                                          _grasp("right", (1.0, 1.0), width=0.1)]}

# Strain: a 2000 N/m cloth carrying its own weight (~2 N) and gripped or pinned
# stretches by a few per cent, more next to a point pin (a stress concentration
# that grows with refinement: 4.5 % at level 6, 8.4 % at level 8); 0.15 is
# about twice the worst of that.  The linearisation artefacts this suite exists
# to catch reached 0.24 (a grasp jerked while the cloth was taut), 0.58 (a 5 m/s
# impact) and 1.33 (table_drape, uniform) before the step-size control.
_STRAIN = 0.15

CASES: tuple[Case, ...] = (
    Case(
        name="stiff_material",
        description="stretch stiffness x100 at h = 1/30 s, hung by two corners",
        scene=_HANG,
        overrides={"material.stretch_stiffness": 200000.0,
                   "simulation.time_step": 1.0 / 30.0},
        full=Variant(3.0, 6), quick=Variant(1.0, 4),
        # BW's single linearised implicit step does not see the second-order
        # stretch of triangles that rotate fast (next to the pins, in the first
        # 3-4 steps from the horizontal start): a bounded transient of a few
        # per cent strain and a few times the initial energy (measured: 5 %
        # strain and 4.7x the energy above the lowest reachable state at level 4
        # with LOD off, 3.3x at level 6).  It stays below the step-size
        # control's 0.1 growth per step and is dissipated within ~0.3 s: the
        # final energy must be below the initial.  A blow-up grows without
        # bound (orders of magnitude in a few steps), which these still catch.
        bounds=Bounds(max_strain=_STRAIN, energy_peak=6.0),
        anchors=((0.0, 1.0), (1.0, 1.0)),
    ),
    Case(
        name="grasp_teleport",
        description="a grasp target jumps 0.5 m (up and sideways)",
        scene=_HANG,
        overrides=_HANG_BY_GRASPS,
        full=Variant(3.0, 6), quick=Variant(1.2, 4),
        bounds=Bounds(max_strain=_STRAIN),
        # Jump by (0.3, 0, 0.4) m: towards the other grasp (no stretch) and up.
        events=(Event(0.5, "teleport", ("left", (0.3, 0.0, 0.4))),),
        anchors=((0.0, 1.0), (1.0, 1.0)),
        driver_work=_lift_and_speed_work(0.4, 2.0),
        # 0.5 m at the grasp's 2 m/s: on target 0.25 s after the jump.
        catch_up=(("left", 0.5 + 0.5 / 2.0 + 0.05),),
    ),
    Case(
        name="drop_on_sphere_fast",
        description="cloth thrown onto a sphere at 5 m/s",
        scene="drop_on_sphere",
        overrides={},
        full=Variant(3.0, 6), quick=Variant(0.5, 4),
        # Contact is inelastic, so the energy can only fall; but the impact
        # steps still grow some triangles' stretch by up to the step-size
        # control's 0.1 per step, and the linearised step misses that much
        # second-order stretch: measured +6 % (LOD on) and +8 % (off) over the
        # initial energy for one or two steps (0 % at h/4).  Before the
        # step-size control it was 12x, with 58 % strain.
        bounds=Bounds(max_strain=_STRAIN, energy_peak=1.15),
        events=(Event(0.0, "velocity", ((0.0, 0.0, -5.0),)),),
        floor=-0.25,            # the scene's floor plane
    ),
    Case(
        name="near_equal_thresholds",
        description="coarsen threshold 0.99 x refine threshold, hung by two corners",
        scene=_HANG,
        overrides={"lod.coarsen_threshold": 0.00099, "lod.refine_threshold": 0.001},
        full=Variant(5.0, 6), quick=Variant(2.0, 4),
        # Merging a diamond roughly quadruples d on the coarse hinge (d ~ L² κ),
        # so with coarsen ~ refine a merged region is at once over the refine
        # threshold: only the hysteresis (min_lifetime 0.2 s, settled hinges)
        # stops the cycle.  Even then a diamond can split and merge once per
        # 0.2 s (10 operations/s); thrashing is the mesh doing that all over.
        # Bound: half that, 5 operations/s per active particle after 1 s.
        # Measured at level 6: at most 2.7 (default thresholds: 1.3); without
        # min_lifetime: 10-17 (thrashing; test_stress checks it is caught).
        bounds=Bounds(max_strain=_STRAIN, turnover=5.0, startup=1.0),
        anchors=((0.0, 1.0), (1.0, 1.0)),
    ),
    Case(
        name="long_strip",
        description="1 x 10 m strip hung by one end from a horizontal start",
        scene=_HANG,
        overrides={"cloth.width": 1.0, "cloth.height": 10.0, "cloth.base_blocks": [1, 10],
                   "cloth.origin": [0.0, 0.0, 10.0],
                   "pins": [{"name": "end_left", "uv": [0.0, 10.0]},
                            {"name": "end_right", "uv": [1.0, 10.0]}]},
        full=Variant(4.0, 6), quick=Variant(1.0, 4),
        # The falling strip folds over and its free end whips (an ideal chain's
        # would reach infinite speed): the tension that turns it stretches the
        # cloth by 11 % (13 % at h/4), so the strain bound is higher here.
        bounds=Bounds(max_strain=0.2),
        anchors=((0.0, 10.0), (1.0, 10.0)),
    ),
    Case(
        name="twist_two_grasps",
        description="two grasps twist a 2 x 0.5 m strip half a turn",
        scene=_HANG,
        # The grasps hold the short ends (a 0.5 m patch each) and, from 0.5 s,
        # turn +90 and -90 degrees about the strip's axis at their default
        # 6 rad/s while moving 0.1 m closer each at 0.4 m/s (a twisted strip
        # shortens).
        overrides={"cloth.width": 2.0, "cloth.height": 0.5, "cloth.base_blocks": [4, 1],
                   "pins": [],
                   "grasps": [_grasp(name, (u, 0.25), width=0.5, max_speed=0.4)
                              for name, u in (("a", 0.0), ("b", 2.0))]},
        full=Variant(3.0, 6), quick=Variant(1.6, 4),
        bounds=Bounds(max_strain=_STRAIN),
        events=(Event(0.5, "turn", ("a", (1.0, 0.0, 0.0), math.pi / 2, (0.1, 0.0, 0.0))),
                Event(0.5, "turn", ("b", (1.0, 0.0, 0.0), -math.pi / 2, (-0.1, 0.0, 0.0)))),
        anchors=((0.0, 0.25), (2.0, 0.25)),
        driver_work=_twist_work(math.pi, 0.4),
        # 90 degrees at 6 rad/s (0.26 s) and 0.1 m at 0.4 m/s (0.25 s).
        catch_up=(("a", 0.5 + (math.pi / 2) / 6.0 + 0.05),
                  ("b", 0.5 + (math.pi / 2) / 6.0 + 0.05)),
    ),
    Case(
        name="pin_release",
        description="one of two pins lets go suddenly",
        scene=_HANG,
        overrides={},
        full=Variant(3.0, 6), quick=Variant(1.0, 4),
        bounds=Bounds(max_strain=_STRAIN),
        events=(Event(0.5, "release", ("top_left",)),),
        anchors=((1.0, 1.0),),  # hanging from the other corner in the end
    ),
    Case(
        name="max_level_8",
        description="hung by two corners, refined down to level 8",
        scene=_HANG,
        # The scene's thresholds never need level 8; 0.2 mm / 0.05 mm refine
        # there within 0.4 s.  LOD off: the uniform 65 x 65 mesh (~500 CG
        # iterations a step, so the full run is short).  Quick: one base block
        # (17 x 17 at level 8).
        overrides={"lod.refine_threshold": 0.0002, "lod.coarsen_threshold": 0.00005},
        full=Variant(0.6, 8), quick=Variant(0.6, 8, (("cloth.base_blocks", [1, 1]),)),
        bounds=Bounds(max_strain=_STRAIN, min_level=8),
        anchors=((0.0, 1.0), (1.0, 1.0)),
    ),
)


# -- running ----------------------------------------------------------------------

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
            deepest_level=self.deepest_level,
            triangles_final=self.triangles_final, wall_seconds=self.wall_seconds,
            series=dict(time=self.time.tolist(), max_strain=self.max_strain.tolist(),
                        max_speed=self.max_speed.tolist(), energy=self.energy.tolist(),
                        cg_iterations=self.cg_iterations.tolist(),
                        topology_ops=self.topology_ops.tolist(),
                        substeps=self.substeps.tolist()))


def build_scene(case: Case, lod: bool, quick: bool):
    """The :class:`~cloth_lod_ros.config.SceneConfig` of ``case`` (LOD on/off, flavour)."""
    variant = case.quick if quick else case.full
    overrides = dict(case.overrides)
    overrides.update(dict(variant.overrides))
    overrides["cloth.level"] = variant.level
    overrides["simulation.duration"] = variant.duration
    overrides["lod.enabled"] = lod
    if lod:
        overrides["lod.initial_level"] = 0
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


def run_case(case: Case, lod: bool, quick: bool = False) -> RunResult:
    """Run ``case`` and check every step against its bounds.

    Returns:
        :class:`RunResult` (never raises for a failing run: a refused step is a
        failure like any other).
    """
    bounds = case.bounds
    result = RunResult(case=case.name, lod=lod, quick=quick)
    sim = ClothSim(build_scene(case, lod, quick))
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
                              "substeps", "particles")}
    deepest = 0
    collector = _Collect()
    sim_log = logging.getLogger("cloth_lod_ros")
    sim_log.addHandler(collector)
    propagate, sim_log.propagate = sim_log.propagate, False
    start = _time.perf_counter()
    try:
        for _ in range(steps):
            while pending and pending[0].time <= sim.time + 1e-9:
                _apply_event(sim, pending.pop(0))
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
                               ("substeps", s.substeps),
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
        sim_log.removeHandler(collector)
        sim_log.propagate = propagate

    result.steps = len(series["time"])
    result.time = np.array(series["time"], dtype=float)
    result.max_strain = np.array(series["strain"], dtype=float)
    result.max_speed = np.array(series["speed"], dtype=float)
    result.energy = np.array(series["energy"], dtype=float)
    result.cg_iterations = np.array(series["cg"], dtype=int)
    result.converged = np.array(series["conv"], dtype=bool)
    result.topology_ops = np.array(series["ops"], dtype=int)
    result.substeps = np.array(series["substeps"], dtype=int)
    result.deepest_level = deepest
    result.triangles_final = int(sim.mesh.triangle_count)
    result.warnings = collector.messages
    result.max_ops_per_second, result.max_turnover = _max_ops_per_second(
        result.time, result.topology_ops, np.array(series["particles"], dtype=float), h,
        bounds.startup)
    _check_series(result, bounds, fail)
    order = ("finite", "strain", "speed", "energy", "energy_final", "mass", "mesh", "pins",
             "grasps", "catch_up", "contact", "topology", "level", "solver")
    result.failures = [f"{k}: {failures[k]}" for k in order if k in failures]
    return result


def _check_holders(sim: ClothSim, bounds: Bounds, catch_up: dict, fail) -> None:
    """Pins and closed grasps exactly on their targets; grips caught up on time."""
    t = sim.time
    tol = bounds.holder_tolerance
    for p in sim.pins:
        if p.active(t):
            err = float(np.linalg.norm(sim.positions[p.vertex] - p.target(t)))
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
              progress: Callable[[RunResult], None] | None = None) -> list[RunResult]:
    """Run every case in every LOD mode, one at a time; ``progress`` sees each result."""
    results = []
    for case in cases:
        for lod in lod_modes:
            result = run_case(case, lod, quick)
            results.append(result)
            if progress is not None:
                progress(result)
    return results


# -- report -----------------------------------------------------------------------

_COLUMNS = (("case", 21, "<"), ("LOD", 3, "<"), ("steps", 5, ">"), ("cut", 4, ">"),
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
    return _row([result.case, "on" if result.lod else "off", result.steps, s["split_steps"],
                 s["deepest_level"], f"{s['max_strain']:.4f}", f"{s['max_speed']:.2f}", energy,
                 f"{s['cg_mean']:.0f}/{s['cg_max']:.0f}",
                 f"{s['topology_ops']}/{s['max_ops_per_second']:.0f}",
                 f"{result.wall_seconds:.1f}", verdict])


def format_table(results) -> str:
    """The report table (header and one row per run)."""
    return "\n".join([format_header()] + [format_row(r) for r in results])


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
          "reachable height; cut = steps redone in substeps (step-size control); level = "
          "deepest reached; ops = splits + merges, max per s after start-up")
    print(format_header(), flush=True)
    start = _time.perf_counter()
    results = run_cases([by_name[n] for n in names], lod_modes, args.quick,
                        progress=lambda r: print(format_row(r), flush=True))
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
