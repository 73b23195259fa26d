"""Every sensor at its own rate: filters take each sample once, when it is new.

A synthetic IMU (exact truth) at 200 Hz whose magnetometer is kept at 50 Hz and its
accelerometer at 100 Hz, each on its own clock (offset time stamps): the compiled run
equals the readable ``update_reference`` fed ``None`` where no new sample arrived, and the
accuracy stays that of the full-rate recording."""

import numpy as np
import pytest

from gnomon.estimators import registry
from gnomon.metrics import error_angle_rad
from gnomon.recording import Recording
from gnomon.rotation import quat_from_euler

MULTI_RATE = [n for n in registry.names("imu") if registry.get(n).multi_rate]


def _decimated(rec: Recording, acc_every=2, mag_every=4, offset_s=0.001) -> Recording:
    """``rec`` with the accelerometer and magnetometer kept at a lower rate, their time
    stamps ``offset_s`` before the gyro's (sampled on their own clock)."""
    ia = np.arange(0, len(rec), acc_every)
    im = np.arange(1, len(rec), mag_every)
    return Recording(t=rec.t, gyro=rec.gyro, accel=rec.accel[ia], accel_t=rec.t[ia] - offset_s,
                     mag=rec.mag[im], mag_t=rec.t[im] - offset_s, q_true=rec.q_true,
                     source="decimated")


@pytest.fixture(scope="module")
def recs():
    from conftest import synthetic_imu

    full = synthetic_imu(quat_from_euler([0.3, -0.2, 2.0]), [0.3, -0.4, 0.5], n=6000,
                         fs=200.0, gyro_bias=[0.01, -0.02, 0.005], noise=0.005, seed=4)
    return full, _decimated(full)


def test_the_registry_has_multi_rate_imu_filters():
    assert {"mahony", "robust-ahrs", "tilt-cf"} <= set(MULTI_RATE)


@pytest.mark.slow(reason="6 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name", ["mahony", "robust-ahrs", "tilt-cf"])
def test_compiled_run_equals_update_with_none_where_no_sample(recs, name):
    _, rec = recs
    params = {"init_samples": 1} if name == "tilt-cf" else {}
    est = registry.create(name, params).run(rec)
    twin = registry.create(name, params)
    if name == "robust-ahrs":
        twin.start(*(rec.nominal_dt_s(n, twin.params.max_dt_s) for n in ("gyro", "accel",
                                                                          "mag")))
    acc, mag = rec.on_time_base("accel"), rec.on_time_base("mag")
    dt = np.diff(rec.t, prepend=rec.t[0])
    q = []
    for k in range(len(rec)):
        a = acc[k] if np.isfinite(acc[k, 0]) else None
        m = mag[k] if np.isfinite(mag[k, 0]) else None
        if k == 0 and name == "mahony":
            twin.initialise(rec.accel[:1], rec.mag[:1])
        if k == 0 and name == "tilt-cf":
            a = rec.accel[0]
        args = (dt[k], rec.gyro[k], a) if name == "tilt-cf" else (dt[k], rec.gyro[k], a, m)
        q.append(twin.update_reference(*args).copy())
    np.testing.assert_allclose(np.array(q), est.q, atol=1e-11)


@pytest.mark.parametrize("name", MULTI_RATE)
def test_lower_sensor_rates_keep_the_accuracy(recs, name):
    full, dec = recs
    settle = full.t >= 10.0
    # robust-ahrs averages mag_every magnetometer samples per heading update (a speed
    # setting for fast magnetometers): at 50 Hz every sample is an update
    params = {"mag_every": 1} if name == "robust-ahrs" else {}
    e_full = np.degrees(error_angle_rad(full.q_true, registry.create(name, params).run(full).q))
    e_dec = np.degrees(error_angle_rad(dec.q_true, registry.create(name, params).run(dec).q))
    rms_full = np.sqrt(np.mean(e_full[settle] ** 2))
    rms_dec = np.sqrt(np.mean(e_dec[settle] ** 2))
    # the same information at a quarter of the rate: within 0.25 deg (or 30 %) of full rate
    # (the ESKF: 0.41 / 0.62 deg since its low-pass follows the corrections; 5.1 / 0.88
    # before, when the full rate fed the repeated tilt measurement into the bias)
    assert np.isfinite(e_dec).all()
    assert rms_dec < max(1.3 * rms_full, rms_full + 0.25), (rms_full, rms_dec)


@pytest.mark.slow(reason="10 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("params", [{}, {"bias_gate": 0.05, "bias_gate_tau": 0.05}])
@pytest.mark.parametrize("name", ["eskf-r6", "eskf-r3"])
def test_eskf_one_sensor_rows_equal_the_readable_update(recs, name, params):
    """The ESKF corrects with the accelerometer's or the magnetometer's rows alone where
    only one has a new sample (here never both: their samples arrive in alternate rows);
    with a tiny ``bias_gate`` the bias is held on some of them. The readable
    ``update_reference`` and the compiled ``update``, resumed from a saved state, both
    give the compiled run."""
    _, rec = recs
    start = registry.create(name, params)
    start.run(rec.slice(0, 400))
    rest = rec.slice(400, len(rec))
    kernel, twin, fast = (registry.create(name, params) for _ in range(3))
    fast.update(0.0, rest.gyro[0], rest.accel[0], rest.mag[0])  # started, then resumed:
    for f in (kernel, twin, fast):  # the saved state replaces what the first sample set
        f.set_state(start.get_state())
    est = kernel.run(rest)
    acc, mag = rest.on_time_base("accel"), rest.on_time_base("mag")
    assert not (np.isfinite(acc[:, 0]) & np.isfinite(mag[:, 0])).any()
    dt = np.diff(rest.t, prepend=rec.t[399])
    for f, tol in ((twin, 1e-10), (fast, 1e-12)):
        step = f.update_reference if f is twin else f.update
        q = np.array([step(dt[k], rest.gyro[k], acc[k] if np.isfinite(acc[k, 0]) else None,
                           mag[k] if np.isfinite(mag[k, 0]) else None)
                      for k in range(len(rest))])
        np.testing.assert_allclose(q, est.q, atol=tol)
        np.testing.assert_allclose(f.P, kernel.P, atol=1e-12)
        np.testing.assert_allclose(f.bias, kernel.bias, atol=1e-12)
    if params:  # the gate both shut and open
        moved = np.any(np.diff(est.signals["bias_rad_s"], axis=0) != 0, axis=1)
        assert 0.05 < moved.mean() < 0.95, moved.mean()
