"""Self-collision: geometry against brute force, the continuous check, whole
simulations of layered cloth (checked by the stress suite's independent
intersection test), LOD near layers, and the configuration section."""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.contact import self_contact as self_contact_module
from cloth_lod_ros.sim.scene.config import (SceneError, load_scene, scene_from_dict, scene_to_dict,
                                            self_collision_on)
from cloth_lod_ros.sim.contact.self_contact import SelfCollision, SelfCounters
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.contact.self_broad import (SPREAD_DIRECTIONS, BroadPhase, box_pairs,
                                                  layered_boxes)
from cloth_lod_ros.sim.contact.self_narrow import (ee_crossing, point_triangle, segment_segment,
                                                   vf_crossing)
from cloth_lod_ros.tools.stress.intersect import intersecting_pairs

THICKNESS = 0.004
RNG = np.random.default_rng(7)


# -- geometry ------------------------------------------------------------------------

def test_closest_points_match_a_dense_search():
    p, a, b, c = (RNG.normal(size=(60, 3)) for _ in range(4))
    w = point_triangle(p, a, b, c)
    assert np.all(w >= -1e-12) and np.allclose(w.sum(axis=1), 1.0)
    d = np.linalg.norm(p - (w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c), axis=1)
    g = np.linspace(0.0, 1.0, 151)
    u, v = np.meshgrid(g, g)
    inside = u + v <= 1.0
    u, v = u[inside], v[inside]
    s, t = segment_segment(p, a, b, c)
    e = np.linalg.norm(p + s[:, None] * (a - p) - (b + t[:, None] * (c - b)), axis=1)
    for i in range(len(p)):
        dense = a[i] + u[:, None] * (b[i] - a[i]) + v[:, None] * (c[i] - a[i])
        assert d[i] <= np.linalg.norm(dense - p[i], axis=1).min() + 1e-12
        seg = np.linalg.norm((p[i] + g[:, None, None] * (a[i] - p[i]))
                             - (b[i] + g[None, :, None] * (c[i] - b[i])), axis=2)
        assert e[i] <= seg.min() + 1e-12


def test_box_pairs_are_exactly_the_overlapping_boxes():
    lo = RNG.uniform(0.0, 1.0, (400, 3))
    hi = lo + RNG.uniform(0.0, 0.1, (400, 3))
    lo2 = RNG.uniform(0.0, 1.0, (300, 3))
    hi2 = lo2 + 0.02
    ia, ib = box_pairs(lo, hi, lo2, hi2)
    overlap = np.all((lo[:, None] <= hi2[None]) & (lo2[None] <= hi[:, None]), axis=2)
    assert set(zip(ia.tolist(), ib.tolist())) == set(zip(*np.nonzero(overlap)))
    ia, ib = box_pairs(lo, hi)
    overlap = np.triu(np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2), 1)
    assert set(zip(ia.tolist(), ib.tolist())) == set(zip(*np.nonzero(overlap)))
    # Few boxes take the all-pairs path: the same answer, in the same order.
    for k_a, k_b in ((40, 25), (60, None)):
        lo, lo2 = RNG.uniform(0.0, 1.0, (k_a, 3)), RNG.uniform(0.0, 1.0, (k_b or k_a, 3))
        hi, hi2 = lo + RNG.uniform(0.0, 0.3, lo.shape), lo2 + 0.2
        if k_b is None:
            lo2, hi2 = lo, hi
        overlap = np.all((lo[:, None] <= hi2[None]) & (lo2[None] <= hi[:, None]), axis=2)
        ia, ib = box_pairs(lo, hi) if k_b is None else box_pairs(lo, hi, lo2, hi2)
        expected = np.nonzero(np.triu(overlap, 1) if k_b is None else overlap)
        assert len(ia) and ia.tolist() == expected[0].tolist() and ib.tolist() == expected[1].tolist()


def _layered_by_cells(lo, hi, uv_lo, uv_hi, pad, normals):
    """The test of :func:`layered_boxes` as its docstring states it, cell by
    cell: the flags ``(k,)``, and the smallest relative margin of the
    decisions behind them (a box corner to a cell boundary, a material spread
    to S, a cosine to 0), which this code reaches by other sums than the
    library's (a mean and a matrix product), so flags decided within round-off
    of a threshold may differ."""
    cell = 1.5 * max(float(np.median((hi - lo).max(axis=1))), 1e-9)
    origin = lo.min(axis=0)
    corners = np.concatenate([lo - origin, hi - origin]) / cell
    off_boundary = np.abs(corners - np.round(corners))[corners != 0.0]   # 0: exact both ways
    margins = [off_boundary.min(initial=1.0)]
    first = np.floor((lo - origin) / cell).astype(int)
    last = np.floor((hi - origin) / cell).astype(int)
    members = {}
    for b in range(len(lo)):
        for i in range(first[b, 0], last[b, 0] + 1):
            for j in range(first[b, 1], last[b, 1] + 1):
                for k in range(first[b, 2], last[b, 2] + 1):
                    members.setdefault((i, j, k), []).append(b)
    far = 2.0 * (np.sqrt(3.0) * cell + 2.0 * pad)
    out = np.zeros(len(lo), bool)
    for ids in members.values():
        spread = max(uv_lo[ids, d].max() - uv_hi[ids, d].min() for d in (0, 1))
        mean = normals[ids].mean(axis=0)
        cosines = normals[ids] @ mean
        # Two normals more than 90 degrees apart along a direction: their
        # projections span more than sqrt(2).
        along = normals[ids] @ np.array(SPREAD_DIRECTIONS).T
        widths = along.max(axis=0) - along.min(axis=0)
        margins += [abs(spread - far) / far,
                    np.abs(cosines).min() / max(np.linalg.norm(mean), 1e-300),
                    np.abs(widths - np.sqrt(2.0)).min()]
        if spread > far or cosines.min() < 0.0 or widths.max() > np.sqrt(2.0):
            out[ids] = True
    return out, min(margins)


@pytest.mark.parametrize("compiled", [False, True], ids=["numpy", "compiled"])
def test_layered_boxes_match_a_cell_by_cell_search(compiled):
    """Flat, folded and torn grids of triangles (a particle pulled 0.5 m away:
    boxes spanning many cells; half the boxes 30 m away: a sparse grid): the
    vectorised test (numpy, or compiled where numba is installed) flags exactly
    the boxes of the cells that the plain search flags."""
    if compiled and not runtime_compiled.available:
        pytest.skip("numba not installed")
    previous = runtime_compiled.use(compiled)
    try:
        _check_layered_boxes()
    finally:
        runtime_compiled.use(previous)


def _check_layered_boxes():
    n = 12
    g = np.linspace(0.0, 0.6, n + 1)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    uv = np.column_stack([u, v])
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    tris = np.concatenate([np.column_stack([corner, corner + 1, corner + n + 2]),
                           np.column_stack([corner, corner + n + 2, corner + n + 1])])
    uv_corners = uv[tris]
    flagged = []
    for trial in range(16):
        x = np.column_stack([u, v, np.zeros_like(u)]) + RNG.normal(0.0, 0.004, (len(u), 3))
        if trial % 4 == 1:                      # folded back over itself
            cut = RNG.uniform(0.2, 0.4)
            fold = u > cut
            x[fold, 0] = 2 * cut - x[fold, 0]
            x[fold, 2] += RNG.uniform(0.005, 0.05)
        elif trial % 4 == 2:
            x[RNG.integers(len(x))] += RNG.normal(0.0, 0.3, 3)
        corners = x[tris]
        lo, hi = corners.min(axis=1) - 0.008, corners.max(axis=1) + 0.008
        if trial % 4 == 3:
            lo[::2] += 30.0
            hi[::2] += 30.0
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        args = (lo, hi, uv_corners.min(axis=1), uv_corners.max(axis=1), 0.02, normals)
        out = layered_boxes(*args)
        expected, margin = _layered_by_cells(*args)
        if margin > 1e-9:          # every decision clear of round-off: the same flags
            assert np.array_equal(out, expected)
            flagged.append(out.any())
    assert len(flagged) >= 14      # at most 2 of 16 trials too close to a threshold
    assert any(flagged) and not all(flagged)


def _pleated_sheet(opening: float, rotation: np.ndarray):
    """A 0.6 m x 0.3 m sheet (2 cm grid, material coordinates u, v) lying in
    z = 0 with a pleat standing up from it: along u, the cloth from u = 0.2 m
    rises 10 cm as a wall, comes back down as a second wall and lies flat
    again from u = 0.4 m.  The walls form an inverted V whose feet are
    ``opening`` m apart: they face -x and +x, both leaning a little towards
    the sheet's +z, so every normal lies within 90 degrees of the mean of any
    cell (the case that hid a closing pleat, issue 31).  ``rotation``
    ``(3, 3)`` turns the whole sheet.  Returns ``(x, triangles, uv)``."""
    step, n_u, n_v = 0.02, 31, 16
    u, v = np.meshgrid(np.arange(n_u) * step, np.arange(n_v) * step, indexing="ij")
    u, v = u.ravel(), v.ravel()
    height = 0.1
    x = np.column_stack([u, v, np.zeros_like(u)])
    rise = (u > 0.2) & (u <= 0.3)
    fall = (u > 0.3) & (u < 0.4)
    x[rise, 0] = 0.2 + (u[rise] - 0.2) / height * 0.5 * opening
    x[rise, 2] = u[rise] - 0.2
    x[fall, 0] = 0.2 + 0.5 * opening + (u[fall] - 0.3) / height * 0.5 * opening
    x[fall, 2] = 0.4 - u[fall]
    x[u >= 0.4, 0] = u[u >= 0.4] - 0.2 + opening
    corner = (np.arange(n_u - 1)[:, None] * n_v + np.arange(n_v - 1)[None, :]).ravel()
    tris = np.concatenate([np.column_stack([corner, corner + n_v, corner + n_v + 1]),
                           np.column_stack([corner, corner + n_v + 1, corner + 1])])
    return x @ rotation.T, tris, np.column_stack([u, v])


def _random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


@pytest.mark.parametrize("compiled", [False, True], ids=["numpy", "compiled"])
@pytest.mark.parametrize("opening", [0.004, 0.012])
def test_every_vertex_triangle_pair_within_the_band_is_a_candidate(compiled, opening):
    """The broad phase (its layered-cell prefilter included) misses no pair
    that the proximity test would keep: every vertex-triangle pair sharing
    no particle and closer than twice the thickness, found by brute force
    over all pairs, is among its candidates.  Standing pleats with feet 4 and
    12 mm apart, in six orientations: their walls face opposite ways but
    every normal is within 90 degrees of its cell's mean."""
    if compiled and not runtime_compiled.available:
        pytest.skip("numba not installed")
    previous = runtime_compiled.use(compiled)
    rng = np.random.default_rng(11)
    try:
        for trial in range(6):
            rotation = np.eye(3) if trial == 0 else _random_rotation(rng)
            x, tris, uv = _pleated_sheet(opening, rotation)
            broad = BroadPhase(THICKNESS, SelfCounters())
            broad.set_topology(tris, uv)
            c = broad.query(x, x, THICKNESS)
            found = set(zip(c["verts"].tolist(), map(tuple, np.sort(c["tris"], 1).tolist())))
            verts = np.repeat(np.arange(len(x)), len(tris))
            every = np.tile(tris, (len(x), 1))
            apart = np.all(every != verts[:, None], axis=1)
            verts, every = verts[apart], every[apart]
            w = point_triangle(x[verts], x[every[:, 0]], x[every[:, 1]], x[every[:, 2]])
            gap = np.linalg.norm(x[verts] - np.einsum("kj,kjd->kd", w, x[every]), axis=1)
            close = gap < 2.0 * THICKNESS
            assert close.sum() > 20                     # the walls do come close
            missed = [(p, t) for p, t in zip(verts[close].tolist(),
                                             map(tuple, np.sort(every[close], 1).tolist()))
                      if (p, t) not in found]
            assert not missed, (trial, len(missed), int(close.sum()))
    finally:
        runtime_compiled.use(previous)


def test_a_vertex_through_a_triangle_is_caught_and_one_passing_beside_it_is_not():
    x0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0.05]], float)
    tri = np.array([[0, 1, 2]])
    through = x0.copy()
    through[3, 2] = -0.05
    beside = x0.copy()
    beside[3] = [1.5, 1.5, -0.05]
    assert vf_crossing(x0, through, np.array([3]), tri, 1e-6).tolist() == [True]
    assert vf_crossing(x0, beside, np.array([3]), tri, 1e-6).tolist() == [False]


def test_the_continuous_check_agrees_with_a_dense_time_sampling():
    n = 400
    x0 = RNG.normal(size=(4 * n, 3))
    x1 = x0 + RNG.normal(size=(4 * n, 3))
    verts = np.arange(n) * 4
    tris = verts[:, None] + np.array([1, 2, 3])
    hit = vf_crossing(x0, x1, verts, tris, 1e-9)
    ts = np.linspace(0.0, 1.0, 4001)[:, None]
    checked = 0
    for i in range(n):
        p, a, b, c = (x0[j] + ts * (x1[j] - x0[j]) for j in (verts[i], *tris[i]))
        f = np.einsum("td,td->t", np.cross(b - a, c - a), p - a)
        changes = np.flatnonzero(np.sign(f[:-1]) != np.sign(f[1:]))
        share = [point_triangle(p[k:k + 1], a[k:k + 1], b[k:k + 1], c[k:k + 1]).min()
                 for k in changes]
        if any(0.0 < w <= 1e-3 for w in share):
            continue                   # grazing an edge: too close to call by sampling
        assert hit[i] == any(w > 1e-3 for w in share)
        checked += 1
    assert checked > 300 and hit.sum() > 10        # the sample has crossings


def _edge_through_edge():
    """Two triangles in perpendicular planes: B (apex down, below A) rises so
    that its top edge passes through A's bottom edge; no vertex of either goes
    through the other triangle."""
    x0 = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0],     # A, plane y = 0
                   [0.0, -1.0, -0.1], [0.0, 1.0, -0.1], [0.0, 0.0, -1.1]])  # B, plane x = 0
    x1 = x0.copy()
    x1[3:, 2] += 0.2
    return x0, x1, np.array([[0, 1, 2], [3, 4, 5]])


def test_an_edge_edge_crossing_is_caught():
    x0, x1, tris = _edge_through_edge()
    # No vertex meets the other triangle: only the edge test can see this.
    verts = np.array([0, 1, 2, 3, 4, 5])
    other = np.array([tris[1]] * 3 + [tris[0]] * 3)
    assert not vf_crossing(x0, x1, verts, other, 1e-6).any()
    assert ee_crossing(x0, x1, np.array([[0, 1]]), np.array([[3, 4]]), 1e-6).tolist() == [True]
    assert not len(intersecting_pairs(x0, tris)) and len(intersecting_pairs(x1, tris))
    sc = SelfCollision(scene_from_dict(_strip_scene(level=0)).self_collision)
    # Far apart in the material (two layers of one cloth).
    sc.set_topology(tris, np.array([[0, 0], [2, 0], [1, 1], [50, 0], [52, 0], [51, 1]], float))
    found = sc.crossings(x0, x1)
    assert len(found) >= 1 and found.hold.all()
    edge_pairs = {(tuple(sorted(a[:2])), tuple(sorted(b[:2])))
                  for a, b in zip(found.a.tolist(), found.b.tolist()) if a[0] != a[1]}
    assert edge_pairs & {((0, 1), (3, 4)), ((3, 4), (0, 1))}
    # The pair's side is the start's: B's edge was below A's.
    assert np.all(np.abs(found.normal[:, 2]) > 0.9)


def _two_patches(height):
    """Two flat 0.2 m square patches of 32 triangles each, far apart in the
    material (two layers), the second ``height`` m above the first and shifted
    so that its particles lie over the first's triangles.  Returns positions
    ``(50, 3)``, triangles, rest coordinates and the upper patch's particles."""
    g = np.linspace(0.0, 0.2, 5)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    corner = (np.arange(4)[:, None] * 5 + np.arange(4)[None, :]).ravel()
    tris = np.concatenate([np.column_stack([corner, corner + 1, corner + 6]),
                           np.column_stack([corner, corner + 6, corner + 5])])
    flat = np.column_stack([u, v, np.zeros_like(u)])
    x = np.concatenate([flat, flat + [0.013, 0.017, height]])
    uv = np.concatenate([np.column_stack([u, v]), np.column_stack([u + 10.0, v])])
    return x, np.concatenate([tris, tris + 25]), uv, np.arange(25, 50)


def test_a_layer_arriving_from_beyond_the_cached_margin_is_still_caught():
    """The broad phase is reused only while the particles' boxes stay inside
    the ones it was built for (padded by a thickness or so).  A layer that
    comes from farther within one step - its start velocity said it would
    not move, or it moves fast - leaves them, and the check is made again."""
    sc = SelfCollision(scene_from_dict(_strip_scene(level=0)).self_collision)
    x, tris, uv, upper = _two_patches(height=0.3)
    sc.set_topology(tris, uv)
    h, rest = 1.0 / 60.0, np.zeros_like(x)
    assert not len(sc.proximity(x, rest, h)) and sc.counters.broad == 1
    # Less than the margin: the certificate (no cell with two layers) holds.
    drift = x.copy()
    drift[upper, 2] -= 0.5 * THICKNESS
    assert not len(sc.crossings(x, drift)) and sc.counters.broad == 1
    # The solve took the upper layer through the lower one in one step.
    through = x.copy()
    through[upper, 2] = -0.05
    found = sc.crossings(x, through)
    assert len(found) and found.hold.all() and sc.counters.broad == 2
    # The sides are the start's: normals from side B to side A, up when A is
    # the upper layer.
    a_above = np.isin(found.a[:, 0], upper)
    assert np.all(np.where(a_above, found.normal[:, 2], -found.normal[:, 2]) > 0.9)
    # Checked at rest, then 5 cm above and falling at 6 m/s: in contact
    # before the step ends.
    sc = SelfCollision(sc.config)
    sc.set_topology(tris, uv)
    assert not len(sc.proximity(x, rest, h)) and sc.counters.broad == 1
    near, fall = x.copy(), rest.copy()
    near[upper, 2], fall[upper, 2] = 0.05, -6.0
    pairs = sc.proximity(near, fall, h)
    assert len(pairs) and sc.counters.broad == 2 and sc.counters.with_pairs == 1


def test_separate_builds_the_broad_phase_that_the_next_step_reuses():
    """Given the step about to be taken, a split's separation builds its broad
    phase over that motion, and the step's detection reuses it."""
    x, tris, uv, _ = _two_patches(height=0.3)
    v = np.zeros_like(x)
    v[:, 0] = 0.5                                     # sideways, 8 mm per step
    h = 1.0 / 60.0
    for ahead, builds in ((True, 1), (False, 2)):
        sc = SelfCollision(scene_from_dict(_strip_scene(level=0)).self_collision)
        sc.set_topology(tris, uv)
        out = sc.separate(x, np.array([3]), *((v, h) if ahead else ()))
        assert np.array_equal(out, x)                 # nothing near: nothing moved
        assert not len(sc.proximity(out, v, h)) and sc.counters.broad == builds


# -- whole simulations ----------------------------------------------------------------

def _strip_scene(level=3, lod=False, enabled=True, **extra):
    data = {"name": "z_fold",
            "cloth": {"width": 1.5, "height": 0.5, "base_blocks": [3, 1], "level": level,
                      "origin": [0.0, 0.0, THICKNESS]},
            "air": {"density": 0.0},
            "obstacles": [{"type": "plane", "centre": [0, 0, 0], "normal": [0, 0, 1],
                           "friction": 0.5}],
            "simulation": {"time_step": 1 / 60, "duration": 1.0},
            "self_collision": {"enabled": enabled, "thickness": THICKNESS, "friction": 0.1},
            "lod": {"enabled": lod, "initial_level": level if lod else 0}}
    data.update(extra)
    return data


def _path_xz(s, segments, start=(0.0, THICKNESS)):
    """Arc-length parametrised path in the xz-plane through ``('line', L)`` and
    ``('arc', r, angle)`` pieces; returns x, z at arc lengths ``s``."""
    pts, lengths, heading, p = [np.array(start)], [0.0], 0.0, np.array(start, float)
    for seg in segments:
        n = 400
        for k in range(1, n + 1):
            if seg[0] == "line":
                q = p + seg[1] * k / n * np.array([np.cos(heading), np.sin(heading)])
                step = seg[1] / n
            else:
                r, angle = seg[1], seg[2]
                centre = p + r * np.sign(angle) * np.array([-np.sin(heading), np.cos(heading)])
                h = heading + angle * k / n
                q = centre - r * np.sign(angle) * np.array([-np.sin(h), np.cos(h)])
                step = r * abs(angle) / n
            pts.append(q)
            lengths.append(lengths[-1] + step)
        if seg[0] == "arc":
            heading += seg[2]
        p = pts[-1].copy()
    pts, lengths = np.array(pts), np.array(lengths)
    return np.interp(s, lengths, pts[:, 0]), np.interp(s, lengths, pts[:, 1])


#: A strip lying in a Z: a layer on the floor, a tight fold back over it, and
#: a loop lifting the last part 0.26 m above: that part falls on the folded cloth.
Z_FOLD = [("line", 0.5), ("arc", 0.02, np.pi), ("line", 0.45), ("arc", 0.1, -np.pi),
          ("line", 1.0)]


def _z_folded(sim):
    u, v = sim.rest_uv[:, 0], sim.rest_uv[:, 1]
    x, z = _path_xz(u, Z_FOLD)
    sim.state.positions[:] = np.column_stack([x, v, z])
    if sim.hierarchy is not None:
        sim._sync_hierarchy()
    return sim


def _run_counting_intersections(sim, steps):
    crossed = 0
    for _ in range(steps):
        sim.step()
        crossed += bool(len(intersecting_pairs(sim.positions, sim.triangles)))
    return crossed


def test_a_cloth_dropped_on_a_folded_cloth_stays_above_it():
    sim = _z_folded(ClothSim(scene_from_dict(_strip_scene(level=4))))
    assert not len(intersecting_pairs(sim.positions, sim.triangles))
    assert _run_counting_intersections(sim, 75) == 0
    # Layer by layer: every particle of the upper layer that lies over the
    # lower one is above it (its height there, from the triangle beneath).
    u, x, tri = sim.rest_uv[:, 0], sim.positions, sim.triangles
    layers = [u < 0.45, (u > 0.62) & (u < 0.95), u > 1.35]
    gaps = []
    for lower, upper in zip(layers, layers[1:]):
        below = tri[lower[tri].all(axis=1)]
        a, b, c = (x[below[:, k], :2] for k in range(3))
        for p in x[upper]:
            m = np.stack([b - a, c - a], axis=2)               # (t, 2, 2)
            w = np.linalg.solve(m, (p[:2] - a)[:, :, None])[:, :, 0]
            inside = np.flatnonzero((w >= 0).all(axis=1) & (w.sum(axis=1) <= 1))
            for k in inside:
                z = x[below[k], 2] @ np.array([1 - w[k].sum(), w[k, 0], w[k, 1]])
                gaps.append(p[2] - z)
    # Above it everywhere, and kept about the thickness apart (the push-out of a
    # particle found inside the thickness is gradual, so not everywhere exactly).
    assert len(gaps) >= 5 and min(gaps) > 0.0
    assert np.median(gaps) > 0.75 * THICKNESS
    assert sim.self_collision.counters.with_pairs > 0


def test_without_self_collision_the_layers_pass_through_each_other():
    """The scene of the test above does test something."""
    sim = _z_folded(ClothSim(scene_from_dict(_strip_scene(level=4, enabled=False))))
    assert sim.self_collision is None
    assert _run_counting_intersections(sim, 75) > 0


def test_with_lod_layers_stay_apart_and_no_merge_touches_a_particle_near_another_layer():
    sim = _z_folded(ClothSim(scene_from_dict(_strip_scene(level=4, lod=True))))
    distance = sim.scene.self_collision.detail_distance
    for _ in range(60):
        before = sim.vertex_ids.copy()
        near = sim.self_collision.near(sim.positions, distance)
        sim.step()
        removed = ~np.isin(before, sim.vertex_ids)
        assert not np.any(near & removed)        # no particle near another layer merged
        assert not len(intersecting_pairs(sim.positions, sim.triangles))
    # The policy, asked later (every triangle old enough), would merge near
    # particles without the mask and merges none of them with it.
    near = sim.self_collision.near(sim.positions, distance)
    h = sim.hierarchy
    sim._sync_hierarchy()

    def merged(layered):
        decision = sim.lod_policy.decide(
            h, sim.elements, sim.vertex_ids, sim.triangle_ids, sim.positions, sim.velocities,
            sim.masses, sim.time + 10.0, sim._held_nodes(), layered=layered)
        mids = [h.midpoint[e] for e in decision.merge]
        return near[np.searchsorted(sim.vertex_ids, mids)] if mids else np.zeros(0, bool)

    assert merged(None).any()
    assert not merged(near).any()


def test_a_split_particle_inside_another_layer_is_moved_out():
    sc = SelfCollision(scene_from_dict(_strip_scene(level=0)).self_collision)
    # A flat triangle and, 1 mm above it, a particle of another piece.
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0.001], [3, 0, 0.001],
                  [3, 1, 0.001]], float)
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    sc.set_topology(tris, np.array([[0, 0], [1, 0], [0, 1], [50, 0], [53, 0], [53, 1]], float))
    out = sc.separate(x, np.array([3]))
    assert out[3, 2] == pytest.approx(THICKNESS)
    assert np.array_equal(np.delete(out, 3, axis=0), np.delete(x, 3, axis=0))


def test_no_self_collision_code_runs_when_it_is_off(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("self-collision code ran")
    for name in ("proximity", "crossings", "constraints", "near", "separate", "set_topology"):
        monkeypatch.setattr(self_contact_module.SelfCollision, name, forbidden)
    sim = ClothSim(load_scene("grasp_lift", ["simulation.duration=0.1",
                                            "self_collision.enabled=false"]))
    assert sim.self_collision is None
    sim.run()
    assert all(s.self_collision_ms == 0.0 and s.self_contact_count == 0 for s in sim.stats)


# -- configuration ---------------------------------------------------------------------

def test_the_section_is_validated_and_round_trips():
    scene = scene_from_dict(_strip_scene())
    assert scene_from_dict(scene_to_dict(scene)) == scene
    default = load_scene("hang_two_corners")
    assert default.self_collision.enabled == "auto" and self_collision_on(default)
    assert load_scene("fold_in_half").self_collision.enabled is True
    assert not self_collision_on(load_scene("hang_two_corners", ["self_collision.enabled=false"]))
    # auto where the band cannot fit the finest mesh (level 12: particles 2.8 mm
    # apart, band 8 mm): off, where true is refused.
    fine = ["cloth.level=12", "lod.enabled=true"]
    assert not self_collision_on(load_scene("hang_two_corners", fine))
    with pytest.raises(SceneError, match=r"self_collision\.thickness"):
        load_scene("hang_two_corners", fine + ["self_collision.enabled=true"])
    with pytest.raises(SceneError, match=r"true, false or auto"):
        load_scene("hang_two_corners", ["self_collision.enabled=sometimes"])
    for field, value, words in (("thickness", 0.1, "self_collision.thickness"),
                                ("thickness", -1.0, "self_collision.thickness"),
                                ("friction", -0.1, "self_collision.friction"),
                                ("detail_distance", 0.001, "self_collision.detail_distance"),
                                ("colour", 1, "self_collision.colour")):
        data = _strip_scene()
        data["self_collision"] = {"enabled": True, "thickness": THICKNESS, field: value}
        with pytest.raises(SceneError, match=words.replace(".", r"\.")):
            scene_from_dict(data)
