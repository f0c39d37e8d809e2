"""Baraff–Witkin conditions: resolution independence, exact gradients, kept Jacobians, SPD."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.physics.forces import evaluate
from cloth_lod_ros.sim.physics.hinges import hinge_angles
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
from cloth_lod_ros.sim.solve.pattern import SparsePattern


def material(ks=100.0, ksh=20.0, kb=1e-2, bs=0.0, bsh=0.0, bb=0.0):
    return SimpleNamespace(stretch_stiffness=ks, shear_stiffness=ksh, bend_stiffness=kb,
                           stretch_damping=bs, shear_damping=bsh, bend_damping=bb)


def mesh_at(level, width=1.0, height=1.0, blocks=(4, 4)):
    return refine_uniform(base_mesh(width, height, *blocks), level)


def flat(mesh):
    return np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])


def total_energy(elements, mat, x):
    ev = evaluate(elements, mat, x, np.zeros_like(x), with_blocks=False)
    return ev.stretch_energy + ev.shear_energy + ev.bend_energy


def dense_blocks(elements, mat, x, v, stiffness_weight, damping_weight):
    """Assembled −(w_K ∂f/∂x + w_D ∂f/∂v) as a dense matrix (no mass)."""
    ev = evaluate(elements, mat, x, v, stiffness_weight, damping_weight)
    pattern = SparsePattern(elements.vertex_count,
                            elements.element_vertices)
    return pattern.assemble(ev.blocks,
                            np.zeros(elements.vertex_count)).toarray()


def random_config(mesh, seed, scale=0.05, stretch=1.0):
    rng = np.random.default_rng(seed)
    return stretch * flat(mesh) + rng.normal(scale=scale, size=(mesh.vertex_count, 3))


# -- resolution independence ----------------------------------------------------

@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-0.6, 0.6), min_size=6, max_size=6))
def test_uniform_strain_gives_same_energy_at_every_level(entries):
    """A uniform deformation gradient gives identical total energy at all levels."""
    F = np.eye(3, 2) + np.array(entries).reshape(3, 2)
    if np.linalg.matrix_rank(F) < 2:
        return
    mat = material()
    energies = []
    for level in range(0, 7):
        m = mesh_at(level)
        el = precompute(m)
        x = m.uv @ F.T
        ev = evaluate(el, mat, x, np.zeros_like(x), with_blocks=False)
        energies.append((ev.stretch_energy, ev.shear_energy, ev.bend_energy))
    energies = np.array(energies)
    fu, fv = F[:, 0], F[:, 1]
    area = 1.0
    expected_stretch = 0.5 * mat.stretch_stiffness * area * (
        (np.linalg.norm(fu) - 1) ** 2 + (np.linalg.norm(fv) - 1) ** 2)
    expected_shear = 0.5 * mat.shear_stiffness * area * (fu @ fv) ** 2
    np.testing.assert_allclose(energies[:, 0], expected_stretch, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(energies[:, 1], expected_shear, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(energies[:, 2], 0.0, atol=1e-12)   # planar: no bending


@pytest.mark.parametrize("axis_angle", [0.0, np.pi / 4, np.pi / 2, 0.3])
def test_cylinder_bending_energy_converges_to_continuum(axis_angle):
    """k_b/2 · R⁻² · area for a cylinder, whatever its direction in (u, v)."""
    radius, kb = 0.4, 1e-3
    mat = material(ks=0.0, ksh=0.0, kb=kb)
    d = np.array([np.cos(axis_angle), np.sin(axis_angle)])
    errors = []
    for level in range(2, 9):
        m = mesh_at(level)
        s, p = m.uv @ d, m.uv @ np.array([-d[1], d[0]])
        x = np.column_stack([radius * np.sin(s / radius), p, radius * (1 - np.cos(s / radius))])
        energy = evaluate(precompute(m), mat, x, np.zeros_like(x), with_blocks=False).bend_energy
        errors.append(abs(energy / (0.5 * kb / radius**2 * 1.0) - 1.0))
    # Every stencil is exact on quadratics: the error is the cylinder's
    # departure from its osculating quadratic, O(h²) (4x per two levels).
    assert errors[-1] < 1e-3
    assert errors[-1] < errors[0] / 30
    assert all(b <= a + 1e-3 for a, b in zip(errors[::2], errors[2::2]))


def test_hinge_weights_are_one_on_a_4_8_mesh():
    for level in range(0, 6):
        np.testing.assert_allclose(precompute(mesh_at(level)).hinge_weight, 1.0, rtol=1e-12)


# -- exact gradients -------------------------------------------------------------

@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.8, 1.3))
def test_forces_are_negative_energy_gradient(seed, stretch):
    m = mesh_at(1, blocks=(2, 2))
    el, mat = precompute(m), material()
    x = random_config(m, seed, scale=0.08, stretch=stretch)
    force = evaluate(el, mat, x, np.zeros_like(x), with_blocks=False).force
    eps = 1e-6
    grad = np.zeros_like(x)
    for i in range(len(x)):
        for d in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, d] += eps
            xm[i, d] -= eps
            grad[i, d] = (total_energy(el, mat, xp) - total_energy(el, mat, xm)) / (2 * eps)
    np.testing.assert_allclose(force, -grad, atol=1e-6 * np.abs(grad).max())


def test_hinge_angle_gradient_matches_finite_differences():
    m = mesh_at(2, blocks=(2, 2))
    hv = precompute(m).hinge_vertices
    x = random_config(m, 3, scale=0.1)
    theta, grad = hinge_angles(x, hv, with_gradient=True)
    assert np.abs(theta).max() > 0.1          # genuinely bent
    eps = 1e-7
    # Finite differences hinge by hinge: give every hinge its own copy of its
    # four points so moving slot k moves only that hinge's corner.
    pts = x[hv]                                            # (h, 4, 3)
    local = np.arange(4 * len(hv)).reshape(-1, 4)
    for k in range(4):
        for d in range(3):
            p_plus, p_minus = pts.copy(), pts.copy()
            p_plus[:, k, d] += eps
            p_minus[:, k, d] -= eps
            fd = (hinge_angles(p_plus.reshape(-1, 3), local)
                  - hinge_angles(p_minus.reshape(-1, 3), local)) / (2 * eps)
            np.testing.assert_allclose(grad[:, k, d], fd, atol=1e-6)


def test_internal_forces_have_no_net_force_or_torque():
    m = mesh_at(2)
    el = precompute(m)
    x = random_config(m, 7, scale=0.1)
    v = np.random.default_rng(8).normal(size=x.shape)
    f = evaluate(el, material(bs=0.05, bsh=0.05, bb=0.2), x, v, with_blocks=False).force
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-10 * np.abs(f).max())
    np.testing.assert_allclose(np.cross(x, f).sum(axis=0), 0.0, atol=1e-9 * np.abs(f).max())


# -- Jacobians --------------------------------------------------------------------

def fd_jacobian(fun, y, eps=1e-6):
    cols = []
    flat_y = y.ravel()
    for k in range(flat_y.size):
        yp, ym = flat_y.copy(), flat_y.copy()
        yp[k] += eps
        ym[k] -= eps
        cols.append((fun(yp.reshape(y.shape)) - fun(ym.reshape(y.shape))).ravel() / (2 * eps))
    return np.array(cols).T


def test_stretch_jacobian_is_exact_in_tension():
    """Stretch keeps its full Jacobian while every triangle is stretched."""
    m = mesh_at(1, blocks=(2, 2))
    el, mat = precompute(m), material(ksh=0.0, kb=0.0)
    x = random_config(m, 11, scale=0.01, stretch=1.2)
    ev = evaluate(el, mat, x, np.zeros_like(x), with_blocks=False)
    assert ev.max_strain > 0.1
    fd = fd_jacobian(lambda y: evaluate(el, mat, y, np.zeros_like(y), with_blocks=False).force, x)
    kept = -dense_blocks(el, mat, x, np.zeros_like(x), 1.0, 0.0)
    np.testing.assert_allclose(kept, fd, atol=1e-5 * np.abs(fd).max())


def test_shear_jacobian_is_gauss_newton_plus_the_dropped_term():
    """FD Jacobian − kept = −k C ∇²C with ∇²C = √A (a_i b_j + b_i a_j) I (dropped)."""
    m = mesh_at(1, blocks=(2, 2))
    el, mat = precompute(m), material(ks=0.0, kb=0.0)
    x = random_config(m, 12, scale=0.05)
    fd = fd_jacobian(lambda y: evaluate(el, mat, y, np.zeros_like(y), with_blocks=False).force, x)
    kept = -dense_blocks(el, mat, x, np.zeros_like(x), 1.0, 0.0)
    dropped = np.zeros_like(fd)
    for t, tri in enumerate(el.triangles):        # reference in plain loops (test only)
        wu = el.coef_u[t] @ x[tri]
        wv = el.coef_v[t] @ x[tri]
        c = np.sqrt(el.area[t]) * wu @ wv
        for i in range(3):
            for j in range(3):
                hess = np.sqrt(el.area[t]) * (el.coef_u[t, i] * el.coef_v[t, j]
                                              + el.coef_v[t, i] * el.coef_u[t, j])
                dropped[3 * tri[i]:3 * tri[i] + 3, 3 * tri[j]:3 * tri[j] + 3] += \
                    -mat.shear_stiffness * c * hess * np.eye(3)
    assert np.abs(dropped).max() > 1e-3 * np.abs(fd).max()     # the term is not trivial
    np.testing.assert_allclose(kept + dropped, fd, atol=1e-5 * np.abs(fd).max())


def test_bend_jacobian_is_exact_in_every_state():
    """The bend energy is quadratic in x (physics.bending): its kept Jacobian
    is the whole one, flat, bent or rotated."""
    m = mesh_at(2, blocks=(2, 2))
    el, mat = precompute(m), material(ks=0.0, ksh=0.0, kb=1.0)

    def bend_force(y):
        return evaluate(el, mat, y, np.zeros_like(y), with_blocks=False).force

    rng = np.random.default_rng(5)
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    for x in (flat(m) @ rot.T * 1.1, flat(m) + 0.3 * random_config(m, 9, scale=1.0, stretch=0.0)):
        fd = fd_jacobian(bend_force, x)
        kept = -dense_blocks(el, mat, x, np.zeros_like(x), 1.0, 0.0)
        assert np.abs(fd).max() > 0
        np.testing.assert_allclose(kept, fd, atol=1e-6 * np.abs(fd).max())


def test_damping_jacobian_is_exact():
    m = mesh_at(1, blocks=(2, 2))
    el = precompute(m)
    mat = material(bs=0.03, bsh=0.05, bb=0.5, kb=1e-1)
    x = random_config(m, 13, scale=0.08)
    v = np.random.default_rng(14).normal(size=x.shape)
    fd = fd_jacobian(lambda w: evaluate(el, mat, x, w, with_blocks=False).force, v)
    kept = -dense_blocks(el, mat, x, v, 0.0, 1.0)
    np.testing.assert_allclose(kept, fd, atol=1e-6 * np.abs(fd).max())


def test_stiffness_times_velocity_matches_assembled_jacobian():
    m = mesh_at(2, blocks=(2, 2))
    el, mat = precompute(m), material(bs=0.01)
    x = random_config(m, 15, scale=0.05, stretch=1.05)
    v = np.random.default_rng(16).normal(size=x.shape)
    ev = evaluate(el, mat, x, v, with_blocks=False)
    kept = -dense_blocks(el, mat, x, v, 1.0, 0.0)
    np.testing.assert_allclose(ev.stiffness_times_velocity.ravel(), kept @ v.ravel(),
                               atol=1e-10 * np.abs(kept).max())


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.5, 1.5), st.floats(0.0, 0.3))
def test_system_matrix_is_symmetric_positive_definite(seed, stretch, noise):
    """M − h∂f/∂v − h²∂f/∂x is SPD even with compressed, sheared and folded triangles."""
    m = mesh_at(2, blocks=(2, 2))
    el = precompute(m)
    mat = material(ks=1e4, ksh=1e3, kb=1.0, bs=0.01, bsh=0.01, bb=0.1)
    x = random_config(m, seed, scale=noise, stretch=stretch)
    v = np.random.default_rng(seed + 1).normal(size=x.shape)
    h = 1.0 / 30
    blocks = dense_blocks(el, mat, x, v, h * h, h)
    mass = 1e-3
    system = blocks + mass * np.eye(len(blocks))
    # Symmetric up to the summation order of the assembly.
    np.testing.assert_allclose(system, system.T, rtol=0, atol=1e-14 * np.abs(system).max())
    assert np.linalg.eigvalsh(system).min() >= mass * (1 - 1e-9)


def test_derived_rest_data_follows_each_topology_and_blocks_match_outer_products():
    """Elements' component-major copies (used by evaluate's per-topology fast
    paths) are rebuilt with every topology, and the membrane blocks built from
    them equal the plain sum of outer products Σ_pq c_p[i] c_q[j] Q_pq."""
    from cloth_lod_ros.sim.physics.forces import _membrane_blocks
    rng = np.random.default_rng(5)
    for mesh in (mesh_at(0, blocks=(2, 2)), mesh_at(2, blocks=(2, 2)), mesh_at(1, 1.5, 1.0, (3, 2))):
        el = precompute(mesh)
        for derived, source in ((el.coef_u_cm, el.coef_u), (el.coef_v_cm, el.coef_v),
                                (el.triangles_cm, el.triangles)):
            assert derived.flags.c_contiguous
            np.testing.assert_array_equal(derived, source.T)
        t = len(el.triangles)
        along, across, shear = rng.uniform(0.5, 2.0, (3, t))
        du, dv, wu, wv = rng.normal(size=(4, 3, t))
        tu, tv = rng.uniform(0, 1, (2, t))
        air = rng.normal(size=(3, 3, t))
        blocks = _membrane_blocks(el, along, across, shear, (du, tu, wv), (dv, tv, wu), air)
        eye = np.eye(3)
        q = {}
        for p, (d, ten, other) in enumerate(((du, tu, wv), (dv, tv, wu))):
            q[p, p] = np.einsum("t,at,bt->tab", along - across * ten, d, d) \
                + np.einsum("t,ab->tab", across * ten, eye) \
                + np.einsum("t,at,bt->tab", shear, other, other)
        q[0, 1] = np.einsum("t,at,bt->tab", shear, wv, wu)
        q[1, 0] = q[0, 1].transpose(0, 2, 1)
        c = (el.coef_u, el.coef_v)
        expect = sum(np.einsum("ti,tj,tab->tiajb", c[p], c[r], q[p, r])
                     for p in range(2) for r in range(2)) + air.transpose(2, 0, 1)[:, None, :, None, :]
        np.testing.assert_allclose(blocks, expect, rtol=1e-12, atol=1e-12)
