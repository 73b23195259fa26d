"""The compiled, batched IMU simulation (gnomon.kernels.simulate, simulate_ahrs_batch)
against its readable twin, closed forms and the noise parameters."""

from __future__ import annotations

import numpy as np
import pytest

from gnomon.kernels.simulate import ahrs_batch
from gnomon.metrics import error_angle_rad
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate
from gnomon.simulation.ahrs import (
    AhrsSimParams,
    simulate_ahrs,
    simulate_ahrs_batch,
    simulate_ahrs_reference,
)

CASES = {
    "default": dict(duration_s=30.0),
    "rest-disturbed": dict(duration_s=30.0, rest_s=3.3, linear_accel_rms=2.0,
                           mag_disturbance_uT=20.0, disturbance_window_s=(10.0, 20.0)),
    # |w h| crosses 0.05 rad: the exact exponential branch
    "fast-one-substep": dict(duration_s=10.0, substeps=1, rate_rms=4.0, rate_hz=50.0),
    "three-substeps": dict(duration_s=10.0, substeps=3, rate_hz=200.0, n_harmonics=2),
}


#: the draw orders, each with the generator it is used with (the ``kind: imu`` scenarios:
#: SFC64 by sample)
ORDERS = {"by-sensor": np.random.default_rng,
          "by-sample": lambda s: np.random.Generator(np.random.SFC64(s))}


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("case", CASES)
def test_batch_equals_reference(case, order):
    """Same draws, same model: every sample equal to rounding (1e-12 of its scale), for
    runs in a full block and in a partial one (11 runs: 8 + 3), in either draw order."""
    p = AhrsSimParams(**CASES[case])
    seeds = list(range(11))
    make = ORDERS[order]
    recs = simulate_ahrs_batch(p, [make(s) for s in seeds], order)
    for s in (0, 7, 10):
        ref = simulate_ahrs_reference(p, make(s), order)
        rec = recs[s]
        np.testing.assert_array_equal(rec.t, ref.t)
        np.testing.assert_allclose(rec.q_true, ref.q_true, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rec.gyro, ref.gyro, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rec.extra["w_true_rad_s"], ref.extra["w_true_rad_s"],
                                   rtol=0, atol=1e-12)
        # the bias is the reference's arithmetic in the reference's order: bit for bit
        np.testing.assert_array_equal(rec.extra["gyro_bias_rad_s"],
                                      ref.extra["gyro_bias_rad_s"])
        np.testing.assert_allclose(rec.accel, ref.accel, rtol=0, atol=1e-11)   # m/s², g ~ 10
        np.testing.assert_allclose(rec.mag, ref.mag, rtol=0, atol=1e-10)       # µT, |m| 50


def test_one_run_is_a_run_of_the_batch():
    p = AhrsSimParams(duration_s=5.0)
    batch = simulate_ahrs_batch(p, [np.random.default_rng(s) for s in (5, 6, 7)])
    one = simulate_ahrs(p, np.random.default_rng(6))
    np.testing.assert_array_equal(one.gyro, batch[1].gyro)
    np.testing.assert_array_equal(one.q_true, batch[1].q_true)
    assert one.gyro.flags.c_contiguous and one.q_true.flags.c_contiguous


def _kernel(n, dt, substeps, f, ph, amp, q0, sigma, rng=None, runs=1, m_n=(0.0, 25.0, -43.3)):
    """ahrs_batch on hand-made sums of sinusoids (runs share them), noise from rng."""
    t = np.arange(n) * dt
    h = np.asarray(f, float).shape[0]
    def tile(a):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(a, float), (runs, h, 3)))
    none = np.zeros((runs, 0, 3))
    draws = [np.zeros((runs, n, 3)) if rng is None else rng.standard_normal((runs, n, 3))
             for _ in range(4)]
    gyro, bias, accel, mag = draws
    q = np.empty((runs, n, 4))
    w = np.empty((runs, n, 3))
    def per_run(a):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(a, float), (runs, len(a))))
    ahrs_batch(t, dt, substeps, 0.0, np.array([0.0, np.inf]), tile(f), tile(ph), tile(amp),
               per_run(q0), per_run([0.0, 0.0, 9.81]), none, none, none, per_run(m_n),
               np.zeros(runs), none, none, none, np.zeros((runs, 3)), per_run(sigma),
               gyro, bias, accel, mag, q, w)
    return t, gyro, bias, accel, mag, q, w


@pytest.mark.slow(reason="6 s (2 cores): long runs or a first compilation")
def test_constant_rate_integrates_to_the_exponential():
    """A constant body rate (one harmonic at 0 Hz, phase π/2) turns q0 by exp(w t) exactly,
    also at a rate whose substeps need the exact exponential (0.3 rad per substep)."""
    q0 = quat_from_rotvec(np.array([0.3, -0.2, 1.0]))
    for w_b, substeps in (([0.4, -0.7, 0.2], 8), ([30.0, 10.0, -5.0], 1)):
        t, gyro, _, _, _, q, w = _kernel(201, 0.01, substeps, np.zeros((1, 3)),
                                         np.full((1, 3), np.pi / 2), [w_b], q0, np.zeros(4))
        expect = quat_mul(q0, quat_from_rotvec(np.outer(t, w_b)))
        err = np.abs(np.where((q * expect).sum(-1, keepdims=True) < 0, -q, q)[0] - expect)
        assert err.max() < 1e-12 * len(t)
        np.testing.assert_allclose(w[0], np.broadcast_to(w_b, (len(t), 3)), atol=1e-12)
        np.testing.assert_allclose(gyro[0], w[0], atol=0)           # no bias, no noise


def test_coning_motion_integrates_to_its_closed_form_at_fourth_order():
    """Classical coning (half-angle a = 0.2 rad at 1 Hz): q(t) = [cos a/2, sin a/2 cos Ωt,
    sin a/2 sin Ωt, 0] for the body rate [-Ω sin a sin Ωt, Ω sin a cos Ωt, -2Ω sin² a/2].
    After 60 s at 100 Hz the 4th-order Magnus step is 8.9e-6 deg off with one substep
    (8 midpoint steps: 2.2e-3 deg), and halving the substep divides the error by 16."""
    om, a = 2.0 * np.pi, 0.2
    f = [[1.0, 1.0, 0.0]]
    ph = [[np.pi, np.pi / 2, -np.pi / 2]]
    amp = [[om * np.sin(a), om * np.sin(a), 2.0 * om * np.sin(a / 2) ** 2]]
    q0 = np.array([np.cos(a / 2), np.sin(a / 2), 0.0, 0.0])
    errs = []
    for substeps in (1, 2):
        t, _, _, _, _, q, w = _kernel(6001, 0.01, substeps, f, ph, amp, q0, np.zeros(4))
        exact = np.stack([np.full_like(t, np.cos(a / 2)), np.sin(a / 2) * np.cos(om * t),
                          np.sin(a / 2) * np.sin(om * t), np.zeros_like(t)], axis=1)
        errs.append(np.degrees(error_angle_rad(exact, q[0])).max())
        mid = t[1:] - 0.005
        np.testing.assert_allclose(w[0, 1:, 2], -2.0 * om * np.sin(a / 2) ** 2, atol=1e-13)
        np.testing.assert_allclose(w[0, 1:, 0], -om * np.sin(a) * np.sin(om * mid), atol=1e-12)
    assert errs[0] < 2e-5
    assert 12.0 < errs[0] / errs[1] < 20.0


def test_resting_imu_reads_gravity_and_the_field():
    """At rest with no noise: accel = R(q0)ᵀ [0, 0, g], mag = R(q0)ᵀ m_n, gyro 0."""
    m_n = np.array([0.0, 25.0, -43.3])
    for q0 in (np.array([1.0, 0.0, 0.0, 0.0]), quat_from_rotvec(np.array([0.2, -0.4, 2.0]))):
        _, gyro, _, accel, mag, q, _ = _kernel(50, 0.01, 8, np.zeros((1, 3)), np.zeros((1, 3)),
                                               np.zeros((1, 3)), q0, np.zeros(4), m_n=m_n)
        np.testing.assert_allclose(q[0], np.broadcast_to(q0, (50, 4)), atol=1e-15)
        np.testing.assert_allclose(accel[0], np.broadcast_to(
            quat_rotate(quat_conj(q0), np.array([0.0, 0.0, 9.81])), (50, 3)), atol=1e-14)
        np.testing.assert_allclose(mag[0], np.broadcast_to(
            quat_rotate(quat_conj(q0), m_n), (50, 3)), atol=1e-13)
        assert not gyro.any()
    np.testing.assert_array_equal(accel[0][0], accel[0][-1])


@pytest.mark.parametrize("order", ORDERS)
def test_noise_and_bias_statistics(order):
    """Noise stds as the parameters, a bias random walk whose variance grows as rw² t;
    in either draw order, the noises of one sample uncorrelated and white.

    40 runs x 2001 samples at rest: 240,000 draws per noise, so each std is known to
    0.15 %; tolerances 1.5 %. The walk's variance across runs at t = 20 s has a relative
    standard error of sqrt(2/40) = 22 %; tolerance 60 % (and the increments' std 1.5 %).
    A correlation of 80,000 independent pairs (40 runs x 2,000 samples, one axis) has a
    standard error of 0.0035: at most 0.02 (5.7 sigma) between two sensors' noise of one
    sample and from one sample to the next (a draw reused or misplaced gives far more).
    """
    p = AhrsSimParams(duration_s=20.0, rate_rms=0.0, gyro_bias_std=0.01, bias_rw=2e-4,
                      gyro_noise=3e-3, accel_noise=0.05, mag_noise_uT=0.4)
    make = ORDERS[order]
    recs = simulate_ahrs_batch(p, [make(100 + s) for s in range(40)], order)
    dt = 1.0 / p.rate_hz
    bias = np.stack([r.extra["gyro_bias_rad_s"] for r in recs])
    gyro_err = np.stack([r.gyro for r in recs]) - bias
    acc = np.stack([r.accel for r in recs])
    mag = np.stack([r.mag for r in recs])
    acc_truth = np.stack([quat_rotate(quat_conj(r.q_true), np.array([0.0, 0.0, p.gravity]))
                          for r in recs])
    inc = np.radians(p.inclination_deg)
    m_n = np.array([0.0, p.field_uT * np.cos(inc), -p.field_uT * np.sin(inc)])
    mag_truth = np.stack([quat_rotate(quat_conj(r.q_true), m_n) for r in recs])
    assert abs(gyro_err.std() / (p.gyro_noise * np.sqrt(p.rate_hz)) - 1) < 0.015
    assert abs(gyro_err.mean()) < 4 * p.gyro_noise * np.sqrt(p.rate_hz) / np.sqrt(gyro_err.size)
    assert abs((acc - acc_truth).std() / p.accel_noise - 1) < 0.015
    assert abs((mag - mag_truth).std() / p.mag_noise_uT - 1) < 0.015
    steps = np.diff(bias, axis=1)
    assert abs(steps.std() / (p.bias_rw * np.sqrt(dt)) - 1) < 0.015
    walk = bias[:, -1] - bias[:, 0]
    t_end = (len(recs[0].t) - 1) * dt
    assert abs(walk.var(axis=0).mean() / (p.bias_rw**2 * t_end) - 1) < 0.6
    b0 = bias[:, 0]
    assert abs(b0.std() / p.gyro_bias_std - 1) < 0.3    # 120 draws: 6.5 % standard error
    noise = [gyro_err[:, 1:] - gyro_err[:, 1:].mean(), steps, (acc - acc_truth)[:, 1:],
             (mag - mag_truth)[:, 1:]]
    for a in range(4):
        for b in range(a + 1, 4):     # bias step, gyro, accelerometer, magnetometer: x axis
            assert abs(np.corrcoef(noise[a][..., 0].ravel(), noise[b][..., 0].ravel())[0, 1]) \
                < 0.02, (a, b)
        lag = np.corrcoef(noise[a][:, 1:, 2].ravel(), noise[a][:, :-1, 2].ravel())[0, 1]
        assert abs(lag) < 0.02, a


def test_draws_by_sample_are_numpy_normals_in_rows_of_twelve():
    """``normals_by_sample`` (numba running numpy's normal on the generator) gives
    ``rng.standard_normal((N, 12))`` bit for bit, split by columns, and leaves the
    generator where numpy's call leaves it; an unknown order is an InputError."""
    from gnomon.errors import InputError
    from gnomon.kernels.simulate import normals_by_sample

    n = 1001
    out = [np.empty((n, 3)) for _ in range(4)]
    rng = np.random.Generator(np.random.SFC64(42))
    normals_by_sample(rng, *out)
    ref_rng = np.random.Generator(np.random.SFC64(42))
    z = ref_rng.standard_normal((n, 12))
    for i in range(4):
        np.testing.assert_array_equal(out[i], z[:, 3 * i:3 * i + 3])
    assert rng.random() == ref_rng.random()
    with pytest.raises(InputError, match="draw order 'sideways'") as err:
        simulate_ahrs(AhrsSimParams(duration_s=1.0), np.random.default_rng(1), "sideways")
    assert err.value.field == "draw_order"


def test_imu_scenario_runs_are_the_by_sample_stream():
    """A ``kind: imu`` scenario's run is ``simulate_ahrs`` with ``imu_rng(seed)`` drawn by
    sample, alone and in a batch (``simulate_many``)."""
    from gnomon.scenarios import load_scenario, simulate, simulate_many
    from gnomon.scenarios.simulator import _imu_params, imu_rng

    sc = load_scenario("imu-handheld").replace({"duration_s": 3.0})
    direct = simulate_ahrs(_imu_params(sc.config), imu_rng(9), "by-sample")
    alone = simulate(sc, rng_seed=9)
    batch = simulate_many([sc, sc, sc], [8, 9, 10])[1]
    for rec in (alone, batch):
        np.testing.assert_array_equal(rec.gyro, direct.gyro)
        np.testing.assert_array_equal(rec.mag, direct.mag)
        np.testing.assert_array_equal(rec.q_true, direct.q_true)


def test_bench_reports_simulated_samples_per_second():
    """``gnomon bench --json``'s ``simulation`` entry (speed measured, not asserted)."""
    from gnomon.speed import run_simulation, simulation_line

    sim = run_simulation(runs=3, duration_s=2.0, repeats=2)
    assert set(sim) == {"samples_per_s", "runs", "samples_timed"}
    assert sim["runs"] == 3 and sim["samples_timed"] == 3 * 201 and sim["samples_per_s"] > 0
    assert "million simulated samples/s" in simulation_line({"simulation": sim})
    assert simulation_line({}) == ""


def test_runs_with_their_own_parameters_in_one_batch():
    """Noise levels, biases, rates and the field may differ per run; the time base may
    not (InputError)."""
    from gnomon.errors import InputError

    base = AhrsSimParams(duration_s=5.0, linear_accel_rms=1.0)
    ps = [base, AhrsSimParams(duration_s=5.0, linear_accel_rms=3.0, gyro_noise=1e-3,
                              accel_noise=0.1, field_uT=30.0, inclination_deg=20.0,
                              rate_rms=1.5, rate_band_hz=(0.1, 1.0), gravity=9.78),
          base]
    recs = simulate_ahrs_batch(ps, [np.random.default_rng(s) for s in (1, 2, 3)])
    for r, (p, s) in enumerate(zip(ps, (1, 2, 3), strict=True)):
        ref = simulate_ahrs_reference(p, np.random.default_rng(s))
        np.testing.assert_allclose(recs[r].gyro, ref.gyro, rtol=0, atol=1e-12)
        np.testing.assert_allclose(recs[r].accel, ref.accel, rtol=0, atol=1e-11)
        np.testing.assert_allclose(recs[r].mag, ref.mag, rtol=0, atol=1e-10)
    with pytest.raises(InputError, match="must share"):
        simulate_ahrs_batch([base, AhrsSimParams(duration_s=6.0, linear_accel_rms=1.0)],
                            [np.random.default_rng(1), np.random.default_rng(2)])
    with pytest.raises(InputError, match="must share"):
        simulate_ahrs_batch([base, AhrsSimParams(duration_s=5.0)],
                            [np.random.default_rng(1), np.random.default_rng(2)])
