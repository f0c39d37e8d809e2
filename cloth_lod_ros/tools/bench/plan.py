"""``cloth-lod bench``: what to run - integrator families × meshes, and the reference runs.

A *family* is one setting of the time integration (``--schemes``, each
``INTEGRATOR`` or ``INTEGRATOR@TOLERANCE``): ``simulation.integrator`` and
``simulation.error_tolerance`` (m; none or 0: one step per frame).  Every
family runs on the uniform mesh at each of ``--levels`` and on the adaptive
mesh at each of ``--max-levels`` × ``--thresholds``.
"""

from __future__ import annotations

import math

from ...sim.integrate.schemes import SCHEMES
from ..reference import ConvergedReference

__all__ = ["BenchError", "FULL", "QUICK", "REFERENCE_KINDS", "parse_scheme", "family_label",
           "configurations", "step_text"]

#: The full run quoted in the README: the paper's step, the default scheme
#: with a fixed step and three error tolerances, each on uniform L2, L4, L6
#: and on the adaptive mesh at the scene's maximum level and thresholds.
FULL = dict(duration=2.0, levels=[2, 4, 6], max_levels=None, thresholds=None,
            schemes=["baraff_witkin", "sdirk2", "sdirk2@1e-3", "sdirk2@3e-4", "sdirk2@1e-4"],
            repeats=3, rest_threshold=1e-6, rest_window=1.0, rest_cap=20.0,
            reference_divisor=8)
# --quick: a smoke test of the whole pipeline in about a minute.  The cloth is
# not at rest by the cap; the tables say so.
QUICK = dict(duration=0.5, levels=[2, 4], max_levels=[4], thresholds=None,
             schemes=["baraff_witkin", "sdirk2", "sdirk2@1e-3"], repeats=2,
             rest_threshold=1e-6, rest_window=0.25, rest_cap=1.0, reference_divisor=8)
#: Kinds of the converged reference's runs: run once, not rows of the table.
REFERENCE_KINDS = ("reference", "reference_2h", "reference_coarse")


class BenchError(RuntimeError):
    """Bad arguments or a failed worker; the message says which."""


def parse_scheme(text: str) -> dict:
    """``INTEGRATOR[@TOLERANCE]`` → a family: ``key``, ``integrator``, ``tolerance`` (m)."""
    name, at, tol = str(text).partition("@")
    if name not in SCHEMES:
        raise BenchError(f"--schemes: unknown integrator {name!r} in {text!r} "
                         f"(one of {', '.join(sorted(SCHEMES))})")
    try:
        tolerance = float(tol) if at else 0.0
    except ValueError:
        raise BenchError(f"--schemes: {text!r}: the error tolerance must be a length in "
                         "metres, e.g. sdirk2@1e-3") from None
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise BenchError(f"--schemes: {text!r}: the error tolerance must be >= 0 m")
    key = name if tolerance == 0 else f"{name}_tol{tolerance:g}"
    return dict(key=key, integrator=name, tolerance=tolerance, spec=text)


def step_text(h: float) -> str:
    """``1/60 s`` for a whole frame rate, else the step in s."""
    rate = 1.0 / h
    return f"1/{round(rate)} s" if abs(rate - round(rate)) < 1e-6 * rate else f"{h:.4g} s"


def family_label(family: dict, frame: float) -> str:
    """E.g. ``baraff_witkin (paper), h = 1/60 s``, ``sdirk2, h = 1/60 s``, ``sdirk2, ε = 0.001 m``."""
    name = family["integrator"] + (" (paper)" if family["integrator"] == "baraff_witkin" else "")
    if family["tolerance"] == 0:
        return f"{name}, h = {step_text(frame)}"
    return f"{name}, ε = {family['tolerance']:g} m"


def _family_overrides(family: dict) -> list[str]:
    return [f"simulation.integrator={family['integrator']}",
            f"simulation.error_tolerance={family['tolerance']!r}"]


def configurations(args, scene, families: list[dict],
                   reference: ConvergedReference | None) -> list[dict]:
    """The runs, in the order of a round: references first (the first one
    finds the rest time), then each family's uniform and adaptive runs.

    Each is a dict with ``key`` (unique tag), ``kind`` (``reference``,
    ``reference_2h``, ``reference_coarse`` for the converged reference;
    ``same_step`` for a family's own uniform run at the reference level in
    ``--reference same-step`` mode; ``uniform``, ``adaptive``), ``family``
    (key, None for the converged reference), ``level`` (uniform level or
    adaptive maximum), ``threshold``/``coarsen`` (m, adaptive only),
    ``time_step`` (s), ``overrides`` and ``label``.
    """
    base = list(args.set or [])
    h = scene.simulation.time_step
    ref_level = args.reference_level
    configs = []
    if reference is not None:
        names = {"reference": f"converged reference L{reference.level}, sdirk2, "
                              f"h/{reference.divisor:g}",
                 "reference_2h": f"reference at 2 h_ref (h/{reference.divisor / 2:g})",
                 "reference_coarse": f"reference one level coarser (L{reference.level - 1})"}
        for run in reference.runs(args.mesh_check):
            configs.append(dict(run, family=None, threshold=None, coarsen=None,
                                overrides=base + run["overrides"], label=names[run["kind"]]))
    def uniform(fam: dict, level: int, kind: str, suffix: str = "") -> dict:
        return dict(key=f"{fam['key']}_uniform_L{level}", kind=kind, family=fam["key"],
                    level=level, threshold=None, coarsen=None, time_step=h,
                    overrides=base + _family_overrides(fam)
                    + ["lod.enabled=false", f"cloth.level={level}"],
                    label=f"{family_label(fam, h)}, uniform L{level}{suffix}")

    if reference is None:                 # same-step: each family's own reference first
        configs += [uniform(fam, ref_level, "same_step", " (reference)") for fam in families]
    for fam in families:
        name = family_label(fam, h)
        levels = sorted(set(args.levels) - ({ref_level} if reference is None else set()))
        configs += [uniform(fam, level, "uniform") for level in levels]
        for level in sorted(set(args.max_levels)):
            for thr in sorted(set(args.thresholds)):
                coarsen = thr * args.coarsen_ratio
                configs.append(dict(
                    key=f"{fam['key']}_adaptive_L{level}_{thr * 1e3:g}mm", kind="adaptive",
                    family=fam["key"], level=level, threshold=thr, coarsen=coarsen,
                    time_step=h,
                    overrides=base + _family_overrides(fam)
                    + ["lod.enabled=true", f"cloth.level={level}",
                       f"lod.refine_threshold={thr!r}", f"lod.coarsen_threshold={coarsen!r}"],
                    label=f"{name}, adaptive max L{level} {thr * 1e3:g} mm"))
    return configs
