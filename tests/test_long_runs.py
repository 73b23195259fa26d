"""Long runs: 10 million samples of a static, noiseless IMU through every IMU filter, and
a satellite held in the orbital frame through every spacecraft filter.

The quaternion must stay normalised (|‖q‖ − 1| < 1e-12), the estimate must not drift
(after the first 1% of the run) and must equal the exactly known attitude: its inclination
always, its heading too when the filter uses a magnetometer. On noiseless input any
drift is the filter's own.
"""

import numpy as np
import pytest

from gnomon.estimators import registry
from gnomon.metrics import broad_errors_rad, error_angle_rad
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_euler, quat_rotate

N = 10_000_000
IMU = {"gyro", "accel", "mag"}


@pytest.fixture(scope="module")
def static_imu():
    q_nb = quat_from_euler([0.2, -0.1, 0.7])
    q_bn = quat_conj(q_nb)
    acc = quat_rotate(q_bn, [0.0, 0.0, 9.81])
    mag = quat_rotate(q_bn, [0.0, 20.0, -45.0])
    t = np.arange(N) * 0.01
    zeros = np.zeros((N, 3))
    rec = Recording(t=t, gyro=zeros, accel=np.broadcast_to(acc, (N, 3)),
                    mag=np.broadcast_to(mag, (N, 3)), mag_unit="uT")
    return rec, q_nb


@pytest.mark.slow(reason="21 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name", [n for n in registry.names(offline=False)
                                  if registry.get(n).kind == "imu"
                                  and set(registry.get(n).needs) <= IMU])
def test_ten_million_static_samples(name, static_imu):
    rec, q_nb = static_imu
    est = registry.create(name).run(rec)
    norm_err = np.abs(np.linalg.norm(est.q[::997], axis=1) - 1.0).max()
    assert norm_err < 1e-12
    drift = np.degrees(error_angle_rad(est.q[N // 100], est.q[-1]))
    assert drift < 1e-6, f"{name} drifted {drift:.3g} deg on noiseless static input"
    inclination = np.degrees(broad_errors_rad(q_nb, est.q[-1])["inclination"])
    assert inclination < 1e-6
    if "mag" in registry.get(name).needs:  # heading observable: the whole attitude is right
        assert np.degrees(error_angle_rad(q_nb, est.q[-1])) < 1e-6
    for key, v in est.signals.items():
        v = np.asarray(v)
        if v.dtype.kind == "f":
            assert np.all(np.isfinite(v[-1])), key


# Spacecraft filters: a satellite held exactly in the orbital frame (q_ob = identity), so the
# gyro reads the orbital rate and both vectors are constant. The gyro-less EKF integrates the
# rigid-body dynamics with RK4 (about 0.1 M samples/s): it gets 1 million samples, the others
# 10 million.
SPACECRAFT = {"ecf-spacecraft": N, "qcf": N, "mekf-delayed": N,
              "mekf-spacecraft": 2_000_000, "ekf-spacecraft": 1_000_000}


def static_satellite(n):
    n_orbit = 0.00106  # rad/s, ~650 km
    w_io_o = np.array([0.0, -n_orbit, 0.0])
    b_o = np.array([20000.0, 5000.0, -30000.0])  # nT
    s_o = np.array([0.0, -1.0, 0.0])

    def const(v):
        return np.broadcast_to(v, (n, 3))

    return Recording(t=np.arange(n) * 1.0, gyro=const(w_io_o), mag=const(b_o), mag_unit="nT",
                     sun=const(s_o), sun_valid=np.ones(n, bool),
                     frames={"reference": "o", "body": "b"},
                     extra={"b_o_nT": const(b_o), "s_o": const(s_o), "w_io_o": const(w_io_o)})


@pytest.mark.slow(reason="96 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name", sorted(SPACECRAFT))
def test_long_static_satellite(name):
    n = SPACECRAFT[name]
    est = registry.create(name).run(static_satellite(n))
    norm_err = np.abs(np.linalg.norm(est.q[::997], axis=1) - 1.0).max()
    assert norm_err < 1e-12
    err = np.degrees(error_angle_rad([1.0, 0.0, 0.0, 0.0], est.q[-1]))
    assert err < 1e-6, f"{name} drifted {err:.3g} deg from the orbital frame"
