"""Seed 004: complementary filters — closed forms vs scipy, discrete vs analytic, 3D tilt filter."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import signal

from gnomon.analysis import complementary as an
from gnomon.errors import InputError
from gnomon.estimators import complementary as cf
from gnomon.estimators import registry
from gnomon.metrics import broad_errors_rad
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_euler
from gnomon.simulation import linear_accel as sim

DEG = math.pi / 180.0
G = sim.G0_M_S2
WD = 5e-5  # rad/s, the paper's gyro drift

# (r1, r2): under-damped (the p004 tuning), critically damped, over-damped
# the paper's first-order filter in 3D: no bias integral, no acceleration rejection
PAPER_3D = {"bias_gain_1_s2": 0.0, "accel_rejection_rel": 0.0}

GAINS = [(math.sqrt(2.0) * 0.01, 1e-4), (0.02, 1e-4), (0.05, 1e-4)]


def lsim(tf, u, t):
    return signal.lsim(tf, u, t, interp=False)[1]


# ---------------------------------------------------------------- analysis: first order
def test_paper_numbers_follow_from_the_formulas():
    # the paper's eq. 7 with a/g = 1, tau = 5 s, w_d = 5e-5 rad/s (its Figs. 3-4)
    assert round(an.first_order_peak_accel_error_small_tau(100.0, 5.0, 1.0) / DEG, 2) == 2.86
    assert round(an.first_order_peak_accel_error_small_tau(200.0, 5.0, 1.0) / DEG, 2) == 1.43
    assert round(an.first_order_steady_drift_error(100.0, WD) / DEG, 2) == 0.29
    assert round(an.first_order_steady_drift_error(200.0, WD) / DEG, 2) == 0.57
    # 2.865 deg is printed as 2.87 by the paper; the exact peak is lower by (1 - e^-x)/x
    x = 5.0 / 100.0
    exact = an.first_order_peak_accel_error(100.0, 5.0, 1.0)
    assert exact == pytest.approx(1.0 - math.exp(-x), rel=1e-15)
    assert exact / an.first_order_peak_accel_error_small_tau(100.0, 5.0, 1.0) == pytest.approx(
        (1 - math.exp(-x)) / x, rel=1e-14)


def test_first_order_accel_error_matches_lsim():
    T, tau, A = 100.0, 5.0, 1.0
    t = np.arange(0.0, 600.0, 0.01)
    u = np.where(t < tau, A, 0.0)
    _, w1 = an.first_order_tf(T)
    y = lsim(w1, u, t)
    assert np.max(np.abs(y - an.first_order_accel_error(t, T, tau, A))) < 1e-6
    assert np.max(np.abs(y)) == pytest.approx(an.first_order_peak_accel_error(T, tau, A), abs=1e-6)
    assert t[np.argmax(y)] == pytest.approx(tau, abs=0.011)


def test_first_order_drift_error_matches_lsim_and_final_value():
    T = 100.0
    t = np.arange(0.0, 1500.0, 0.05)
    W, _ = an.first_order_tf(T)
    # error = W(s) * w_d / s^2: the system W(s)/s driven by a step of w_d
    sys = signal.TransferFunction(W.num, np.polymul(W.den, [1.0, 0.0]))
    y = lsim(sys, np.full_like(t, WD), t)
    assert np.max(np.abs(y - an.first_order_drift_error(t, T, WD))) < 1e-9
    s = 1e-9  # final-value theorem: lim s * W(s) * w_d / s^2
    fv = np.polyval(W.num, s) / np.polyval(W.den, s) * WD / s
    assert fv == pytest.approx(an.first_order_steady_drift_error(T, WD), rel=1e-6)


# ---------------------------------------------------------------- analysis: second order
@pytest.mark.parametrize("r1,r2", GAINS)
@pytest.mark.parametrize("variant", [1, 2])
def test_second_order_step_and_impulse_match_scipy(r1, r2, variant):
    _, w1 = an.second_order_tf(r1, r2, variant)
    t = np.linspace(0.0, 1500.0, 3001)
    _, ys = signal.step(w1, T=t)
    _, yi = signal.impulse(w1, T=t)
    assert np.max(np.abs(ys - an.second_order_step_response(t, r1, r2, variant))) < 1e-9
    assert np.max(np.abs(yi - an.second_order_impulse_response(t, r1, r2, variant))) < 1e-9


@pytest.mark.slow(reason="5 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("r1,r2", GAINS)
@pytest.mark.parametrize("variant", [1, 2])
def test_second_order_pulse_and_drift_errors_match_lsim(r1, r2, variant):
    tau, A = 5.0, 1.0
    t = np.arange(0.0, 1500.0, 0.01)
    W, w1 = an.second_order_tf(r1, r2, variant)
    y = lsim(w1, np.where(t < tau, A, 0.0), t)
    assert np.max(np.abs(y - an.second_order_accel_error(t, r1, r2, variant, tau, A))) < 2e-6
    peak, _ = an.second_order_peak_accel_error(r1, r2, variant, tau, A)
    assert peak == pytest.approx(np.max(np.abs(y)), abs=2e-6)
    sys = signal.TransferFunction(W.num, np.polymul(W.den, [1.0, 0.0]))
    yd = lsim(sys, np.full_like(t, WD), t)
    assert np.max(np.abs(yd - an.second_order_drift_error(t, r1, r2, variant, WD))) < 1e-9
    s = 1e-12  # final-value theorem
    fv = np.polyval(W.num, s) / np.polyval(W.den, s) * WD / s
    assert fv == pytest.approx(an.second_order_steady_drift_error(r1, r2, variant, WD),
                               abs=1e-8 * r1 * WD / r2)


def test_second_order_drift_claim_and_accel_inequality():
    g = an.second_order_gains(0.01)
    # variant 1 leaves r1*w_d/r2 (sqrt(2)*T*w_d at zeta = 1/sqrt(2)); variant 2 leaves nothing
    assert an.second_order_steady_drift_error(g.r1, g.r2, 1, WD) == pytest.approx(
        math.sqrt(2.0) * 100.0 * WD, rel=1e-12)
    assert an.second_order_steady_drift_error(g.r1, g.r2, 2, WD) == 0.0
    # the paper's inequality |r2/D| < |(r1 s + r2)/D| for all w > 0
    w = np.logspace(-5, 2, 300)
    _, v1 = an.second_order_tf(g.r1, g.r2, 1)
    _, v2 = an.second_order_tf(g.r1, g.r2, 2)
    m1, _ = an.bode(v1, w)
    m2, _ = an.bode(v2, w)
    assert np.all(m1 < m2)


@pytest.mark.parametrize("zeta", [0.4, 1.0 / math.sqrt(2.0), 1.0, 2.0])
@pytest.mark.parametrize("variant", [1, 2])
def test_second_order_gains_bandwidth(zeta, variant):
    g = an.second_order_gains(0.01, zeta, variant)
    assert g.r1 == pytest.approx(2 * zeta * math.sqrt(g.r2), rel=1e-14)
    _, w1 = an.second_order_tf(g.r1, g.r2, variant)
    assert abs(an._freqresp(w1, 0.01)) == pytest.approx(1.0 / math.sqrt(2.0), rel=1e-12)
    assert an.bandwidth_rad_s(w1) == pytest.approx(0.01, rel=1e-9)
    _, fo = an.first_order_tf(100.0)
    assert an.bandwidth_rad_s(fo) == pytest.approx(0.01, rel=1e-9)


def test_bode_matches_direct_evaluation():
    W, w1 = an.first_order_tf(100.0)
    w = np.array([1e-3, 1e-2, 1e-1])
    mag, ph = an.bode(w1, w)
    h = 1.0 / (100.0 * 1j * w + 1.0)
    assert np.allclose(mag, 20 * np.log10(np.abs(h)), atol=1e-10)
    assert np.allclose(ph, np.degrees(np.angle(h)), atol=1e-8)
    # W + (1 - W) = 1 for every filter, from scipy's magnitude and phase
    g = an.second_order_gains(0.01)
    for pair in (an.first_order_tf(100.0), an.second_order_tf(g.r1, g.r2, 1),
                 an.second_order_tf(g.r1, g.r2, 2)):
        total = 0.0
        for tf in pair:
            m, p = an.bode(tf, w)
            total = total + 10 ** (m / 20) * np.exp(1j * np.radians(p))
        assert np.allclose(total, 1.0, atol=1e-10)


def test_true_geometry_and_bad_input():
    assert an.accel_tilt_error_rad(1.0, "true") == pytest.approx(math.pi / 4)
    assert an.accel_tilt_error_rad(1.0, "linear") == 1.0
    with pytest.raises(ValueError, match="model"):
        an.accel_tilt_error_rad(1.0, "small")
    with pytest.raises(ValueError, match="T_s"):
        an.first_order_tf(0.0)
    with pytest.raises(ValueError, match="variant"):
        an.second_order_tf(0.1, 0.1, 3)


# ---------------------------------------------------------------- discrete one-axis filters
def _first_order_loop(w, a, dt, T):
    alpha = T / (T + dt)
    y = np.empty_like(w)
    y[0] = a[0]
    for k in range(1, w.size):
        y[k] = alpha * (y[k - 1] + w[k] * dt) + (1 - alpha) * a[k]
    return y


def test_first_order_filter_vs_loop_and_closed_form():
    rng = np.random.default_rng(40)
    w, a = rng.normal(0, 0.1, 5000), rng.normal(0.2, 0.05, 5000)
    assert np.max(np.abs(cf.first_order_filter(w, a, 0.01, 3.0)
                         - _first_order_loop(w, a, 0.01, 3.0))) < 1e-12
    dt, T, tau = 0.01, 100.0, 5.0
    t = np.arange(0.0, 1200.0, dt)
    zero = np.zeros_like(t)
    y = cf.first_order_filter(np.full_like(t, WD), zero, dt, T)
    # the discrete filter's steady drift error is exactly T*w_d
    assert y[-1] == pytest.approx(T * WD * (1 - (T / (T + dt)) ** (t.size - 1)), rel=1e-9)
    assert np.max(np.abs(y - an.first_order_drift_error(t, T, WD))) < 1e-7
    # pulse from t = 1 s: the discrete filter follows the closed form to one sample of timing
    # (it responds to a sample in the same step: a jump of (1 - alpha) ~ dt/T at the edges)
    ya = cf.first_order_filter(zero, np.where((t >= 1.0) & (t < 1.0 + tau), 1.0, 0.0), dt, T)
    assert np.max(np.abs(ya - an.first_order_accel_error(t - 1.0, T, tau, 1.0))) < 1.5 * dt / T


@pytest.mark.parametrize("variant", [1, 2])
def test_second_order_filter_vs_loop_and_closed_form(variant):
    rng = np.random.default_rng(41 + variant)
    r1, r2 = 0.3, 0.02
    w, a = rng.normal(0, 0.1, 5000), rng.normal(0.2, 0.05, 5000)
    y = cf.second_order_filter(w, a, 0.01, r1, r2, variant, phi0_rad=0.1)
    yr = cf.second_order_filter_reference(w, a, 0.01, r1, r2, variant, phi0_rad=0.1)
    assert np.max(np.abs(y - yr)) < 1e-10
    g = an.second_order_gains(0.01)
    dt, tau = 0.01, 5.0
    t = np.arange(0.0, 1500.0, dt)
    zero = np.zeros_like(t)
    yd = cf.second_order_filter(np.full_like(t, WD), zero, dt, g.r1, g.r2, variant)
    assert yd[-1] == pytest.approx(an.second_order_steady_drift_error(g.r1, g.r2, variant, WD),
                                   abs=1e-3 * 100 * WD)
    assert np.max(np.abs(yd - an.second_order_drift_error(t, g.r1, g.r2, variant, WD))) < 1e-6
    ya = cf.second_order_filter(zero, np.where((t >= 1.0) & (t < 1.0 + tau), 1.0, 0.0), dt,
                                g.r1, g.r2, variant)
    ea = an.second_order_accel_error(t - 1.0, g.r1, g.r2, variant, tau, 1.0)
    assert np.max(np.abs(ya - ea)) < 1.5 * dt * g.r1  # one sample of timing, as first order
    peak, _ = an.second_order_peak_accel_error(g.r1, g.r2, variant, tau, 1.0)
    assert np.max(np.abs(ya)) == pytest.approx(peak, rel=1e-3)


# ---------------------------------------------------------------- 3D tilt filter
def _static_recording(q_nb, n=500, fs=100.0, gyro_bias=(0.0, 0.0, 0.0)):
    t = np.arange(n) / fs
    f_b = dcm_from_quat(q_nb).T @ np.array([0.0, 0.0, G])
    return Recording(t=t, gyro=np.tile(gyro_bias, (n, 1)), accel=np.tile(f_b, (n, 1)),
                     q_true=np.tile(q_nb, (n, 1)))


def _up_angle(q_true, q_est):
    """Angle (rad) between the true and estimated vertical in b (accurate near zero)."""
    u = dcm_from_quat(q_true)[..., 2, :]
    v = dcm_from_quat(q_est)[..., 2, :]
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


@pytest.mark.parametrize("rpy_deg", [(0, 0, 0), (20, -35, 120), (-170, 60, -45), (5, 89, 10)])
def test_static_tilt_recovered_exactly(rpy_deg):
    q = quat_from_euler(np.radians(rpy_deg))
    rec = _static_recording(q)
    est = registry.create("tilt-cf", {"time_constant_s": 1.0}).run(rec)
    assert np.max(_up_angle(rec.q_true, est.q)) < 1e-12  # exact to rounding
    assert not est.signals["acc_rejected"].any()


def test_3d_filter_equals_one_axis_true_geometry():
    dt, T = 0.02, 20.0
    t = np.arange(0.0, 100.0, dt)
    a = sim.pulse_profile(t, 5.0, 5.0, 0.7 * G)
    rec = sim.vehicle_recording(t, a, gyro_bias_rad_s=(0.0, -1e-3, 0.0))
    est = cf.TiltComplementaryFilter(time_constant_s=T, init_samples=1, **PAPER_3D).run(rec)
    inc = broad_errors_rad(rec.q_true, est.q)["inclination"]
    w, phi_a = sim.one_axis_inputs(a, 1e-3, "true")
    y = cf.first_order_filter(w, phi_a, dt, T, phi0_rad=0.0)
    assert np.max(np.abs(inc - np.abs(y))) < 1e-9


def test_kernel_matches_python_reference():
    rng = np.random.default_rng(404)
    n = 3000
    gyro = rng.normal(0, 0.5, (n, 3))
    accel = rng.normal(0, 3.0, (n, 3)) + [0.0, 0.0, G]
    accel[[7, 100, 2000]] = 0.0
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    p = cf.TiltCFParams(time_constant_s=0.5, bias_gain_1_s2=0.3, accel_rejection_rel=0.3)
    q0 = cf.quat_from_accel(accel[0])
    q, b, rej = cf.tilt_cf_batch(t, gyro, accel, q0, p)
    from gnomon.kernels.tilt_cf import new_state

    s = new_state(q0).view(np.recarray)[0]
    worst = 0.0
    for k in range(1, n):
        cf.tilt_step_reference(s, p, t[k] - t[k - 1], gyro[k], accel[k])
        worst = max(worst, np.max(np.abs(s.q - q[k])), np.max(np.abs(s.bias - b[k])))
        assert s.acc_rejected == rej[k]
    assert worst < 1e-12
    assert rej[[100, 2000]].all() and 0 < rej.sum() < n


def test_update_streaming_equals_run():
    t = np.arange(0.0, 30.0, 0.01)
    a = sim.pulse_profile(t, 5.0, 10.0, 3.0, edge_s=1.0)
    r = sim.pulse_profile(t, 10.0, 8.0, 0.3, edge_s=1.0)
    rng = np.random.default_rng(5)
    rec = sim.vehicle_recording(t, a, r, gyro_bias_rad_s=(0.01, -0.02, 0.005),
                                gyro_noise_rad_s=1e-3, accel_noise_m_s2=0.05,
                                speed_noise_m_s=0.05, rng=rng)
    for comp in (False, True):
        f = cf.TiltComplementaryFilter(time_constant_s=2.0, bias_gain_1_s2=0.05, init_samples=1,
                                       speed_compensation=comp)
        est = f.run(rec)
        f.reset()
        qs = np.array([f.update(rec.t[k] - rec.t[k - 1] if k else 0.0, rec.gyro[k],
                                rec.accel[k], speed_m_s=rec.extra["speed_m_s"][k])
                       for k in range(t.size)])
        assert np.max(np.abs(qs - est.q)) < 1e-12


def test_bias_integral_estimates_horizontal_gyro_bias():
    bias = np.array([2e-3, -3e-3, 1e-3])
    q = quat_from_euler(np.radians([10.0, -5.0, 30.0]))
    rec = _static_recording(q, n=60000, fs=100.0, gyro_bias=bias)
    est = cf.TiltComplementaryFilter(time_constant_s=5.0, bias_gain_1_s2=0.02).run(rec)
    inc = broad_errors_rad(rec.q_true, est.q)["inclination"]
    assert inc[-1] < 1e-4 * DEG
    # the horizontal part of the bias is estimated; the vertical part is unobservable
    up_b = dcm_from_quat(q).T @ [0.0, 0.0, 1.0]
    b_hat = est.signals["bias_rad_s"][-1]
    horiz = bias - (bias @ up_b) * up_b
    assert np.allclose(b_hat, horiz, atol=1e-7)
    # without the integral, the first-order filter keeps T * |horizontal bias|
    est1 = cf.TiltComplementaryFilter(time_constant_s=5.0, **PAPER_3D).run(rec)
    inc1 = broad_errors_rad(rec.q_true, est1.q)["inclination"]
    assert inc1[-1] == pytest.approx(5.0 * np.linalg.norm(horiz), rel=2e-3)


def test_zero_accel_and_rejection_no_nan():
    n = 400
    t = np.arange(n) * 0.01
    accel = np.zeros((n, 3))
    rec = Recording(t=t, gyro=np.full((n, 3), 0.01), accel=accel)
    est = cf.TiltComplementaryFilter().run(rec)
    assert np.all(np.isfinite(est.q)) and est.signals["acc_rejected"].all()
    assert np.allclose(np.linalg.norm(est.q, axis=1), 1.0, atol=1e-12)
    # gating: during a = g (|f| = sqrt(2) g) the correction is skipped, no acceleration error
    dt = 0.05
    tt = np.arange(0.0, 200.0, dt)
    a = sim.pulse_profile(tt, 10.0, 5.0, G)
    rec2 = sim.vehicle_recording(tt, a, gyro_bias_rad_s=(0.0, 0.0, 0.0))
    est2 = cf.TiltComplementaryFilter(time_constant_s=100.0, accel_rejection_rel=0.1,
                                      bias_gain_1_s2=0.0).run(rec2)
    rej = est2.signals["acc_rejected"]
    assert rej.sum() == int(round(5.0 / dt)) and rej[a > 0].all()
    assert np.max(broad_errors_rad(rec2.q_true, est2.q)["inclination"]) < 1e-9


def test_params_and_inputs_validation():
    with pytest.raises(InputError, match="time_constant"):
        registry.create("tilt-cf", {"time_constant_s": "-1"})
    with pytest.raises(InputError, match="unknown parameter"):
        registry.create("tilt-cf", {"time_constant": 1.0})
    rec = Recording(t=np.arange(3.0), gyro=np.zeros((3, 3)), accel=np.tile([0, 0, G], (3, 1)))
    with pytest.raises(InputError, match="speed_m_s"):
        cf.TiltComplementaryFilter(speed_compensation=True).run(rec)
    with pytest.raises(InputError, match="accel"):
        cf.TiltComplementaryFilter().run(Recording(t=np.arange(3.0), gyro=np.zeros((3, 3))))


def test_compensate_accel_removes_turn_and_acceleration():
    dt = 0.01
    t = np.arange(0.0, 60.0, dt)
    # constant speed 20 m/s in a turn: w x v is removed exactly
    r = np.full_like(t, 0.2)
    rec = sim.vehicle_recording(t, np.zeros_like(t), r, gyro_bias_rad_s=(0, 0, 0), v0_m_s=20.0)
    f = cf.compensate_accel(rec.t, rec.accel, rec.gyro, rec.extra["speed_m_s"])
    assert np.max(np.abs(rec.accel[:, 1])) == pytest.approx(4.0)
    assert np.max(np.abs(f[20:] - [0.0, 0.0, G])) < 1e-9
    # a constant acceleration: the finite difference of the speed samples is exact
    rec = sim.vehicle_recording(t, np.full_like(t, 2.0), gyro_bias_rad_s=(0, 0, 0))
    f = cf.compensate_accel(rec.t, rec.accel, rec.gyro, rec.extra["speed_m_s"])
    assert np.max(np.abs(f[20:] - [0.0, 0.0, G])) < 1e-9


# ---------------------------------------------------------------- reproduction
def test_p004_quick_meets_targets(tmp_path):
    from gnomon.reproduce import p004

    out = p004.run(out_dir=tmp_path, quick=True)
    assert out["paper"] == "004"
    T_s, tau, A = p004.CONFIG["T_s"], p004.CONFIG["tau_s"], p004.CONFIG["a_over_g"]
    for T in T_s:
        r = out["first_order"][f"T{T:g}"]
        assert r["analytic_peak_accel_error_deg"] == pytest.approx(
            an.first_order_peak_accel_error(T, tau, A) / DEG, rel=1e-12)
        assert r["peak_accel_error_deg"] == pytest.approx(r["analytic_peak_accel_error_deg"],
                                                          rel=0.05)
        assert r["drift_error_deg"] == pytest.approx(r["analytic_drift_error_deg"], rel=0.05)
        # also against the paper's small-tau formula (2.87 / 1.43 deg)
        assert r["peak_accel_error_deg"] == pytest.approx(
            r["analytic_peak_accel_error_small_tau_deg"], rel=0.05)
        g = out["first_order_true_geometry"][f"T{T:g}"]
        assert g["peak_accel_error_deg"] == pytest.approx(
            r["peak_accel_error_deg"] * math.atan(A) / A, rel=1e-9)
    so = out["second_order"]
    for v in ("variant1", "variant2"):
        assert so[v]["steady_drift_error_deg"] == pytest.approx(
            so[v]["analytic_steady_drift_error_deg"], abs=1e-3)
        assert so[v]["peak_accel_error_deg"] == pytest.approx(
            so[v]["analytic_peak_accel_error_deg"], rel=0.01)
    assert so["variant1"]["peak_accel_error_deg"] < so["variant2"]["peak_accel_error_deg"]
    v2b = so["variant2_same_bandwidth"]
    assert so["variant1"]["peak_accel_error_deg"] < v2b["peak_accel_error_deg"]
    assert v2b["peak_accel_error_deg"] == pytest.approx(v2b["analytic_peak_accel_error_deg"],
                                                         rel=0.01)
    assert so["variant1"]["analytic_steady_drift_error_deg"] > 0.0
    assert so["variant2"]["analytic_steady_drift_error_deg"] == 0.0
    d3 = out["tilt_cf_3d"]
    tg = out["first_order_true_geometry"]["T100"]
    assert d3["peak_accel_error_deg"] == pytest.approx(tg["peak_accel_error_deg"], abs=1e-6)
    assert d3["drift_error_deg"] == pytest.approx(tg["drift_error_deg"], abs=1e-6)
    c = out["compensated"]
    assert c["peak_accel_error_deg"] <= 0.2 * c["uncompensated_peak_accel_error_deg"]
    assert all(out["targets"].values())
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["first_order"] == out["first_order"]
    for name in ("first_order_T100.png", "first_order_T200.png", "second_order.png",
                 "bode.png", "compensated.png"):
        assert (tmp_path / name).stat().st_size > 10_000
