"""Integration schemes made of implicit stages (design §3).

Schemes (``simulation.integrator``), each a sequence of stages of the form
solved by :class:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver`
(``M (V − v̂) = γh f(x̂ + γh V, V)``, positions ``X = x̂ + γh V``):

* ``baraff_witkin`` - the paper's method (BW eq. 15): one backward-Euler
  stage linearised at ``x_n``, one linear solve.  First order, and its
  numerical damping ``ω²h/2`` over-damps a swinging cloth at 1/60 s.
* ``backward_euler`` - the same equations solved by Newton iterations from
  the predictor ``x_n + h v_n`` (first order; large rotations keep their
  centripetal stretch).
* ``sdirk2`` (default) - Alexander's two-stage, L-stable, stiffly accurate
  singly diagonally implicit Runge–Kutta method, ``γ = 1 − 1/√2``
  (Alexander 1977; Hairer & Wanner, *Solving ODEs II*, §IV.6, table 6.5)::

      Y₁ = y_n + γh F(Y₁)
      y_{n+1} = Y₂ = y_n + (1 − γ)h F(Y₁) + γh F(Y₂)

  for ``y = (x, v)``, ``F = (v, M⁻¹f)``.  Both stages have the backward-Euler
  form with step ``γh``: stage 2 starts from ``x̂ = x_n + (1 − γ)h V₁`` and
  ``v̂ = v_n + (1 − γ)/γ (V₁ − v_n)`` (``M⁻¹f(Y₁) = (V₁ − v_n)/(γh)``, pin
  and contact impulses included).  Second order, with no numerical damping
  of slow modes to leading order, and one-step: nothing to carry across a
  change of topology, of contacts or of the step size (a multistep method
  such as BDF2 would need the previous state mapped through every split and
  merge).

* ``midpoint`` - a study, not a ``simulation.integrator`` (:data:`STUDY_SCHEMES`,
  measured by ``tools/dissipation --integrators midpoint``): the implicit midpoint rule
  ``y_{n+1} = y_n + h F((y_n + y_{n+1})/2)`` (Hairer, Lubich & Wanner,
  *Geometric Numerical Integration*, §VI.3), one backward-Euler stage of step
  ``h/2`` to the midpoint ``Y``, then ``y_{n+1} = 2Y − y_n``.  Second order and
  A-stable but not L-stable: ``|R(iωh)| = 1``, so it takes no energy out of any
  oscillation (the L-stable schemes above damp a mode of ``ωh = 1`` by 0.3 %
  (sdirk2) to 29 % (backward Euler) a step) - nor out of the stretch waves no
  affordable step resolves.  On the undamped swing of docs/model.md
  ("Numerical dissipation") it gains energy under the error control (the
  variable step breaks the rule's symplecticity) and blows up at a fixed
  1/60 s, Newton converged or not, so it is not offered.

Each scheme's step (:meth:`Scheme.step`) also returns the embedded
first-order solution's error estimate, which
:class:`~cloth_lod_ros.sim.integrate.step_control.TimeStepper` controls the
step size with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics.elements import Elements
from .implicit_stage import ImplicitStageSolver, SolveReport
from .state import ClothState

__all__ = ["SCHEMES", "STUDY_SCHEMES", "Scheme", "BaraffWitkin", "BackwardEuler", "Sdirk2",
           "Midpoint"]


@dataclass
class SchemeStep:
    """One step of a scheme: end positions/velocities ``(n, 3)``, the contacts
    that held in its last stage, its report and the embedded error estimate
    ``(n, 3)`` (m)."""

    positions: np.ndarray
    velocities: np.ndarray
    contacts: object
    report: SolveReport
    error: np.ndarray


def _stage_distance(contacts, x_start: np.ndarray, x_hat: np.ndarray, elapsed: float,
                    max_speed: float):
    """The normal distance (m, ``(k,)``) each contact's particle must cover in
    a stage so that it ends on the offset surface, from the stage's base
    positions ``x_hat``: ``d̂ − w E − e``, with ``d̂`` the distance measured at
    ``x_start`` moved to ``x_hat`` along the normal (tangent plane), ``w E``
    how far the surface moves along its normal in the ``elapsed`` s ``E``
    from the step's start to the stage's end (``w = u·n``, ``u`` the contact's
    surface velocity; 0 on a static obstacle) and ``e`` the allowed end
    distance: 0, or for a particle that started inside (``d < 0``) as far in
    as pushing out at ``max_speed`` m/s (relative to the surface) for ``E``
    leaves it.  (The base of a later stage may lie inside although the
    particle did not start there: that is the scheme's extrapolation, not a
    penetration to push out slowly.)  Rows against a second obstacle
    (``contacts.second``) get a second column ``(k, 2)``: the same for it."""
    if contacts is None or not len(contacts):
        return None
    first = _one_stage_distance(contacts, x_start, x_hat, elapsed, max_speed)
    if not contacts.doubled.any():
        return first
    return np.column_stack([first, _one_stage_distance(contacts.second, x_start, x_hat,
                                                       elapsed, max_speed)])


def _one_stage_distance(contacts, x_start, x_hat, elapsed, max_speed):
    d = contacts.distance
    shift = x_hat[contacts.indices] - x_start[contacts.indices]
    d_hat = d + np.einsum("kd,kd->k", shift, contacts.normals)
    allowed = np.where(d < 0.0, np.minimum(d + max_speed * elapsed, 0.0), 0.0)
    surface_vn = contacts.normal_speed()
    if surface_vn is not None:
        d_hat = d_hat - surface_vn * elapsed
    return d_hat - allowed


class Scheme:
    """A one-step integration scheme built from implicit stages.

    Attributes:
        name: the ``simulation.integrator`` value.  order: global order in h.
        newton_iterations, newton_tolerance: budget and stopping test of each
            stage's Newton iterations (see
            :meth:`~cloth_lod_ros.sim.integrate.implicit_stage.ImplicitStageSolver.solve_stage`).
    """

    name = ""
    order = 1

    def __init__(self, newton_iterations: int = 1, newton_tolerance: float = 0.0,
                 max_correction_speed: float = 0.5):
        self.newton_iterations = newton_iterations
        self.newton_tolerance = newton_tolerance
        self.max_correction_speed = max_correction_speed

    def _stage(self, solver, elements, masses, x_start, x_hat, v_hat, gh, elapsed, held,
               predictor, contacts, slot, linearize_at_start=False, iterations=None,
               share=1.0):
        """One stage; its contacts cover ``share`` of the normal distance
        that lands them on the offset surface ``elapsed`` s after the step's
        start."""
        distance = _stage_distance(contacts, x_start, x_hat, elapsed, self.max_correction_speed)
        if distance is not None and share != 1.0:
            distance = share * distance
        return solver.solve_stage(
            elements, masses, x_hat, v_hat, gh, held, predictor, contacts, distance,
            iterations or self.newton_iterations, self.newton_tolerance,
            linearize_at_start, slot)

    def step(self, solver: ImplicitStageSolver, elements: Elements, masses: np.ndarray,
             state: ClothState, start_targets: np.ndarray,
             held: tuple[np.ndarray, np.ndarray], h: float, contacts) -> SchemeStep:
        """Advance ``state`` by ``h`` s; held particles go from ``start_targets``
        ``(k, 3)`` (their positions at the start, m) to ``held[1]``."""
        raise NotImplementedError


class BackwardEuler(Scheme):
    """Backward Euler, Newton iterations from the predictor ``x_n + h v_n``."""

    name = "backward_euler"
    linearize_at_start = False

    def step(self, solver, elements, masses, state, start_targets, held, h, contacts):
        x, v = state.positions, state.velocities
        iterations = 1 if self.linearize_at_start else None
        stage = self._stage(solver, elements, masses, x, x, v, h, h, held, v, contacts, 0,
                            self.linearize_at_start, iterations)
        # Embedded estimate: backward Euler − trapezoidal rule in x.
        error = 0.5 * h * (stage.velocities - v)
        return SchemeStep(stage.positions, stage.velocities, stage.contacts, stage.report,
                          error)


class BaraffWitkin(BackwardEuler):
    """The paper's step: backward Euler linearised at ``x_n``, one solve (BW eq. 15)."""

    name = "baraff_witkin"
    linearize_at_start = True


class Sdirk2(Scheme):
    """Alexander's L-stable two-stage SDIRK, ``γ = 1 − 1/√2`` (module docstring)."""

    name = "sdirk2"
    order = 2
    gamma = 1.0 - 1.0 / math.sqrt(2.0)

    def step(self, solver, elements, masses, state, start_targets, held, h, contacts):
        x, v = state.positions, state.velocities
        g = self.gamma
        indices, end_targets = held
        first_targets = start_targets + g * (end_targets - start_targets)
        # A contact moves along its normal at the one velocity that lands it
        # at the step's end, in both stages, like a held particle: stage 1
        # covers γ of that distance.  (Landing it at the end of stage 1, at
        # γh, the base of stage 2, x_n + (1 − γ)h V₁, lay 1.4 d inside the
        # surface for a gap d, and stage 2 pushed it back out at 1.4 d/γh,
        # dragging its free neighbours with it: 19 m/s for a 4 mm gap at
        # h = 1 ms, issue 31.)
        one = self._stage(solver, elements, masses, x, x, v, g * h, h,
                          (indices, first_targets), v, contacts, 0, share=g)
        v1 = one.velocities
        x_hat = x + (1.0 - g) * h * v1
        # M⁻¹f(Y₁) = (V₁ − v_n)/(γh) less the contact impulses: an impact is
        # not a smooth force, and extrapolating it by (1 − γ)/γ = 2.4 would
        # throw the particle off the surface in stage 2.
        change = v1 - v
        if one.contact_impulse is not None:
            change = change - one.contact_impulse / masses[:, None]
        v_hat = v + ((1.0 - g) / g) * change
        two = self._stage(solver, elements, masses, x, x_hat, v_hat, g * h, h, held, v1,
                          contacts, 1)
        two.report.add(one.report)
        # Embedded first-order solution x_n + h V₁.
        error = g * h * (two.velocities - v1)
        return SchemeStep(two.positions, two.velocities, two.contacts, two.report, error)


class Midpoint(Scheme):
    """The implicit midpoint rule (module docstring): a stage of step ``h/2`` to the
    midpoint, extrapolated to the step's end."""

    name = "midpoint"
    order = 2

    def step(self, solver, elements, masses, state, start_targets, held, h, contacts):
        x, v = state.positions, state.velocities
        indices, end_targets = held
        # Held particles are at the midpoint of their straight path at the stage's
        # end, so 2Y − y_n puts them on their end targets; a contact covers half of
        # the normal distance that lands it at the step's end.
        mid = self._stage(solver, elements, masses, x, x, v, 0.5 * h, h,
                          (indices, 0.5 * (start_targets + end_targets)), v, contacts, 0,
                          share=0.5)
        V = mid.velocities
        positions = 2.0 * mid.positions - x            # = x_n + h V
        # The smooth forces act over the whole step (their change doubles); a contact
        # impulse is an event, applied once: doubled it would bounce the particle off.
        change = V - v
        if mid.contact_impulse is not None:
            change = change - mid.contact_impulse / masses[:, None]
        velocities = v + 2.0 * change
        if mid.contact_impulse is not None:
            velocities += mid.contact_impulse / masses[:, None]
        held_contacts = mid.contacts
        if held_contacts is not None and len(held_contacts):
            # Along a held contact's normal the particle moves with the stage's
            # prescribed velocity (the surface's): no velocity into or out of it.
            for rows in (held_contacts, held_contacts.second if held_contacts.doubled.any()
                         else None):
                if rows is None:
                    continue
                k = rows.indices
                n = rows.normals
                gap = np.einsum("kd,kd->k", V[k] - velocities[k], n)
                velocities[k] += gap[:, None] * n
        velocities[indices] = V[indices]
        # Embedded first-order solution x_n + h v_n (explicit Euler).
        error = h * change
        return SchemeStep(positions, velocities, mid.contacts, mid.report, error)


SCHEMES = {cls.name: cls for cls in (BaraffWitkin, BackwardEuler, Sdirk2)}
#: Schemes measured but not offered as ``simulation.integrator`` (module docstring).
STUDY_SCHEMES = {Midpoint.name: Midpoint}
