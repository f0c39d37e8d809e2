"""Tolerances for comparing the float results of two different implementations.

The compiled kernels (numba) and the numpy reference compute the same
quantities; the tests compare them.  Whether they may be compared bit for
bit depends on which operations produce the numbers:

* IEEE 754 basic operations (``+ - * /`` and ``sqrt``) are correctly rounded,
  so the same operations on the same operands in the same order give the
  same bits on every conforming CPU.  numba compiles without ``fastmath``:
  LLVM then neither reassociates nor contracts ``a * b + c`` into a fused
  multiply-add, and separate numpy ufunc calls cannot be fused with each
  other.  Element-wise code of this kind, integer and topology results,
  copies, and the *same* code run twice in one process (a replay, a
  thread-count or storage change that the code is meant not to see) are
  compared bitwise.
* Transcendental functions (``arctan2``, ``tan``, ...) are not correctly
  rounded.  numpy dispatches its own SIMD implementations at run time (on
  CPUs with AVX512_SKX those vendored from Intel's SVML), while the compiled
  code calls the C library's ``atan2``; each is within a few ULP of the true
  value (numpy's ``test_umath_accuracy`` and the glibc manual's "Errors in
  Math Functions" table state the bounds per function), so the two may
  differ by a few ULP.  Seen: ``-0.7184953507961719`` against
  ``-0.718495350796172`` (1 ULP) for a hinge angle on an AMD EPYC with
  AVX-512, numpy 2.4.6, numba 0.68.1.
* Reductions (``np.einsum``, ``np.sum``, ``@``) sum in an order chosen by
  the numpy build and the BLAS kernel picked for the CPU, and compilers
  for aarch64 contract ``a * b + c`` in numpy's C loops into FMAs
  (numpy issue #22993).  The kernels reproduce numpy's x86_64 order, which
  is not a promise on every machine.

What reaches the compared value from such a difference is bounded by
standard error analysis (Higham, *Accuracy and Stability of Numerical
Algorithms*, 2nd ed., 2002, §1.5 and §3.1): a value computed from a few
transcendental results through a well-conditioned chain of basic
operations differs by a small multiple of those functions' ULPs
(:data:`ULPS`); a sum of ``n`` terms computed in two orders, with or
without FMA, differs by at most ``γ_n Σ|terms|`` with ``γ_n = n u / (1 - n u)``,
``u = 2⁻⁵³`` — relative to the *terms*, not to the sum, which cancellation
can make arbitrarily small.  Callers pass that scale as ``abs_floor``
(:func:`sum_floor`).  Both bounds are far below the 1e-6 relative change a
wrong formula, a missing term or a stale input makes, so the tests still
fail on a real difference.

Where a compared float decides something (refine or merge, inside a box or
not), a tolerance on the float is not enough: a value within its tolerance
of the threshold may go either way.  :func:`near` marks those entries, and
:func:`assert_decisions_agree` checks that decisions agree everywhere else
and that the excluded entries are few, so the comparison still has
something to compare.
"""

from __future__ import annotations

import numpy as np

#: Unit roundoff of float64, ``2⁻⁵³`` (Higham §2.1).
UNIT_ROUNDOFF = np.finfo(np.float64).eps / 2.0

#: ULPs, per element, between two implementations of a value computed from a
#: few transcendental functions (each within ~2 ULP of the true value, so two
#: of them within ~4 of each other) through a short chain of correctly rounded
#: operations whose condition number is O(1) (one to a few ULP more each).
ULPS = 16

#: Headroom over the ``γ_n`` bound for sums: the bound is a worst case of
#: ``n`` roundings in either order; a factor 4 covers the few roundings of
#: the terms themselves (products, a transcendental ULP) before the sum.
SUM_HEADROOM = 4.0


def sum_floor(terms_magnitude, count: int) -> float | np.ndarray:
    """Absolute tolerance of a sum of ``count`` terms whose absolute values add
    up to ``terms_magnitude`` (``Σ|terms|``, scalar or per element), computed in
    two different orders (with or without fused multiply-adds):
    ``SUM_HEADROOM · γ_count · Σ|terms|`` (Higham eq. (3.5)).  Units: those of
    the terms."""
    gamma = count * UNIT_ROUNDOFF / (1.0 - count * UNIT_ROUNDOFF)
    return SUM_HEADROOM * gamma * np.asarray(terms_magnitude, dtype=float)


def tolerance(expected, ulps: float = ULPS, rel: float = 0.0, abs_floor=0.0) -> np.ndarray:
    """Per-element tolerance ``max(ulps · ulp(expected), rel · |expected|, abs_floor)``,
    in the units of ``expected`` (``abs_floor`` scalar or broadcastable)."""
    expected = np.asarray(expected, dtype=float)
    magnitude = np.abs(expected)
    ulp = np.spacing(np.where(np.isfinite(magnitude), magnitude, 0.0))
    return np.maximum(np.maximum(ulps * ulp, rel * magnitude), abs_floor)


def assert_close_ulps(actual, expected, ulps: float = ULPS, rel: float = 0.0, abs_floor=0.0,
                      err_msg: str = "") -> None:
    """Assert ``actual`` equals ``expected`` to :func:`tolerance`.

    Shapes and dtypes must be equal; integer and boolean arrays exactly; NaNs
    must sit at the same places and infinities be the same infinities (a
    degenerate element must be degenerate on both paths)."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, f"{err_msg}: shape {actual.shape} != {expected.shape}"
    assert actual.dtype == expected.dtype, f"{err_msg}: dtype {actual.dtype} != {expected.dtype}"
    if expected.dtype.kind != "f":
        np.testing.assert_array_equal(actual, expected, err_msg=err_msg)
        return
    np.testing.assert_array_equal(np.isnan(actual), np.isnan(expected),
                                  err_msg=f"{err_msg}: NaN at different places")
    infinite = np.isinf(expected)
    np.testing.assert_array_equal(actual[infinite], expected[infinite],
                                  err_msg=f"{err_msg}: infinities differ")
    finite = np.isfinite(expected)
    assert np.isfinite(actual[finite]).all(), f"{err_msg}: non-finite where expected is finite"
    error = np.abs(actual - expected)
    allowed = np.broadcast_to(tolerance(expected, ulps, rel, abs_floor), expected.shape)
    bad = finite & ~(error <= allowed)
    if bad.any():
        worst = np.unravel_index(np.argmax(np.where(bad, error / np.maximum(allowed, 1e-300),
                                                    0.0)), expected.shape)
        raise AssertionError(
            f"{err_msg}: {int(bad.sum())} of {expected.size} entries beyond tolerance; worst at "
            f"{tuple(int(i) for i in worst)}: {actual[worst]!r} vs {expected[worst]!r} "
            f"(difference {error[worst]:.3g}, allowed {allowed[worst]:.3g}, "
            f"{error[worst] / max(np.spacing(abs(expected[worst])), 1e-300):.3g} ULP)")


def near(values, threshold, tol) -> np.ndarray:
    """Entries within ``tol`` (per element or scalar) of ``threshold``: their
    comparison with the threshold may go either way between two
    implementations that agree to ``tol``.  NaN is never near (both paths
    compare NaN as false)."""
    values = np.asarray(values, dtype=float)
    return np.abs(values - threshold) <= tol


def assert_decisions_agree(ours, reference, ambiguous, max_fraction: float = 0.02,
                           max_count: int = 2, err_msg: str = "") -> None:
    """Boolean decisions ``(k,)`` agree wherever ``ambiguous`` is false, and at
    most ``max(max_count, max_fraction · k)`` entries are ambiguous (so the
    exclusion cannot swallow the comparison)."""
    ours, reference = np.asarray(ours, dtype=bool), np.asarray(reference, dtype=bool)
    ambiguous = np.broadcast_to(np.asarray(ambiguous, dtype=bool), reference.shape)
    assert ours.shape == reference.shape, err_msg
    allowed = max(max_count, int(max_fraction * reference.size))
    assert ambiguous.sum() <= allowed, (
        f"{err_msg}: {int(ambiguous.sum())} of {reference.size} decisions within tolerance of "
        f"their threshold (at most {allowed} may be)")
    differ = (ours != reference) & ~ambiguous
    assert not differ.any(), (
        f"{err_msg}: decisions differ away from the threshold at {np.flatnonzero(differ)[:10]}")


# -- LOD decisions -----------------------------------------------------------------

#: Merge energies ΔE (J) are compared to this fraction of the larger of
#: |ΔE| and the merge bound ½ ρ A v² (the merge test's scale).  ΔE is a
#: difference of the diamond's element, kinetic and gravity energies, which
#: may cancel; their differences between the two paths (an angle's ULPs,
#: einsum's order) are ~1e-16 of those energies.  Measured with numpy's
#: arctan2, tan and einsum moved by ±1 ULP on a third of their entries
#: (test_lod_kernels' random cloths, flat to crumpled): at most 1.8e-13 of
#: that scale; 1e-9 leaves a factor of ~5000 and is still 1000 times below
#: the 1e-6 relative change of a wrong or missing term.
ENERGY_REL = 1e-9


def energy_floor(total, bound):
    """Absolute tolerance, J, of merge energies ``total`` with bounds ``bound``
    (``(k,)`` each): :data:`ENERGY_REL` of the larger of the two."""
    return ENERGY_REL * np.maximum(np.abs(np.nan_to_num(np.asarray(total, dtype=float))),
                                   np.asarray(bound, dtype=float))


def _criterion_tolerances(measures, rate_terms, lookahead):
    """Per-hinge tolerances of the criterion's measures ``(h,)``: (deviation m,
    rate rad/s, bend force N, refine deviation m)."""
    rate_tol = tolerance(measures.rate, abs_floor=sum_floor(rate_terms, 12))
    deviation_tol = tolerance(measures.deviation)
    # d = ½ L tan(|θ|/4) has dd/dθ = (L/8) sec²(θ/4) ≤ L/4 for |θ| ≤ π: the
    # look-ahead angle θ + τ θ̇ carries θ̇'s tolerance into d by at most that.
    height = np.nan_to_num(measures.height, nan=0.0, posinf=0.0)   # degenerate: d is inf or NaN
    refine_tol = deviation_tol + 0.25 * height * lookahead * rate_tol
    return deviation_tol, rate_tol, tolerance(measures.bend_force), refine_tol


def reference_criterion(elements, bend_stiffness, x, v, lookahead=0.0):
    """The numpy reference's hinge measures and refine deviations with their
    tolerances: ``(measures, refine_deviation, (deviation_tol, rate_tol,
    force_tol, refine_tol))`` (see :func:`_criterion_tolerances`)."""
    from cloth_lod_ros.sim.lod import policy as lod_policy
    from cloth_lod_ros.sim.physics import hinges as physics_hinges
    from cloth_lod_ros.sim.runtime import compiled
    previous = compiled.use(False)
    try:
        measures, refine_deviation = lod_policy._criterion(elements, bend_stiffness, x, v, None,
                                                           lookahead)
        hv = elements.hinge_vertices
        _, grad = physics_hinges.hinge_angles(x, hv, with_gradient=True)
    finally:
        compiled.use(previous)
    # θ̇ = Σ ∂θ/∂x_k · v_k, 12 terms: their magnitude bounds its rounding.
    rate_terms = (np.abs(grad) * np.abs(v[hv])).sum(axis=(1, 2))
    return measures, refine_deviation, _criterion_tolerances(measures, rate_terms, lookahead)


def assert_lod_decisions_agree(ours, reference, policy, hierarchy, elements, vertex_ids,
                               triangle_ids, x, v, masses, lookahead=0.0, err_msg=""):
    """Two :class:`~cloth_lod_ros.sim.lod.policy.LodDecision` of one state, by the
    compiled kernels (``ours``) and the numpy reference, agree away from the
    thresholds.

    Refinements: the same triangles in the same order, except the triangles of
    hinges whose refine deviation is within tolerance of ``refine_threshold``
    (they may be in one list only), and except that triangles whose leading
    deviations are within tolerance of each other may swap.  Merges: the same
    edges, except those with a hinge within tolerance of a settled test's
    threshold (deviation, rate, bend force) at their midpoint or with an
    energy within :func:`energy_floor` of the bound; the same energies to
    that tolerance.  At most 2 (or 2 %) hinges may be that close.

    The other arguments are :meth:`LodPolicy.decide`'s (compact ``x``, ``v``
    ``(n, 3)`` m, m/s, ``masses`` ``(n,)`` kg, ``lookahead`` s)."""
    cfg = policy.config
    measures, refine_dev, (dev_tol, rate_tol, force_tol, refine_tol) = reference_criterion(
        elements, policy.material.bend_stiffness, x, v, lookahead)
    hinges = len(refine_dev)
    allowed = max(2, int(0.02 * hinges))
    # Refinements.
    refine_near = near(refine_dev, cfg.refine_threshold, refine_tol)
    unsure = set(triangle_ids[elements.hinge_triangles[refine_near]].ravel().tolist())
    assert refine_near.sum() <= allowed, (
        f"{err_msg}: {int(refine_near.sum())} hinges within tolerance of refine_threshold")
    key = {}                                     # pool triangle -> its leading deviation
    over = np.flatnonzero(refine_dev > cfg.refine_threshold)
    for h in over:
        for t in triangle_ids[elements.hinge_triangles[h]].tolist():
            key[t] = max(key.get(t, -np.inf), refine_dev[h])
    a = [t for t in ours.refine if t not in unsure]
    b = [t for t in reference.refine if t not in unsure]
    assert sorted(a) == sorted(b), f"{err_msg}: refined triangles differ"
    slack = refine_tol.max(initial=0.0)
    for s, r in zip(a, b):
        if s != r:
            ks, kr = key.get(s, -np.inf), key.get(r, -np.inf)
            assert np.isfinite(ks) and np.isfinite(kr) and abs(ks - kr) <= slack, (
                f"{err_msg}: refinement order differs at triangles {s}, {r} "
                f"(deviations {ks!r}, {kr!r})")
    # Merges: tests (a)-(c) near their thresholds at a hinge, or (e) near its bound.
    settled_near = (near(measures.deviation, cfg.coarsen_threshold, dev_tol)
                    | near(np.abs(measures.rate), cfg.max_hinge_rate, rate_tol)
                    | near(measures.bend_force, cfg.max_bend_force, force_tol))
    assert settled_near.sum() <= allowed, (
        f"{err_msg}: {int(settled_near.sum())} hinges within tolerance of a settled threshold")
    ours_merge = {tuple(e): i for i, e in enumerate(ours.merge)}
    ref_merge = {tuple(e): i for i, e in enumerate(reference.merge)}
    differ = set(ours_merge) ^ set(ref_merge)
    assert len(differ) <= allowed, f"{err_msg}: merges differ: {sorted(differ)[:10]}"
    if differ:
        from cloth_lod_ros.sim.runtime import compiled
        from cloth_lod_ros.sim.lod.merge_energy import merge_energy_change
        mids = np.array([hierarchy.midpoint[e] for e in sorted(differ)], dtype=np.int64)
        previous = compiled.use(False)
        try:
            added = merge_energy_change(hierarchy, elements, vertex_ids, triangle_ids, mids, x,
                                        v, masses, policy.material, policy.gravity)
        finally:
            compiled.use(previous)
        bound = 0.5 * policy.material.density * added.area * cfg.max_merge_speed ** 2
        energy_near = near(added.total, bound, energy_floor(added.total, bound))
        compact = np.searchsorted(vertex_ids, mids)
        for k, edge in enumerate(sorted(differ)):
            at_mid = (elements.hinge_vertices == compact[k]).any(axis=1)
            assert energy_near[k] or settled_near[at_mid].any(), (
                f"{err_msg}: merge {edge} decided differently away from every threshold")
    common = sorted(set(ours_merge) & set(ref_merge))
    i = [ours_merge[e] for e in common]
    j = [ref_merge[e] for e in common]
    if common:
        scale = energy_floor(np.asarray(reference.merge_energy)[j],
                             np.asarray(reference.merge_bound)[j])
        for name in ("merge_energy", "merge_kinetic"):
            assert_close_ulps(np.asarray(getattr(ours, name))[i],
                              np.asarray(getattr(reference, name))[j], abs_floor=scale,
                              err_msg=f"{err_msg}: {name}")
        assert_close_ulps(np.asarray(ours.merge_bound)[i], np.asarray(reference.merge_bound)[j],
                          err_msg=f"{err_msg}: merge_bound")
