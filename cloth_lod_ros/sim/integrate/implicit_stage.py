"""Implicit stages: the nonlinear equations of one implicit stage, solved by
Newton iterations with pins, contact and friction (design §3).

Every scheme of :mod:`~cloth_lod_ros.sim.integrate.step_control` (the paper's linearised
backward Euler, backward Euler with Newton, the L-stable SDIRK2) is made of
*stages* of one form: find the velocities ``V`` ``(n, 3)`` (m/s) with

    M (V − v̂) = γh · f(x̂ + γh V, V)                                 (1)

for given ``x̂`` (m), ``v̂`` (m/s) and stage step ``γh`` (s); the stage's
positions are ``X = x̂ + γh V``.  Backward Euler is one stage with
``x̂ = x_n, v̂ = v_n, γh = h``.  :class:`ImplicitStageSolver` solves (1):

* Newton: the residual ``r(V) = γh f(X, V) − M (V − v̂)`` (N·s) is linearised
  with the kept Jacobian (:mod:`~cloth_lod_ros.sim.physics.forces`), i.e. the system
  matrix ``A = M − γh ∂f/∂v − γh² ∂f/∂x`` of BW eq. 15, and ``A ΔV = r`` is
  solved by the configured backend (:mod:`~cloth_lod_ros.sim.solve.backends`) with
  held particles and contacts as filtered constraints (BW §5.3);
* the first iteration starts from a predictor (``V⁰``: the previous velocity,
  so ``X⁰ = x̂ + γh V⁰``; held particles start on their targets, contact
  particles on the predictor like their neighbours) and takes the full
  step; later ones backtrack
  along ``ΔV`` while the filtered residual ``|S r|_{M⁻¹}`` does not decrease
  (the kept Jacobian is Gauss–Newton, so a full step is not guaranteed to
  improve);
* it stops after ``max_iterations`` or once the last correction moved the
  particles by at most ``tolerance`` (RMS over particles, m);
* BW's own step (``linearize_at_start``) evaluates the forces at ``x̂``
  instead and adds ``γh² K V⁰`` to the right-hand side (BW eq. 15): one
  iteration of that is the paper's method.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from ..physics import forces_kernels
from ..physics.elements import Elements
from ..contact.contact_rows import TwoNormals
from ..contact.layer_reactions import layer_reactions
from ..solve.constraints import Constraints
from ..solve.pattern import PatternStorage, SparsePattern
from ..solve.sparse import bsr_product
from ..solve.factorisation import factorisation_count
from ..solve.backends import make_solver

__all__ = ["ImplicitStageSolver", "SolveReport", "StageResult"]


@dataclass
class SolveReport:
    """What the solver reports alongside the new state (times in ms).

    ``iterations`` are linear-solver (CG) iterations, ``solves`` linear solves,
    ``factorisations`` the numeric factorisations among them (direct backends;
    a solve of an unchanged system only back-substitutes),
    ``newton_iterations`` Newton iterations (one linearisation each) over all
    stages; ``line_search_cuts`` how often a Newton step was shortened.
    """

    iterations: int
    residual: float
    converged: bool
    force_ms: float
    assembly_ms: float
    solve_ms: float
    contacts: int = 0
    released: int = 0
    solves: int = 1
    newton_iterations: int = 1
    line_search_cuts: int = 0
    factorisations: int = 0

    @classmethod
    def empty(cls) -> "SolveReport":
        return cls(0, 0.0, True, 0.0, 0.0, 0.0, solves=0, newton_iterations=0)

    def add(self, other: "SolveReport") -> None:
        """Fold in the work of another stage or attempt at the same step (a
        rejected one, a re-solve): work, releases and times add up, the worst
        residual and convergence are kept; ``contacts`` stays this report's."""
        self.iterations += other.iterations
        self.released += other.released
        self.solves += other.solves
        self.factorisations += other.factorisations
        self.force_ms += other.force_ms
        self.assembly_ms += other.assembly_ms
        self.solve_ms += other.solve_ms
        self.newton_iterations += other.newton_iterations
        self.line_search_cuts += other.line_search_cuts
        self.residual = max(self.residual, other.residual)
        self.converged = self.converged and other.converged


@dataclass
class StageResult:
    """Solution of one stage: ``velocities`` ``(n, 3)`` m/s, ``positions`` ``(n, 3)``
    m (``x̂ + γh V``), the contacts that held at the end (``None`` without
    obstacles), the report and the impulse ``(n, 3)`` N·s the contacts
    applied in the stage (``None`` without contacts)."""

    positions: np.ndarray
    velocities: np.ndarray
    contacts: object
    report: SolveReport
    contact_impulse: np.ndarray | None = None


class ImplicitStageSolver:
    """Solves implicit stages (equation (1) of the module docstring; design §3).

    Keeps the sparsity pattern and the last correction of each stage slot
    (warm start of the iterative backends) while the topology is unchanged;
    call :meth:`reset_topology` after it changes.
    """

    #: Most solves of one contact solve (``contact.friction_rounds``): the first,
    #: the release re-solve and the rounds in which new contacts start to slip.
    friction_rounds = 6
    #: The friction rounds go on while a sliding contact's Coulomb impulse
    #: (μ times its normal load in the last solve) changes by more than this
    #: fraction of the largest one.
    friction_tolerance = 1e-3
    #: Reactions passed to other layers (:mod:`~cloth_lod_ros.sim.contact.layer_reactions`)
    #: that would change no particle's velocity by more than this (m/s) are
    #: added directly (a layer lying on a table that holds it: nothing moves);
    #: larger ones are the load of one more solve, so that the cloth answers.
    transfer_speed = 1e-3
    #: Slack (m/s) of the limit on the reactions passed to other layers
    #: (:func:`~cloth_lod_ros.sim.contact.layer_reactions.layer_reactions`): a share
    #: may bring a particle up to the velocity of the contacts pushing it plus
    #: this, never faster relative to them than it was plus this.  About the
    #: speed of cloth landing on cloth (0.2 m of fall): only the catches of
    #: whole sheets (tens of m/s) are cut.  On ``drop_crumple`` (16 runs: L5,
    #: LOD on and off, μ 0-0.3, thickness 4 and 4.5 mm) 0.5 m/s cut enough
    #: unbalanced impulse to let three runs gain energy, 2 m/s none.
    transfer_slack = 2.0

    def __init__(self, solver_config, material, gravity, geometry=None, air=None):
        """Args:
            solver_config: the scene's ``solver`` section (method, tolerance, ...).
            material: the scene's material.  gravity: ``(3,)`` m/s².
            geometry: ``(width, height, block)`` of the cloth in m, for the
                multigrid backend's lattices.
            air: the scene's ``air`` section (face drag, wind) or None; passed
                to :func:`~cloth_lod_ros.sim.physics.forces.evaluate`.
        """
        self.material = material
        self.air = air
        self.gravity = np.asarray(gravity, dtype=float)
        self.backend = make_solver(solver_config.method, solver_config.tolerance,
                                   solver_config.max_iterations, geometry)
        self._pattern: SparsePattern | None = None
        self._pattern_storage = PatternStorage()       # shared by successive patterns
        self.pattern_ms = 0.0
        self._graded = False
        self._uv: np.ndarray | None = None
        self._warm: dict = {}
        self._evaluated = None
        self._solves = 0
        self._previous_dv = None
        self._contact_distance = None
        self._transfer = None       # the last contact solve's reactions on other layers

    def reset_topology(self, elements: Elements | None = None,
                       uv: np.ndarray | None = None, graded: bool | None = None) -> None:
        """Forget per-topology caches; with ``elements`` (and the particles' rest
        ``uv`` ``(n, 2)`` m), build the new pattern and set up the backend now.
        ``graded``: whether the new mesh mixes levels (the backend's hint)."""
        if self._pattern is not None:
            # Only this solver assembles with its pattern: its storage is
            # reused by the next one (see PatternStorage).
            self._pattern.retire(self._pattern_storage)
        self._pattern = None
        self._warm = {}
        self._evaluated = None
        if uv is not None:
            self._uv = uv
        if graded is not None:
            self._graded = bool(graded)
        if elements is not None:
            self._new_pattern(elements)

    def _new_pattern(self, elements: Elements) -> None:
        start = _time.perf_counter()
        # The bend stencils couple each vertex's two-ring (physics.bending).
        self._pattern = SparsePattern(elements.vertex_count,
                                      elements.element_vertices,
                                      storage=self._pattern_storage)
        self.backend.reset_topology(self._pattern, self._uv,
                                    graded=self._graded)
        self.pattern_ms += 1e3 * (_time.perf_counter() - start)

    def take_pattern_ms(self) -> float:
        """Milliseconds spent building sparsity patterns since the last call
        (LOD bookkeeping: a topology change pays it)."""
        ms, self.pattern_ms = self.pattern_ms, 0.0
        return ms

    def evaluate(self, elements: Elements, x: np.ndarray, v: np.ndarray, gh: float):
        """Forces, energies and system blocks (weights ``γh²``, ``γh``) at ``(x, v)``.

        A contact re-solve repeats the step from the same predictor, so the
        last evaluation is kept and reused for the same (topology, material,
        x, v, γh).  Returns ``(evaluation, milliseconds it took)``.
        """
        cached = self._evaluated
        if (cached is not None and cached[0] is elements and cached[1] == gh
                and cached[2] is self.material and cached[6] is self.air   # live changes
                and np.array_equal(cached[3], x) and np.array_equal(cached[4], v)):
            return cached[5], 0.0
        start = _time.perf_counter()
        # Compiled kernels when numba is there (physics/forces_kernels.py; the same numbers to
        # round-off): they add the blocks straight into the pattern's data.
        ev = forces_kernels.evaluate(elements, self.material, x, v,
                                     stiffness_weight=gh * gh, damping_weight=gh, air=self.air,
                                     pattern=self._pattern)
        ms = 1e3 * (_time.perf_counter() - start)
        self._evaluated = (elements, gh, self.material, x.copy(), v.copy(), ev, self.air)
        return ev, ms

    def _linearise(self, elements, masses, x_hat, v_hat, gh, velocities, at_start):
        """Residual ``r`` ``(n, 3)`` N·s and system matrix at the iterate
        ``velocities`` (at ``x̂`` with BW's correction when ``at_start``)."""
        x = x_hat if at_start else x_hat + gh * velocities
        ev, ms = self.evaluate(elements, x, velocities, gh)
        t0 = _time.perf_counter()
        drag = self.material.air_drag
        force = ev.force + masses[:, None] * (self.gravity - drag * velocities)
        if at_start:
            # BW eq. 15: f(x̂ + γh V) ≈ f(x̂) + ∂f/∂x γh V.
            force = force + gh * ev.stiffness_times_velocity
        residual = gh * force - masses[:, None] * (velocities - v_hat)
        t1 = _time.perf_counter()
        # M − γh ∂f/∂v includes the drag term γh·c·M on the diagonal.
        matrix = forces_kernels.assemble(self._pattern, ev, masses * (1.0 + gh * drag))
        t2 = _time.perf_counter()
        return residual, matrix, ms + 1e3 * (t1 - t0), 1e3 * (t2 - t1)

    def residual_norm(self, elements: Elements, masses: np.ndarray, x_hat: np.ndarray,
                      v_hat: np.ndarray, gh: float, velocities: np.ndarray,
                      frozen: np.ndarray, impulse: np.ndarray | None = None) -> float:
        """``|S r|_{M⁻¹}`` (N·s/√kg = m/s·√kg) of the stage equations at
        ``velocities`` ``(n, 3)`` m/s, the particles ``frozen`` (held, in
        contact) left out: the line search's merit.  Forces only, no blocks.
        ``impulse``: ``(n, 3)`` N·s acting besides the forces (the reactions
        of contacts between layers on the other layer's particles)."""
        x = x_hat + gh * velocities
        ev = forces_kernels.evaluate(elements, self.material, x, velocities, with_blocks=False,
                                     air=self.air)
        drag = self.material.air_drag
        force = ev.force + masses[:, None] * (self.gravity - drag * velocities)
        residual = gh * force - masses[:, None] * (velocities - v_hat)
        if impulse is not None:
            residual += impulse
        residual[frozen] = 0.0
        return float(np.sqrt(np.sum(residual * residual / masses[:, None])))

    def solve_stage(self, elements: Elements, masses: np.ndarray, x_hat: np.ndarray,
                    v_hat: np.ndarray, gh: float, held: tuple[np.ndarray, np.ndarray],
                    predictor: np.ndarray, contacts=None, contact_distance=None,
                    max_iterations: int = 1,
                    tolerance: float = 0.0, linearize_at_start: bool = False,
                    slot: int = 0) -> StageResult:
        """Solve one stage (module docstring, equation (1)).

        Args:
            elements: rest data of the current topology.
            masses: ``(n,)`` particle masses, kg.
            x_hat, v_hat: ``(n, 3)`` the stage's base positions (m) and
                velocities (m/s).  gh: the stage step ``γh``, s.
            held: ``(indices (k,), targets (k, 3))``: particles that must be
                exactly at ``targets`` (m) at the end of the stage.
            predictor: ``(n, 3)`` first iterate ``V⁰`` (m/s).
            contacts: a :class:`~cloth_lod_ros.sim.contact.contacts.ContactSet` or None;
                ``contact_distance`` ``(k,)``: the normal distance (m) from
                ``x̂`` each contact's particle must cover towards the obstacle
                in this stage to end on the offset surface where it is at the
                stage's end (negative: away from it, a push-out or a surface
                moving out).  A contact prescribes that normal
                velocity; contacts whose force would pull are released;
                Coulomb friction follows.
            max_iterations, tolerance: Newton budget and stopping test (the
                RMS displacement of the last correction, m; 0: use the budget).
            linearize_at_start: BW's linearisation at ``x̂`` (first iteration).
            slot: which warm start to use (one per stage of a scheme).
        """
        if self._pattern is None:
            self._new_pattern(elements)
        solves_before = self._solves
        factorised_before = factorisation_count()
        held_idx, targets = held
        velocities = predictor.copy()
        # Held particles start on their end-of-stage velocity, so every Newton
        # correction leaves them exactly there (and a line search cannot move them).
        velocities[held_idx] = (targets - x_hat[held_idx]) / gh
        # Contact particles keep the predictor of the rest of the cloth: the
        # first iteration's forces are evaluated on a cloth that moves on as a
        # whole, and its solve puts them on the surface.  (Moving only them
        # onto the surface - before issue 31 - put a kink as deep as the
        # contact band where they meet free neighbours: a strip landing over a
        # table's edge came out of one Gauss-Newton iteration 7 % stretched.)
        pinned = Constraints(indices=held_idx, projectors=np.zeros((len(held_idx), 3, 3)),
                             prescribed=np.zeros((len(held_idx), 3)))
        frozen = held_idx if contacts is None else np.concatenate([held_idx, contacts.indices])
        report = SolveReport.empty()
        impulse = None
        transfer = None         # reactions of layer contacts on the other layer (n, 3) N·s
        merit = None
        released = 0
        warm = self._warm.get(slot)
        for iteration in range(max_iterations):
            residual, matrix, force_ms, assembly_ms = self._linearise(
                elements, masses, x_hat, v_hat, gh, velocities,
                linearize_at_start and iteration == 0)
            t0 = _time.perf_counter()
            self._previous_dv = warm if iteration == 0 else None
            if contacts is not None and len(contacts):
                result, contacts, n_released = self._solve_with_contacts(
                    matrix, residual, pinned, contacts, masses, velocities, gh,
                    contact_distance)
                transfer = self._transfer
                released += n_released
                # The contacts that held (released ones and those short of
                # the surface are gone for later iterations).
                frozen = np.concatenate([held_idx, contacts.indices])
                contact_distance = self._contact_distance
            else:
                result = self._solve(matrix, residual, pinned)
            solve_ms = 1e3 * (_time.perf_counter() - t0)
            if iteration == 0 and np.all(np.isfinite(result.dv)):
                warm = result.dv
            dv = result.dv
            step = 1.0
            if iteration > 0:
                # Backtracking on the filtered residual (Gauss–Newton Jacobian).
                if merit is None:
                    merit = self.residual_norm(elements, masses, x_hat, v_hat, gh,
                                               velocities, frozen, transfer)
                for _ in range(4):
                    trial = self.residual_norm(elements, masses, x_hat, v_hat, gh,
                                               velocities + step * dv, frozen, transfer)
                    if trial < merit or not np.isfinite(trial):
                        break
                    step *= 0.5
                    report.line_search_cuts += 1
                merit = trial
            velocities = velocities + step * dv
            if contacts is not None and len(contacts):
                # The contact impulses (N·s, friction included) of this
                # iteration's linear model: A Δv − r on the contact rows, and
                # the reactions of layer contacts on the other layer's particles.
                impulse = np.zeros_like(velocities) if transfer is None else transfer.copy()
                rows = contacts.indices
                impulse[rows] = (bsr_product(matrix, dv) - residual)[rows]
            stage_report = SolveReport(result.iterations, result.residual, result.converged,
                                       force_ms, assembly_ms, solve_ms, solves=0,
                                       newton_iterations=1)
            report.add(stage_report)
            moved = gh * step * float(np.sqrt(np.mean(np.sum(dv * dv, axis=1))))
            if tolerance > 0.0 and moved <= tolerance:
                break
        self._warm[slot] = warm
        report.solves = self._solves - solves_before
        report.factorisations = factorisation_count() - factorised_before
        report.contacts = len(contacts) if contacts is not None else 0
        report.released = released
        return StageResult(x_hat + gh * velocities, velocities, contacts, report, impulse)

    def _keep_warm_start(self, dv: np.ndarray) -> None:
        """Start the next CG solve from ``dv`` (``(n, 3)`` m/s), unless it is not
        finite (a rejected step's NaN would spread into the retry)."""
        self._previous_dv = dv if np.all(np.isfinite(dv)) else None

    def _solve(self, matrix, rhs, constraints):
        self._solves += 1
        return self.backend.solve(matrix, rhs, constraints, self._previous_dv)

    def _solve_with_contacts(self, matrix, rhs, pinned, contacts, masses, v, h, distance):
        """Solve ``A Δv = rhs`` with pins plus one-sided contacts and Coulomb
        friction (BW §5.3, §6), ``v`` ``(n, 3)`` being the current iterate (m/s),
        ``h`` the stage step (s) and ``distance`` ``(k,)`` the normal distance
        each contact's particle must cover in the stage (m).
        The contacts left after releases and their distances are kept in
        ``self._contact_distance``, the reactions passed to other layers
        (step 3) in ``self._transfer``.

        0. A contact in the speculative band whose particle would not be
           moving towards the surface at its landing velocity by the end of
           the stage - moving on with its velocity and falling with gravity,
           relative to the surface - is left out (:func:`_short_of_surface`):
           holding it would pull the particle in at ``d/h``, 13 m/s for a 4
           mm gap in a 0.3 ms stage, the more the smaller the step, and the
           release in step 1 misses those whose push in the all-held solve
           came from rows it lets go (a strip over a table's edge was thrown
           off at 19 m/s that way before issue 31).  One the cloth pushes in
           after all gets a held contact from the step's penetration check.
        1. Every other contact is held: its normal velocity lands it on the offset
           surface (see ``distance``; a penetrating one is pushed out slowly) and,
           where the obstacle has friction, its tangential velocity is that of
           the surface point it touches (``contacts.velocity``; 0 on a static
           obstacle): a sticking contact moves with the surface.
           The reaction ``R = A Δv − b`` (an impulse, N·s) is what holding
           costs; contacts whose normal reaction would pull are released and
           the system is solved again (once).
        2. Coulomb: a contact whose tangential reaction exceeds ``μ R·n``
           cannot stick; it slides on the surface with the friction impulse
           ``μ (R·n) R̂_t`` in the right-hand side (``R_t`` is what would have
           held it on the surface point, so this opposes the slip *relative*
           to the surface), and the
           system is solved again; repeated (at most ``friction_rounds``
           solves in all, ``contact.friction_rounds``) while new contacts start
           to slip, because when one row lets go the next row
           takes its load; a sliding contact's impulse is re-formed each
           round from its normal load in the last solve (in which it slid),
           and the rounds go on while those change.  Friction is inside the implicit solve,
           so the rest of the cloth responds to it in the same step.
        3. Contacts with another layer of the cloth (``contacts.partners``):
           the other layer's particles take the opposite of what each contact
           applied (:func:`~cloth_lod_ros.sim.contact.layer_reactions.layer_reactions`),
           as the load of one more solve with the same constraints, so that
           the layers exchange equal and opposite impulses and the other
           layer answers through the cloth in the same step.
        """
        released = 0
        iterations = 0
        short = _short_of_surface(contacts, distance, v[contacts.indices], h, self.gravity)
        if short.any():
            contacts, distance = contacts.subset(~short), distance[~short]
        self._transfer = None
        if not len(contacts):
            self._contact_distance = distance
            return self._solve(matrix, rhs, pinned), contacts, released
        slip = np.zeros(len(contacts), dtype=bool)
        friction_impulse = np.zeros((len(contacts), 3))
        # The tangential impulse that held each sliding contact when it began
        # to slip: what stops its sliding.  Friction never exceeds it.
        stopping = np.zeros(len(contacts))
        rounds = self.friction_rounds     # a slip front moves one row of contacts per round
        for attempt in range(rounds):
            normals = contacts.normals
            target_vn = -_first(distance) / h
            current = v[contacts.indices]
            # Rows against two obstacles (contact_rows): both normals held.
            doubled = contacts.doubled
            two = TwoNormals(normals[doubled], contacts.second.normals[doubled]) \
                if doubled.any() else None
            friction = contacts.friction
            if two is not None:
                friction = friction + contacts.second.friction
            sliding = (friction <= 0.0) | slip
            projectors = np.zeros((len(contacts), 3, 3))
            projectors[sliding] = np.eye(3) - normals[sliding, :, None] * normals[sliding, None, :]
            # Held contacts: full Δv to (target_vn n) plus the surface's
            # tangential velocity (a moving surface carries a sticking particle);
            # sliding: normal part only.
            prescribed = target_vn[:, None] * normals - current
            surface_vn = contacts.normal_speed()
            if surface_vn is not None:
                # Sticking moves with the surface: its tangential velocity too.
                prescribed += contacts.velocity - surface_vn[:, None] * normals
            current_vn = np.einsum("kd,kd->k", current, normals)
            prescribed[sliding] = ((target_vn - current_vn)[sliding, None] * normals[sliding])
            if two is not None:
                # Landing on both surfaces; a sticking row also moves with
                # the first surface along their common tangent.
                targets = -distance[doubled] / h
                land = two.landing(current[doubled], targets)
                free = two.free_projectors()
                stick = land + np.einsum("kab,kb->ka", free, contacts.surface_velocity()[doubled]
                                         - current[doubled])
                slides = sliding[doubled]
                prescribed[doubled] = np.where(slides[:, None], land, stick)
                projectors[doubled] = np.where(slides[:, None, None], free, 0.0)
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
            reaction = (bsr_product(matrix, result.dv) - step_rhs)[contacts.indices]
            normal_reaction = np.einsum("kd,kd->k", reaction, normals)
            pulling = (normal_reaction < 0.0) & ~contacts.hold
            pulling_second = np.zeros(len(contacts), bool)
            if two is not None:
                loads = two.normal_loads(reaction[doubled])          # (k₂, 2) N·s
                normal_reaction[doubled] = loads[:, 0]
                pulling[doubled] = (loads[:, 0] < 0.0) & ~contacts.hold[doubled]
                pulling_second[doubled] = (loads[:, 1] < 0.0) & ~contacts.second.hold[doubled]
            if (pulling.any() or pulling_second.any()) and attempt == 0:
                released += int(pulling.sum() + pulling_second.sum())
                contacts, distance, keep = _release(contacts, distance, pulling,
                                                    pulling_second)
                slip = slip[keep]
                friction_impulse = friction_impulse[keep]
                stopping = stopping[keep]
                if not len(contacts):
                    result = self._solve(matrix, rhs, pinned)
                    iterations += result.iterations
                    break
                continue
            tangential = reaction - normal_reaction[:, None] * normals
            if two is not None:
                tangential[doubled] = reaction[doubled] - two.in_plane(reaction[doubled])
            magnitude = np.linalg.norm(tangential, axis=1)
            # Normal load for friction: the reaction less what pushing a particle
            # out of the offset surface costs (a position correction is not a load).
            # On a moving surface, the part of the normal velocity that is the
            # surface's own motion is a load (a tray lifting the cloth), not a
            # correction.
            push_out = target_vn if surface_vn is None else target_vn - surface_vn
            correction = masses[contacts.indices] * np.maximum(push_out, 0.0)
            limit = contacts.friction * np.maximum(normal_reaction - correction, 0.0)
            if two is not None:
                second = contacts.second.subset(doubled)
                push_out = targets[:, 1]
                if second.velocity is not None:
                    push_out = push_out - second.normal_speed()
                correction = masses[second.indices] * np.maximum(push_out, 0.0)
                limit[doubled] += second.friction * np.maximum(loads[:, 1] - correction, 0.0)
            # A sliding contact's friction is μ times its normal load *while it
            # slides*: the load of this solve, in which it slid, not that of
            # the solve that first held it.  Holding a contact at an edge or a
            # corner (normal not across its velocity) stops the cloth's
            # momentum partly along the normal, an impulse of order m v per
            # step: taken as the load, friction grew as 1/h and the finer the
            # step the later `table_drape` slid off (issue 31).  Re-solved
            # while these impulses still change (``friction_tolerance``).
            refreshed = False
            # Contacts with another layer keep the load of the holding solve:
            # theirs is settled only when the other layer takes its reaction
            # (step 3, after these rounds); refreshed here, a patch sliding
            # on a sheet lost 7 % of its friction (test_layer_friction).
            sliding_rows = slip & np.all(contacts.partner_arrays()[1] == 0.0, axis=1)
            if sliding_rows.any():
                before = np.linalg.norm(friction_impulse[sliding_rows], axis=1)
                unit = friction_impulse[sliding_rows] / np.maximum(before, 1e-300)[:, None]
                # Coulomb: at most μ times the load, and never more than the
                # impulse that held the contact (more would reverse its sliding).
                after = np.minimum(limit[sliding_rows], stopping[sliding_rows])
                friction_impulse[sliding_rows] = after[:, None] * unit
                refreshed = bool(np.max(np.abs(after - before))
                                 > self.friction_tolerance * max(float(np.max(limit)), 1e-300))
            new_slip = (friction > 0.0) & (magnitude > limit) & ~slip
            if not new_slip.any() and not refreshed:
                break
            slip |= new_slip
            stopping[new_slip] = magnitude[new_slip]
            friction_impulse[new_slip] = (limit[new_slip] / magnitude[new_slip])[:, None] \
                * tangential[new_slip]
        result.iterations = iterations
        self._contact_distance = distance
        self._transfer = None
        if len(contacts) and contacts.partners is not None:
            # The last solve's slip state, friction and filters are those above.
            relative_vn = target_vn if surface_vn is None else target_vn - surface_vn
            transfer, free = layer_reactions(
                matrix, step_rhs, v, result.dv, contacts, pinned.indices, masses,
                sliding, friction_impulse, relative_vn, projectors, self.transfer_slack)
            if transfer is not None:
                self._transfer = transfer
                kick = free / masses[:, None]
                if np.sqrt(np.max(np.sum(kick * kick, axis=1))) <= self.transfer_speed:
                    result.dv = result.dv + kick
                else:
                    final = self._solve(matrix, step_rhs + transfer,
                                        _merge_constraints(pinned, contacts.indices,
                                                           projectors, prescribed))
                    result.dv = final.dv
                    result.iterations += final.iterations
                    self._keep_warm_start(final.dv)
        return result, contacts, released


def _short_of_surface(contacts, distance: np.ndarray, velocities: np.ndarray, h: float,
                      gravity: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: contacts in the speculative band whose particles would
    not be moving towards the surface at their landing velocity ``−distance/h``
    (``distance`` ``(k,)`` or ``(k, 2)`` m) by the end of a stage of ``h`` s,
    moving on with ``velocities`` ``(k, 3)`` m/s and falling with ``gravity``
    ``(3,)`` m/s² (``v·n + g·n h > −distance/h``, relative to the surface,
    along every normal of the row): holding one at its landing velocity
    would draw it in faster than anything moves it.  The margin over "would
    reach the surface" (``v·n + g·n h/2``) is a step's fall ``g h²/2``, the
    band's own allowance for a particle resting on a surface (a cloth thrown
    onto a ball at 5 m/s had rows 1.4 mm short of it in a 1/60 s step; left
    out, the paper's linearised step gained 15 % of the energy).  (Gravity counts for a contact with another layer too, as if
    that layer were supported.)  Contacts found past the surface (``hold``)
    are never short."""
    short = ~contacts.hold
    for j, part in enumerate((contacts, contacts.second)):
        if j == 1 and (part is None or distance.ndim == 1):
            break
        gap = distance if distance.ndim == 1 else distance[:, j]
        surface = part.normal_speed()
        surface = 0.0 if surface is None else surface
        end = (np.einsum("kd,kd->k", velocities, part.normals) - surface
               + h * (part.normals @ gravity))
        target = -gap / h - surface
        below = (target < 0.0) & (end > target)
        if j == 1:
            below |= ~np.any(part.normals != 0.0, axis=1)       # no second obstacle
        short &= below
    return short

def _merge_constraints(pinned: Constraints, indices, projectors, prescribed) -> Constraints:
    return Constraints(indices=np.concatenate([pinned.indices, indices]),
                       projectors=np.concatenate([pinned.projectors, projectors]),
                       prescribed=np.concatenate([pinned.prescribed, prescribed]))


def _first(distance: np.ndarray) -> np.ndarray:
    """``(k,)`` the first obstacle's column of a ``(k,)`` or ``(k, 2)`` distance."""
    return distance if distance.ndim == 1 else distance[:, 0]


def _release(contacts, distance, first: np.ndarray, second: np.ndarray):
    """Release the obstacles that pull: ``first``/``second`` ``(k,)`` bool
    mark rows whose first/second obstacle's normal load is negative.  A row
    keeps the obstacle that still pushes (its second becomes its first when
    only the first lets go) and goes when neither does.  Returns
    ``(contacts, distance, keep)``, ``keep`` ``(k,)`` bool the rows left."""
    doubled = contacts.doubled
    swap = first & doubled & ~second
    drop_second = second & ~first
    keep = ~(first & (~doubled | second))
    if swap.any() or drop_second.any():
        distance = distance.copy()
        if swap.any():
            contacts = contacts.swapped(swap)
            distance[swap, 0] = distance[swap, 1]
        if drop_second.any():
            contacts = contacts.without_second(drop_second)
        distance[swap | drop_second, 1] = 0.0
    return contacts.subset(keep), distance[keep], keep
