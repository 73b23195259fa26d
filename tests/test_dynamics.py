"""Attitude dynamics and sensor models: invariants, closed forms, compiled vs readable kernel,
sensor statistics (Allan deviation)."""

from __future__ import annotations

import numpy as np
import pytest

from gnomon.dynamics import check_inertia, integrate_attitude
from gnomon.environment.orbit import R_EARTH, KeplerOrbit
from gnomon.errors import InputError
from gnomon.frames import quat_io, w_io_o
from gnomon.rotation import (
    dcm_from_quat,
    euler_from_quat,
    quat_conj,
    quat_from_euler,
    quat_mul,
    quat_rotate,
)
from gnomon.sensors import allan_deviation, gyro_model, magnetometer_model, sun_sensor_model

J_FULL = np.array([[0.55, 0.01, -0.005], [0.01, 0.62, 0.008], [-0.005, 0.008, 0.40]])


def _env(n, dt=1.0, alt=600e3, field_T=None):
    orb = KeplerOrbit(R_EARTH + alt, 0.0, 1.7, 0.3, 0.0, 0.0, "2026-01-01T00:00:00Z", j2=False)
    th = np.arange(2 * n - 1) * dt / 2
    r, v = orb.propagate(th)
    b = np.zeros_like(r) if field_T is None else np.broadcast_to(field_T, r.shape).copy()
    return orb, r, b, quat_io(r[::2], v[::2]), w_io_o(r[::2], v[::2])


def test_torque_free_rigid_body_conserves_momentum_and_energy():
    n = 5900
    _, r, b, q_io, wio = _env(n)
    w0 = np.array([0.01, -0.02, 0.015])
    h = integrate_attitude([1.0, 0, 0, 0], w0, np.zeros(3), J_FULL, 1.0, r, b, q_io, wio,
                           mode="none", gravity_gradient=False)
    L_i = np.einsum("nij,nj->ni", dcm_from_quat(h.q_ib), h.w_ib_b @ J_FULL.T)
    E = 0.5 * np.sum(h.w_ib_b * (h.w_ib_b @ J_FULL.T), axis=1)
    assert np.max(np.linalg.norm(L_i - L_i[0], axis=1)) / np.linalg.norm(L_i[0]) < 1e-9
    assert np.max(np.abs(E - E[0])) / E[0] < 1e-9
    np.testing.assert_allclose(np.linalg.norm(h.q_ib, axis=1), 1.0, atol=1e-14)
    # the body really tumbles (non-trivial test): w changes direction in b
    assert np.max(np.linalg.norm(h.w_ib_b - w0, axis=1)) > 0.005


def test_momentum_exchange_with_wheels_conserves_total_momentum():
    n = 600
    _, r, b, q_io, wio = _env(n)
    h = integrate_attitude([1.0, 0, 0, 0], [0.0, 0.0, 0.0], np.zeros(3), J_FULL, 1.0, r, b,
                           q_io, wio, mode="wheel_pd", kp=1e-4, kd=1.2e-2,
                           max_wheel_torque=2e-3, max_wheel_momentum=0.05,
                           gravity_gradient=False)
    # no external torque (field zero, no gravity gradient): J w + h is constant in i
    L_i = np.einsum("nij,nj->ni", dcm_from_quat(h.q_ib), h.w_ib_b @ J_FULL.T + h.h_b)
    assert np.max(np.abs(h.h_b)) > 1e-3                   # the wheels did work
    assert np.max(np.abs(h.hdot_b)) <= 2e-3 + 1e-15        # torque limit
    assert np.max(np.linalg.norm(L_i - L_i[0], axis=1)) < 1e-7


def test_gravity_gradient_pitch_libration_frequency():
    # small pitch oscillation about the orbital frame: w_p = n sqrt(3 (Ix - Iz) / Iy)
    J = np.diag([0.55, 0.62, 0.40])
    n_steps = 30000
    orb, r, b, q_io, wio = _env(n_steps)
    q_ob0 = quat_from_euler([0.0, 2.0 * np.pi / 180, 0.0])
    q_ib0 = quat_mul(q_io[0], q_ob0)
    w_ib0 = quat_rotate(quat_conj(q_ob0), wio[0])
    h = integrate_attitude(q_ib0, w_ib0, np.zeros(3), J, 1.0, r, b, q_io, wio, mode="none")
    pitch = euler_from_quat(quat_mul(quat_conj(q_io), h.q_ib))[:, 1]
    zc = np.flatnonzero(np.diff(np.sign(pitch)) > 0)
    period = np.mean(np.diff(zc))
    expected = 2 * np.pi / (orb.n * np.sqrt(3 * (0.55 - 0.40) / 0.62))
    assert period == pytest.approx(expected, rel=0.01)


def test_compiled_kernel_matches_readable_version():
    n = 40
    _, r, _, q_io, wio = _env(n)
    b = np.tile([2e-5, -1e-5, 3e-5], (len(r), 1)) + 1e-6 * np.sin(np.arange(len(r)))[:, None]
    kw = dict(mode="bdot_then_pd", k_bdot=1e4, kp=1e-5, kd=2e-3, switch_rate=0.01,
              max_dipole=0.3, residual_dipole=(0.01, 0.0, -0.02))
    q0 = quat_from_euler([0.1, -0.2, 0.3])
    fast = integrate_attitude(q0, [0.02, 0.01, -0.03], [0, 0.01, 0], J_FULL, 1.0, r, b, q_io,
                              wio, **kw)
    slow = integrate_attitude(q0, [0.02, 0.01, -0.03], [0, 0.01, 0], J_FULL, 1.0, r, b, q_io,
                              wio, compiled=False, **kw)
    for a, c in zip(fast.__dict__.values(), slow.__dict__.values(), strict=True):
        np.testing.assert_allclose(a, c, rtol=1e-12, atol=1e-18)


def test_bdot_detumbles():
    from gnomon.environment.magnetic import field_i_nT, field_model

    n = 11800                                   # two orbits
    orb, r, _, q_io, wio = _env(n)
    th = np.arange(len(r)) * 0.5
    b = field_i_nT(field_model("igrf"), orb.epoch, th, r) * 1e-9
    w0 = np.radians([3.0, -2.0, 2.5])
    h = integrate_attitude([1.0, 0, 0, 0], w0, np.zeros(3), J_FULL, 1.0, r, b, q_io, wio,
                           mode="bdot", k_bdot=1e6, max_dipole=0.5, gravity_gradient=False)
    assert np.all(np.abs(h.m_b) <= 0.5 + 1e-15)
    assert np.max(np.abs(h.m_b)) == pytest.approx(0.5)          # saturates while tumbling
    E = 0.5 * np.sum(h.w_ib_b * (h.w_ib_b @ J_FULL.T), axis=1)
    assert E[-1] < 0.01 * E[0]


@pytest.mark.parametrize("J, word", [([0.5, -0.2, 0.4], "positive"),
                                     ([[0.5, 0.6, 0], [0.6, 0.5, 0], [0, 0, 0.4]], "definite"),
                                     ([[0.5, 0.1, 0], [0.0, 0.5, 0], [0, 0, 0.4]], "symmetric"),
                                     ([0.1, 0.1, 0.5], "triangle")])
def test_bad_inertia_is_rejected(J, word):
    with pytest.raises(InputError, match=word):
        check_inertia(J)


# ------------------------------------------------------------------ sensors
def test_gyro_allan_deviation_white_noise_and_bias_walk():
    rng = np.random.default_rng(11)
    dt, n = 0.1, 400000
    t = np.arange(n) * dt
    arw = 1e-4                                  # rad/sqrt(s)
    g, _ = gyro_model(t, np.zeros((n, 3)), rng, arw_rad_rt_s=arw)
    taus = np.array([0.1, 1.0, 10.0, 100.0])
    ad = allan_deviation(g[:, 0], dt, taus)
    slope = np.diff(np.log(ad)) / np.diff(np.log(taus))
    np.testing.assert_allclose(slope, -0.5, atol=0.05)
    assert ad[1] == pytest.approx(arw, rel=0.05)              # ADEV(1 s) = N for white rate noise
    rrw = 1e-6                                   # rad/s/sqrt(s)
    g, bias = gyro_model(t, np.zeros((n, 3)), np.random.default_rng(12), bias_rw_rad_s_rt_s=rrw)
    taus = np.array([100.0, 1000.0, 4000.0])
    ad = np.mean([allan_deviation(g[:, k], dt, taus) for k in range(3)], axis=0)
    slope = np.diff(np.log(ad)) / np.diff(np.log(taus))
    np.testing.assert_allclose(slope, 0.5, atol=0.15)
    np.testing.assert_allclose(ad, rrw * np.sqrt(taus / 3), rtol=0.3)   # K sqrt(tau/3)
    np.testing.assert_array_equal(g, bias)


def test_gyro_step_drift_and_constant_bias():
    t = np.arange(100.0)
    g, bias = gyro_model(t, np.ones((100, 3)), np.random.default_rng(0),
                         bias_rad_s=[1e-3, 0, 0], step_rad_s=[0, 2e-3, 0], step_time_s=50.0)
    np.testing.assert_allclose(g[:50] - 1.0, np.tile([1e-3, 0, 0], (50, 1)))
    np.testing.assert_allclose(g[50:] - 1.0, np.tile([1e-3, 2e-3, 0], (50, 1)))
    np.testing.assert_allclose(bias, g - 1.0)


def test_magnetometer_noise_and_scale():
    rng = np.random.default_rng(2)
    b = np.tile([20000.0, -5000.0, 30000.0], (50000, 1))
    m, A = magnetometer_model(b, rng, noise_nT=300.0, bias_nT=[100, 0, -50], scale_pct=1.0,
                              misalignment_deg=0.5)
    resid = m - (b @ A.T + [100, 0, -50])
    np.testing.assert_allclose(resid.std(axis=0), 300.0, rtol=0.02)
    assert np.all(np.abs(np.diag(A) - 1) < 0.05) and np.any(A - np.diag(np.diag(A)) != 0)


def test_sun_sensor_noise_fov_and_eclipse():
    rng = np.random.default_rng(4)
    n = 20000
    ang = np.linspace(0, np.pi, n)
    s = np.stack([np.sin(ang), np.zeros(n), np.cos(ang)], -1)      # sweeps from +z to -z
    illum = np.ones(n)
    illum[:1000] = 0.0
    out, valid = sun_sensor_model(s, illum, rng, noise_deg=0.2, boresight_b=[0, 0, 1],
                                  fov_half_angle_deg=60.0)
    expect = (ang <= np.radians(60.0)) & (illum >= 0.5)
    np.testing.assert_array_equal(valid, expect)
    assert np.all(np.isnan(out[~valid]))
    err = np.degrees(np.arccos(np.clip(np.sum(out[valid] * s[valid], 1), -1, 1)))
    # angle of a 2-D Gaussian error with sigma per axis: Rayleigh, RMS = sqrt(2) sigma
    assert np.sqrt(np.mean(err**2)) == pytest.approx(np.sqrt(2) * 0.2, rel=0.03)


def test_control_mode_names_match_the_kernel():
    from gnomon.dynamics import CONTROL_MODES
    from gnomon.kernels import dynamics as K

    assert CONTROL_MODES == {"none": 0, "bdot": K.MODE_BDOT, "magnetic_pd": K.MODE_MAGNETIC_PD,
                             "bdot_then_pd": K.MODE_BDOT_THEN_PD, "wheel_pd": K.MODE_WHEEL_PD}
