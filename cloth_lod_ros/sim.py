"""``ClothSim``: the scriptable facade over mesh, state, inputs and solver.

Data, state and operators are kept apart (DESIGN.md §9):

* :class:`~cloth_lod_ros.mesh48.RestMesh` + :class:`~cloth_lod_ros.forces.Elements`
  — topology and rest state;
* :class:`ClothState` — positions, velocities and time;
* :class:`Pin` — inputs (material point, target path, release time);
* :class:`ImplicitEulerSolver` — ``step(elements, masses, state, pins, h)``.

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
from dataclasses import dataclass, field

import numpy as np

from .config import SceneConfig, SceneError, load_scene
from .contact import find_contacts, make_obstacle, nearest_surface, penetrations
from .grasps import Grasp
from .forces import Elements, elastic_energies, evaluate, precompute, stretch_lengths
from .hierarchy import Hierarchy48
from .lod import LodPolicy
from .mesh48 import RestMesh, base_mesh, lumped_masses, refine_uniform
from .metrics import PointLocator
from .solver import Constraints, SparsePattern, filtered_pcg, solve_projected_direct

__all__ = ["ClothSim", "ClothState", "Pin", "StepStats", "SimulationError",
           "ImplicitEulerSolver"]

log = logging.getLogger(__name__)


class SimulationError(RuntimeError):
    """The step could not produce a finite state; the previous state is kept."""


@dataclass
class ClothState:
    """Dynamic state. ``positions``/``velocities``: ``(n, 3)`` in m and m/s; ``time`` in s."""

    positions: np.ndarray
    velocities: np.ndarray
    time: float = 0.0

    def copy(self) -> "ClothState":
        return ClothState(self.positions.copy(), self.velocities.copy(), self.time)


@dataclass
class Pin:
    """A particle held at a target.

    Attributes:
        name: label.
        uv: requested material point (m); ``vertex`` is the (compact) index of
            the particle holding it, ``node`` its permanent id (pool id with LOD
            on; equal to ``vertex`` otherwise), and ``snap_distance`` (m) how far
            that particle's rest point is.
        anchor: ``(3,)`` target used when there are no waypoints (m).
        waypoints: ``(w, 4)`` rows ``[t, x, y, z]``; linear in between, held at
            the ends.
        release_time: time (s) after which the pin no longer holds, or None.
    """

    name: str
    uv: np.ndarray
    vertex: int
    snap_distance: float
    node: int
    anchor: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    release_time: float | None = None

    def active(self, time: float) -> bool:
        return self.release_time is None or time < self.release_time

    def target(self, time: float) -> np.ndarray:
        """Target position (m) at simulation time ``time`` (s)."""
        if len(self.waypoints) == 0:
            return self.anchor
        t = self.waypoints[:, 0]
        return np.array([np.interp(time, t, self.waypoints[:, d]) for d in (1, 2, 3)])


@dataclass
class StepStats:
    """Statistics of one time step (SI units; times in milliseconds).

    ``vertex_count``/``triangle_count``/``triangles_per_level`` describe the
    mesh the step simulated (after this step's refines and merges);
    ``step_ms`` includes ``lod_ms`` (criterion, operations and the refresh of
    compact arrays) and the physics (``force_ms + assembly_ms + solve_ms``).
    ``substeps`` is how many linearised solves the step was split into (1 unless
    its stretch grew too fast, see :attr:`ClothSim.max_strain_growth`); with
    more than one, the solver figures add up over all of them (the rejected
    attempts included).
    """

    step_index: int
    time: float
    vertex_count: int
    triangle_count: int
    pinned_count: int
    contact_count: int
    refines: int
    merges: int
    triangles_per_level: tuple
    cg_iterations: int
    residual: float
    converged: bool
    step_ms: float
    lod_ms: float
    force_ms: float
    assembly_ms: float
    solve_ms: float
    kinetic_energy: float
    gravity_energy: float
    stretch_energy: float
    shear_energy: float
    bend_energy: float
    max_strain: float
    max_speed: float
    substeps: int = 1

    @property
    def total_energy(self) -> float:
        return (self.kinetic_energy + self.gravity_energy + self.stretch_energy
                + self.shear_energy + self.bend_energy)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class SolveReport:
    """What the solver reports alongside the new state (times in ms)."""

    iterations: int
    residual: float
    converged: bool
    force_ms: float
    assembly_ms: float
    solve_ms: float
    contacts: int = 0
    released: int = 0


class ImplicitEulerSolver:
    """One linearised backward-Euler step with filtered PCG (DESIGN.md §3).

    Keeps the sparsity pattern and the previous Δv (warm start) while the
    topology is unchanged; call :meth:`reset_topology` after it changes.
    """

    def __init__(self, solver_config, material, gravity):
        self.config = solver_config
        self.material = material
        self.gravity = np.asarray(gravity, dtype=float)
        self._pattern: SparsePattern | None = None
        self._previous_dv: np.ndarray | None = None
        self._prepared = None

    def reset_topology(self, elements: Elements | None = None) -> None:
        """Forget per-topology caches; with ``elements``, build the new pattern now."""
        self._pattern = None
        self._previous_dv = None
        self._prepared = None
        if elements is not None:
            self._pattern = SparsePattern(elements.vertex_count,
                                          [elements.triangles, elements.hinge_vertices])

    def prepare(self, elements: Elements, state: ClothState, h: float):
        """Forces, energies and system blocks at ``state`` (cached).

        The LOD criterion reads the hinge angles and gradients from this same
        evaluation, and a contact re-solve repeats the step from the same
        state, so it is computed once per (topology, state).  Returns
        ``(evaluation, milliseconds it took)``.
        """
        cached = self._prepared
        if (cached is not None and cached[0] is elements and cached[1] == h
                and cached[6] is self.material          # the node can change it live
                and np.array_equal(cached[2], state.positions)
                and np.array_equal(cached[3], state.velocities)):
            return cached[4], cached[5]
        start = _time.perf_counter()
        ev = evaluate(elements, self.material, state.positions, state.velocities,
                      stiffness_weight=h * h, damping_weight=h)
        ms = 1e3 * (_time.perf_counter() - start)
        self._prepared = (elements, h, state.positions.copy(), state.velocities.copy(), ev, ms,
                          self.material)
        return ev, ms

    def step(self, elements: Elements, masses: np.ndarray, state: ClothState,
             constraints_targets: tuple[np.ndarray, np.ndarray], h: float,
             contacts=None, max_correction_speed: float = 0.5):
        """Advance ``state`` by ``h`` seconds.

        Args:
            elements: rest data of the current topology.
            masses: ``(n,)`` particle masses, kg.
            state: current state (not modified).
            constraints_targets: ``(indices (k,), targets (k, 3))``: particles
                that must be exactly at ``targets`` (m) at the end of the step.
            h: time step, s.
            contacts: a :class:`~cloth_lod_ros.contact.ContactSet` or None.  Each
                contact forbids motion into the obstacle (normal velocity
                prescribed to push out of the offset surface at most
                ``max_correction_speed`` m/s); contacts whose force would pull
                are released and the system solved again; friction follows.

        Returns:
            ``(new_state, SolveReport)``.
        """
        mat = self.material
        x, v = state.positions, state.velocities
        if self._pattern is None:
            self._pattern = SparsePattern(elements.vertex_count,
                                          [elements.triangles, elements.hinge_vertices])
        ev, evaluate_ms = self.prepare(elements, state, h)
        t0 = _time.perf_counter() - 1e-3 * evaluate_ms     # force_ms includes the evaluation
        drag = mat.air_drag
        force = ev.force + masses[:, None] * (self.gravity - drag * v)
        rhs = h * (force + h * ev.stiffness_times_velocity)
        t1 = _time.perf_counter()
        # M − h ∂f/∂v includes the drag term h·c·M on the diagonal.
        matrix = self._pattern.assemble([ev.triangle_blocks, ev.hinge_blocks],
                                        masses * (1.0 + h * drag))
        t2 = _time.perf_counter()

        held, targets = constraints_targets
        # Velocity that lands a held particle on its target: x + h v_new = target.
        target_velocity = (targets - x[held]) / h
        pinned = Constraints(indices=held, projectors=np.zeros((len(held), 3, 3)),
                             prescribed=target_velocity - v[held])
        released = 0
        if contacts is not None and len(contacts):
            result, contacts, released = self._solve_with_contacts(
                matrix, rhs, pinned, contacts, masses, v, h, max_correction_speed)
        else:
            result = self._solve(matrix, rhs, pinned)
        t3 = _time.perf_counter()
        new_v = v + result.dv
        new_x = x + h * new_v
        if contacts is not None and len(contacts):
            # Inelastic contact: the normal velocity that moved a particle onto
            # the offset surface (landing or push-out) is a position correction,
            # not motion to keep; storing it would bounce it off next step.
            n_c = contacts.normals
            vn = np.einsum("kd,kd->k", new_v[contacts.indices], n_c)
            new_v[contacts.indices] -= vn[:, None] * n_c
        # Held particles: exactly on target (the velocity above agrees to rounding).
        new_x[held] = targets
        new_v[held] = target_velocity
        self._keep_warm_start(result.dv)
        report = SolveReport(result.iterations, result.residual, result.converged,
                             1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2),
                             len(contacts) if contacts is not None else 0, released)
        return ClothState(new_x, new_v, state.time + h), report

    def _keep_warm_start(self, dv: np.ndarray) -> None:
        """Start the next CG solve from ``dv`` (``(n, 3)`` m/s), unless it is not
        finite (a rejected step's NaN would spread into the retry)."""
        self._previous_dv = dv if np.all(np.isfinite(dv)) else None

    def _solve(self, matrix, rhs, constraints):
        if self.config.method == "direct":
            return solve_projected_direct(matrix, rhs, constraints)
        return filtered_pcg(matrix, rhs, constraints, self._pattern.diagonal_blocks(matrix),
                            guess=self._previous_dv, tolerance=self.config.tolerance,
                            max_iterations=self.config.max_iterations)

    def _solve_with_contacts(self, matrix, rhs, pinned, contacts, masses, v, h, max_speed):
        """Solve with pins plus one-sided contacts and Coulomb friction (BW §5.3, §6).

        1. Every contact is held: its normal velocity lands it on the offset
           surface (a penetrating one is pushed out at most ``max_speed``) and,
           where the obstacle has friction, its tangential velocity is 0.
           The reaction ``R = A Δv − b`` (an impulse, N·s) is what holding
           costs; contacts whose normal reaction would pull are released and
           the system is solved again (once).
        2. Coulomb: a contact whose tangential reaction exceeds ``μ R·n``
           cannot stick; it slides on the surface with the friction impulse
           ``μ (R·n) R̂_t`` (opposing the slip) in the right-hand side, and the
           system is solved again; repeated (at most 6 rounds) while new
           contacts start to slip, because when one row lets go the next row
           takes its load.  Friction is inside the implicit solve,
           so the rest of the cloth responds to it in the same step.
        """
        released = 0
        iterations = 0
        slip = np.zeros(len(contacts), dtype=bool)
        friction_impulse = np.zeros((len(contacts), 3))
        rounds = 6          # a slip front moves one row of contacts per round
        for attempt in range(rounds):
            normals = contacts.normals
            target_vn = np.minimum(-contacts.distance / h, max_speed)
            current = v[contacts.indices]
            sliding = (contacts.friction <= 0.0) | slip
            projectors = np.zeros((len(contacts), 3, 3))
            projectors[sliding] = np.eye(3) - normals[sliding, :, None] * normals[sliding, None, :]
            # Held contacts: full Δv to (target_vn n); sliding: normal part only.
            prescribed = target_vn[:, None] * normals - current
            current_vn = np.einsum("kd,kd->k", current, normals)
            prescribed[sliding] = ((target_vn - current_vn)[sliding, None] * normals[sliding])
            step_rhs = rhs
            if slip.any():
                step_rhs = rhs.copy()
                step_rhs[contacts.indices] += friction_impulse
            result = self._solve(matrix, step_rhs,
                                 _merge_constraints(pinned, contacts.indices, projectors,
                                                    prescribed))
            iterations += result.iterations
            self._keep_warm_start(result.dv)       # warm start for the next round
            if attempt == rounds - 1:
                break
            reaction = ((matrix @ result.dv.ravel()).reshape(-1, 3) - step_rhs)[contacts.indices]
            normal_reaction = np.einsum("kd,kd->k", reaction, normals)
            pulling = (normal_reaction < 0.0) & ~contacts.hold
            if pulling.any() and attempt == 0:
                released += int(pulling.sum())
                contacts = contacts.subset(~pulling)
                slip = slip[~pulling]
                friction_impulse = friction_impulse[~pulling]
                if not len(contacts):
                    result = self._solve(matrix, rhs, pinned)
                    iterations += result.iterations
                    break
                continue
            tangential = reaction - normal_reaction[:, None] * normals
            magnitude = np.linalg.norm(tangential, axis=1)
            # Normal load for friction: the reaction less what pushing a particle
            # out of the offset surface costs (a position correction is not a load).
            correction = masses[contacts.indices] * np.maximum(target_vn, 0.0)
            limit = contacts.friction * np.maximum(normal_reaction - correction, 0.0)
            new_slip = (contacts.friction > 0.0) & (magnitude > limit) & ~slip
            if not new_slip.any():
                break
            slip |= new_slip
            friction_impulse[new_slip] = (limit[new_slip] / magnitude[new_slip])[:, None] \
                * tangential[new_slip]
        result.iterations = iterations
        return result, contacts, released


def _merge_constraints(pinned: Constraints, indices, projectors, prescribed) -> Constraints:
    return Constraints(indices=np.concatenate([pinned.indices, indices]),
                       projectors=np.concatenate([pinned.projectors, projectors]),
                       prescribed=np.concatenate([pinned.prescribed, prescribed]))


class ClothSim:
    """A cloth scene ready to step.

    Build from a :class:`~cloth_lod_ros.config.SceneConfig` or with
    :meth:`from_scene` (built-in name or YAML path, plus ``key=value``
    overrides).  Arrays returned by the properties are the live state: copy
    them if you keep them across steps.

    Step-size control (BW §5: the step is cut where the stretch changes too
    much in one step): one linearised backward-Euler step cannot see the
    second-order stretch of motion *across* an unstretched edge (its tangent
    stiffness there is zero), so a part of the cloth that is stopped or turned
    abruptly while its neighbours move on (a fast impact, a sharp jerk of a
    grasp) comes out of the step stretched far beyond what the material does
    and with energy it never had (a 5 m/s impact at 1/60 s: 58 % strain and
    14x the energy; at 1/240 s: 4 %, no gain).  A step in which any
    triangle's stretch ``|w|`` grows by more than :attr:`max_strain_growth`
    (or that is not finite) is therefore redone as two half steps, nested up to
    :attr:`max_substep_depth` times; held particles move along the straight
    line to their end-of-step targets.  Ordinary motion stays below the limit
    (the built-in scenes: at most 0.08 per step) and is not affected; the one
    step of theirs it splits is ``table_drape`` with LOD off, where the cloth
    leaving the table edge used to be stretched by 133 % and thrown back.
    """

    max_strain_growth = 0.1     # largest |w| increase of a triangle in one (sub)step
    max_substep_depth = 3       # at most 2**3 = 8 substeps per step

    def __init__(self, scene: SceneConfig, keep_stats: int | None = None):
        """Args:
            scene: the validated scene.
            keep_stats: keep only the statistics of about this many latest steps
                in :attr:`stats` (a long-running node); ``None`` keeps all.
        """
        if keep_stats is not None and keep_stats < 1:
            raise ValueError(f"keep_stats must be at least 1, got {keep_stats}")
        self.scene = scene
        cloth = scene.cloth
        base = base_mesh(cloth.width, cloth.height, *cloth.base_blocks)
        origin = np.asarray(cloth.origin, dtype=float)
        axes = np.array([cloth.u_axis, cloth.v_axis], dtype=float)
        self.solver = ImplicitEulerSolver(scene.solver, scene.material,
                                          scene.simulation.gravity)
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
            # compact copies of the active ones (DESIGN.md §4).
            self.hierarchy = Hierarchy48(base, origin + base.uv @ axes,
                                         scene.material.density, max_level=cloth.level)
            self.hierarchy.refine_uniform(scene.lod.initial_level)
            self.lod_policy = LodPolicy(scene.lod, scene.material.bend_stiffness)
            self.state = ClothState(np.zeros((0, 3)), np.zeros((0, 3)), 0.0)
            self._adopt_hierarchy()
        else:
            self.mesh: RestMesh = refine_uniform(base, cloth.level)
            self.elements: Elements = precompute(self.mesh)
            self.masses = lumped_masses(self.mesh.uv, self.mesh.triangles,
                                        scene.material.density)
            self.vertex_ids = np.arange(self.mesh.vertex_count)
            positions = origin + self.mesh.uv @ axes
            self.state = ClothState(positions, np.zeros_like(positions), 0.0)
        self.pins = [self._make_pin(p) for p in scene.pins]
        # Inputs beyond pins: obstacles (contact) and grasps.  A scene without
        # obstacles never evaluates contact code.
        self.obstacles = [make_obstacle(o) for o in scene.obstacles]
        self.grasps = [Grasp.from_config(g) for g in scene.grasps]
        self._scripted_closed = {g.name: False for g in self.grasps}
        self.contacts = None
        self._contacts_version = -1

    def _adopt_hierarchy(self) -> None:
        """Refresh the compact arrays after the hierarchy's topology changed."""
        h = self.hierarchy
        self.mesh, self.vertex_ids, self.triangle_ids = h.active_mesh()
        self.elements = precompute(self.mesh)
        self.masses = h.masses[self.vertex_ids]
        self.state = ClothState(h.x[self.vertex_ids].copy(), h.v[self.vertex_ids].copy(),
                                self.state.time)
        self.solver.reset_topology(self.elements)
        self._locator = None
        for pin in getattr(self, "pins", ()):
            pin.vertex = int(np.searchsorted(self.vertex_ids, pin.node))
        for g in getattr(self, "grasps", ()):
            if g.closed and g.width > 0:
                # A closed patch holds the material inside it: particles that
                # splits made there are held too (else a patch closed on a
                # coarse mesh would hold only its first few particles and let
                # the refined cloth between them flap).
                near = np.linalg.norm(self.mesh.uv - g.uv, axis=1) <= 0.5 * g.width + 1e-12
                new = np.setdiff1d(self.vertex_ids[near], g.nodes)
                if len(new):
                    g.hold_more(new, self.state.positions[np.searchsorted(self.vertex_ids, new)])

    @classmethod
    def from_scene(cls, scene: str | os.PathLike,
                   overrides: list[str] | dict | None = None) -> "ClothSim":
        """Load a scene (built-in name or path) with optional overrides."""
        return cls(load_scene(scene, overrides))

    # -- inputs -------------------------------------------------------------
    def _make_pin(self, cfg) -> Pin:
        uv = np.asarray(cfg.uv, dtype=float)
        dist = np.linalg.norm(self.mesh.uv - uv, axis=1)
        vertex = int(dist.argmin())
        if dist[vertex] > 1e-9 * max(self.mesh.width, self.mesh.height):
            log.warning("pin %r at uv=%s snapped to the nearest particle uv=%s (%.4g m away)",
                        cfg.name, uv.tolist(), self.mesh.uv[vertex].tolist(), dist[vertex])
        return Pin(name=cfg.name, uv=uv, vertex=vertex, snap_distance=float(dist[vertex]),
                   node=int(self.vertex_ids[vertex]),
                   anchor=self.state.positions[vertex].copy(),
                   waypoints=np.asarray(cfg.waypoints, dtype=float).reshape(-1, 4),
                   release_time=cfg.release_time)

    def pin(self, name: str) -> Pin:
        for p in self.pins:
            if p.name == name:
                return p
        raise KeyError(f"no pin named {name!r}; pins: {[p.name for p in self.pins]}")

    def set_pin_target(self, name: str, position) -> None:
        """Hold pin ``name`` at ``position`` (m) from the next step on.

        The particle moves there in one step with the prescribed velocity
        ``(target − x)/h`` (speed limiting belongs to the grasp layer).
        """
        position = np.asarray(position, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ValueError(f"pin target must be 3 finite numbers, got {position!r}")
        pin = self.pin(name)
        pin.anchor = position.copy()
        pin.waypoints = np.zeros((0, 4))

    def release_pin(self, name: str) -> None:
        """Let pin ``name`` go from now on."""
        self.pin(name).release_time = self.state.time

    def _held(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Compact indices and end-of-step targets of every held particle."""
        indices = [np.array([p.vertex for p in self.pins if p.active(time)], dtype=np.int64)]
        targets = [np.array([p.target(time) for p in self.pins if p.active(time)],
                            dtype=float).reshape(-1, 3)]
        for g in self.grasps:
            if g.closed:
                indices.append(np.searchsorted(self.vertex_ids, g.nodes))
                targets.append(g.held_targets())
        return np.concatenate(indices), np.concatenate(targets)

    def _held_nodes(self) -> np.ndarray:
        time = self.state.time
        nodes = [p.node for p in self.pins if p.active(time)]
        nodes += [int(n) for g in self.grasps if g.closed for n in g.nodes]
        return np.array(nodes, dtype=np.int64)

    # -- grasps -------------------------------------------------------------
    def grasp(self, name: str) -> Grasp:
        for g in self.grasps:
            if g.name == name:
                return g
        raise KeyError(f"no grasp named {name!r}; grasps: {[g.name for g in self.grasps]}")

    def close_grasp(self, name: str) -> None:
        """Close grasp ``name`` on the cloth at its material point.

        With LOD on, the mesh is refined until a particle lies within the
        grasp's ``tolerance`` of its (u, v) (or the maximum level is reached,
        then the nearest particle is used and a warning logged).  With a
        ``width``, every particle within ``width/2`` in (u, v) is held.
        """
        g = self.grasp(name)
        if g.closed:
            return
        node, _ = self._particle_at(g.uv, g.tolerance, name)
        nodes = np.array([node], dtype=np.int64)
        if g.width > 0:
            near = np.linalg.norm(self.rest_uv - g.uv, axis=1) <= 0.5 * g.width + 1e-12
            nodes = np.union1d(nodes, self.vertex_ids[near])
        compact = np.searchsorted(self.vertex_ids, nodes)
        grip = self.positions[np.searchsorted(self.vertex_ids, node)]
        g.attach(nodes, self.positions[compact].copy(), grip)

    def open_grasp(self, name: str) -> None:
        """Release grasp ``name`` (the cloth falls free of it)."""
        self.grasp(name).release()

    def set_grasp_target(self, name: str, position, orientation=None) -> None:
        """Command grasp ``name`` to a pose: position (m), quaternion [x, y, z, w].

        The held particles follow at the grasp's speed limits.

        Raises:
            KeyError: unknown grasp; ValueError: non-finite or malformed pose.
        """
        self.grasp(name).set_target(position, orientation)

    def _particle_at(self, uv, tolerance: float, label: str) -> tuple[int, float]:
        """Permanent id of a particle at material point ``uv`` (refining if LOD is on)."""
        uv = np.asarray(uv, dtype=float)
        for _ in range(4 * (self.max_level + 2)):
            dist = np.linalg.norm(self.rest_uv - uv, axis=1)
            nearest = int(dist.argmin())
            if dist[nearest] <= tolerance or self.hierarchy is None:
                break
            if self._locator is None:
                self._locator = PointLocator(self.mesh.uv, self.mesh.triangles,
                                             self.mesh.width, self.mesh.height)
            tri, _ = self._locator.locate(uv[None, :])
            pool_tri = int(self.triangle_ids[tri[0]])
            if not self.refine(pool_tri):
                break                              # at the maximum level
        if dist[nearest] > tolerance:
            log.warning("%s: no particle within %.3g m of uv=%s; using the nearest, "
                        "%.3g m away", label, tolerance, uv.tolist(), dist[nearest])
        return int(self.vertex_ids[nearest]), float(dist[nearest])

    def _run_grasp_script(self, time: float) -> None:
        for g in self.grasps:
            if g.close_time is None:
                continue
            want = g.close_time <= time and (g.open_time is None or time < g.open_time)
            if want != self._scripted_closed[g.name]:
                self._scripted_closed[g.name] = want
                (self.close_grasp if want else self.open_grasp)(g.name)

    # -- stepping -----------------------------------------------------------
    def step(self) -> StepStats:
        """Advance by one time step; return its statistics.

        Raises:
            SimulationError: the new state would not be finite (the state is
                left at the previous step).
        """
        h = self.time_step
        start = _time.perf_counter()
        next_time = self.state.time + h
        if self.grasps:
            self._run_grasp_script(next_time)
        refines = merges = 0
        lod_ms = 0.0
        if self.hierarchy is not None and self.step_count % self.scene.lod.check_interval == 0:
            lod_start = _time.perf_counter()
            evaluation, evaluate_ms = self.solver.prepare(self.elements, self.state, h)
            refines, merges = self.adapt(evaluation)
            lod_ms = 1e3 * (_time.perf_counter() - lod_start)
            if not (refines or merges):
                # The physics reuses this evaluation (reported in force_ms).  After
                # a topology change it is thrown away: then it was LOD's cost.
                lod_ms -= evaluate_ms
        for g in self.grasps:
            if g.closed:
                g.advance(next_time, h)
        held = self._held(next_time)
        new_state, report, contacts, substeps = self._advance(self.state, held, h, 0)
        new_state.time = next_time          # not the sum of the substeps' roundings
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
            max_speed=float(np.sqrt(np.max(np.sum(v * v, axis=1)))), substeps=substeps)
        self.stats.append(stats)
        self.step_count += 1
        if self.keep_stats is not None and len(self.stats) > 2 * self.keep_stats:
            del self.stats[:-self.keep_stats]      # amortised: trim by half at a time
        return stats

    def update_parameters(self, changes: dict) -> None:
        """Change scene fields between steps, validated as a whole scene.

        Args:
            changes: ``{"section.field": value}``, e.g.
                ``{"lod.refine_threshold": 0.002, "material.bend_stiffness": 1e-4}``.
                Only material (not density) and LOD thresholds take effect on a
                running simulation (the mesh, masses, pins and obstacles are
                built once).

        Raises:
            SceneError: a field is unknown, not live, or the resulting scene
                is invalid; nothing is changed.
        """
        from .config import scene_from_dict, scene_to_dict
        data = scene_to_dict(self.scene)
        for path, value in changes.items():
            section, _, key = path.partition(".")
            # Density sets the particle masses, built once with the mesh.
            if (section not in ("material", "lod") or key not in data.get(section, {})
                    or path in ("material.density", "lod.enabled", "lod.initial_level")):
                raise SceneError(f"{path}: not a live parameter (material.* except density, "
                                 "lod.* except enabled and initial_level)")
            data[section][key] = value
        scene = scene_from_dict(data)
        self.scene = scene
        self.solver.material = scene.material
        if self.lod_policy is not None:
            self.lod_policy.config = scene.lod
            self.lod_policy.bend_stiffness = scene.material.bend_stiffness

    def _advance(self, state: ClothState, held: tuple[np.ndarray, np.ndarray], h: float,
                 depth: int) -> tuple:
        """Advance ``state`` by ``h`` s with the held particles ending on ``held``'s
        targets; a step whose stretch grows too fast (see the class docstring)
        is redone as two halves.  Returns ``(state, report, contacts, substeps)``."""
        new_state, report, contacts = self._solve_step(state, held, h)
        if depth >= self.max_substep_depth or self._acceptable(state, new_state):
            return new_state, report, contacts, 1
        indices, targets = held
        halfway = (indices, 0.5 * (state.positions[indices] + targets))
        middle, first, _, n_first = self._advance(state, halfway, 0.5 * h, depth + 1)
        end, second, contacts, n_second = self._advance(middle, held, 0.5 * h, depth + 1)
        # The report covers all the work of the step, the rejected attempt included.
        second.iterations += first.iterations + report.iterations
        second.residual = max(first.residual, second.residual)
        second.converged = first.converged and second.converged
        second.force_ms += first.force_ms + report.force_ms
        second.assembly_ms += first.assembly_ms + report.assembly_ms
        second.solve_ms += first.solve_ms + report.solve_ms
        second.released += first.released
        return end, second, contacts, n_first + n_second

    def _acceptable(self, start: ClothState, end: ClothState) -> bool:
        """Finite, and no triangle's stretch grew by more than ``max_strain_growth``."""
        if not (np.all(np.isfinite(end.positions)) and np.all(np.isfinite(end.velocities))):
            return False
        growth = (stretch_lengths(self.elements, end.positions)
                  - stretch_lengths(self.elements, start.positions))
        return not len(growth) or float(growth.max()) <= self.max_strain_growth

    def _solve_step(self, state: ClothState, held: tuple[np.ndarray, np.ndarray],
                    h: float) -> tuple:
        """One linearised backward-Euler step of ``h`` s from ``state`` with contacts.

        Returns ``(new_state, report, contacts)``.
        """
        contacts = None
        thickness = self.scene.contact.thickness
        if self.obstacles:
            contacts = find_contacts(self.obstacles, state.positions, thickness,
                                     exclude=held[0], velocities=state.velocities, h=h)
        new_state, report = self.solver.step(
            self.elements, self.masses, state, held, h, contacts,
            self.scene.contact.max_correction_speed)
        for _ in range(2 if self.obstacles else 0):
            # A particle that the start-of-step test missed (accelerated into an
            # obstacle, or released and pushed in) gets a contact and the step is
            # solved again.
            missed = penetrations(self.obstacles, state.positions, new_state.positions,
                                  thickness, exclude=held[0])
            if not len(missed):
                break
            contacts = contacts.union(missed)
            new_state, retry = self.solver.step(
                self.elements, self.masses, state, held, h, contacts,
                self.scene.contact.max_correction_speed)
            retry.iterations += report.iterations
            report = retry
        return new_state, report, contacts

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
        """Apply :class:`~cloth_lod_ros.hierarchy.Split`/``Merge`` values (LOD on only).

        For scripting and tests; the state is carried over as the operations
        define (face rule on split, momentum-conserving merge).
        """
        h = self._sync_hierarchy()
        for op in ops:
            h.apply(op, self.state.time)
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

    def adapt(self, evaluation=None) -> tuple[int, int]:
        """Evaluate the LOD criterion on the current state and refine/simplify now.

        ``step()`` calls this every ``lod.check_interval`` steps, passing the
        step's own force evaluation (its hinge angles and gradients are what
        the criterion needs).  Returns ``(splits, merges)`` performed.
        """
        if evaluation is None:
            evaluation, _ = self.solver.prepare(self.elements, self.state, self.time_step)
        h, time = self.hierarchy, self.state.time
        held_nodes = self._held_nodes()
        detail_points = np.array([g.uv for g in self.grasps if g.closed]).reshape(-1, 2)
        in_contact = np.zeros(len(self.vertex_ids), dtype=bool)
        if (self.contacts is not None and len(self.contacts)
                and self._contacts_version == h.version):     # same compact numbering
            in_contact[self.contacts.indices] = True
        decision = self.lod_policy.decide(
            h, self.elements, self.vertex_ids, self.triangle_ids, self.state.positions,
            self.state.velocities, time, held_nodes, detail_points=detail_points,
            in_contact=in_contact,
            supported=self._merge_would_sink if self.obstacles else None,
            evaluation=evaluation)
        if not decision.refine and not decision.merge:
            return 0, 0
        self._sync_hierarchy()
        splits, merges = LodPolicy.apply(h, decision, time)
        if splits or merges:
            if self.obstacles and splits:
                self._lift_new_particles()
            self._adopt_hierarchy()
        return splits, merges

    def _lift_new_particles(self) -> None:
        """Put particles just made by splits that lie inside an obstacle's offset
        surface onto it.  A split places them on the chord between two particles,
        which sags into a curved obstacle (by s²/8R); only these new particles
        move, and their velocities (hence momentum) are unchanged."""
        h = self.hierarchy
        new = np.setdiff1d(h.active_vertices(), self.vertex_ids, assume_unique=True)
        if not len(new):
            return
        thickness = self.scene.contact.thickness
        best, normal, _ = nearest_surface(self.obstacles, h.x[new])
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
