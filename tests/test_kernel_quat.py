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
