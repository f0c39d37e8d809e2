"""The time integrator: one implicit step with pins, contact and friction (design §3).

* :class:`ImplicitEulerSolver` - one linearised backward-Euler step (BW eq. 15)
  solved by the filtered PCG of BW §5.3 (or the direct baseline), with exact
  pins and one-sided contacts with Coulomb friction inside the solve;
* :class:`StepControl` - what is wrapped around that step: re-solves for
  particles that went into an obstacle during the step, and the step-size
  control that redoes a step in halves where the stretch grows too fast.

Data, state and operators are kept apart: the integrator's entry point is
``step(elements, masses, state, (held, targets), h, contacts)`` and it keeps
nothing but per-topology caches (sparsity pattern, warm start).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from .contact import find_contacts, penetrations
from .forces import Elements, evaluate, stretch_lengths
from .linear import Constraints, SparsePattern
from .solvers import make_solver
from .state import ClothState

__all__ = ["ImplicitEulerSolver", "SolveReport", "StepControl"]


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
    solves: int = 1

    def add(self, other: "SolveReport") -> None:
        """Fold in the work of another attempt at the same step (a rejected one,
        a re-solve): iterations, solves and times add up."""
        self.iterations += other.iterations
        self.solves += other.solves
        self.force_ms += other.force_ms
        self.assembly_ms += other.assembly_ms
        self.solve_ms += other.solve_ms


class ImplicitEulerSolver:
    """One linearised backward-Euler step with filtered PCG (design §3).

    Keeps the sparsity pattern and the previous Δv (warm start) while the
    topology is unchanged; call :meth:`reset_topology` after it changes.
    """

    def __init__(self, solver_config, material, gravity, geometry=None, air=None):
        """Args:
            solver_config: the scene's ``solver`` section (method, tolerance, ...).
            material: the scene's material.  gravity: ``(3,)`` m/s².
            geometry: ``(width, height, block)`` of the cloth in m, for the
                multigrid backend's lattices.
            air: the scene's ``air`` section (face drag, wind) or None; passed
                to :func:`~cloth_lod_ros.sim.forces.evaluate`.
        """
        self.material = material
        self.air = air
        self.gravity = np.asarray(gravity, dtype=float)
        self.backend = make_solver(solver_config.method, solver_config.tolerance,
                                   solver_config.max_iterations, geometry)
        self._pattern: SparsePattern | None = None
        self._uv: np.ndarray | None = None
        self._previous_dv: np.ndarray | None = None
        self._prepared = None
        self._solves = 0

    def reset_topology(self, elements: Elements | None = None,
                       uv: np.ndarray | None = None) -> None:
        """Forget per-topology caches; with ``elements`` (and the particles' rest
        ``uv`` ``(n, 2)`` m), build the new pattern and set up the backend now."""
        self._pattern = None
        self._previous_dv = None
        self._prepared = None
        if uv is not None:
            self._uv = uv
        if elements is not None:
            self._new_pattern(elements)

    def _new_pattern(self, elements: Elements) -> None:
        self._pattern = SparsePattern(elements.vertex_count,
                                      [elements.triangles, elements.hinge_vertices])
        self.backend.reset_topology(self._pattern, self._uv)

    def prepare(self, elements: Elements, state: ClothState, h: float):
        """Forces, energies and system blocks at ``state`` (cached).

        A contact re-solve repeats the step from the same state (and a caller
        may ask again), so it is computed once per (topology, state).  Returns
        ``(evaluation, milliseconds it took)``.
        """
        cached = self._prepared
        if (cached is not None and cached[0] is elements and cached[1] == h
                and cached[6] is self.material and cached[7] is self.air   # live changes
                and np.array_equal(cached[2], state.positions)
                and np.array_equal(cached[3], state.velocities)):
            return cached[4], cached[5]
        start = _time.perf_counter()
        ev = evaluate(elements, self.material, state.positions, state.velocities,
                      stiffness_weight=h * h, damping_weight=h, air=self.air)
        ms = 1e3 * (_time.perf_counter() - start)
        self._prepared = (elements, h, state.positions.copy(), state.velocities.copy(), ev, ms,
                          self.material, self.air)
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
            contacts: a :class:`~cloth_lod_ros.sim.contact.ContactSet` or None.  Each
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
            self._new_pattern(elements)
        solves_before = self._solves
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
                             len(contacts) if contacts is not None else 0, released,
                             solves=self._solves - solves_before)
        return ClothState(new_x, new_v, state.time + h), report

    def _keep_warm_start(self, dv: np.ndarray) -> None:
        """Start the next CG solve from ``dv`` (``(n, 3)`` m/s), unless it is not
        finite (a rejected step's NaN would spread into the retry)."""
        self._previous_dv = dv if np.all(np.isfinite(dv)) else None

    def _solve(self, matrix, rhs, constraints):
        self._solves += 1
        return self.backend.solve(matrix, rhs, constraints, self._previous_dv)

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


class StepControl:
    """Contact re-solves and step-size control around one integrator step.

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

    Args:
        solver: the integrator (:class:`ImplicitEulerSolver`).
        obstacles: the scene's obstacles (empty: no contact code runs).
        contact: the scene's contact settings (``thickness`` m,
            ``max_correction_speed`` m/s).
    """

    max_strain_growth = 0.1     # largest |w| increase of a triangle in one (sub)step
    max_substep_depth = 3       # at most 2**3 = 8 substeps per step

    def __init__(self, solver: "ImplicitEulerSolver", obstacles: list, contact):
        self.solver = solver
        self.obstacles = obstacles
        self.contact = contact

    def advance(self, elements: Elements, masses: np.ndarray, state: ClothState,
                held: tuple[np.ndarray, np.ndarray], h: float, depth: int = 0) -> tuple:
        """Advance ``state`` by ``h`` s with the held particles ending on ``held``'s
        targets; a step whose stretch grows too fast (see the class docstring)
        is redone as two halves.  Returns ``(state, report, contacts, substeps)``."""
        new_state, report, contacts = self._solve_step(elements, masses, state, held, h)
        if depth >= self.max_substep_depth or self._acceptable(elements, state, new_state):
            return new_state, report, contacts, 1
        indices, targets = held
        halfway = (indices, 0.5 * (state.positions[indices] + targets))
        middle, first, _, n_first = self.advance(elements, masses, state, halfway, 0.5 * h, depth + 1)
        end, second, contacts, n_second = self.advance(elements, masses, middle, held, 0.5 * h, depth + 1)
        # The report covers all the work of the step, the rejected attempt included.
        second.add(first)
        second.add(report)
        second.residual = max(first.residual, second.residual)
        second.converged = first.converged and second.converged
        second.released += first.released
        return end, second, contacts, n_first + n_second

    def _acceptable(self, elements: Elements, start: ClothState, end: ClothState) -> bool:
        """Finite, and no triangle's stretch grew by more than ``max_strain_growth``."""
        if not (np.all(np.isfinite(end.positions)) and np.all(np.isfinite(end.velocities))):
            return False
        growth = (stretch_lengths(elements, end.positions)
                  - stretch_lengths(elements, start.positions))
        return not len(growth) or float(growth.max()) <= self.max_strain_growth

    def _solve_step(self, elements: Elements, masses: np.ndarray, state: ClothState,
                    held: tuple[np.ndarray, np.ndarray], h: float) -> tuple:
        """One linearised backward-Euler step of ``h`` s from ``state`` with contacts.

        Returns ``(new_state, report, contacts)``.
        """
        contacts = None
        thickness = self.contact.thickness
        if self.obstacles:
            contacts = find_contacts(self.obstacles, state.positions, thickness,
                                     exclude=held[0], velocities=state.velocities, h=h)
        new_state, report = self.solver.step(
            elements, masses, state, held, h, contacts,
            self.contact.max_correction_speed)
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
                elements, masses, state, held, h, contacts,
                self.contact.max_correction_speed)
            retry.add(report)              # the first attempt's work counts too
            report = retry
        return new_state, report, contacts

