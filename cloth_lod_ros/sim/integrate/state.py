"""Simulator state and per-step records (data only, no operators; design §9).

* :class:`ClothState` - positions, velocities and time of the active particles;
* :class:`StepStats` - what one step did and cost;
* :class:`SimulationError` - a step that could not produce a finite state.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["ClothState", "StepStats", "SimulationError"]


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
class StepStats:
    """Statistics of one time step (SI units; times in milliseconds).

    ``vertex_count``/``triangle_count``/``triangles_per_level`` describe the
    mesh the step simulated (after this step's refines and merges);
    ``step_ms`` includes ``lod_ms`` (criterion, operations, the refresh of
    compact arrays and the new sparsity pattern; a direct solver's symbolic
    analysis of it counts in ``solve_ms``) and the physics
    (``force_ms + assembly_ms + solve_ms``).
    A step advances one frame (``simulation.time_step``): ``substeps`` is how
    many integrator steps covered it (1 with a fixed step unless its stretch
    grew too fast; more under error control, see
    :class:`~cloth_lod_ros.sim.integrate.step_control.TimeStepper`), ``rejected_steps``
    how many attempts were redone smaller and ``smallest_step`` (s) the
    smallest accepted one; the solver figures add up over all of them (the
    rejected attempts included).  ``newton_iterations`` counts linearisations
    (over stages and substeps), ``solves`` every linear solve of the step
    (Newton iterations, friction rounds, contact re-solves, rejected attempts),
    all timed in ``solve_ms``, ``factorisations`` the numeric factorisations
    among them (a direct backend reuses its factorisation when only the
    right-hand side changed; 0 for the iterative ones); ``solver`` names the backend that ran
    (:mod:`~cloth_lod_ros.sim.solve.backends`).
    ``air_power`` (W) is the power of the air on the cloth at the end of the
    step (face drag relative to the wind plus the isotropic
    ``material.air_drag``; :func:`~cloth_lod_ros.sim.physics.air.air_power`): never
    positive in still air, where ``−air_power`` is what the air dissipates.
    ``self_collision_ms`` is the time the step spent in self-collision code
    (detection, continuous checks, LOD queries; not the re-solves, which are
    in ``solve_ms``) and ``self_contact_count`` the particles a self-contact
    constrained in the step's last solve (0 when it is off).
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
    solves: int = 1
    factorisations: int = 0
    solver: str = ""
    rejected_steps: int = 0
    smallest_step: float = 0.0
    newton_iterations: int = 1
    air_power: float = 0.0
    self_collision_ms: float = 0.0
    self_contact_count: int = 0

    @property
    def total_energy(self) -> float:
        return (self.kinetic_energy + self.gravity_energy + self.stretch_energy
                + self.shear_energy + self.bend_energy)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


