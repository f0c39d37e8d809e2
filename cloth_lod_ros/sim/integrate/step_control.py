"""Time stepping: the step-size control that advances the cloth by one frame
with a scheme of :mod:`.schemes` (design §3).

Step-size control (:class:`TimeStepper`): ``simulation.time_step`` is the
frame period ``H`` - the largest step and the interval at which the cloth is
returned to the caller (node, recorder, bench).  With
``simulation.error_tolerance`` ``ε`` > 0 (m) a frame is covered by steps whose
estimated local position error (mass-weighted RMS over the free particles)
is at most ``ε``; a step above it is redone with a smaller ``h``; the next
step grows by ``0.9 (ε/err)^{1/2}`` (between 0.2× and 2×), never below
``simulation.min_time_step`` nor above ``H``.  The estimates are those of the
embedded first-order solutions: ``x_n + h V₁`` for SDIRK2 (error
``γh (V₂ − V₁)``) and the trapezoidal rule for the Euler schemes (error
``h/2 (v_{n+1} − v_n)``), so the control is conservative.  With ``ε = 0`` each
frame is one step of ``H``.

In both modes a step in which any triangle's stretch ``|w|`` grows by more
than :attr:`TimeStepper.max_strain_growth` (or that is not finite) is redone
with half the step: one linearised backward-Euler step cannot see the
second-order stretch of motion *across* an unstretched edge (its tangent
stiffness there is zero), so a part of the cloth that is stopped or turned
abruptly while its neighbours move on (a fast impact, a sharp jerk of a
grasp) comes out of the step stretched far beyond what the material does
and with energy it never had (a 5 m/s impact at 1/60 s with BW: 58 % strain
and 14x the energy; at 1/240 s: 4 %, no gain).  Held particles move along the
straight line from their frame-start positions to their frame-end targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..contact.contacts import find_contacts, penetrations
from ..contact.contact_rows import TwoNormals
from ..contact.self_contact import merge_contacts
from ..physics.elements import Elements
from ..physics.energies_kernels import stretch_lengths    # compiled when numba is there
from .implicit_stage import ImplicitStageSolver, SolveReport
from .state import ClothState
from .schemes import BaraffWitkin, SCHEMES

__all__ = ["TimeStepper", "FrameSteps", "DEFAULT_ERROR_TOLERANCE", "effective_tolerance"]


#: ``simulation.error_tolerance`` when the scene leaves it unset, m.
DEFAULT_ERROR_TOLERANCE = 1e-3


def effective_tolerance(simulation) -> float:
    """The error tolerance (m) a ``simulation`` section asks for: its own, or
    when unset :data:`DEFAULT_ERROR_TOLERANCE` - except for the paper's
    configuration, whose step is fixed (one linearised step per frame)."""
    if simulation.error_tolerance is not None:
        return simulation.error_tolerance
    return 0.0 if simulation.integrator == BaraffWitkin.name else DEFAULT_ERROR_TOLERANCE


@dataclass
class FrameSteps:
    """How a frame was covered: accepted ``substeps``, ``rejected`` attempts
    (error or stretch too large), ``forced`` steps accepted at the smallest
    step allowed although their test failed, and the smallest and largest
    accepted step (s)."""

    substeps: int = 0
    rejected: int = 0
    forced: int = 0
    smallest: float = math.inf
    largest: float = 0.0


class TimeStepper:
    """Advances the cloth by one frame with a scheme, contacts and step-size
    control (module docstring).

    Args:
        solver: the stage solver.  simulation: the scene's ``simulation``
            section (integrator, Newton settings, error tolerance, min step).
        obstacles: the scene's obstacles (empty: no contact code runs).
        contact: the scene's contact settings (``thickness`` m,
            ``max_correction_speed`` m/s).
    """

    max_strain_growth = 0.1     # largest |w| increase of a triangle in one step
    # Largest |w| increase in one step for which a step kept at the smallest
    # size still gets the self-collision search: beyond it triangles more than
    # doubled in one step (no fabric does; the node reports ERROR long before),
    # crossings mean nothing, and the boxes of such motion overlap pairwise, so
    # the search would cost the square of the triangle count.
    torn_strain_growth = 1.0
    max_substep_depth = 3       # fixed step: at most 2**3 = 8 steps per frame
    growth_limits = (0.2, 2.0)  # bounds of the step-size factor after a step
    safety = 0.9

    def __init__(self, solver: ImplicitStageSolver, simulation, obstacles: list, contact,
                 self_collision=None):
        self.solver = solver
        self.obstacles = obstacles
        self.contact = contact
        # SelfCollision or None (off: no self-collision code runs).
        self.self_collision = self_collision
        # Against gravity (z without it), tilted a little so that no layer
        # lies exactly across it: the side of a layer contact that carries
        # friction is the one above.
        g = np.asarray(solver.gravity, dtype=float)
        up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
        up = up + np.array([1e-3, 2e-3, 3e-3])
        self._up = up / np.linalg.norm(up)
        self._crossing = False
        self.configure(simulation)
        self._next_step: float | None = None
        self._smallest = 0.0

    def configure(self, simulation) -> None:
        """Take the scheme and step-size settings from a ``simulation`` section."""
        self.simulation = simulation
        self.scheme = SCHEMES[simulation.integrator](
            simulation.newton_iterations, simulation.newton_tolerance,
            self.contact.max_correction_speed)
        self.tolerance = effective_tolerance(simulation)

    def advance(self, elements: Elements, masses: np.ndarray, state: ClothState,
                held: tuple[np.ndarray, np.ndarray], frame: float, obstacles_at=None):
        """Advance ``state`` by ``frame`` s with the held particles ending on
        ``held``'s targets.  Returns ``(state, report, contacts, FrameSteps)``;
        the report covers all the work, rejected attempts included.

        ``obstacles_at``: callable(fraction of the frame, 0 to 1) -> the
        obstacles at that time, moving ones with their velocities (None: the
        static :attr:`obstacles`), so each step of the frame sees them where
        they are at its start and end."""
        indices, end_targets = held
        start = state.positions[indices]
        adaptive = self.tolerance > 0.0
        smallest = (min(self.simulation.min_time_step, frame) if adaptive
                    else frame / 2 ** self.max_substep_depth)
        h = min(self._next_step or frame, frame) if adaptive else frame
        self._smallest = smallest
        steps = FrameSteps()
        total = SolveReport.empty()
        contacts = None
        done = 0.0
        current = state
        while frame - done > 1e-9 * frame:
            remaining = frame - done
            if h >= remaining * (1.0 - 1e-9):
                h = remaining
            elif h > 0.5 * remaining:
                h = 0.5 * remaining          # no sliver of a step at the frame's end
            h = max(h, min(smallest, remaining))
            fraction = (done + h) / frame
            targets = start + fraction * (end_targets - start)
            previous = start + (done / frame) * (end_targets - start)
            moving = None
            if obstacles_at is not None:
                moving = (obstacles_at(done / frame), obstacles_at(min(fraction, 1.0)))
            new, report, step_contacts, error = self._attempt(
                elements, masses, current, previous, (indices, targets), h, moving)
            total.add(report)
            sound = self._acceptable(elements, current, new)
            if self._crossing:
                sound = False                # a layer went through another
            accurate = not adaptive or (sound and error <= self.tolerance)
            if (sound and accurate) or h <= smallest * (1.0 + 1e-9):
                steps.forced += not (sound and accurate)
                if self._crossing:
                    # Last resort at the smallest step: stop the crossing zone.
                    x, v, _, _ = self.self_collision.stop_zone(
                        current.positions, new.positions, new.velocities, indices)
                    new = ClothState(x, v, new.time)
                steps.substeps += 1
                steps.smallest = min(steps.smallest, h)
                steps.largest = max(steps.largest, h)
                current, contacts = new, step_contacts
                total.contacts = report.contacts
                done += h
                h = self._proposal(h, error) if adaptive else min(2.0 * h, frame)
            else:
                steps.rejected += 1
                if self._crossing:
                    self.self_collision.counters.refused += 1
                factor = (min(self._factor(error), 0.5) if adaptive and sound else 0.5)
                h = max(h * factor, smallest)
        if adaptive:
            self._next_step = min(h, frame)
        return current, total, contacts, steps

    def _with_self(self, contacts, pairs, velocities, masses, held_indices):
        """Obstacle ``contacts`` merged with the self-contact constraints of ``pairs``."""
        sc = self.self_collision
        # Infinitely heavy for the pairs' common velocity: held particles and
        # those resting on an obstacle (not merely in its speculative band);
        # along the surface only if it has friction (a frictionless one lets
        # the layer above drag them).
        fixed = np.zeros(len(masses), dtype=bool)
        slides = np.zeros(len(masses), dtype=bool)
        if contacts is not None:
            resting = contacts.distance < 0.5 * self.contact.thickness
            fixed[contacts.indices[resting]] = True
            slides[contacts.indices[resting & (contacts.friction <= 0.0)]] = True
        fixed[held_indices] = True
        slides[held_indices] = False
        merged, sc.last_constraints = merge_contacts(
            contacts, sc.constraints(pairs, velocities, masses, fixed, held_indices, slides,
                                     self._up))
        return merged

    def _factor(self, error: float) -> float:
        low, high = self.growth_limits
        if not error > 0.0:
            return high
        return min(high, max(low, self.safety * math.sqrt(self.tolerance / error)))

    def _proposal(self, h: float, error: float) -> float:
        return max(h * self._factor(error), self.simulation.min_time_step)

    def _acceptable(self, elements: Elements, start: ClothState, end: ClothState,
                    limit: float | None = None) -> bool:
        """Finite, and no triangle's stretch grew by more than ``limit``
        (:attr:`max_strain_growth` when None)."""
        if not (np.all(np.isfinite(end.positions)) and np.all(np.isfinite(end.velocities))):
            return False
        growth = (stretch_lengths(elements, end.positions)
                  - stretch_lengths(elements, start.positions))
        limit = self.max_strain_growth if limit is None else limit
        return not len(growth) or float(growth.max()) <= limit

    def _attempt(self, elements: Elements, masses: np.ndarray, state: ClothState,
                 start_targets: np.ndarray, held: tuple[np.ndarray, np.ndarray], h: float,
                 moving=None):
        """One scheme step of ``h`` s with contacts and re-solves for missed
        penetrations.  Returns ``(state, report, contacts, error)``: the
        contacts found for the step (near or touching a surface, the LOD keeps
        detail there; the solve may have released some), ``error``
        being the estimated local position error in m (mass-weighted RMS over
        the particles, held and contact ones counting as zero).  ``moving``:
        ``(obstacles at the step's start, at its end)`` or None (static)."""
        contacts = None
        thickness = self.contact.thickness
        indices, targets = held
        at_start, at_end = moving if moving is not None else (self.obstacles, self.obstacles)
        if self.obstacles:
            contacts = find_contacts(at_start, state.positions, thickness,
                                     exclude=indices, velocities=state.velocities, h=h)
        sc = self.self_collision
        solved = contacts
        if sc is not None:
            pairs = sc.proximity(state.positions, state.velocities, h)
            solved = self._with_self(contacts, pairs, state.velocities, masses, indices)
        result = self.scheme.step(self.solver, elements, masses, state, start_targets,
                                  held, h, solved)
        report = result.report
        self._crossing = False
        rounds = sc.config.max_resolves if sc is not None else (4 if self.obstacles else 0)
        for attempt in range(rounds + (sc is not None)):
            # A particle that the start-of-step test missed (accelerated into an
            # obstacle, or released and pushed in) gets a contact, a pair of the
            # cloth that met during the step a held self-contact, and the step is
            # solved again.
            missed = crossed = None
            if self.obstacles:
                missed = penetrations(at_end, state.positions, result.positions,
                                      thickness, exclude=indices, h=h)
            if sc is not None and not self._acceptable(
                    elements, state, ClothState(result.positions, result.velocities,
                                                state.time + h),
                    self.max_strain_growth if h > self._smallest * (1.0 + 1e-9)
                    else self.torn_strain_growth):
                # A step the controller refuses anyway (not finite, or stretched
                # past its limit) and retries shorter, or one torn at the
                # smallest step: no crossing search over motion that may span
                # kilometres.  (A step kept at the smallest size within the tear
                # limit is searched, and its crossing zone stopped.)
                self._crossing = False
                break
            if sc is not None:
                crossed = sc.crossings(state.positions, result.positions)
                self._crossing = bool(len(crossed))
            if not (missed is not None and len(missed)) and not (crossed is not None
                                                                 and len(crossed)):
                break
            if attempt == rounds:
                break                        # (self-collision: the final check)
            if missed is not None and len(missed):
                contacts = contacts.union(missed)
            solved = contacts
            if sc is not None:
                if len(crossed):
                    sc.counters.resolves += 1
                    pairs = pairs.concat(crossed)
                solved = self._with_self(contacts, pairs, result.velocities, masses, indices)
            result = self.scheme.step(self.solver, elements, masses, state, start_targets,
                                      held, h, solved)
            result.report.add(report)       # the first attempt's work counts too
            report = result.report
        if sc is not None:
            contacts = solved    # the LOD keeps detail where the cloth touches anything
        positions, velocities = result.positions, result.velocities
        held_contacts = result.contacts
        if held_contacts is not None and len(held_contacts):
            # Inelastic contact: the normal velocity that moved a particle onto
            # the offset surface (landing or push-out) is a position correction,
            # not motion to keep; storing it would bounce it off next step.  On
            # a moving surface only the velocity relative to it goes: the
            # particle keeps moving with the surface along the normal.
            n_c = held_contacts.normals
            vn = np.einsum("kd,kd->k", velocities[held_contacts.indices], n_c)
            surface_vn = held_contacts.normal_speed()
            if surface_vn is not None:
                vn = vn - surface_vn
            velocities[held_contacts.indices] -= vn[:, None] * n_c
            _drop_second_normal_velocity(held_contacts, velocities)
        # Held particles: exactly on target (the stage velocities agree to rounding).
        positions[indices] = targets
        error = result.error
        error[indices] = 0.0
        if held_contacts is not None and len(held_contacts):
            # A contact's normal motion is set by its constraint, and an
            # impact's velocity jump is not a smooth error to resolve in time.
            error[held_contacts.indices] = 0.0
        weights = np.ones(len(masses)) if masses.sum() <= 0 else masses
        rms = float(np.sqrt(np.sum(weights * np.sum(error * error, axis=1)) / weights.sum()))
        return ClothState(positions, velocities, state.time + h), report, contacts, rms


def _drop_second_normal_velocity(contacts, velocities: np.ndarray) -> None:
    """Rows against two obstacles: the velocity relative to both surfaces in
    the plane of their normals goes (``velocities`` ``(n, 3)`` m/s, in place;
    the first normal's part has gone already, :meth:`TimeStepper._attempt`)."""
    doubled = contacts.doubled
    if not doubled.any():
        return
    rows = contacts.indices[doubled]
    first, second = contacts.subset(doubled), contacts.second.subset(doubled)
    relative = np.zeros((len(rows), 2))
    for j, part in enumerate((first, second)):
        speed = part.normal_speed()
        if speed is not None:
            relative[:, j] = speed
    geometry = TwoNormals(first.normals, second.normals)
    velocities[rows] += geometry.landing(velocities[rows], relative)
