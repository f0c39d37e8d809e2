"""Contact rounds on one factorisation with the constrained particles last
(sim/solve/trailing_ldl.py): the same solutions as refactorising, an exact Schur
complement, and a choice that depends on counts only."""

import numpy as np
import pytest

from cloth_lod_ros.sim.solve import backends
from cloth_lod_ros.sim.solve import factorisation
from cloth_lod_ros.sim.solve.constraints import Constraints
from cloth_lod_ros.sim.solve.backends import make_solver

trailing_ldl = pytest.importorskip("cloth_lod_ros.sim.solve.trailing_ldl")
block_ldl = pytest.importorskip("cloth_lod_ros.sim.solve.block_ldl")

from test_backends import system  # noqa: E402

NZ = np.array([0.0, 0.0, 1.0])
SLIDING = np.eye(3) - np.outer(NZ, NZ)


def contacts(mesh, seed, released=0.0, sliding=0.0):
    """Two held corners and the bottom row in contact: some of its particles
    released (absent), some sliding (normal held), the rest sticking."""
    rng = np.random.default_rng(seed)
    corners = np.flatnonzero(np.isclose(mesh.uv[:, 1], 1.0) & np.isin(mesh.uv[:, 0], [0.0, 1.0]))
    row = np.flatnonzero(np.isclose(mesh.uv[:, 1], 0.0))
    row = row[rng.random(len(row)) >= released]
    slides = rng.random(len(row)) < sliding
    projectors = np.concatenate([np.zeros((len(corners), 3, 3)),
                                 np.where(slides[:, None, None], SLIDING, 0.0)])
    prescribed = rng.normal(scale=0.01, size=(len(corners) + len(row), 3))
    return Constraints(np.concatenate([corners, row]), projectors, prescribed), \
        np.concatenate([corners, row])


def trailing_factor(matrix, pattern, trailing):
    n = matrix.shape[0] // 3
    indptr, indices = matrix.indptr.astype(np.int64), matrix.indices.astype(np.int64)
    order = backends.particle_ordering(indptr, indices, n)
    factor = trailing_ldl.TrailingFactor(indptr, indices, order, np.sort(trailing),
                                         block_ldl.symbolic, pattern.diagonal_block)
    assert factor.refactor(matrix, np.ascontiguousarray(matrix.data))
    return factor


def test_the_trailing_block_is_the_schur_complement_of_the_rest():
    matrix, rhs, pattern, mesh = system(3, seed=4)
    _, trailing = contacts(mesh, 0)
    factor = trailing_factor(matrix, pattern, trailing)
    dense = matrix.toarray()
    c = np.sort(trailing)
    rest = np.setdiff1d(np.arange(mesh.vertex_count), c)
    dofs = lambda p: (3 * p[:, None] + np.arange(3)).ravel()      # noqa: E731
    a_cc = dense[np.ix_(dofs(c), dofs(c))]
    a_ci = dense[np.ix_(dofs(c), dofs(rest))]
    a_ii = dense[np.ix_(dofs(rest), dofs(rest))]
    schur = a_cc - a_ci @ np.linalg.solve(a_ii, a_ci.T)
    got = factor.schur.transpose(0, 2, 1, 3).reshape(schur.shape)
    np.testing.assert_allclose(got, schur, atol=1e-10 * np.abs(schur).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_round_equals_refactorising(seed):
    """The rounds of a contact solve: all held, some released, some sliding;
    each solved on the one trailing factorisation and by a fresh one."""
    matrix, rhs, pattern, mesh = system(4, seed=seed)
    first, trailing = contacts(mesh, seed)
    factor = trailing_factor(matrix, pattern, trailing)
    from cloth_lod_ros.sim.solve import projection_kernels as projection
    rounds = [first, contacts(mesh, seed, released=0.3)[0],
              contacts(mesh, seed, released=0.3, sliding=0.5)[0],
              contacts(mesh, seed, released=0.3, sliding=1.0)[0]]
    for constraints in rounds:
        reference = make_solver("block_ldl", 1e-8, 100)
        reference.trailing_rounds = False
        reference.reset_topology(pattern, mesh.uv)
        want = reference.solve(matrix, rhs, constraints, None)
        state, filters = projection.particle_filters(matrix, rhs, constraints)
        assert factor.covers(state)
        status, dv, residual = factor.round(matrix, rhs, constraints)
        assert status == 0 and residual < 1e-10
        np.testing.assert_allclose(dv, want.dv, atol=1e-10 * np.abs(want.dv).max())
        # The same residual as the reference computes for that Δv.
        check = backends._factorised_result(matrix, rhs, constraints,
                                            dv, np.zeros_like(dv), 1e-8)
        assert check.residual < 1e-10
        held = constraints.indices[~np.any(constraints.projectors != 0.0, axis=(1, 2))]
        last = {int(p): k for k, p in enumerate(constraints.indices)}
        for p in held:          # held particles land exactly on their prescribed change
            np.testing.assert_array_equal(dv[p], constraints.prescribed[last[int(p)]])
    # A constraint outside the trailing block is refused, not solved.
    outside = Constraints(np.array([mesh.vertex_count // 2]), np.zeros((1, 3, 3)),
                          np.zeros((1, 3)))
    assert not factor.member[mesh.vertex_count // 2]
    assert factor.round(matrix, rhs, outside)[0] == 1


def test_the_backend_serves_rounds_on_one_factorisation_and_falls_back_outside_it():
    matrix, rhs, pattern, mesh = system(5, seed=3)
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    reference = make_solver("block_ldl", 1e-8, 100)
    reference.trailing_rounds = False
    reference.reset_topology(pattern, mesh.uv)
    rounds = [contacts(mesh, 5)[0], contacts(mesh, 5, released=0.3)[0],
              contacts(mesh, 5, released=0.3, sliding=0.5)[0],
              contacts(mesh, 5, released=0.3, sliding=1.0)[0]]
    factorised = []
    for k in range(5):                                   # five linearisations
        a = matrix * (1.0 + 0.01 * k)
        before = factorisation.factorisation_count()
        for constraints in rounds:
            got = backend.solve(a, rhs, constraints, None)
            want = reference.solve(a, rhs, constraints, None)
            np.testing.assert_allclose(got.dv, want.dv, atol=1e-9 * np.abs(want.dv).max())
        # A constraint outside the trailing block: the ordinary factorisation.
        extra = Constraints(np.array([mesh.vertex_count // 2]), np.zeros((1, 3, 3)),
                            np.zeros((1, 3)))
        outside = rounds[-1]
        outside = Constraints(np.concatenate([outside.indices, extra.indices]),
                              np.concatenate([outside.projectors, extra.projectors]),
                              np.concatenate([outside.prescribed, extra.prescribed]))
        got = backend.solve(a, rhs, outside, None)
        want = reference.solve(a, rhs, outside, None)
        np.testing.assert_allclose(got.dv, want.dv, atol=1e-9 * np.abs(want.dv).max())
        factorised.append(factorisation.factorisation_count() - before
                          - len(rounds) - 1)   # the reference's own
    # Once it has seen matrices solved four times, one factorisation serves
    # the four rounds (and one more the outsider).
    assert factorised[0] == 5
    assert factorised[-1] == 2


def test_the_choice_depends_on_counts_only_so_runs_repeat_bit_for_bit():
    matrix, rhs, pattern, mesh = system(5, seed=6)
    results = []
    for _ in range(2):
        backend = make_solver("block_ldl", 1e-8, 100)
        backend.reset_topology(pattern, mesh.uv)
        out = []
        for k in range(4):
            a = matrix * (1.0 + 0.01 * k)
            for constraints in (contacts(mesh, 7)[0],
                                contacts(mesh, 7, released=0.3, sliding=0.5)[0]):
                out.append(backend.solve(a, rhs, constraints, None).dv)
        results.append(np.stack(out))
    np.testing.assert_array_equal(results[0], results[1])


def test_small_systems_and_single_solves_keep_the_ordinary_factorisation():
    matrix, rhs, pattern, mesh = system(3, seed=1)        # 81 particles: small
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    for k in range(4):
        a = matrix * (1.0 + 0.01 * k)
        for constraints in (contacts(mesh, 1)[0], contacts(mesh, 1, sliding=1.0)[0]):
            backend.solve(a, rhs, constraints, None)
    assert backend._trailing.factor is None


def test_a_topology_change_keeps_the_rounds_learnt_and_refactorises():
    matrix, rhs, pattern, mesh = system(5, seed=3)
    backend = make_solver("block_ldl", 1e-8, 100)
    backend.reset_topology(pattern, mesh.uv)
    rounds = [contacts(mesh, 5)[0], contacts(mesh, 5, released=0.3)[0],
              contacts(mesh, 5, released=0.3, sliding=1.0)[0]]
    for k in range(4):
        a = matrix * (1.0 + 0.01 * k)       # one linearisation: one matrix object
        for constraints in rounds:
            backend.solve(a, rhs, constraints, None)
    backend.reset_topology(pattern, mesh.uv)        # the particles may be renumbered
    assert backend._trailing.factor is None
    before = factorisation.factorisation_count()
    a = matrix * 1.5
    for constraints in rounds:
        got = backend.solve(a, rhs, constraints, None)
        assert got.converged and got.residual < 1e-10
    assert factorisation.factorisation_count() - before == 1
