"""``ClothSim``: the scriptable facade over mesh, state, inputs and solver.

Data, state and operators are kept apart (design §9):

* :class:`~cloth_lod_ros.sim.mesh.mesh48.RestMesh` +
  :class:`~cloth_lod_ros.sim.physics.elements.Elements` - topology and rest state;
* :class:`~cloth_lod_ros.sim.integrate.state.ClothState` - positions, velocities and time;
* :class:`~cloth_lod_ros.sim.inputs.pins.Pin`, :class:`~cloth_lod_ros.sim.inputs.grasps.Grasp`
  - inputs (material patch, target path, release; their methods in
  :class:`~cloth_lod_ros.sim.inputs.holding.HeldInputs`);
* :class:`~cloth_lod_ros.sim.integrate.step_control.TimeStepper` (scheme, step size,
  contacts) over :class:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver`
  (Newton on implicit stages) - ``advance(elements, masses, state, held, H)``;
* :class:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48` (mechanism) and
  :class:`~cloth_lod_ros.sim.lod.policy.LodPolicy` (policy) - the adaptive mesh.

Example::

    sim = ClothSim.from_scene("hang_two_corners", overrides=["cloth.level=4"])
    for _ in range(60):
        stats = sim.step()
    print(stats.cg_iterations, sim.sample([[0.5, 0.5]]))
"""

from __future__ import annotations

import dataclasses

import logging
import os
import time as _time

import numpy as np

from .runtime.blas_threads import one_blas_thread
from .scene.config import (SceneConfig, SceneError, load_scene, scene_from_dict, scene_to_dict,
                           self_collision_on)
from .contact.contacts import nearest_surface
from .physics.elements import Elements
from .physics.air import air_power
from .warm_up import warm_up_compiled_code
from .physics.elements_kernels import adopt as adopt_compiled, precompute   # compiled with numba
from .physics.energies_kernels import elastic_energies   # compiled when numba is there
from .inputs.grasps import Grasp
from .inputs.holding import HeldInputs
from .mesh.hierarchy import Hierarchy48
from .integrate.implicit_stage import ImplicitStageSolver
from .inputs.obstacle_motion import ObstacleInputs
from .lod.policy import LodDecision, LodPolicy
from .mesh.operations import OperationLog
from .mesh.topology import MeshError
from .mesh.mesh48 import RestMesh, base_mesh, lumped_masses, refine_uniform
from .mesh.sampling import PointLocator
from .contact.self_contact import SelfCollision
from .integrate.state import ClothState, SimulationError, StepStats
from .integrate.step_control import TimeStepper

__all__ = ["ClothSim", "live_update", "LIVE_STEPPING"]

log = logging.getLogger(__name__)


#: ``simulation`` fields a running simulation can change (the time stepping).
LIVE_STEPPING = ("integrator", "error_tolerance", "min_time_step", "newton_iterations",
                 "newton_tolerance")


def live_update(scene: SceneConfig, changes: dict) -> SceneConfig:
    """The scene with ``changes`` (``{"section.field": value}``) applied, validated
    as a whole; only fields a running simulation can take (material except
    density, air, LOD except ``enabled`` and ``initial_level``, and the time
    stepping: ``simulation.integrator``, ``error_tolerance``, ``min_time_step``,
    ``newton_iterations``, ``newton_tolerance``).  Pure: ``scene`` is not
    modified, so a caller can validate without touching a running simulator.

    Raises:
        SceneError: a field is unknown, not live, or the result is invalid.
    """
    data = scene_to_dict(scene)
    for path, value in changes.items():
        section, _, key = str(path).partition(".")
        # Density sets the particle masses, built once with the mesh; the frame
        # period, duration and gravity are the run's, not the stepping's.
        if (section not in ("material", "air", "lod", "simulation")
                or key not in data.get(section, {})
                or path in ("material.density", "lod.enabled", "lod.initial_level")
                or (section == "simulation" and key not in LIVE_STEPPING)):
            raise SceneError(f"{path}: not a live parameter (material.* except density, "
                             "air.*, lod.* except enabled and initial_level, simulation."
                             + ", simulation.".join(LIVE_STEPPING) + ")")
        data[section][key] = value
    return scene_from_dict(data)


# Empties for adapt's rounds that need no held nodes, grasp points, merges.
_NO_NODES = np.zeros(0, dtype=np.int64)
_NO_POINTS = np.zeros((0, 2))
_NO_NODES.setflags(write=False)
_NO_POINTS.setflags(write=False)
_NO_EDGES = np.zeros((0, 2), dtype=np.int64)   # writeable: numba types read-only arrays apart


class ClothSim(HeldInputs, ObstacleInputs):
    """A cloth scene ready to step.

    Build from a :class:`~cloth_lod_ros.sim.scene.config.SceneConfig` or with
    :meth:`from_scene` (built-in name or YAML path, plus ``key=value``
    overrides).  Arrays returned by the properties are the live state: copy
    them if you keep them across steps.

    Each step advances one frame (``simulation.time_step``): the LOD criterion
    and its splits and merges (LOD on), the grasps' script and speed-limited
    targets, then the time stepper
    (:class:`~cloth_lod_ros.sim.integrate.step_control.TimeStepper`: the scheme's
    implicit stages, solved by
    :class:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver`, contact
    re-solves and the error-controlled step size).  A step that fails is
    refused whole: its mesh operations are undone and the state is kept.
    """

    #: A check's later rounds on the hierarchy's pools, adopting the mesh once
    #: (:meth:`adapt`); False: adopt after every round (the same operations).
    pool_rounds = True

    def __init__(self, scene: SceneConfig, keep_stats: int | None = None):
        """Args:
            scene: the validated scene.
            keep_stats: keep only the statistics of about this many latest steps
                in :attr:`stats` (a long-running node); ``None`` keeps all.
        """
        if keep_stats is not None and keep_stats < 1:
            raise ValueError(f"keep_stats must be at least 1, got {keep_stats}")
        warm_up_compiled_code(ClothSim, scene)   # the kernels this scene needs, before any is called
        self.scene = scene
        cloth = scene.cloth
        base = base_mesh(cloth.width, cloth.height, *cloth.base_blocks)
        origin = np.asarray(cloth.origin, dtype=float)
        axes = np.array([cloth.u_axis, cloth.v_axis], dtype=float)
        self.solver = ImplicitStageSolver(
            scene.solver, scene.material, scene.simulation.gravity,
            geometry=(cloth.width, cloth.height, cloth.width / cloth.base_blocks[0]),
            air=scene.air)
        self.time_step = scene.simulation.time_step
        self.stats: list[StepStats] = []
        self.keep_stats = keep_stats
        self.step_count = 0             # steps taken since construction
        self._locator: PointLocator | None = None
        self._unconverged_steps = 0
        self.max_level = cloth.level
        self.hierarchy: Hierarchy48 | None = None
        self.lod_policy: LodPolicy | None = None
        if scene.lod.enabled:
            # Adaptive: the hierarchy owns the particles; the step works on
            # compact copies of the active ones (design §4).
            self.hierarchy = Hierarchy48(base, origin + base.uv @ axes,
                                         scene.material.density, max_level=cloth.level)
            self.hierarchy.refine_uniform(scene.lod.initial_level)
            self._resolve_pin_patches()
            self.lod_policy = LodPolicy(scene.lod, scene.material, scene.simulation.gravity,
                                        cloth)
            self.state = ClothState(np.zeros((0, 3)), np.zeros((0, 3)), 0.0)
            self._adopt_hierarchy()
        else:
            self.mesh: RestMesh = refine_uniform(base, cloth.level)
            self.elements: Elements = precompute(self.mesh)
            self.masses = lumped_masses(self.mesh.uv, self.mesh.triangles,
                                        scene.material.density)
            self.vertex_ids = np.arange(self.mesh.vertex_count)
            self.solver.reset_topology(self.elements, self.mesh.uv)
            positions = origin + self.mesh.uv @ axes
            self.state = ClothState(positions, np.zeros_like(positions), 0.0)
        self.pins = [self._make_pin(p) for p in scene.pins]
        # Inputs beyond pins: obstacles (contact; static, scripted or driven
        # live) and grasps.  A scene without obstacles never evaluates contact code.
        self._make_obstacles()
        self.solver.friction_rounds = scene.contact.friction_rounds
        # Self-collision only when on (enabled, or auto where its thickness
        # fits the finest mesh): otherwise no code of it runs.  On, it costs
        # one broad-phase question a step until two layers come close.
        self.self_collision = (SelfCollision(scene.self_collision)
                               if self_collision_on(scene) else None)
        if self.self_collision is None and scene.self_collision.enabled == "auto":
            log.info("self-collision off: twice self_collision.thickness (%g m) does not fit "
                     "between neighbouring particles of the finest mesh",
                     scene.self_collision.thickness)
        if self.self_collision is not None:
            self.self_collision.set_topology(self.elements.triangles, self.mesh.uv)
        self.stepper = TimeStepper(self.solver, scene.simulation, self.obstacles,
                                   scene.contact, self.self_collision)
        self.grasps = [Grasp.from_config(g) for g in scene.grasps]
        self._scripted_closed = {g.name: False for g in self.grasps}
        self.contacts = None
        self._contacts_version = -1
        self._step_operations: OperationLog | None = None   # the LOD operations of the step running

    def _clamp_bending(self, held: np.ndarray) -> None:
        """Give the bending energy the held particles ``held`` (compact indices)
        as its clamps (:func:`~.physics.bending.bend_stencils`): new stencils
        and sparsity pattern when what is held changed."""
        mask = np.zeros(self.elements.vertex_count, dtype=bool)
        mask[held] = True
        current = self.elements.clamped
        if (not mask.any() and current is None) or (
                current is not None and np.array_equal(current, mask)):
            return
        self.elements = dataclasses.replace(self.elements,
                                            clamped=mask if mask.any() else None)
        self.solver.reset_topology()

    def _reach_anchors(self, grasp, time: float) -> list:
        """The other held points of ``grasp`` at ``time``: ``[(position (3,) m, rest
        distance in (u, v) m)]`` of every other closed grasp and active pin."""
        anchors = [(g.position, float(np.linalg.norm(g.uv - grasp.uv)))
                   for g in self.grasps if g is not grasp and g.closed]
        anchors += [(p.target(time), float(np.linalg.norm(p.uv - grasp.uv)))
                    for p in self.pins if p.active(time)]
        return anchors

    def _adopt_hierarchy(self) -> None:
        """Refresh the compact arrays after the hierarchy's topology changed."""
        h = self.hierarchy
        adopted = adopt_compiled(h)         # all of it in one compiled call, or None
        if adopted is not None:
            (self.mesh, self.vertex_ids, self.triangle_ids, self.elements, self.masses, x,
             v) = adopted
        else:
            self.mesh, self.vertex_ids, self.triangle_ids = h.active_mesh()
            self.elements = precompute(self.mesh)
            # (h.masses is the whole pool's; a gather copies, no .copy() needed)
            self.masses = h.mass_units[self.vertex_ids] * h.unit_mass
            x, v = h.x[self.vertex_ids], h.v[self.vertex_ids]
        self.state = ClothState(x, v, self.state.time)
        # The sparsity pattern: at the first solve on this topology.
        levels = self.mesh.levels
        self.solver.reset_topology(uv=self.mesh.uv,
                                   graded=bool(len(levels) and levels.min() != levels.max()))
        if getattr(self, "self_collision", None) is not None:
            self.self_collision.set_topology(self.elements.triangles, self.mesh.uv)
        self._locator = None
        self._refresh_held()

    @classmethod
    def from_scene(cls, scene: str | os.PathLike,
                   overrides: list[str] | dict | None = None) -> "ClothSim":
        """Load a scene (built-in name or path) with optional overrides."""
        return cls(load_scene(scene, overrides))

    # -- stepping -----------------------------------------------------------
    def step(self) -> StepStats:
        """Advance by one time step; return its statistics.

        Raises:
            SimulationError: the step failed - the new state would not be
                finite, or the numerics broke down on absurd inputs (a singular
                system, an overflow: e.g. gravity of 1e12 m/s^2 or a target
                1e30 m away).  The cloth's state is left at the previous step;
                no other exception escapes a step.
        """
        before = self.state.copy()
        self._step_operations = OperationLog()
        try:
            # Deterministic whatever the machine's cores, and no spinning
            # BLAS threads on the core the node's inputs need (blas_threads).
            with one_blas_thread():
                return self._step()
        except SimulationError:
            self._roll_back(before)
            raise
        except (np.linalg.LinAlgError, ArithmeticError, ValueError) as exc:
            self._roll_back(before)
            raise SimulationError(f"step from t = {before.time:.4f} s failed "
                                  f"({type(exc).__name__}: {exc}); step refused") from exc
        finally:
            self._step_operations = None

    def _roll_back(self, before: ClothState) -> None:
        """Undo a refused step: the mesh operations its LOD pass made (their
        inverses, in reverse order) and the state, so the cloth is exactly as
        it was before the step."""
        if self._step_operations:
            for op in reversed(self._step_operations):
                self.hierarchy.apply(op.inverse(), before.time)
            self._step_operations = OperationLog()
            self._adopt_hierarchy()
        self.state = before
        self.solver.reset_topology()

    def _step(self) -> StepStats:
        h = self.time_step
        start = _time.perf_counter()
        next_time = self.state.time + h
        if self.grasps:
            self._run_grasp_script(next_time)
        refines = merges = 0
        lod_ms = 0.0
        sc = self.self_collision
        sc_ms = sc.counters.ms if sc is not None else 0.0
        if self.hierarchy is not None and self.step_count % self.scene.lod.check_interval == 0:
            lod_start = _time.perf_counter()
            # The criterion needs only the hinges' angles and gradients, computed
            # here on their own: the full force evaluation waits until the mesh
            # is final for this step, so none is made for a topology that the
            # criterion then changes (most adaptive steps change it).
            # Merges are never urgent (a diamond left fine a few steps longer
            # costs only time), while every pass that changes the topology
            # costs a new sparsity pattern and factorisation analysis: they are
            # batched every merge_interval checks.  Refinement is checked at
            # every one, as it is what keeps the error down.
            check = self.step_count // self.scene.lod.check_interval
            # Before the first step, as many rounds as there are levels: the
            # run starts on the mesh its initial shape needs (a start on too
            # coarse a mesh carries its error through the run).
            rounds = (self.scene.lod.check_interval if self.step_count
                      else max(self.scene.lod.check_interval, self.max_level))
            refines, merges = self.adapt(
                simplify=check % self.scene.lod.merge_interval == 0, rounds=rounds)
            lod_ms = 1e3 * (_time.perf_counter() - lod_start)
        for g in self.grasps:
            if g.closed:
                g.advance(next_time, h, self._reach_anchors(g, next_time))
        held = self._held(next_time)
        self._clamp_bending(held[0])
        # Kinematic obstacles: their motion over this step is known now; they
        # take their end poses only if the step succeeds.
        sweep = self._obstacle_sweep(next_time, h)
        new_state, report, contacts, steps = self.stepper.advance(
            self.elements, self.masses, self.state, held, h,
            None if sweep is None else sweep.at)
        new_state.time = next_time          # not the sum of the substeps' roundings
        # The new topology's sparsity pattern is built by its first solve; it
        # is LOD bookkeeping, not solving (a uniform mesh builds it once, at set-up).
        pattern_ms = self.solver.take_pattern_ms()
        if self.hierarchy is not None:
            lod_ms += pattern_ms
        self.contacts = contacts
        self._contacts_version = self.hierarchy.version if self.hierarchy is not None else 0
        if not (np.isfinite(report.residual)
                and np.all(np.isfinite(new_state.positions))
                and np.all(np.isfinite(new_state.velocities))):
            self.solver.reset_topology()
            raise SimulationError(f"non-finite state at t = {new_state.time:.4f} s "
                                  f"(CG residual {report.residual:.3g}); step refused")
        if not report.converged:
            self._unconverged_steps += 1
            if self._unconverged_steps in (1, 10, 100) or self._unconverged_steps % 1000 == 0:
                log.warning("linear solve did not converge at t = %.4f s: residual %.3g "
                            "after %d iterations (%d such steps so far)", new_state.time,
                            report.residual, report.iterations, self._unconverged_steps)
        self.state = new_state
        self._commit_obstacles(sweep)
        x, v = new_state.positions, new_state.velocities
        elastic = elastic_energies(self.elements, self.scene.material, x)
        per_level = np.bincount(self.mesh.levels, minlength=self.max_level + 1)
        stats = StepStats(
            step_index=self.step_count, time=new_state.time,
            vertex_count=self.mesh.vertex_count, triangle_count=self.mesh.triangle_count,
            pinned_count=len(held[0]), contact_count=report.contacts,
            refines=refines, merges=merges,
            triangles_per_level=tuple(int(c) for c in per_level),
            cg_iterations=report.iterations,
            residual=report.residual, converged=report.converged,
            step_ms=1e3 * (_time.perf_counter() - start), lod_ms=lod_ms,
            force_ms=report.force_ms,
            assembly_ms=report.assembly_ms, solve_ms=report.solve_ms,
            kinetic_energy=float(0.5 * np.sum(self.masses * np.sum(v * v, axis=1))),
            gravity_energy=float(-np.sum(self.masses * (x @ self.solver.gravity))),
            stretch_energy=elastic["stretch"], shear_energy=elastic["shear"],
            bend_energy=elastic["bend"], max_strain=elastic["max_strain"],
            max_speed=float(np.sqrt(np.max(np.sum(v * v, axis=1)))),
            substeps=steps.substeps, rejected_steps=steps.rejected,
            smallest_step=steps.smallest, newton_iterations=report.newton_iterations,
            solves=report.solves, factorisations=report.factorisations,
            solver=self.solver.backend.name,
            air_power=air_power(self.elements, self.scene.air, self.scene.material.air_drag,
                                self.masses, x, v),
            self_collision_ms=sc.counters.ms - sc_ms if sc is not None else 0.0,
            self_contact_count=sc.last_constraints if sc is not None else 0)
        self.stats.append(stats)
        self.step_count += 1
        if self.keep_stats is not None and len(self.stats) > 2 * self.keep_stats:
            del self.stats[:-self.keep_stats]      # amortised: trim by half at a time
        return stats

    def update_parameters(self, changes: dict) -> None:
        """Change scene fields between steps, validated as a whole scene.

        Args:
            changes: ``{"section.field": value}``, e.g.
                ``{"lod.refine_threshold": 0.002, "air.wind": [2, 0, 0]}``.
                Only material (not density), air, LOD thresholds and the time
                stepping (:data:`LIVE_STEPPING`) take effect on a running
                simulation (the mesh, masses, pins and obstacles are built once).

        Raises:
            SceneError: a field is unknown, not live, or the resulting scene
                is invalid; nothing is changed.
        """
        scene = live_update(self.scene, changes)
        self.scene = scene
        self.solver.material = scene.material
        self.solver.air = scene.air
        self.stepper.configure(scene.simulation)
        if self.lod_policy is not None:
            self.lod_policy.config = scene.lod
            self.lod_policy.material = scene.material

    def _sync_hierarchy(self) -> Hierarchy48:
        """Write the live state back into the hierarchy (it is only read at
        topology changes) and return it."""
        if self.hierarchy is None:
            raise RuntimeError("mesh operations need lod.enabled: true")
        self.hierarchy.x[self.vertex_ids] = self.state.positions
        self.hierarchy.v[self.vertex_ids] = self.state.velocities
        return self.hierarchy

    def _merge_would_sink(self, vertices: np.ndarray) -> np.ndarray:
        """For split particles (pool ids): would removing them let the coarse edge
        through them sink into an obstacle (more than half the contact thickness)?
        Such a particle is a contact support and is not merged away."""
        ends = np.searchsorted(self.vertex_ids, self.hierarchy.vertex_edge[vertices])
        midpoints = 0.5 * (self.positions[ends[:, 0]] + self.positions[ends[:, 1]])
        return nearest_surface(self.obstacles, midpoints)[0] < 0.5 * self.scene.contact.thickness

    def apply_mesh_operations(self, ops) -> None:
        """Apply :class:`~cloth_lod_ros.sim.mesh.operations.Split`/``Merge`` values (LOD on only).

        For scripting and tests; the state is carried over as the operations
        define (face rule on split, momentum-conserving merge).

        Raises:
            MeshError: an operation is not valid on the mesh as it is (a merge
                whose children the steps since refined further); the ones
                before it are undone: the mesh is as it was.
        """
        h = self._sync_hierarchy()
        done = []
        try:
            for op in ops:
                h.apply(op, self.state.time)
                done.append(op)
        except MeshError:
            for op in reversed(done):
                h.apply(op.inverse(), self.state.time)
            raise
        finally:
            if done:
                self._adopt_hierarchy()

    def refine(self, triangle: int) -> list:
        """Refine the active triangle with pool id ``triangle`` (forcing splits of
        coarser neighbours); returns the splits made, which
        ``apply_mesh_operations([op.inverse() for op in reversed(ops)])`` undoes."""
        h = self._sync_hierarchy()
        ops = h.refine(int(triangle), self.state.time)
        if ops:
            self._adopt_hierarchy()
        return ops

    def adapt(self, simplify: bool = True, rounds: int = 1) -> tuple[int, int]:
        """Evaluate the LOD criterion on the current state and refine/simplify now.

        ``step()`` calls this every ``lod.check_interval`` steps, before the
        step's force evaluation: the criterion computes the hinges' angles and
        gradients only.  With ``rounds`` > 1 the criterion is evaluated again
        on the triangles a round has just made and they are refined further,
        up to ``rounds`` times in all: what checking at each of that many
        steps would have refined one level at a time (merges: first round
        only).  Returns ``(splits, merges)`` performed.
        """
        lookahead = (self.scene.lod.check_interval - 1) * self.time_step
        sc, own = self.self_collision, self.scene.self_collision
        # Self-collision matters to the mesh only where layers were close in
        # the last step's broad phase; elsewhere it is as if off (no layers to
        # keep detail at, no split particle to move out of one).
        if sc is not None and sc.apart(len(self.vertex_ids)):
            sc = None
        total_splits = total_merges = 0
        recheck = None      # after a round: its merged edges (the next one re-checks)
        # Rounds after the first run on the pools, adopting once, after the last
        # (round_kernels); with self-collision each round adopts (new particles
        # are moved out of the other layers on the adopted mesh).
        on_pools = sc is None and self.pool_rounds
        stale = False       # the hierarchy changed since the mesh was adopted
        detail_points = (np.array([g.uv for g in self.grasps if g.closed]).reshape(-1, 2)
                         if self.grasps else _NO_POINTS)
        for round_index in range(max(1, int(rounds))):
            h, time = self.hierarchy, self.state.time
            merging = simplify and round_index == 0
            if stale:
                splits = self._round_on_pools(recheck, detail_points, lookahead)
                if splits is not None:
                    recheck = []
                    total_splits += splits
                    if not splits:
                        break
                    continue
                self._adopt_hierarchy()         # the kernels cannot: adopt and decide
                stale = on_pools = False
            # Held particles matter to merges only; grasps' points only if any.
            held_nodes = self._held_nodes() if merging else _NO_NODES
            # How many obstacles each particle touches (0, 1 or 2); None: none
            # touches any (decide then skips what it would find nothing in).
            in_contact = None
            if (self.contacts is not None and len(self.contacts)
                    and self._contacts_version == h.version):     # same compact numbering
                in_contact = np.zeros(len(self.vertex_ids), dtype=np.int8)
                in_contact[self.contacts.indices] = 1 + self.contacts.doubled
            layered = (sc.near(self.state.positions, own.detail_distance)
                       if sc is not None else None)
            decision = self.lod_policy.decide(
                h, self.elements, self.vertex_ids, self.triangle_ids, self.state.positions,
                self.state.velocities, self.masses, time, held_nodes,
                detail_points=detail_points, in_contact=in_contact,
                supported=self._merge_would_sink if self.obstacles else None,
                simplify=merging, lookahead=lookahead,
                layered=layered, layered_level=own.detail_level, recheck=recheck)
            if not decision.refine and not decision.merge:
                break
            recheck = decision.merge
            self._sync_hierarchy()
            old_ids = self.vertex_ids
            splits, merges = LodPolicy.apply(h, decision, time, log=self._step_operations)
            if splits or merges:
                if self.obstacles and splits:
                    self._lift_new_particles()
                if on_pools:
                    stale = True
                    total_splits += splits
                    total_merges += merges
                    if not splits:
                        break
                    continue
                self._adopt_hierarchy()
                if sc is not None and splits:
                    # A split's particle sits on the chord, which can lie inside the
                    # thickness of a layer the curved cloth is wrapped on: move it
                    # out (never across anything).
                    new = np.flatnonzero(~np.isin(self.vertex_ids, old_ids))
                    self.state.positions = sc.separate(self.state.positions, new,
                                                       self.state.velocities, self.time_step)
            total_splits += splits
            total_merges += merges
            if not splits:
                break
        if stale:
            self._adopt_hierarchy()
        return total_splits, total_merges

    def _round_on_pools(self, merged, detail_points: np.ndarray,
                        lookahead: float) -> int | None:
        """A refinement round after a check's first, on the hierarchy's pools (not
        adopted since): ``merged`` the check's merge edges; the splits it made,
        or None when the kernels cannot (then adopt and decide)."""
        h, time = self.hierarchy, self.state.time
        refine = self.lod_policy.recheck_on_pools(h, time, merged, detail_points, lookahead)
        if refine is None or not len(refine):
            return None if refine is None else 0
        before = h.active_vertices() if self.obstacles else None
        done = h.carry_out(refine, _NO_EDGES, time, log=self._step_operations)
        splits = (done if done is not None else LodPolicy.apply(
            h, LodDecision(refine.tolist(), []), time, log=self._step_operations))[0]
        if self.obstacles and splits:
            self._lift_new_particles(before)
        return splits

    def _lift_new_particles(self, known: np.ndarray | None = None) -> None:
        """Put particles just made by splits that lie inside an obstacle's offset
        surface onto it.  A split places them on the chord between two particles,
        which sags into a curved obstacle (by s²/8R); only these new particles
        move, and their velocities (hence momentum) are unchanged.  New: active
        now and not among ``known`` (pool ids, increasing; default the adopted
        mesh's particles)."""
        h = self.hierarchy
        known = self.vertex_ids if known is None else known
        new = np.setdiff1d(h.active_vertices(), known, assume_unique=True)
        if not len(new):
            return
        thickness = self.scene.contact.thickness
        # Each obstacle in turn, twice: a particle in the corner between two
        # (a box standing on the table) lifted out of one must not stay in
        # the other.
        for obstacle in 2 * list(self.obstacles) if len(self.obstacles) > 1 else self.obstacles:
            best, normal = obstacle.distance(h.x[new])
            inside = best < thickness
            h.x[new[inside]] += (thickness - best[inside])[:, None] * normal[inside]

    def run(self, duration: float | None = None, callback=None) -> list[StepStats]:
        """Step until ``duration`` more seconds (default: the scene's) have passed."""
        duration = self.scene.simulation.duration if duration is None else duration
        steps = int(round(duration / self.time_step))
        out = []
        for _ in range(steps):
            out.append(self.step())
            if callback is not None:
                callback(self, out[-1])
        return out

    # -- views --------------------------------------------------------------
    @property
    def positions(self) -> np.ndarray:
        """``(n, 3)`` particle positions, m."""
        return self.state.positions

    @property
    def velocities(self) -> np.ndarray:
        """``(n, 3)`` particle velocities, m/s."""
        return self.state.velocities

    @property
    def time(self) -> float:
        """Simulation time, s."""
        return self.state.time

    @property
    def rest_uv(self) -> np.ndarray:
        """``(n, 2)`` rest material coordinates, m."""
        return self.mesh.uv

    @property
    def triangles(self) -> np.ndarray:
        """``(t, 3)`` vertex indices of the active triangles."""
        return self.mesh.triangles

    @property
    def triangle_levels(self) -> np.ndarray:
        """``(t,)`` bisection level of each triangle."""
        return self.mesh.levels

    def sample(self, uv) -> np.ndarray:
        """3-D positions ``(m, 3)`` of material points ``uv`` ``(m, 2)`` (m).

        Barycentric interpolation in the rest triangle containing each point.
        """
        if self._locator is None:
            self._locator = PointLocator(self.mesh.uv, self.mesh.triangles,
                                         self.mesh.width, self.mesh.height)
        return self._locator.sample(self.state.positions, uv)

    def energy(self) -> dict:
        """Energies (J) of the current state: kinetic, gravity, stretch, shear, bend."""
        x, v = self.state.positions, self.state.velocities
        elastic = elastic_energies(self.elements, self.scene.material, x)
        return dict(kinetic=float(0.5 * np.sum(self.masses * np.sum(v * v, axis=1))),
                    gravity=float(-np.sum(self.masses * (x @ self.solver.gravity))),
                    stretch=elastic["stretch"], shear=elastic["shear"], bend=elastic["bend"])
