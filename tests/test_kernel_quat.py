"""The shared quaternion kernel ``exp_mul``: short forms against the exact rotation."""

import numpy as np

from gnomon.kernels.quat import NEAR_UNIT, exp_mul
from gnomon.rotation import quat_from_rotvec, quat_mul


def _random_unit(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_short_forms_equal_the_exact_rotation_below_the_threshold():
    rng = np.random.default_rng(0)
    q = _random_unit(rng, 2000)
    r = rng.normal(size=(2000, 3))
    r *= rng.uniform(0.0, 0.0499, (2000, 1)) / np.linalg.norm(r, axis=1, keepdims=True)
    worst = 0.0
    for qi, ri in zip(q, r, strict=True):
        w, x, y, z, redo = exp_mul(*qi, *ri, False, True)
        assert not redo
        exact = quat_mul(qi, quat_from_rotvec(ri))
        worst = max(worst, np.abs(np.array([w, x, y, z]) - exact).max())
    assert worst < 1e-15  # rounding only (Taylor terms dropped are < 4e-18)


def test_large_rotations_and_non_unit_inputs_are_flagged_and_exact_with_trig():
    rng = np.random.default_rng(1)
    q = _random_unit(rng, 1)[0]
    big = np.array([0.3, -0.2, 0.1])
    assert exp_mul(*q, *big, False, True)[4]  # flagged for a redo
    w, x, y, z, _ = exp_mul(*q, *big, True, True)
    np.testing.assert_allclose([w, x, y, z], quat_mul(q, quat_from_rotvec(big)), atol=1e-15)
    q_far = q * (1.0 + 10 * NEAR_UNIT)
    small = np.array([1e-3, 2e-3, -1e-3])
    assert exp_mul(*q_far, *small, False, True)[4]
    w, x, y, z, _ = exp_mul(*q_far, *small, True, True)
    assert abs(np.linalg.norm([w, x, y, z]) - 1.0) < 1e-15
    np.testing.assert_allclose([w, x, y, z], quat_mul(q, quat_from_rotvec(small)), atol=1e-15)


def test_chain_products_equals_the_sequential_products():
    from gnomon.kernels.quat import chain_products

    rng = np.random.default_rng(2)
    steps = quat_from_rotvec(rng.normal(0.0, 0.3, (500, 3)))
    q0 = _random_unit(rng, 1)[0]
    out = np.empty((501, 4))
    chain_products(q0, steps, out)
    q = q0
    for k in range(500):
        q = quat_mul(q, steps[k])
        q = q / np.linalg.norm(q)
        np.testing.assert_allclose(out[k + 1], q, atol=1e-14)


def test_integrate_rates_follows_the_closed_form_of_a_constant_rate():
    from gnomon.kernels.quat import integrate_rates

    rng = np.random.default_rng(3)
    q0 = _random_unit(rng, 1)[0]
    for w in ([0.3, -0.2, 0.5], [20.0, -7.0, 11.0]):  # small steps (Taylor) and large (trig)
        w = np.array(w)
        dt, n = 0.01, 2000
        out = np.empty((n + 1, 4))
        integrate_rates(q0, np.tile(w, (n, 1)), dt, out)
        exact = quat_mul(q0, quat_from_rotvec(np.arange(n + 1)[:, None] * dt * w))
        sign = np.sign(np.sum(out * exact, axis=1))[:, None]
        assert np.abs(out - sign * exact).max() < 1e-12


# ---------------------------------------------------------------- the kernel toolbox
def _scipy(q):
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.roll(q, -1))


def test_toolbox_products_and_rotations_agree_with_scipy():
    from gnomon.kernels import quat as kq

    rng = np.random.default_rng(3)
    for _ in range(200):
        p, q = _random_unit(rng, 2)
        v = rng.normal(size=3)
        pq = np.array(kq.mul(*p, *q))
        ref = np.roll((_scipy(p) * _scipy(q)).as_quat(), 1)
        assert min(np.abs(pq - ref).max(), np.abs(pq + ref).max()) < 1e-15
        np.testing.assert_allclose(kq.mul_arr(p, q), pq, atol=0)
        np.testing.assert_allclose(kq.rotate(*q, *v), _scipy(q).apply(v), atol=1e-14)
        np.testing.assert_allclose(kq.rotate_inv(*q, *v), _scipy(q).inv().apply(v), atol=1e-14)
        np.testing.assert_allclose(kq.rotate_arr(q, v), kq.rotate(*q, *v), atol=0)
        np.testing.assert_allclose(kq.rotate_inv_arr(q, v), kq.rotate_inv(*q, *v), atol=0)
        np.testing.assert_allclose(np.reshape(kq.dcm(*q), (3, 3)), _scipy(q).as_matrix(),
                                   atol=1e-15)
        n = np.array(kq.normalised(*(3.0 * q)))
        np.testing.assert_allclose(n, q, atol=1e-15)


def test_toolbox_exponential_agrees_with_scipy_at_small_and_large_angles():
    from scipy.spatial.transform import Rotation

    from gnomon.kernels.quat import exp

    rng = np.random.default_rng(4)
    for angle in (0.0, 1e-9, 1e-4, 0.0499, 0.05, 0.3, 3.0):
        axis = rng.normal(size=3)
        r = angle * axis / np.linalg.norm(axis)
        ref = np.roll(Rotation.from_rotvec(r).as_quat(), 1)
        np.testing.assert_allclose(exp(*r), ref, atol=2e-16)


def test_linalg_toolbox_agrees_with_numpy():
    from gnomon.kernels import linalg as kl

    rng = np.random.default_rng(5)
    for _ in range(100):
        a, b = rng.normal(size=(2, 3))
        np.testing.assert_allclose(kl.cross(*a, *b), np.cross(a, b), atol=1e-15)
        np.testing.assert_allclose(kl.cross_arr(a, b), np.cross(a, b), atol=1e-15)
        np.testing.assert_allclose(kl.skew_arr(a) @ b, np.cross(a, b), atol=1e-15)
        m = rng.normal(size=(3, 3)) + 3.0 * np.eye(3)
        det, *inv = kl.inv3(*m.ravel())
        assert abs(det - np.linalg.det(m)) < 1e-12 * abs(det)
        np.testing.assert_allclose(np.reshape(inv, (3, 3)), np.linalg.inv(m), rtol=1e-12,
                                   atol=1e-14)
        out = np.empty((3, 3))
        assert kl.inv3_into(m, out) == det
        np.testing.assert_allclose(out, np.linalg.inv(m), rtol=1e-12, atol=1e-14)
        flat = np.empty(9)
        kl.inv3_into(m.ravel(), flat)
        np.testing.assert_allclose(flat, out.ravel(), atol=0)
        P = rng.normal(size=(6, 6))
        S = P.copy()
        kl.symmetrise(S)
        np.testing.assert_allclose(S, 0.5 * (P + P.T), atol=0)
    assert kl.clip(3.0, 2.0) == 2.0 and kl.clip(-3.0, 2.0) == -2.0 and kl.clip(1.5, 2.0) == 1.5


def test_mat3_tuple_helpers_agree_with_numpy():
    from gnomon.kernels import linalg as kl

    rng = np.random.default_rng(6)
    for _ in range(50):
        a, b = rng.normal(size=(2, 3, 3))
        v = rng.normal(size=3)
        ta, tb = tuple(a.ravel()), tuple(b.ravel())
        np.testing.assert_array_equal(kl.mat3_load(a), ta)
        out = np.empty((3, 3))
        kl.mat3_store(out, ta)
        np.testing.assert_array_equal(out, a)
        np.testing.assert_allclose(kl.mat3_vec(ta, *v), a @ v, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(kl.mat3_tvec(ta, *v), a.T @ v, rtol=1e-14, atol=1e-14)
        for f, ref in ((kl.mat3_mul, a @ b), (kl.mat3_mul_bt, a @ b.T), (kl.mat3_tmul, a.T @ b)):
            np.testing.assert_allclose(np.reshape(f(ta, tb), (3, 3)), ref, rtol=1e-14,
                                       atol=1e-14)


def test_skew_into_writes_a_scaled_cross_product_block():
    from gnomon.kernels import linalg as kl

    rng = np.random.default_rng(6)
    v, b = rng.normal(size=(2, 3))
    out = np.full((6, 3), np.nan)
    kl.skew_into(out, 3, 2.0, *v)
    np.testing.assert_allclose(out[3:] @ b, 2.0 * np.cross(v, b), atol=1e-15)
    np.testing.assert_array_equal(out[3:], 2.0 * kl.skew_arr(v))
    assert np.all(np.isnan(out[:3]))  # the other rows are left alone


def test_quadratic_rotation_and_its_jacobian_hold_off_the_unit_sphere():
    from gnomon.kernels import quat as kq

    rng = np.random.default_rng(6)
    for _ in range(100):
        q = rng.normal(size=4)  # any length: the quadratic form is |q|² times the rotation
        v = rng.normal(size=3)
        n2 = q @ q
        np.testing.assert_allclose(kq.rotate_quadratic(*q, *v), n2 * _scipy(q).apply(v),
                                   rtol=1e-13, atol=1e-13 * n2)
        u = q / np.sqrt(n2)
        np.testing.assert_allclose(kq.rotate_quadratic(*u, *v), kq.rotate(*u, *v), atol=1e-14)
        A = np.empty((3, 4))
        kq.rotate_quadratic_jac(*q, *v, A)
        eps = 1e-6
        for k in range(4):
            d = np.zeros(4)
            d[k] = eps
            fd = (np.array(kq.rotate_quadratic(*(q + d), *v))
                  - np.array(kq.rotate_quadratic(*(q - d), *v))) / (2 * eps)
            np.testing.assert_allclose(A[:, k], fd, atol=1e-8)


def test_up_row_and_product_matrices_agree_with_the_rotation_and_product():
    """``up_row`` is R(q)ᵀ e_z; ``xi(q) v`` and ``omega(v) q`` equal ``q ⊗ [0, v]``."""
    from gnomon.kernels.quat import omega, up_row, xi
    from gnomon.rotation import quat_rotate

    rng = np.random.default_rng(5)
    for q in _random_unit(rng, 50):
        up = quat_rotate(np.array([q[0], -q[1], -q[2], -q[3]]), np.array([0.0, 0.0, 1.0]))
        np.testing.assert_allclose(up_row(*q), up, atol=1e-15)
        v = rng.normal(size=3)
        prod = quat_mul(q, np.concatenate([[0.0], v]))
        np.testing.assert_allclose(xi(q) @ v, prod, atol=1e-14)
        np.testing.assert_allclose(omega(v) @ q, prod, atol=1e-14)
