"""Issue 20: the error-state RTS smoother on the ESKF (``eskf-offline``).

The forward pass is the filter (``eskf-r3``'s ``q`` exactly); the compiled backward pass
equals its readable twin (``rts_reference``); the kernel's RTS step (``rts_core``)
equals the batch least-squares solution of a linear-Gaussian problem with the ESKF's
transition and process noise (an independent check of the algebra); on noise-free data
the smoother returns the truth; on simulated MEMS data whose noise the filter's
parameters describe, the smoothed error is smaller than the causal one and its
covariance is consistent (NEES in its chi-square band).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from gnomon.errors import InputError
from gnomon.estimators.eskf import EskfR3, process_noise, transition_matrix
from gnomon.estimators.eskf_offline import EskfOffline, rts_reference
from gnomon.metrics import error_angle_rad, rms_deg
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_mul
from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

DEG = np.pi / 180.0


def _sim(seed: int, **kw) -> Recording:
    return simulate_ahrs(AhrsSimParams(**{"duration_s": 30.0, **kw}),
                         np.random.default_rng(seed))


def _matched(sim: AhrsSimParams) -> dict:
    """Filter parameters describing the simulation's sensors (as ``p002.filter_params_for``:
    noise levels, known inclination, no low-pass or gates)."""
    from gnomon.reproduce.p002 import filter_params_for

    return filter_params_for(sim)


def _rotation_error(q_true, q_est) -> np.ndarray:
    """Rotation vector (rad, body axes) of the error ``δq = q̂* ⊗ q`` (true = estimate ⊗
    error, the filter's convention), small-angle: ``2 vec(δq)`` with ``w >= 0``."""
    d = quat_mul(quat_conj(q_est), q_true)
    return 2.0 * d[:, 1:] * np.where(d[:, :1] < 0.0, -1.0, 1.0)


def _multi_rate(rec: Recording) -> Recording:
    """``rec`` with the accelerometer at half and the magnetometer at a quarter of the gyro's
    rate, on their own clocks (1 ms early)."""
    ia, im = np.arange(0, len(rec), 2), np.arange(1, len(rec), 4)
    return Recording(t=rec.t, gyro=rec.gyro, accel=rec.accel[ia], accel_t=rec.t[ia] - 1e-3,
                     mag=rec.mag[im], mag_t=rec.t[im] - 1e-3, mag_unit=rec.mag_unit,
                     q_true=rec.q_true, frames=rec.frames, source="multi-rate")


# ---------------------------------------------------------------- forward pass = the filter
def test_forward_pass_is_eskf_r3():
    """``forward_q`` equals ``EskfR3().run(rec).q`` to 1e-12 on a single-rate, a multi-rate
    and a tesla-unit recording (with linear acceleration: gates and low-pass at work), and
    on a run split in two (the filter's state continues); the state is left where
    ``eskf-r3`` leaves it. (The same step compiled into another loop: fastmath may order a
    sum differently; measured differences up to 6e-15, none on some recordings.)"""
    rec = _sim(0, duration_s=20.0, linear_accel_rms=0.5)
    mr = _multi_rate(rec)
    tesla = dataclasses.replace(rec, mag=rec.mag * 1e-6, mag_unit="T")
    for r in (rec, mr, tesla):
        off, causal = EskfOffline(), EskfR3()
        e = off.run(r)
        np.testing.assert_allclose(e.signals["forward_q"], causal.run(r).q, rtol=0, atol=1e-12)
        for name in off.state.dtype.names:  # the state it leaves (rounding: fastmath)
            np.testing.assert_allclose(off.state[name], causal.state[name], rtol=1e-9,
                                       atol=1e-15)
        assert e.q.shape == (len(r), 4) and e.estimator == "eskf-offline"
    half = len(rec) // 2
    parts = [Recording(t=rec.t[s], gyro=rec.gyro[s], accel=rec.accel[s], mag=rec.mag[s],
                       mag_unit=rec.mag_unit) for s in (slice(0, half), slice(half, None))]
    off, causal = EskfOffline(), EskfR3()
    for p in parts:
        np.testing.assert_allclose(off.run(p).signals["forward_q"], causal.run(p).q,
                                   rtol=0, atol=1e-12)
    assert off.t_last == causal.t_last == rec.t[-1]


# ---------------------------------------------------------------- backward pass
def test_compiled_backward_pass_equals_readable_reference():
    """The kernel's backward pass against ``rts_reference`` (numpy: ``transition_matrix``,
    ``process_noise``, ``np.linalg.solve``) on the filter's own forward pass, default
    tuning (low-pass, gates, bias bound) on data with linear acceleration."""
    from gnomon.kernels import eskf as kern
    from gnomon.kernels import eskf_smoother as sm

    rec = _sim(1, duration_s=20.0, linear_accel_rms=0.3)
    f = EskfOffline()
    inputs = f._kernel_inputs(rec)
    c = kern.coefficients(f.params)
    out = sm.new_passes(len(rec), attitude_cov=True)
    sm.forward_pass(inputs, f.state, c, out)
    b_fwd = out.bias.copy()
    iu = np.triu_indices(6)
    P_fwd = np.zeros((len(rec), 6, 6))
    P_fwd[:, iu[0], iu[1]] = out.P
    P_fwd = P_fwd + np.triu(P_fwd, 1).transpose(0, 2, 1)
    sm.backward_pass(inputs, c, out)
    p = f.params
    q_s, b_s, P_s = rts_reference(out.q_fwd, b_fwd, P_fwd, inputs.gyro, inputs.dt,
                                  p.gyro_noise, p.bias_rw, p.bias_limit)
    np.testing.assert_allclose(out.q, q_s, rtol=0, atol=1e-10)
    np.testing.assert_allclose(out.bias, b_s, rtol=0, atol=1e-12)  # rad/s
    std = 2.0 * np.sqrt(np.diagonal(P_s, axis1=1, axis2=2)[:, :3])
    np.testing.assert_allclose(out.att_std, std, rtol=1e-8)
    iu3 = np.triu_indices(3)
    np.testing.assert_allclose(out.att_cov, 4.0 * P_s[:, iu3[0], iu3[1]], rtol=1e-7,
                               atol=1e-8 * float(np.max(P_s[:, :3, :3])))
    # the smoothing did something: the first sample moved by more than rounding
    assert np.degrees(error_angle_rad(out.q_fwd[:1], out.q[:1]))[0] > 1e-3


def test_rts_step_equals_batch_least_squares():
    """A linear-Gaussian problem with the ESKF's structure: ``x_k = Φ_k x_{k-1} + w_k``,
    ``Φ_k = transition_matrix(ω_k, dt)`` (rates large enough that ``A`` matters),
    ``Q = process_noise``, prior ``x_0 ~ N(m0, P0)``, measurements ``y_k = H_k x_k + v_k``
    on two rows in three (the others prediction only). A numpy Kalman filter forward,
    the kernel's ``rts_core`` backward (``δ = x_s,k+1 - Φ x⁺_k``, ``x_s,k = x⁺_k + C δ``),
    against the solution of the stacked weighted least-squares problem over all states
    (prior, dynamics and measurement residuals): its mean and the diagonal blocks of the
    inverse information matrix are the smoothed means and covariances."""
    from gnomon.kernels.eskf_smoother import rts_core

    rng = np.random.default_rng(20)
    n, dt, sg, sb = 25, 0.1, 0.05, 0.02  # samples, s, rad/s/√Hz, rad/s/√s
    w = rng.normal(0.0, 1.0, (n, 3))     # ω̂ of each interval, rad/s
    Phi = [transition_matrix(w[k], dt) for k in range(n)]  # Φ[k]: x_{k-1} -> x_k
    Q = process_noise(dt, sg, sb)
    P0 = np.diag([0.1, 0.2, 0.15, 0.05, 0.04, 0.03]) ** 2
    m0 = rng.normal(0.0, 0.1, 6)
    R = np.diag(rng.uniform(0.01, 0.05, 3) ** 2)
    H = [rng.normal(size=(3, 6)) if k % 3 != 1 else None for k in range(n)]
    x = rng.multivariate_normal(m0, P0)
    y = []
    for k in range(n):
        if k:
            x = Phi[k] @ x + rng.multivariate_normal(np.zeros(6), Q)
        y.append(None if H[k] is None else H[k] @ x + rng.multivariate_normal(np.zeros(3), R))
    # forward Kalman filter
    xf, Pf = np.empty((n, 6)), np.empty((n, 6, 6))
    xk, Pk = m0, P0
    for k in range(n):
        if k:
            xk, Pk = Phi[k] @ xk, Phi[k] @ Pk @ Phi[k].T + Q
        if H[k] is not None:
            K = np.linalg.solve(H[k] @ Pk @ H[k].T + R, H[k] @ Pk).T
            xk, Pk = xk + K @ (y[k] - H[k] @ xk), (np.eye(6) - K @ H[k]) @ Pk
            Pk = 0.5 * (Pk + Pk.T)
        xf[k], Pf[k] = xk, Pk
    # backward: the kernel's RTS step
    xs, Ps = np.empty((n, 6)), np.empty((n, 6, 6))
    xs[-1], Ps[-1] = xf[-1], Pf[-1]
    M, Pm, L, X = np.empty((6, 6)), np.empty((6, 6)), np.zeros((6, 6)), np.empty((6, 6))
    invd, dx = np.empty(6), np.empty(6)
    for k in range(n - 2, -1, -1):
        P = np.ascontiguousarray(Pf[k])
        Pnext = Ps[k + 1].copy()
        d = xs[k + 1] - Phi[k + 1] @ xf[k]
        rts_core(P, Pnext, d, w[k + 1, 0], w[k + 1, 1], w[k + 1, 2], dt,
                 0.25 * sg**2 * dt, sb**2 * dt, M, Pm, L, invd, X, dx)
        xs[k], Ps[k] = xf[k] + dx, Pnext
    # batch least squares: information matrix J and vector h over [x_0; ...; x_{n-1}]
    J, h = np.zeros((6 * n, 6 * n)), np.zeros(6 * n)
    blk = [slice(6 * k, 6 * k + 6) for k in range(n)]
    J[blk[0], blk[0]] += np.linalg.inv(P0)
    h[blk[0]] += np.linalg.solve(P0, m0)
    Qi, Ri = np.linalg.inv(Q), np.linalg.inv(R)
    for k in range(1, n):  # residual x_k - Φ_k x_{k-1} = G [x_{k-1}; x_k], G = [-Φ_k, I]
        G = np.hstack([-Phi[k], np.eye(6)])
        J[6 * (k - 1):6 * (k + 1), 6 * (k - 1):6 * (k + 1)] += G.T @ Qi @ G
    for k in range(n):
        if H[k] is not None:
            J[blk[k], blk[k]] += H[k].T @ Ri @ H[k]
            h[blk[k]] += H[k].T @ Ri @ y[k]
    z = np.linalg.solve(J, h)
    S = np.linalg.inv(J)
    np.testing.assert_allclose(xs, z.reshape(n, 6), rtol=0, atol=1e-10)
    for k in range(n):
        np.testing.assert_allclose(Ps[k], S[blk[k], blk[k]], rtol=1e-8,
                                   atol=1e-10 * np.abs(S[blk[k], blk[k]]).max())
    assert np.abs(xs - xf).max() > 1e-3  # the smoothing changed the estimates


def test_noise_free_data_give_the_truth():
    """Noise-free sensors (a constant gyro bias of 0.5 °/s unknown to the filter; 1 s at
    rest first so the TRIAD start is exact): the causal estimate is off by hundredths of a
    degree while it learns the bias, the smoothed attitude and bias are the truth within
    1e-3 ° and 1e-4 °/s over the whole log. The 1e-3 ° is the model's own error: the
    filter steps with one rate per sample, the truth is 4th-order (two rates per sample),
    and the bias-free gyro integrated alone departs from it by up to 1.9e-3 ° over the
    60 s (measured), which the accelerometer and magnetometer pull back to 5e-4 °."""
    sim = AhrsSimParams(duration_s=60.0, gyro_noise=0.0, bias_rw=0.0, accel_noise=0.0,
                        mag_noise_uT=0.0, substeps=1, rest_s=1.0, gyro_bias_std=0.01)
    rec = simulate_ahrs(sim, np.random.default_rng(3))
    f = EskfOffline(gyro_noise=3e-4, bias_rw=1e-6, accel_noise=0.02, mag_noise=0.006,
                    init_bias_std=0.02, accel_gate=0.0, mag_gate=0.0, accel_lowpass_tau=0.0,
                    inclination_known=True, inclination=np.radians(60.0))
    e = f.run(rec)
    fwd = np.degrees(error_angle_rad(rec.q_true, e.signals["forward_q"]))
    err = np.degrees(error_angle_rad(rec.q_true, e.q))
    db = np.degrees(np.abs(e.signals["bias_rad_s"] - rec.extra["gyro_bias_rad_s"]))
    assert fwd.max() > 0.01
    assert err.max() < 1e-3
    assert db.max() < 1e-4


# ---------------------------------------------------------------- accuracy and consistency
SEEDS = range(6)
DURATION_S = 60.0
#: the smoothed errors decorrelate within ~2 s (autocorrelation of the normalised errors
#: below 0.3 at 2 s on these runs); samples this far apart count as independent
DECORRELATION_S = 5.0


@pytest.fixture(scope="module")
def mc_runs():
    """Six 60-s MEMS simulations (the default ``AhrsSimParams``: gyro 3e-4 rad/s/√Hz, bias
    0.01 rad/s + 2e-5 rad/s/√s, accel 0.02 m/s², mag 0.3 µT of 50 µT, 100 Hz), each
    smoothed with the filter tuned to those levels."""
    sim = AhrsSimParams(duration_s=DURATION_S)
    out = []
    for seed in SEEDS:
        rec = simulate_ahrs(sim, np.random.default_rng(seed))
        out.append((rec, EskfOffline(**_matched(sim), std_consistency_window_s=0.0)
                    .smooth(rec, attitude_cov=True)))
    return out


def test_smoothed_error_smaller_than_causal(mc_runs):
    """Per run: smoothed attitude RMS below 0.8 of the causal one (measured 0.54-0.63)
    and below 0.05 °; the smoothed bias error RMS below 0.02 °/s."""
    for rec, e in mc_runs:
        fwd = rms_deg(error_angle_rad(rec.q_true, e.signals["forward_q"]))
        smo = rms_deg(error_angle_rad(rec.q_true, e.q))
        assert smo < 0.8 * fwd and smo < 0.05
        db = np.linalg.norm(e.signals["bias_rad_s"] - rec.extra["gyro_bias_rad_s"], axis=1)
        assert rms_deg(db) < 0.02


def test_smoothed_covariance_is_consistent(mc_runs):
    """NEES of the smoothed attitude error ``ε`` (rotation vector, body axes) with the
    smoother's covariance: ``ε_kᵀ Σ_k⁻¹ ε_k`` (Σ = ``att_cov_rad2``, 3 dof), averaged over
    every sample of every run.

    Band: for K independent samples of a consistent estimator, the sum of the K NEES is
    chi-square with 3K degrees of freedom, so the mean lies in
    ``[chi2.ppf(0.025, 3K), chi2.ppf(0.975, 3K)] / K`` with probability 0.95. The samples
    of one run are correlated, so K is the number of independent ones:
    runs × duration / ``DECORRELATION_S`` (6 × 12 = 72; band about [2.47, 3.57]).
    ``att_std_rad`` per axis: the mean of ``(ε_i / std_i)²`` (1 dof each) lies in
    ``chi2.ppf([0.025, 0.975], K) / K``; and ``att_std_rad`` is the square root of
    ``att_cov_rad2``'s diagonal.
    """
    nees, per_axis = [], []
    for rec, e in mc_runs:
        eps = _rotation_error(rec.q_true, e.q)
        cov = e.signals["att_cov_rad2"]
        std = e.signals["att_std_rad"]
        np.testing.assert_allclose(std, np.sqrt(np.diagonal(cov, axis1=1, axis2=2)),
                                   rtol=1e-12)
        nees.append(np.einsum("ni,ni->n", eps, np.linalg.solve(cov, eps[:, :, None])[:, :, 0]))
        per_axis.append((eps / std) ** 2)
    k = len(SEEDS) * int(DURATION_S / DECORRELATION_S)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * k) / k
    mean = float(np.concatenate(nees).mean())
    assert lo < mean < hi, (lo, mean, hi)
    lo1, hi1 = stats.chi2.ppf([0.025, 0.975], k) / k
    axis_mean = np.concatenate(per_axis).mean(0)
    assert np.all((lo1 < axis_mean) & (axis_mean < hi1)), (lo1, axis_mean, hi1)
    # the independent samples alone (one every DECORRELATION_S s of each run)
    every = int(DECORRELATION_S * 100.0)
    spaced = np.concatenate([x[every // 2::every] for x in nees])
    lo_s, hi_s = stats.chi2.ppf([0.025, 0.975], 3 * len(spaced)) / len(spaced)
    assert lo_s < spaced.mean() < hi_s, (lo_s, spaced.mean(), hi_s)


def test_std_within_the_causal_filters(mc_runs):
    """Smoothing adds information: the smoothed variance is at most the filtered one at
    every sample (to rounding), and equal at the last."""
    from gnomon.kernels import eskf as kern
    from gnomon.kernels import eskf_smoother as sm

    rec, e = mc_runs[0]
    f = EskfOffline(**_matched(AhrsSimParams(duration_s=DURATION_S)),
                    std_consistency_window_s=0.0)
    inputs = f._kernel_inputs(rec)
    out = sm.new_passes(len(rec))
    sm.forward_pass(inputs, f.state, kern.coefficients(f.params), out)
    fwd_std = 2.0 * np.sqrt(out.P[:, [0, 6, 11]])  # P00, P11, P22 of the upper triangle
    assert np.all(e.signals["att_std_rad"] <= fwd_std * (1.0 + 1e-9))
    np.testing.assert_allclose(e.signals["att_std_rad"][-1], fwd_std[-1], rtol=1e-12)
    assert np.median(e.signals["att_std_rad"] / fwd_std) < 0.9


def _nees(rec, e) -> float:
    eps = _rotation_error(rec.q_true, e.q)
    return float(((eps / e.signals["att_std_rad"]) ** 2).sum(axis=1).mean())


def test_consistency_widening_only_widens_and_leaves_a_true_model_about_alone(mc_runs):
    """Default ``std_consistency_window_s`` (30 s) on the matched simulations: the band is
    the model's times ``std_scale`` >= 1 (exactly), and stays near honest: mean NEES in
    [2.0, 3.57] (the model's own: in its band [2.47, 3.57]; measured 2.8 → 2.3)."""
    nees = []
    for rec, e_model in mc_runs:
        e = EskfOffline(**_matched(AhrsSimParams(duration_s=DURATION_S))).run(rec)
        scale = e.signals["std_scale"]
        assert np.all(scale >= 1.0)
        np.testing.assert_allclose(e.signals["att_std_rad"],
                                   e_model.signals["att_std_rad"] * scale[:, None], rtol=1e-12)
        np.testing.assert_array_equal(e.q, e_model.q)
        nees.append(_nees(rec, e))
    assert 2.0 < np.mean(nees) < 3.57, np.round(nees, 2)


def test_consistency_widening_catches_an_overconfident_model():
    """Filter noise parameters 5x below the simulated sensors' (and unmodelled linear
    acceleration): the model's band is far too narrow (NEES >> 3); the widened one is
    within a factor 2 of honest in standard deviation (NEES < 12) and at least 3x
    closer to 3 than the model's."""
    sim = AhrsSimParams(duration_s=DURATION_S, linear_accel_rms=0.3)
    kw = _matched(sim)
    kw.update(gyro_noise=kw["gyro_noise"] / 5, accel_noise=kw["accel_noise"] / 5,
              mag_noise=kw["mag_noise"] / 5)
    model, widened = [], []
    for seed in range(3):
        rec = simulate_ahrs(sim, np.random.default_rng(100 + seed))
        model.append(_nees(rec, EskfOffline(**kw, std_consistency_window_s=0.0).run(rec)))
        widened.append(_nees(rec, EskfOffline(**kw).run(rec)))
    assert np.mean(model) > 12.0, model
    assert np.mean(widened) < 12.0 and np.mean(widened) < np.mean(model) / 3, (model,
                                                                              widened)


# ---------------------------------------------------------------- interface and bad input
def test_interface():
    assert EskfOffline.name == "eskf-offline" and EskfOffline.offline is True
    assert issubclass(EskfOffline.Params, EskfR3.Params)  # and the band's widening
    assert EskfOffline().params.measurement == "r3"
    rec = _sim(2, duration_s=2.0)
    e = EskfOffline().run(rec)
    assert set(e.signals) >= {"bias_rad_s", "att_std_rad", "forward_q", "bias_at_limit"}
    assert e.signals["bias_rad_s"].shape == (len(rec), 3)
    assert e.signals["att_std_rad"].shape == (len(rec), 3)
    assert e.signals["forward_q"].shape == (len(rec), 4)
    np.testing.assert_allclose(np.linalg.norm(e.q, axis=1), 1.0, atol=1e-12)
    assert "att_cov_rad2" not in e.signals


def test_bad_input_raises_the_filters_errors():
    rec = _sim(2, duration_s=1.0)
    with pytest.raises(InputError, match="field 'mag'"):
        EskfOffline().run(Recording(t=rec.t, gyro=rec.gyro, accel=rec.accel))
    with pytest.raises(InputError, match="frames.reference"):
        EskfOffline().run(dataclasses.replace(rec, frames={"reference": "NED", "body": "b"}))
    with pytest.raises(InputError, match="field 'measurement'"):
        EskfOffline(measurement="r6")
    with pytest.raises(InputError, match="field 'accel_noise'"):
        EskfOffline(accel_noise=-1.0)
    with pytest.raises(InputError, match="field 'gyro_nosie'"):
        EskfOffline(gyro_nosie=1e-3)
    f = EskfOffline()
    f.run(rec)
    with pytest.raises(InputError, match="field 't'"):  # continuing needs later samples
        f.run(rec)
    with pytest.raises(InputError, match="field 'update'"):
        EskfOffline().update(0.01, [0.0, 0.0, 0.0])


def test_a_direction_without_uncertainty_is_left_alone():
    """No bias uncertainty at all (``init_bias_std = bias_rw = 0``): ``P⁻`` is singular; the
    smoother leaves the bias at the filter's (zero) instead of dividing by rounding noise,
    and the attitude is smoothed, finite, with a standard deviation within the filter's."""
    rec = _sim(4, duration_s=10.0)
    e = EskfOffline(init_bias_std=0.0, bias_rw=0.0).run(rec)
    assert np.all(e.signals["bias_rad_s"] == 0.0)
    assert np.all(np.isfinite(e.q)) and np.all(np.isfinite(e.signals["att_std_rad"]))
    assert np.all(e.signals["att_std_rad"] > 0.0)
    assert rms_deg(error_angle_rad(rec.q_true, e.q)) < rms_deg(
        error_angle_rad(rec.q_true, e.signals["forward_q"]))
