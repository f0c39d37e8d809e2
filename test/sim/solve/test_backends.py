"""Linear-solver backends: the same answer on the same systems, the properties
each backend is for (a factorisation analysed once per topology, multigrid
iterations that do not grow with the mesh), and honest accounting of solves."""

import numpy as np
import pytest
from types import SimpleNamespace

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.physics.forces import evaluate
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.solve.constraints import Constraints
from cloth_lod_ros.sim.solve.pattern import SparsePattern
from cloth_lod_ros.sim.solve.pcg import filtered_pcg
from cloth_lod_ros.sim.solve.projection import project_system
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, lumped_masses, refine_uniform
from cloth_lod_ros.sim.solve.multigrid import lattice_hierarchy
from cloth_lod_ros.sim.solve import backends
from cloth_lod_ros.sim.solve import factorisation
from cloth_lod_ros.sim.solve.backends import make_solver

MATERIAL = SimpleNamespace(stretch_stiffness=2000.0, shear_stiffness=200.0, bend_stiffness=2e-4,
                           stretch_damping=0.01, shear_damping=0.01, bend_damping=0.1)


def system(level, seed=0, flat=False, h=1 / 60):
    """A real step system of a cloth (deformed, or flat and unstrained: the
    anisotropic case), its pattern and rest coordinates."""
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
    el = precompute(mesh)
    rng = np.random.default_rng(seed)
    x = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    v = np.zeros_like(x)
    if not flat:
        x += rng.normal(scale=0.01, size=x.shape)
        v = rng.normal(scale=0.3, size=x.shape)
    ev = evaluate(el, MATERIAL, x, v, h * h, h)
    masses = lumped_masses(mesh.uv, mesh.triangles, 0.2)
    pattern = SparsePattern(mesh.vertex_count, el.element_vertices)
    matrix = pattern.assemble(ev.blocks, masses)
    rhs = h * (ev.force + masses[:, None] * np.array([0, 0, -9.81]) + h * ev.stiffness_times_velocity)
    return matrix, rhs, pattern, mesh


def constraints_for(mesh, seed=1):
    """Two held corners plus a row of plane contacts (normal z), prescribed."""
    n = mesh.vertex_count
    corners = np.flatnonzero(np.isclose(mesh.uv[:, 1], 1.0) & np.isin(mesh.uv[:, 0], [0.0, 1.0]))
    row = np.flatnonzero(np.isclose(mesh.uv[:, 1], 0.0))
    nz = np.array([0.0, 0.0, 1.0])
    projectors = np.concatenate([np.zeros((len(corners), 3, 3)),
                                 np.repeat((np.eye(3) - np.outer(nz, nz))[None], len(row), 0)])
    rng = np.random.default_rng(seed)
    prescribed = rng.normal(scale=0.01, size=(len(corners) + len(row), 3))
    assert n > len(corners) + len(row)
    return Constraints(np.concatenate([corners, row]), projectors, prescribed)


def reference(matrix, rhs, pattern, constraints):
    return filtered_pcg(matrix, rhs, constraints, pattern.diagonal_blocks(matrix),
                        tolerance=1e-12, max_iterations=20000).dv


@pytest.mark.parametrize("method", backends.available_methods())
@pytest.mark.parametrize("held", [False, True], ids=["free", "held"])
def test_every_backend_solves_the_same_system(method, held):
    matrix, rhs, pattern, mesh = system(4)
    constraints = constraints_for(mesh) if held else Constraints.none()
    exact = reference(matrix, rhs, pattern, constraints)
    backend = make_solver(method, 1e-8, 5000, geometry=(1.0, 1.0, 0.25))
    backend.reset_topology(pattern, mesh.uv)
    result = backend.solve(matrix, rhs, constraints, None)
    assert result.converged
    assert np.abs(result.dv - exact).max() <= 1e-5 * np.abs(exact).max()
    if held:                                  # held directions exactly as prescribed
        c = constraints
        held_part = result.dv[c.indices] - np.einsum("kab,kb->ka", c.projectors, result.dv[c.indices])
        want = c.prescribed - np.einsum("kab,kb->ka", c.projectors, c.prescribed)
        np.testing.assert_allclose(held_part, want, atol=1e-12)


def test_the_projected_system_keeps_the_pattern_and_is_spd():
    matrix, rhs, pattern, mesh = system(3)
    projected, b, z = project_system(matrix, rhs, constraints_for(mesh), pattern)
    np.testing.assert_array_equal(projected.indices, matrix.indices)
    np.testing.assert_array_equal(projected.indptr, matrix.indptr)
    dense = projected.toarray()
    np.testing.assert_allclose(dense, dense.T, atol=1e-12 * np.abs(dense).max())
    assert np.linalg.eigvalsh(dense).min() > 0


def test_the_projected_system_equals_its_definition():
    """Â = S A S + (I − S) D (I − S) and b̂ = S (b − A z), densely, for fully held,
    sliding (tilted normals) and free particles, one particle listed twice."""
    matrix, rhs, pattern, mesh = system(3)
    rng = np.random.default_rng(3)
    n = mesh.vertex_count
    held = rng.choice(n, size=12, replace=False)
    normals = rng.normal(size=(6, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    projectors = np.concatenate([np.zeros((6, 3, 3)),
                                 np.eye(3) - normals[:, :, None] * normals[:, None, :],
                                 np.zeros((1, 3, 3))])
    indices = np.concatenate([held, held[:1]])      # the last entry of held[0] wins
    constraints = Constraints(indices, projectors, rng.normal(size=(13, 3)))
    projected, b, z = project_system(matrix, rhs, constraints, pattern)
    s = np.eye(3 * n)
    for i, p in zip(indices, projectors):
        s[3 * i:3 * i + 3, 3 * i:3 * i + 3] = p
    a = matrix.toarray()
    d = np.zeros_like(a)
    for i in range(n):
        d[3 * i:3 * i + 3, 3 * i:3 * i + 3] = a[3 * i:3 * i + 3, 3 * i:3 * i + 3]
    c = np.eye(3 * n) - s
    scale = np.abs(a).max()
    np.testing.assert_allclose(projected.toarray(), s @ a @ s + c @ d @ c, atol=1e-13 * scale)
    np.testing.assert_allclose(b.ravel(), s @ (rhs.ravel() - a @ z.ravel()),
                               atol=1e-13 * scale * (1 + np.abs(z).max()))
    np.testing.assert_allclose(s @ z.ravel(), 0.0, atol=1e-15)      # z: held directions only
    np.testing.assert_allclose(z[held[0]], constraints.prescribed[-1], atol=0)


def test_the_factorisation_is_analysed_once_per_topology(monkeypatch):
    if "direct" not in backends.available_methods():
        pytest.skip("qdldl is a dependency of the package; this only runs without it")
    analyses = []
    real = backends._qdldl.Solver

    def counting(*args, **kwargs):
        analyses.append(1)
        return real(*args, **kwargs)
    monkeypatch.setattr(backends._qdldl, "Solver", counting)
    matrix, rhs, pattern, mesh = system(3)
    backend = make_solver("direct", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    for k in range(4):                     # new numbers and new constraint sets each time
        c = constraints_for(mesh, seed=k) if k % 2 else Constraints.none()
        result = backend.solve(matrix * (1.0 + 0.1 * k), rhs, c, None)
        np.testing.assert_allclose(result.dv, reference(matrix * (1.0 + 0.1 * k), rhs, pattern, c),
                                   atol=1e-8)
    assert len(analyses) == 1
    backend.reset_topology(pattern, mesh.uv)
    backend.solve(matrix, rhs, Constraints.none(), None)
    assert len(analyses) == 2


@pytest.mark.parametrize("method", [m for m in ("direct", "block_ldl", "cholmod")
                                    if m in backends.available_methods()])
def test_a_factorisation_is_reused_only_for_the_same_system(method):
    """Another right-hand side or other prescribed values on the same matrix
    and filters only back-substitute; new numbers in the same matrix object
    (the assembly reuses its storage) or another filter factorise again.
    Every answer is that of a fresh backend."""
    matrix, rhs, pattern, mesh = system(3)
    held = constraints_for(mesh)
    backend = make_solver(method, 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)

    def check(matrix, rhs, constraints, factorised):
        before = factorisation._FactoredSystem.factorisations
        result = backend.solve(matrix, rhs, constraints, None)
        assert factorisation._FactoredSystem.factorisations - before == factorised
        fresh = make_solver(method, 1e-8, 100)
        fresh.reset_topology(pattern, mesh.uv)
        np.testing.assert_allclose(result.dv, fresh.solve(matrix, rhs, constraints, None).dv,
                                   rtol=0, atol=1e-12 * np.abs(result.dv).max())

    check(matrix, rhs, held, 1)
    check(matrix, 2.0 * rhs + 1e-3, held, 0)                       # another load
    other = Constraints(held.indices, held.projectors, -held.prescribed)
    check(matrix, rhs, other, 0)                                   # other prescribed values
    turned = held.projectors.copy()
    turned[-1] = np.diag([1.0, 0.0, 1.0])
    check(matrix, rhs, Constraints(held.indices, turned, held.prescribed), 1)
    matrix.data *= 1.5                                             # same object, new numbers
    check(matrix, rhs, held, 1)
    backend.reset_topology(pattern, mesh.uv)                        # forgets across topologies
    check(matrix, rhs, held, 1)


@pytest.mark.parametrize("flat", [False, True], ids=["deformed", "flat"])
def test_multigrid_iterations_do_not_grow_with_the_mesh(flat):
    """Block-Jacobi PCG needs about twice the iterations per halving of the edge;
    the lattice V-cycle keeps them nearly constant (flat: the anisotropic start)."""
    counts = {}
    for level in (3, 5, 7):
        matrix, rhs, pattern, mesh = system(level, flat=flat)
        c = constraints_for(mesh)
        backend = make_solver("multigrid", 1e-6, 2000, geometry=(1.0, 1.0, 0.25))
        backend.reset_topology(pattern, mesh.uv)
        mg = backend.solve(matrix, rhs, c, None)
        jacobi = filtered_pcg(matrix, rhs, c, pattern.diagonal_blocks(matrix), tolerance=1e-6)
        assert mg.converged and jacobi.converged
        counts[level] = (mg.iterations, jacobi.iterations)
    assert counts[7][1] > 2.5 * counts[3][1]                 # block-Jacobi grows
    # Multigrid does not (level 3 has two levels only, its coarse one solved exactly).
    assert counts[7][0] <= max(counts[3][0], counts[5][0]) + 4, counts
    assert counts[7][0] < counts[7][1] / 10, counts


def test_lattice_prolongations_interpolate_linear_functions_exactly():
    for uv in (refine_uniform(base_mesh(1.0, 1.0, 4, 4), 5).uv,
               ClothSim.from_scene("hang_two_corners", ["cloth.level=6"]).rest_uv):
        for p in lattice_hierarchy(uv, 1.0, 1.0, 0.25):
            np.testing.assert_allclose(np.asarray(p.sum(axis=1)).ravel(), 1.0)  # partition of unity
            assert np.all(np.asarray(p.sum(axis=0)).ravel() > 0)                 # no empty node
            coarse_points = _coarse_points(p, uv)
            linear = coarse_points @ [0.3, -0.7] + 0.1
            np.testing.assert_allclose(p @ linear, uv @ [0.3, -0.7] + 0.1, atol=1e-12)
            uv = coarse_points


def _coarse_points(p, fine):
    """The coarse nodes' (u, v), recovered from the interpolation: exact when
    the nodes reproduce linear functions (least squares on a full-rank P)."""
    return np.linalg.lstsq(p.toarray(), fine, rcond=None)[0]


def _factorisation() -> str:
    """What ``auto`` factorises with: the block LDLᵀ (numba), else CHOLMOD if
    installed, else QDLDL, else PCG."""
    available = backends.available_methods()
    return next((m for m in ("block_ldl", "cholmod", "direct") if m in available), "pcg")


def test_auto_factorises_small_systems_and_uses_multigrid_on_large_ones():
    small = ClothSim.from_scene("hang_two_corners")                       # adaptive, ~200 particles
    # Uniform L8 (4,225 particles) is above every factorisation's uniform limit.
    large = ClothSim.from_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=8"])
    assert small.step().solver == _factorisation()
    assert large.step().solver == "multigrid"


def test_every_solve_of_a_step_is_counted_and_timed(monkeypatch):
    """Contact steps solve several times (friction rounds, re-solves): the
    statistics count each call to the backend and include the first attempt's
    time when a step is solved again."""
    sim = ClothSim.from_scene("grasp_lift", ["cloth.level=4"])
    calls = []
    backend = sim.solver.backend
    real = backend.solve

    def spy(*args):
        import time
        start = time.perf_counter()
        result = real(*args)
        calls.append(1e3 * (time.perf_counter() - start))
        return result
    monkeypatch.setattr(backend, "solve", spy)
    several = 0
    for _ in range(40):
        calls.clear()
        stats = sim.step()
        assert stats.solves == len(calls)
        assert stats.solve_ms >= sum(calls) * 0.999
        # A factorising backend: each solve factorises, or solves on the
        # trailing factorisation of its matrix (trailing_ldl.TrailingRounds,
        # worth it where the bend stencils' two-ring makes a factorisation dear).
        assert 1 <= stats.factorisations <= stats.solves
        several += stats.solves > 1
    assert several > 0


@pytest.mark.parametrize("method", ["pcg", "multigrid", "direct", "block_ldl", "cholmod", "superlu"])
def test_backends_agree_over_a_run_within_the_tolerance(method):
    """The same steps with each backend: trajectories within what the solver
    tolerance allows (1e-4 relative: sub-millimetre over a short swing)."""
    if method not in backends.available_methods():
        pytest.skip(f"{method} not installed")
    base = ["lod.enabled=false", "cloth.level=4"]
    ref = ClothSim.from_scene("hang_two_corners", base + ["solver.method=pcg", "solver.tolerance=1e-9"])
    sim = ClothSim.from_scene("hang_two_corners", base + [f"solver.method={method}"])
    for _ in range(30):
        ref.step()
        stats = sim.step()
        assert stats.converged and stats.solver == method
    assert np.abs(sim.positions - ref.positions).max() < 5e-4


def test_auto_factorises_larger_graded_meshes_than_uniform_ones():
    """``auto`` picks its factorisation up to that backend's uniform limit and
    up to its graded limit on a graded mesh (where the lattice V-cycle is
    weaker), multigrid above; and says which ran."""
    auto = make_solver("auto", 1e-6, 1000, geometry=(1.0, 1.0, 0.25))
    uniform_limit, graded_limit = auto.limits
    if _factorisation() == "pcg":
        pytest.skip("no factorisation installed")
    # Uniform levels: 4 -> 289, 5 -> 545, 6 -> 1,089, 7 -> 2,113, 8 -> 4,225 particles.
    counts = {level: (2 ** (level // 2 + 2) + 1) ** 2 if level % 2 == 0
              else (2 ** (level // 2 + 2) + 1) ** 2 + (2 ** (level // 2 + 2)) ** 2
              for level in range(4, 9)}
    small = max(level for level, c in counts.items() if c <= uniform_limit)
    middle = min(level for level, c in counts.items() if c > uniform_limit)
    assert counts[middle] <= graded_limit

    def topology(level):
        mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), level)
        assert mesh.vertex_count == counts[level]
        el = precompute(mesh)
        return SparsePattern(mesh.vertex_count, el.element_vertices), mesh.uv

    auto.reset_topology(*topology(small))
    assert auto.name == _factorisation()
    bigger = topology(middle)
    auto.reset_topology(*bigger)
    assert auto.name == "multigrid"
    auto.reset_topology(*bigger, graded=True)
    assert auto.name == _factorisation()


def test_cholmod_factorises_the_same_system_as_qdldl_and_refuses_politely_when_absent(
        monkeypatch):
    """The optional CHOLMOD backend gives QDLDL's solution (same projected
    system, pins exact) and keeps its analysis while the topology stands;
    without cvxopt, asking for it is a clear configuration error."""
    if "cholmod" in backends.available_methods() and "direct" in backends.available_methods():
        sim = ClothSim.from_scene("grasp_lift", ["cloth.level=3", "solver.method=cholmod"])
        systems = []
        backend = sim.solver.backend
        real = backend.solve
        monkeypatch.setattr(backend, "solve",
                            lambda *a: systems.append(a) or real(*a))
        for _ in range(20):
            sim.step()
        qdldl = make_solver("direct", 1e-8, 100)
        analyses = []
        cholmod = backends._cholmod_modules()[1]
        symbolic = cholmod.symbolic
        monkeypatch.setattr(cholmod, "symbolic", lambda *a, **k: analyses.append(1)
                            or symbolic(*a, **k))
        other = make_solver("cholmod", 1e-8, 100)
        qdldl.reset_topology(sim.solver._pattern, None)
        other.reset_topology(sim.solver._pattern, None)
        checked = 0
        for matrix, rhs, constraints, _ in systems[-6:]:
            if matrix.shape[0] != 3 * sim.solver._pattern.vertex_count:
                continue                   # an earlier topology
            a = qdldl.solve(matrix, rhs, constraints, None)
            b = other.solve(matrix, rhs, constraints, None)
            assert b.converged and b.residual < 1e-10
            np.testing.assert_allclose(b.dv, a.dv, rtol=0, atol=1e-10 * np.abs(a.dv).max())
            held = constraints.indices
            np.testing.assert_allclose(
                np.einsum("kab,kb->ka", np.eye(3) - constraints.projectors, b.dv[held]),
                np.einsum("kab,kb->ka", np.eye(3) - constraints.projectors,
                          constraints.prescribed), atol=1e-12)
            checked += 1
        assert checked >= 1 and analyses == [1]
    monkeypatch.setattr(backends, "_CHOLMOD", ())
    assert "cholmod" not in backends.available_methods()
    with pytest.raises(ValueError, match="cvxopt"):
        make_solver("cholmod", 1e-4, 100)
