"""The reference that ``cloth-lod compare`` and ``cloth-lod bench`` measure error against.

Design §5: error is the distance from the **converged motion of the model**,
approximated by a *converged reference*: the scene on the uniform mesh at a
level at least as fine as any run compared (default: the finest asked),
integrated by ``sdirk2`` (second order) with a fixed step ``h_ref = H /
divisor`` (``H`` the scene's frame period, ``simulation.time_step``; default
divisor 8), no error control and up to 3 Newton iterations per stage to
1e-8 m.  Its own remaining error is estimated, not assumed:

* **time**: a second run at ``2 h_ref``.  For a second-order method the error
  of the run at ``h_ref`` is ``≈ |ref(2 h_ref) − ref(h_ref)| / (2² − 1)``;
* **mesh** (optional, it costs a run of about half the reference's price): a
  run one level coarser at ``h_ref``.  The distance between the two is the
  size of the reference's mesh error (equal to it for second-order
  convergence in the edge length, which one level divides by √2; 2.4× it for
  first order).

The old reference, the uniform mesh at the *same* step and integrator as the
run compared, measures mesh error only: results measured that way carry
:data:`SAME_STEP_LABEL`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MODES", "SAME_STEP_LABEL", "ConvergedReference", "self_error",
           "point_distances"]

MODES = ("converged", "same-step")
SAME_STEP_LABEL = "same-step reference (mesh error only)"
#: Richardson's factor 2^p − 1 for the second-order reference integrator.
TIME_ERROR_DIVISOR = 3.0


@dataclass(frozen=True)
class ConvergedReference:
    """Settings of the converged reference (module docstring).

    Attributes:
        level: uniform bisection level of the reference mesh.
        frame: the scene's frame period ``H`` (s).
        divisor: ``h_ref = frame / divisor``.
        newton_iterations, newton_tolerance: per implicit stage (m).
    """

    level: int
    frame: float
    divisor: int = 8
    newton_iterations: int = 3
    newton_tolerance: float = 1e-8
    integrator: str = "sdirk2"

    def __post_init__(self):
        if self.level < 0:
            raise ValueError(f"reference level {self.level} is below the base mesh (level 0)")
        if int(self.divisor) != self.divisor or self.divisor < 1:
            raise ValueError(f"reference step divisor must be a whole number >= 1, "
                             f"got {self.divisor}")

    @property
    def time_step(self) -> float:
        """``h_ref`` (s)."""
        return self.frame / self.divisor

    def overrides(self, level: int | None = None, time_step: float | None = None) -> list[str]:
        """Scene overrides of a reference run (after the caller's own ``--set``)."""
        level = self.level if level is None else level
        h = self.time_step if time_step is None else time_step
        return ["lod.enabled=false", f"cloth.level={level}",
                f"simulation.integrator={self.integrator}", f"simulation.time_step={h!r}",
                "simulation.error_tolerance=0",
                f"simulation.newton_iterations={self.newton_iterations}",
                f"simulation.newton_tolerance={self.newton_tolerance!r}"]

    def runs(self, mesh_check: bool) -> list[dict]:
        """The reference runs: ``key``, ``kind`` (``reference``, ``reference_2h``,
        ``reference_coarse``), ``level``, ``time_step`` and ``overrides``.  The
        coarser run is left out at level 0 (there is nothing coarser)."""
        h = self.time_step
        out = [dict(key=f"reference_L{self.level}", kind="reference", level=self.level,
                    time_step=h, overrides=self.overrides()),
               dict(key=f"reference_L{self.level}_2h", kind="reference_2h", level=self.level,
                    time_step=2 * h, overrides=self.overrides(time_step=2 * h))]
        if mesh_check and self.level > 0:
            out.append(dict(key=f"reference_L{self.level - 1}", kind="reference_coarse",
                            level=self.level - 1, time_step=h,
                            overrides=self.overrides(level=self.level - 1)))
        return out

    def describe(self) -> str:
        """One line: what the reference is."""
        return (f"converged reference: uniform L{self.level}, {self.integrator}, fixed "
                f"h_ref = H/{self.divisor:g} = {self.time_step:.4g} s, "
                f"{self.newton_iterations} Newton iterations per stage to "
                f"{self.newton_tolerance:g} m")

    def as_dict(self) -> dict:
        return dict(mode="converged", level=self.level, frame=self.frame,
                    divisor=self.divisor, time_step=self.time_step,
                    integrator=self.integrator, newton_iterations=self.newton_iterations,
                    newton_tolerance=self.newton_tolerance, label=self.describe())


def point_distances(a, b) -> np.ndarray:
    """``|a_i − b_i|`` (m) of two ``(m, 3)`` sample sets."""
    return np.linalg.norm(np.asarray(a, dtype=float) - np.asarray(b, dtype=float), axis=-1)


def self_error(reference, reference_2h=None, coarse=None, side: float = 1.0) -> dict:
    """The reference's own error at one sample time (fractions of ``side``).

    Args:
        reference, reference_2h, coarse: ``(m, 3)`` samples (m) of the reference,
            the run at twice its step and the run one level coarser (None: not
            run, or not at this time).
    Returns:
        ``time_rms``, ``time_max``: ``|ref(2h) − ref(h)| / 3`` (estimated time
        error); ``mesh_rms``, ``mesh_max``: ``|coarser − ref|`` (size of the
        mesh error); None where the run is missing.
    """
    out = dict(time_rms=None, time_max=None, mesh_rms=None, mesh_max=None)
    if reference_2h is not None:
        d = point_distances(reference_2h, reference) / TIME_ERROR_DIVISOR
        out.update(time_rms=float(np.sqrt(np.mean(d**2))) / side, time_max=float(d.max()) / side)
    if coarse is not None:
        d = point_distances(coarse, reference)
        out.update(mesh_rms=float(np.sqrt(np.mean(d**2))) / side, mesh_max=float(d.max()) / side)
    return out
