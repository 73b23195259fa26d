"""The 9-axis explicit complementary filter: compiled kernel vs readable update, convergence."""

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.estimators.mahony import Mahony, MahonyParams
from gnomon.metrics import error_angle_rad
from gnomon.recording import Recording
from gnomon.rotation import quat_from_euler


def test_kernel_equals_reference_sample_by_sample(imu_factory):
    rec = imu_factory(quat_from_euler([0.3, -0.2, 2.0]), [0.2, -0.5, 0.4], n=3000,
                      gyro_bias=[0.01, -0.02, 0.005], noise=0.01, seed=3)
    params = MahonyParams(kp_acc_rad_s=1.0, kp_mag_rad_s=0.5, ki_rad_s2=0.05,
                          mag_heading_only=True)
    est = Mahony(params).run(rec)
    ref = Mahony(params)
    dt = np.diff(rec.t, prepend=rec.t[0])
    q_ref = np.array([ref.update_reference(dt[i], rec.gyro[i], rec.accel[i], rec.mag[i])
                      for i in range(len(rec))])
    np.testing.assert_allclose(est.q, q_ref, atol=1e-12)
    np.testing.assert_allclose(est.signals["bias_rad_s"][-1], ref.bias, atol=1e-12)


@pytest.mark.parametrize("heading_only", [True, False])
def test_converges_and_estimates_bias(imu_factory, heading_only):
    bias = np.array([0.02, -0.01, 0.03])  # rad/s
    rec = imu_factory(quat_from_euler([0.5, 0.3, -1.0]), [0.0, 0.0, 0.0], n=30000, fs=100,
                      gyro_bias=bias)
    est = Mahony(kp_acc_rad_s=1.0, kp_mag_rad_s=1.0, ki_rad_s2=0.1,
                 mag_heading_only=heading_only).run(rec)
    np.testing.assert_allclose(est.signals["bias_rad_s"][-1], bias, atol=1e-4)
    assert np.degrees(error_angle_rad(rec.q_true[-1], est.q[-1])) < 0.01


def test_tracks_rotation_with_initial_error(imu_factory):
    rec = imu_factory(quat_from_euler([0.1, 0.2, 0.3]), [0.3, 0.2, -0.6], n=6000, fs=100)
    f = Mahony(kp_acc_rad_s=2.0, kp_mag_rad_s=2.0, ki_rad_s2=0.0)
    f.q = quat_from_euler([0.4, -0.3, 1.0])  # 40+ degrees off
    est = f.run(rec)
    err = np.degrees(error_angle_rad(rec.q_true, est.q))
    assert err[0] > 30
    assert err[-1000:].max() < 1e-3


def test_zero_vectors_and_gaps_coast_without_nan():
    n = 200
    t = np.arange(n) / 100.0
    t[100:] += 5.0  # a 5 s gap
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    mag = np.tile([0.0, 20.0, -40.0], (n, 1))
    acc[50:60] = 0.0
    mag[70:80] = 0.0
    rec = Recording(t=t, gyro=np.zeros((n, 3)), accel=acc, mag=mag)
    est = Mahony().run(rec)
    assert np.all(np.isfinite(est.q))
    assert est.signals["acc_skipped"][50:60].all() and not est.signals["acc_skipped"][60:].any()
    assert est.signals["mag_skipped"][70:80].all()
    assert est.signals["gap"][100] and est.signals["gap"].sum() == 1
    ref = Mahony()
    dt = np.diff(t, prepend=t[0])
    for i in range(n):
        ref.update_reference(dt[i], rec.gyro[i], acc[i], mag[i])
    np.testing.assert_allclose(est.q[-1], ref.q, atol=1e-12)


def test_params_reject_unknown_and_bad_values():
    with pytest.raises(InputError, match="kp_ac"):
        MahonyParams.from_dict({"kp_ac": 1.0})
    with pytest.raises(InputError, match="ki_rad_s2"):
        MahonyParams(ki_rad_s2=-1.0)
    with pytest.raises(InputError, match="renamed: use 'ki_rad_s2'") as err:
        MahonyParams.from_dict({"ki_per_s": 0.01})  # the old name carried a wrong unit
    assert err.value.field == "ki_per_s"
    p = MahonyParams.from_dict({"kp_acc_rad_s": "0.5", "mag_heading_only": "false"})
    assert p.kp_acc_rad_s == 0.5 and p.mag_heading_only is False
    with pytest.raises(InputError, match="mag_heading_only"):
        MahonyParams.from_dict({"mag_heading_only": "maybe"})


def test_needs_magnetometer():
    rec = Recording(t=np.arange(10.0), gyro=np.zeros((10, 3)), accel=np.ones((10, 3)))
    with pytest.raises(InputError, match="'mag'"):
        Mahony().run(rec)


def test_batch_over_runs_equals_single_runs(imu_factory):
    from gnomon.estimators.mahony import run_batch

    recs = [imu_factory(quat_from_euler([0.1 * k, -0.2, 1.0 + k]), [0.2, -0.1 * k, 0.3],
                        n=500, noise=0.01, seed=k) for k in range(5)]
    params = MahonyParams(kp_acc_rad_s=0.8, ki_rad_s2=0.05)
    q = run_batch(recs[0].t, np.stack([r.gyro for r in recs]), np.stack([r.accel for r in recs]),
                  np.stack([r.mag for r in recs]), params)
    assert q.shape == (5, 500, 4)
    for k, rec in enumerate(recs):
        np.testing.assert_allclose(q[k], Mahony(params).run(rec).q, atol=1e-12)


@pytest.mark.parametrize("heading_only", [True, False])
def test_batch_redoes_the_steps_that_need_exact_forms(imu_factory, heading_only):
    """Fast turns (> 0.05 rad a step), a gap, a zero vector and a non-unit initial
    quaternion take the batch kernel's exact path; every run still equals its own run."""
    from gnomon.estimators.mahony import run_batch

    rates = [[0.2, -0.1, 0.3], [9.0, -2.0, 4.0], [0.1, 0.0, -0.2], [0.5, 7.5, -6.0]]
    recs = [imu_factory(quat_from_euler([0.2, -0.1 * k, 0.5 * k]), w, n=400, noise=0.01,
                        seed=10 + k) for k, w in enumerate(rates)]
    t = recs[0].t.copy()
    t[200:] += 3.0  # a gap longer than max_dt_s
    acc = np.stack([r.accel for r in recs])
    acc[2, 50:55] = 0.0
    q0 = np.stack([quat_from_euler([0.1, 0.2, 0.3 * k]) for k in range(4)])
    q0[3] *= 1.001  # far from unit norm: normalised by 1/sqrt, not by the Newton step
    params = MahonyParams(kp_acc_rad_s=0.8, kp_mag_rad_s=0.4, ki_rad_s2=0.05,
                          mag_heading_only=heading_only)
    q = run_batch(t, np.stack([r.gyro for r in recs]), acc, np.stack([r.mag for r in recs]),
                  params, q0=q0)
    for k, rec in enumerate(recs):
        single = Mahony(params)
        single.q = q0[k].copy()
        one = single.run(Recording(t=t, gyro=rec.gyro, accel=acc[k], mag=rec.mag))
        np.testing.assert_allclose(q[k], one.q, atol=1e-12)
    ref = Mahony(params)  # the readable reference, for the fastest run
    ref.q = q0[1].copy()
    dt = np.diff(t, prepend=t[0])
    q_ref = np.array([ref.update_reference(dt[i], recs[1].gyro[i], acc[1, i], recs[1].mag[i])
                      for i in range(len(t))])
    np.testing.assert_allclose(q[1], q_ref, atol=1e-12)


def test_batch_writes_into_an_earlier_result(imu_factory):
    from gnomon.estimators.mahony import run_batch

    recs = [imu_factory(quat_from_euler([0.1, -0.2, k]), [0.2, 0.1 * k, 0.3], n=300,
                        noise=0.01, seed=k) for k in range(3)]
    g, a, m = (np.stack([getattr(r, f) for r in recs]) for f in ("gyro", "accel", "mag"))
    first = run_batch(recs[0].t, g, a, m)
    kept = first.copy()
    again = run_batch(recs[0].t, g[::-1], a[::-1], m[::-1], out=first)
    assert np.shares_memory(again, first)
    np.testing.assert_allclose(again, kept[::-1], atol=1e-12)
    with pytest.raises(InputError, match="out"):
        run_batch(recs[0].t, g, a, m, out=np.empty((3, 300, 4)))  # not run-minor memory


def test_split_run_with_saved_state_equals_whole_run(imu_factory):
    rec = imu_factory(quat_from_euler([0.3, 0.1, -0.5]), [0.3, 0.2, -0.1], n=2000, noise=0.01)
    whole = Mahony().run(rec).q
    first = Mahony()
    a = first.run(rec.slice(0, 1234)).q
    resumed = Mahony()
    resumed.set_state(first.get_state())
    b = resumed.run(rec.slice(1234, len(rec))).q
    np.testing.assert_array_equal(np.vstack([a, b]), whole)
    with pytest.raises(InputError, match="not after"):
        resumed.run(rec.slice(0, 10))
