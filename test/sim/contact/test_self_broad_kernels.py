"""The compiled self-collision broad phase (contact/self_broad_kernels.py) equals the numpy
reference: the same boxes, normals, layered flags, candidate pairs and - with
the conservative ``may_touch`` skipping narrow phases - the same contact and
crossing pairs, bit for bit, on cloth with and without layers, with
degenerate triangles, on sparse grids and with non-finite positions.
Bitwise by construction on every CPU: boxes are minima, maxima and one
addition; normals and the layered test's sums are basic operations in the
reference's order (np.bincount and ufunc.at add in index order, as the
kernels' loops do), which are correctly rounded everywhere
(test/tolerances.py); pairs and flags are comparisons of those same
numbers, and the narrow phase is the same numpy code on the same pairs."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from cloth_lod_ros.sim.contact import self_broad_kernels
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled  # noqa: E402
from cloth_lod_ros.sim.scene.config import load_scene  # noqa: E402
from cloth_lod_ros.sim.contact.self_broad import BroadPhase  # noqa: E402
from cloth_lod_ros.sim.contact.self_contact import SelfCollision, SelfCounters  # noqa: E402
from cloth_lod_ros.sim.contact.self_broad import box_pairs, layered_boxes  # noqa: E402

THICKNESS = 0.004
RNG = np.random.default_rng(11)


@pytest.fixture(autouse=True)
def restore():
    previous = runtime_compiled.use(True)
    yield
    runtime_compiled.use(previous)


def _both(function):
    """``function()`` on the numpy path, then on the compiled one."""
    runtime_compiled.use(False)
    try:
        reference = function()
    finally:
        runtime_compiled.use(True)
    return reference, function()


def _same(a, b):
    """Bitwise equal arrays (NaN equal to NaN), dtypes and shapes included."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    if a.dtype.kind == "f":
        assert np.array_equal(a.view(np.int64), b.view(np.int64))
    else:
        assert np.array_equal(a, b)


def _grid(n=9, size=0.3):
    """A square of ``n`` x ``n`` particles, ``2 (n-1)²`` triangles: positions
    flat in z = 0 ``(n², 3)``, triangles, rest coordinates ``(n², 2)``."""
    g = np.linspace(0.0, size, n)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    corner = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    tris = np.concatenate([np.column_stack([corner, corner + 1, corner + n + 1]),
                           np.column_stack([corner, corner + n + 1, corner + n])])
    return np.column_stack([u, v, np.zeros_like(u)]), tris.astype(np.int64), np.column_stack([u, v])


def _folded(gap, n=9, size=0.3):
    """The grid folded in half along u = size/2: the far half lies ``gap`` m
    above the near one (two layers)."""
    x, tris, uv = _grid(n, size)
    half = 0.5 * size
    over = uv[:, 0] > half
    x[over, 0] = 2.0 * half - uv[over, 0]
    x[over, 2] = gap * np.minimum(1.0, (uv[over, 0] - half) / (size / (n - 1)))
    return x, tris, uv


def _degenerate(x, tris, uv):
    """Append a zero-area triangle (a repeated corner) and a collinear one,
    lying in the cloth where it is flat (no layer of their own)."""
    n = len(x)
    extra = np.array([[0.01, 0.05, 0.0], [0.06, 0.05, 0.0], [0.11, 0.05, 0.0]])
    x = np.concatenate([x, extra])
    uv = np.concatenate([uv, extra[:, :2]])
    more = np.array([[n, n, n + 1], [n, n + 1, n + 2]], np.int64)
    return x, np.concatenate([tris, more]), uv


def _scenes():
    flat = _grid()
    wavy = _grid()
    wavy[0][:, 2] = 0.01 * np.sin(20.0 * wavy[0][:, 0])
    close = _folded(0.006)
    far = _folded(0.05)
    sparse = _grid(n=5)
    sparse = (np.concatenate([sparse[0], sparse[0] + [40.0, 30.0, 20.0]]),
              np.concatenate([sparse[1], sparse[1] + 25]),
              np.concatenate([sparse[2], sparse[2] + [10.0, 0.0]]))
    return {"flat": flat, "wavy": wavy, "folded-close": close, "folded-far": far,
            "flat-degenerate": _degenerate(*flat), "folded-degenerate": _degenerate(*close),
            "sparse": sparse}


SCENES = _scenes()


@pytest.mark.parametrize("name", sorted(SCENES))
def test_broad_boxes_equal_the_numpy_boxes_normals_and_flags(name):
    x, tris, uv = SCENES[name]
    y = x + RNG.normal(scale=0.002, size=x.shape)
    pad = 2.0 * THICKNESS
    broad = BroadPhase(THICKNESS, SelfCounters())
    broad.set_topology(tris, uv)
    lo, hi, lo_t, hi_t, normals, layered, status = self_broad_kernels.broad_boxes(
        x, y, pad, broad.triangles, broad._uv)
    _same(lo, np.minimum(x, y) - pad)
    _same(hi, np.maximum(x, y) + pad)
    ref_lo_t, ref_hi_t = broad._triangle_boxes(lo, hi)
    _same(lo_t, ref_lo_t)
    _same(hi_t, ref_hi_t)
    _same(normals, np.ascontiguousarray(broad._normals(x)))
    assert status == (self_broad_kernels.SPARSE if name == "sparse" else self_broad_kernels.DONE)
    runtime_compiled.use(False)
    reference = layered_boxes(ref_lo_t, ref_hi_t, *broad.uv_boxes,
                              0.5 * float((hi - lo).max()), broad._normals(x))
    if status == self_broad_kernels.DONE:
        _same(layered, reference)
    assert reference.any() == name.startswith("folded")


def _cache_of(x, y, tris, uv, need):
    broad = BroadPhase(THICKNESS, SelfCounters())
    broad.set_topology(tris, uv)
    c = broad.query(x, y, need)
    return {k: c[k] for k in ("lo", "hi", "verts", "tris", "e1", "e2", "layered")}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_the_compiled_query_finds_the_numpy_candidates(name):
    x, tris, uv = SCENES[name]
    y = x + RNG.normal(scale=0.003, size=x.shape)
    reference, compiled = _both(lambda: _cache_of(x, y, tris, uv, THICKNESS))
    for key in reference:
        _same(compiled[key], reference[key])
    assert reference["layered"] == name.startswith("folded")
    if name == "folded-close":
        assert len(reference["verts"]) and len(reference["e1"])


def test_non_finite_positions_take_the_reference_path():
    """A NaN or infinite position: the compiled path does what the numpy
    reference does (which cannot grid such boxes, and says so)."""
    x, tris, uv = SCENES["folded-close"]
    y = x.copy()
    y[3, 1] = np.nan
    y[7, 0] = np.inf
    outcomes = []
    for compiled in (False, True):
        runtime_compiled.use(compiled)
        try:
            with np.errstate(invalid="ignore", over="ignore"):
                outcomes.append(_cache_of(x, y, tris, uv, THICKNESS))
        except (IndexError, ValueError) as error:
            outcomes.append(type(error))
    if isinstance(outcomes[0], dict):
        for key in outcomes[0]:
            _same(outcomes[1][key], outcomes[0][key])
    else:
        assert outcomes[1] is outcomes[0]


def test_the_cache_test_equals_numpy_with_nan():
    x, tris, uv = SCENES["wavy"]
    broad = BroadPhase(THICKNESS, SelfCounters())
    broad.set_topology(tris, uv)
    broad.query(x, x, THICKNESS)
    for shift, expected in ((0.5 * THICKNESS, True), (3.0 * THICKNESS, False)):
        y = x.copy()
        y[5, 2] += shift
        assert _both(lambda: broad._valid(x, y, THICKNESS)) == (expected, expected)
    y = x.copy()
    y[5, 2] = np.nan                    # NaN never counts as outside
    assert _both(lambda: broad._valid(x, y, THICKNESS)) == (True, True)
    y[6, 0] = -np.inf
    assert _both(lambda: broad._valid(x, y, THICKNESS)) == (False, False)


@pytest.mark.parametrize("same", [True, False])
def test_box_pairs_compiled_equal_numpy(same):
    """Random boxes, ties (boxes on a coarse lattice), degenerate (flat)
    boxes and a NaN bound, few and many (the numpy hash), and all
    overlapping (more pairs than the kernel's first guess): the same pairs
    in the same order."""
    for trial in range(64):
        ka, kb = RNG.integers(0, 80, 2) if trial < 50 else RNG.integers(150, 400, 2)
        size = 0.2 if trial < 60 else 2.0
        lo_a = RNG.random((ka, 3))
        hi_a = lo_a + RNG.random((ka, 3)) * size
        lo_b = RNG.random((kb, 3))
        hi_b = lo_b + RNG.random((kb, 3)) * size
        if trial % 3 == 0:
            lo_a, hi_a, lo_b, hi_b = (np.round(a * 4.0) / 4.0 for a in (lo_a, hi_a, lo_b, hi_b))
        if trial % 4 == 0 and ka:
            flat = RNG.integers(0, ka)
            hi_a[flat, 1] = lo_a[flat, 1]                      # a flat box
        if trial % 5 == 0 and ka and trial < 50:       # (the hash: finite boxes only)
            lo_a[RNG.integers(0, ka), RNG.integers(0, 3)] = np.nan
        args = (lo_a, hi_a) if same else (lo_a, hi_a, lo_b, hi_b)
        reference, compiled = _both(lambda: box_pairs(*args))
        _same(compiled[0], reference[0])
        _same(compiled[1], reference[1])


def _collision():
    config = load_scene("hang_two_corners", ["self_collision.enabled=true",
                                             f"self_collision.thickness={THICKNESS}"])
    return SelfCollision(config.self_collision)


def _pairs_fields(pairs):
    return [getattr(pairs, f) for f in ("a", "wa", "b", "wb", "normal", "gap", "hold")]


@pytest.mark.parametrize("name", ["folded-close", "folded-far", "folded-degenerate", "wavy"])
def test_proximity_and_crossings_are_unchanged_by_the_compiled_path(name):
    """Layers near and far, moving towards each other, apart and through:
    the compiled broad phase and ``may_touch`` (which skips narrow phases)
    give the numpy path's pairs, bit for bit."""
    x, tris, uv = SCENES[name]
    h = 1.0 / 60.0
    top = x[:, 2] > 1e-9
    found = 0
    for trial in range(12):
        v = RNG.normal(scale=0.05, size=x.shape)
        v[top, 2] += (-1.0) ** trial * 0.3 * trial      # together, apart, fast
        x1 = x + h * v
        x1[top, 2] -= 0.002 * trial

        def run():
            sc = _collision()
            sc.set_topology(tris, uv)
            return sc.proximity(x, v, h), sc.crossings(x, x1)
        reference, compiled = _both(run)
        for ref, ours in zip(reference, compiled):
            for a, b in zip(_pairs_fields(ref), _pairs_fields(ours)):
                _same(b, a)
        found += len(reference[0]) + len(reference[1])
    if name in ("folded-close", "folded-degenerate"):
        assert found                    # the comparison saw real pairs


def test_may_touch_is_a_lower_bound():
    """Single random candidates, degenerate ones included: whenever the
    narrow phase would keep a pair (closer than the limit after closing by
    the relative motion), ``may_touch`` says so."""
    sc = _collision()
    kept = 0
    for trial in range(400):
        x = RNG.normal(scale=0.02, size=(7, 3))
        if trial % 4 == 0:
            x[2] = x[1] + (x[1] - x[0]) * RNG.random()   # a collinear triangle
        if trial % 7 == 0:
            x[5] = x[4]                                   # a zero-length edge
        v = RNG.normal(scale=0.3, size=(7, 3))
        h, band = 1.0 / 60.0, 0.02
        verts, tris = np.array([3]), np.array([[0, 1, 2]])
        e1, e2 = np.array([[4, 5]]), np.array([[0, 6]])
        vf, ee = sc._vf_pairs(x, verts, tris), sc._ee_pairs(x, e1, e2)
        for ((a, wa, b, wb), gap), args in ((vf, (verts, tris, e1[:0], e2[:0])),
                                            (ee, (verts[:0], tris[:0], e1, e2))):
            d = np.linalg.norm(gap, axis=1)
            n = gap / np.maximum(d, 1e-300)[:, None]
            rel = np.einsum("kj,kjd->kd", wa, v[a]) - np.einsum("kj,kjd->kd", wb, v[b])
            if (d + h * np.minimum(np.einsum("kd,kd->k", rel, n), 0.0) < band).any():
                assert self_broad_kernels.may_touch(x, v, *args, band, h)
                kept += 1
    assert kept > 20


def _brute_pairs(lo_a, hi_a, lo_b, hi_b, same):
    """Every overlapping pair by a double loop: the outside reference."""
    pairs = [(i, j) for i in range(len(lo_a)) for j in range(len(lo_b))
             if (not same or i < j)
             and np.all(lo_a[i] <= hi_b[j]) and np.all(lo_b[j] <= hi_a[i])]
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


@pytest.mark.parametrize("same", [True, False])
def test_boxes_of_unphysical_motion_are_searched_in_bounded_work(same):
    """A few boxes swept over 1e8 m (a step under gravity 1e12, refused or torn)
    among many small ones: the numpy hash would enumerate ~1e24 cells for them.
    Both paths return every overlapping pair (a double loop checks) and the
    layered flags are conservative: every box flagged."""
    rng = np.random.default_rng(7)
    k = 300
    lo = rng.random((k, 3))
    hi = lo + 0.03 * rng.random((k, 3))
    lo[:3] -= 1e8
    hi[:3] += 1e8
    lo_b = rng.random((200, 3))
    hi_b = lo_b + 0.03
    args = (lo, hi) if same else (lo, hi, lo_b, hi_b)
    expected = _brute_pairs(lo, hi, lo if same else lo_b, hi if same else hi_b, same)
    reference, compiled = _both(lambda: box_pairs(*args))
    for found in (reference, compiled):
        np.testing.assert_array_equal(np.column_stack(found), expected)
    normals = np.tile([0.0, 0.0, 1.0], (k, 1))
    uv_lo = rng.random((k, 2))
    flags = _both(lambda: layered_boxes(lo, hi, uv_lo, uv_lo + 0.01, 0.01, normals))
    for flagged in flags:
        assert flagged.all()
