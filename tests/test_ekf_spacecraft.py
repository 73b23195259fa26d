"""Seed-001 EKF and the gyro-aided MEKF preset: Jacobians against finite differences, the
measurement model against gnomon.rotation, convergence in the ideal case, eclipse,
compiled kernels against their interpreted twins."""

from __future__ import annotations

import numpy as np
import pytest

from gnomon.estimators import registry
from gnomon.estimators.ekf_spacecraft import EKFSpacecraft, triad_q_ob
from gnomon.estimators.mekf import MEKFSpacecraft
from gnomon.kernels import ekf_spacecraft as K
from gnomon.kernels.linalg import skew_arr
from gnomon.metrics import error_angle_rad
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_euler, quat_rotate
from gnomon.scenarios import load_scenario, simulate

J = np.array([[0.40, 0.006, -0.004], [0.006, 0.58, 0.01], [-0.004, 0.01, 0.55]])


def _fd_jacobian(f, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=1)


def test_measurement_model_is_the_orbital_to_body_rotation():
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = quat_from_euler(rng.uniform(-3, 3, 3))
        v = rng.standard_normal(3)
        np.testing.assert_allclose(K.rt_v(q, v), quat_rotate(quat_conj(q), v), atol=1e-12)


def test_H_against_finite_differences():
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.standard_normal(4)          # also off the unit sphere: the polynomial model
        v = rng.standard_normal(3)
        np.testing.assert_allclose(K.d_rt_v(q, v), _fd_jacobian(lambda x, v=v: K.rt_v(x, v), q),
                                   atol=1e-8)


@pytest.mark.parametrize("m", [3, 6])
def test_row_at_a_time_update_is_the_joint_joseph_update(m):
    """``correct`` takes the rows one by one; with a diagonal R that is the paper's joint
    update ``K = P Hᵀ (H P Hᵀ + R)⁻¹``, ``P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ`` (numpy's
    solve here), the quaternion renormalised after."""
    rng = np.random.default_rng(5)
    for _ in range(5):
        A = rng.standard_normal((7, 7))
        P = A @ A.T * 1e-3 + np.eye(7) * 1e-4
        z = np.concatenate([rng.normal(0, 0.01, 3), quat_from_euler(rng.uniform(-2, 2, 3))])
        Hq = rng.standard_normal((m, 4))
        y = rng.normal(0, 0.05, m)
        r = rng.uniform(1e-4, 4e-4, m)
        H = np.hstack([np.zeros((m, 3)), Hq])
        K_ = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(r))
        IKH = np.eye(7) - K_ @ H
        P_joint = IKH @ P @ IKH.T + K_ @ np.diag(r) @ K_.T
        z_joint = z + K_ @ y
        z_joint[3:] /= np.linalg.norm(z_joint[3:])
        zz, PP = z.copy(), P.copy()
        w = K.workspace()
        K.correct(m, zz, PP, Hq, y, r, w.dz, w.p, w.kg)
        np.testing.assert_allclose(zz, z_joint, rtol=0, atol=1e-13)
        np.testing.assert_allclose(PP, P_joint, rtol=1e-10, atol=1e-18)
        np.testing.assert_array_equal(PP, PP.T)
        assert np.all(np.linalg.eigvalsh(PP) > 0)


@pytest.mark.slow(reason="5 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("gg", [0.0, 3 * 0.0011**2])
def test_F_against_finite_differences(gg):
    rng = np.random.default_rng(2)
    Jinv = np.linalg.inv(J)
    for _ in range(10):
        z = np.concatenate([rng.normal(0, 0.01, 3), quat_from_euler(rng.uniform(-2, 2, 3))])
        h = rng.normal(0, 0.01, 3)
        hdot = rng.normal(0, 1e-4, 3)
        tau = rng.normal(0, 1e-5, 3)
        w_io = np.array([0.0, -0.0011, 0.0])
        F = K.ekf_jacobian(z, J, Jinv, h, w_io, gg)
        Ffd = _fd_jacobian(
            lambda x, a=(h, hdot, tau, w_io): K.ekf_f(x, J, Jinv, *a, gg), z)
        np.testing.assert_allclose(F, Ffd, atol=1e-9, rtol=1e-6)
    # the top-left block is the paper's J^-1([(Jw)x] - [wx]J) when h = 0
    w = z[:3]
    F0 = K.ekf_jacobian(z, J, Jinv, np.zeros(3), w_io, gg)
    np.testing.assert_allclose(F0[:3, :3], Jinv @ (skew_arr(J @ w) - skew_arr(w) @ J),
                               atol=1e-15)


def test_triad_recovers_the_rotation():
    q = quat_from_euler([0.3, -0.2, 1.1])
    a_o, b_o = np.array([0.2, 0.5, -0.8]), np.array([1.0, 0.1, 0.3])
    qt = triad_q_ob(quat_rotate(quat_conj(q), a_o), quat_rotate(quat_conj(q), b_o), a_o, b_o)
    assert np.degrees(error_angle_rad(q, qt)) < 1e-9


@pytest.fixture(scope="module")
def ideal():
    """2400 s of the seed-001 scenario without sensor noise (eclipse from 1859 s)."""
    sc = load_scenario("seed001").replace({
        "duration_s": 2400.0, "sensors.magnetometer.noise_nT": 0.0,
        "sensors.sun_sensor.noise_deg": 0.0})
    return simulate(sc)


@pytest.fixture(scope="module")
def noisy():
    return simulate(load_scenario("seed001").replace({"duration_s": 2400.0}))


def _err_deg(rec, est):
    return np.degrees(error_angle_rad(rec.q_true, est.q))


def test_registered():
    assert registry.get("ekf-spacecraft") is EKFSpacecraft
    assert registry.get("mekf-spacecraft") is MEKFSpacecraft
    assert "extra.b_o_nT" in EKFSpacecraft.needs and "extra.s_o" in MEKFSpacecraft.needs


@pytest.mark.slow(reason="26 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("cls", [EKFSpacecraft, MEKFSpacecraft])
def test_ideal_case_converges(ideal, cls):
    err = _err_deg(ideal, cls().run(ideal))
    sunlit = (ideal.t > 300) & ideal.sun_valid
    # paper: errors between 0 and 0.5 deg in the ideal case
    assert np.sqrt(np.mean(err[sunlit] ** 2)) < 0.2
    assert err[sunlit].max() < 0.5


def test_ekf_estimates_the_body_rate_without_a_gyro(ideal):
    est = EKFSpacecraft().run(ideal)
    sunlit = (ideal.t > 300) & ideal.sun_valid
    dw = est.signals["w_ib_b_rad_s"] - ideal.extra["w_ib_b"]
    assert np.degrees(np.abs(dw[sunlit])).max() < 0.01        # deg/s


def test_eclipse_gyroless_degrades_mekf_holds(noisy):
    ecl = ~noisy.sun_valid
    assert ecl.sum() > 400
    e_ekf = _err_deg(noisy, EKFSpacecraft().run(noisy))
    e_mekf = _err_deg(noisy, MEKFSpacecraft().run(noisy))
    sunlit = (noisy.t > 300) & noisy.sun_valid
    rms_sun = np.sqrt(np.mean(e_ekf[sunlit] ** 2))
    assert e_ekf[ecl].max() > 5 * rms_sun                  # issue 5 target, gyro-less filter
    assert e_mekf[ecl].max() < 1.0
    assert e_mekf[ecl].max() < e_ekf[ecl].max() / 2.5


def test_invalid_sun_rows_are_not_used(noisy):
    """In eclipse the sun sensor is ignored: garbage in the invalid rows changes nothing."""
    sun = noisy.sun.copy()
    sun[~noisy.sun_valid] = [0.0, 0.0, 1.0]
    rec2 = Recording(t=noisy.t, gyro=noisy.gyro, mag=noisy.mag, mag_unit=noisy.mag_unit,
                     sun=sun, sun_valid=noisy.sun_valid, q_true=noisy.q_true,
                     frames=noisy.frames, extra=noisy.extra)
    for cls in (EKFSpacecraft, MEKFSpacecraft):
        a, b = cls().run(noisy), cls().run(rec2)
        np.testing.assert_array_equal(a.q, b.q)
        assert np.all(np.isnan(a.signals["innovation_sun"][~noisy.sun_valid]))


@pytest.mark.parametrize("cls, kernel", [(EKFSpacecraft, K)])
def test_kernel_equals_interpreted_twin(noisy, cls, kernel, monkeypatch):
    """The compiled batch against its ``py_func`` twin, sample by sample in every signal,
    also when a run continues an earlier one (the MEKF's twin: tests/test_mekf.py)."""
    rec = noisy.slice(1800, 1950)           # crosses the eclipse entry at 1859 s
    f = cls()
    a = [f.run(rec.slice(0, 60)), f.run(rec.slice(60, len(rec)))]
    # every helper interpreted too: the module's dispatchers replaced by their py_func
    for name in dir(kernel):
        fn = getattr(kernel, name)
        if hasattr(fn, "py_func"):
            monkeypatch.setattr(kernel, name, fn.py_func)
    g = cls()
    b = [g.run(rec.slice(0, 60), compiled=False), g.run(rec.slice(60, len(rec)), compiled=False)]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x.q, y.q, atol=1e-12)
        for key in x.signals:
            np.testing.assert_allclose(x.signals[key], y.signals[key], rtol=1e-9, atol=1e-15,
                                       err_msg=key)
    np.testing.assert_allclose(f.P, g.P, rtol=1e-9, atol=1e-18)


def test_split_run_equals_one_run(noisy):
    """The state holds the inputs of the last sample: a run continued from it equals one run
    (the kernels predict sample k with the inputs of sample k-1)."""
    rec = noisy.slice(1780, 1900)
    for cls in (EKFSpacecraft, MEKFSpacecraft):
        whole = cls().run(rec).q
        f = cls()
        parts = [f.run(rec.slice(0, 47)).q, f.run(rec.slice(47, len(rec))).q]
        np.testing.assert_allclose(np.vstack(parts), whole, rtol=0, atol=1e-13)


def _rows(rec, k):
    """Keyword arguments of the streaming ``update`` at sample k (no sun in eclipse)."""
    kw = dict(mag_b=rec.mag[k], mag_ref_o=rec.extra["b_o_model_nT"][k],
              w_io_o_rad_s=rec.extra["w_io_o"][k])
    if rec.sun_valid[k]:
        kw.update(sun_b=rec.sun[k], sun_ref_o=rec.extra["s_o"][k])
    return kw


@pytest.mark.slow(reason="22 s (2 cores): long runs or a first compilation")
def test_streaming_update_equals_batch(noisy):
    rec = noisy.slice(1780, 1900)           # sunlit, then eclipse
    J = rec.extra["inertia_model_kg_m2"][0]
    a = EKFSpacecraft().run(rec)
    f = EKFSpacecraft()
    tau = np.cross(rec.extra["m_dipole_b_Am2"], rec.mag * 1e-9)
    q = []
    for k in range(len(rec)):
        q.append(f.update(1.0, None, **_rows(rec, k), h_b_Nms=rec.extra["h_wheel_b_Nms"][k],
                          hdot_b_Nm=rec.extra["hdot_wheel_b_Nm"][k], tau_b_Nm=tau[k],
                          inertia_kg_m2=J))
    # the batch takes the gravity-gradient coefficient from the mean orbit rate
    assert np.degrees(error_angle_rad(a.q, np.array(q))).max() < 1e-4
    m = MEKFSpacecraft()
    b = m.run(rec)
    m.reset()
    q = [m.update(1.0, rec.gyro[k], **_rows(rec, k)) for k in range(len(rec))]
    np.testing.assert_allclose(np.array(q), b.q, atol=1e-12)
    # ... and a run continues the streamed state
    c = MEKFSpacecraft().run(noisy.slice(1780, 1960)).q
    m.t_last = float(rec.t[-1])
    np.testing.assert_allclose(m.run(noisy.slice(1900, 1960)).q, c[120:], atol=1e-12)


def test_missing_reference_vectors_named(noisy):
    extra = {k: v for k, v in noisy.extra.items() if k not in ("s_o",)}
    rec = Recording(t=noisy.t, gyro=noisy.gyro, mag=noisy.mag, mag_unit="nT", sun=noisy.sun,
                    sun_valid=noisy.sun_valid, extra=extra)
    with pytest.raises(Exception, match="extra.s_o"):
        MEKFSpacecraft().run(rec)


def test_any_split_into_update_and_update_many_equals_run_across_the_eclipse(noisy):
    """``update`` and ``update_many`` in any split carry the state of ``run`` (the held
    wheel momentum and torques, the recording's inertia and gravity gradient): the same
    result across the eclipse entry; the compiled ``update`` equals ``update_reference``."""
    rec = noisy.slice(1780, 1960)
    ref = EKFSpacecraft().run(rec).q
    f = EKFSpacecraft()
    f.prepare(rec)
    args, kwargs = f.buffer_inputs(rec)
    rows = list(f.sample_inputs(rec))
    q = list(f.update_many(*(x[:40] for x in args), **{k: v[:40] for k, v in kwargs.items()}).q)
    q += [f.update(*a, **kw) for a, kw in rows[40:100]]
    q += list(f.update_many(*(x[100:] for x in args),
                            **{k: v[100:] for k, v in kwargs.items()}).q)
    np.testing.assert_allclose(np.array(q), ref, rtol=0, atol=1e-12)
    twin = EKFSpacecraft()
    twin.prepare(rec)
    q_twin = np.array([twin.update_reference(*a, **kw) for a, kw in rows])
    np.testing.assert_allclose(q_twin, ref, rtol=0, atol=1e-12)
