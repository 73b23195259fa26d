"""Star tracker model (``gnomon.sensors.star_tracker_model``) and its scenario block.

Truths used: noise statistics in a boresight frame built here (not the model's),
constant-rate rotation in closed form for rate and latency, cone geometry for the
exclusions, the alternating-renewal fraction ``λμ / (1 + λμ)`` for random outages.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from gnomon import io
from gnomon.environment.orbit import R_EARTH
from gnomon.errors import InputError
from gnomon.rotation import (
    error_angle,
    quat_conj,
    quat_from_rotvec,
    quat_mul,
    quat_rotate,
    rotvec_from_quat,
)
from gnomon.scenarios import Scenario, load_scenario, simulate
from gnomon.sensors import STAR_TRACKER_FLAGS, boresight_frame, star_tracker_model

ARCSEC = np.pi / 180.0 / 3600.0
DEG = np.pi / 180.0


def _perpendicular_basis(z):
    """Two unit vectors perpendicular to ``z`` and to each other (built independently of
    ``boresight_frame``: from the x axis, or y when z is close to x)."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = a - (a @ z) * z
    u /= np.linalg.norm(u)
    return u, np.cross(z, u)


def _rotating(t, w_b, q0=(1.0, 0.0, 0.0, 0.0)):
    """Closed form of a constant body rate: ``q_ib(t) = q0 ⊗ exp(w_b t)``."""
    return quat_mul(np.asarray(q0, float), quat_from_rotvec(np.outer(t, w_b)))


def _pointing(directions_i):
    """``q_ib`` rows that turn the body z axis onto the given unit directions in i."""
    d = np.asarray(directions_i, float)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s = np.linalg.norm(axis, axis=1, keepdims=True)
    ang = np.arctan2(s[:, 0], d @ z)
    axis = np.where(s > 1e-12, axis / np.where(s > 0, s, 1.0), [1.0, 0.0, 0.0])
    return quat_from_rotvec(axis * ang[:, None])


def test_boresight_frame_is_orthonormal_right_handed_with_z_on_the_boresight():
    for bs in ([0, 0, 1], [0.3, -0.7, 0.65], [-1, 0, 0], [0, 2, 0], [1, 1, 1]):
        R = boresight_frame(bs)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
        np.testing.assert_allclose(R[:, 2], np.asarray(bs, float) / np.linalg.norm(bs),
                                   atol=1e-15)


def test_noise_statistics_about_and_across_an_arbitrary_boresight():
    rng = np.random.default_rng(1)
    n = 40_000
    t = np.arange(n) * 0.2
    q_ib = quat_from_rotvec(rng.uniform(-3.0, 3.0, (n, 3)))       # attitudes all over
    bs = np.array([0.3, -0.7, 0.65])
    sc, sa = 10.0 * ARCSEC, 60.0 * ARCSEC
    q, valid, flags = star_tracker_model(t, q_ib, np.random.default_rng(2), boresight_b=bs,
                                         noise_cross_rad=sc, noise_about_rad=sa)
    assert valid.all() and not flags.any()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    # the error is on the right, in body axes: conj(q_ib) ⊗ q̂_ib = exp(δθ_b)
    d_b = rotvec_from_quat(quat_mul(quat_conj(q_ib), q))
    z = bs / np.linalg.norm(bs)
    u, v = _perpendicular_basis(z)
    comps = np.stack([d_b @ u, d_b @ v, d_b @ z], axis=1)
    std = comps.std(axis=0)
    np.testing.assert_allclose(std, [sc, sc, sa], rtol=0.02)
    assert np.all(np.abs(comps.mean(axis=0)) < 4 * np.array([sc, sc, sa]) / np.sqrt(n))
    assert abs(np.corrcoef(comps.T)[0, 2]) < 0.03 and abs(np.corrcoef(comps.T)[0, 1]) < 0.03
    # the other side (inertial axes) would not show sigma_about along the body boresight
    d_i = rotvec_from_quat(quat_mul(q, quat_conj(q_ib)))
    assert np.std(d_i @ z) < 0.8 * sa


def test_no_noise_gives_the_truth_exactly():
    t = np.arange(10) * 1.0
    q_ib = _rotating(t, [0.01, -0.02, 0.03])
    q, valid, _ = star_tracker_model(t, q_ib, np.random.default_rng(0))
    assert valid.all()
    np.testing.assert_array_equal(q, q_ib)


def test_rate_every_kth_sample_and_own_clock():
    t = np.arange(201) * 0.1                                      # 10 Hz time base, 20 s
    q_ib = _rotating(t, [0.0, 0.0, 0.05])
    _, valid, _ = star_tracker_model(t, q_ib, np.random.default_rng(0), rate_hz=2.0)
    np.testing.assert_array_equal(np.flatnonzero(valid), np.arange(0, 201, 5))
    # 3 Hz on a 10 Hz base: stamped at the first sample at or after each tick k/3 s
    _, valid, _ = star_tracker_model(t, q_ib, np.random.default_rng(0), rate_hz=3.0)
    ticks = np.arange(61) / 3.0
    expected = np.searchsorted(t, ticks - 1e-9, side="left")
    np.testing.assert_array_equal(np.flatnonzero(valid), expected)
    with pytest.raises(InputError) as err:
        star_tracker_model(t, q_ib, np.random.default_rng(0), rate_hz=20.0)
    assert err.value.field == "rate_hz"


def test_latency_measures_the_attitude_latency_earlier_closed_form():
    dt, lat = 0.1, 0.25                                           # not a multiple of dt
    t = np.arange(301) * dt
    w = np.array([0.02, -0.05, 0.03])                             # rad/s, constant, in b
    q0 = quat_from_rotvec([0.4, -1.2, 0.7])
    q, valid, flags = star_tracker_model(t, _rotating(t, w, q0), np.random.default_rng(0),
                                         latency_s=lat)
    early = t < lat
    assert not valid[early].any()
    assert np.all(flags[early] == STAR_TRACKER_FLAGS["no_history"])
    assert valid[~early].all()
    truth = _rotating(t[~early] - lat, w, q0)                     # closed form at t - L
    assert np.max(error_angle(truth, q[~early])) < 1e-12
    # and it is not the attitude at t (the rotation in 0.25 s is ~0.015 rad)
    assert np.min(error_angle(_rotating(t[~early], w, q0), q[~early])) > 0.01


def test_sun_and_moon_exclusion_cone():
    excl = 30.0 * DEG
    angles = np.array([0.0, 0.5 * excl, excl - 1e-6, excl + 1e-6, 2 * excl, np.pi])
    n = angles.size
    t = np.arange(n) * 1.0
    rng = np.random.default_rng(3)
    q_ib = quat_from_rotvec(rng.uniform(-2, 2, (n, 3)))
    bs_b = np.array([0.2, 0.5, -0.8])
    bs_b /= np.linalg.norm(bs_b)
    u, _ = _perpendicular_basis(bs_b)
    # direction at the given angle from the boresight, in b, then in i
    d_b = np.cos(angles)[:, None] * bs_b + np.sin(angles)[:, None] * u
    d_i = quat_rotate(q_ib, d_b)
    expected = np.array([False, False, False, True, True, True])
    for key in ("sun", "moon"):
        kw = {f"{key}_i": d_i * 7.0, f"{key}_exclusion_rad": excl}       # any length
        _, valid, flags = star_tracker_model(t, q_ib, np.random.default_rng(0),
                                             boresight_b=bs_b, **kw)
        np.testing.assert_array_equal(valid, expected)
        np.testing.assert_array_equal(flags, np.where(expected, 0, STAR_TRACKER_FLAGS[key]))


def test_earth_limb_exclusion_nadir_excluded_zenith_allowed():
    r = 7_000e3
    rho = np.arcsin(R_EARTH / r)                                   # angular radius of the Earth
    margin = 20.0 * DEG
    alpha = np.array([0.0, rho, rho + margin - 1e-6, rho + margin + 1e-6, np.pi / 2, np.pi])
    n = alpha.size
    r_i = np.tile([0.0, 0.0, -r], (n, 1))                         # nadir = +z_i
    d_i = np.stack([np.sin(alpha), np.zeros(n), np.cos(alpha)], axis=1)  # alpha from nadir
    q_ib = _pointing(d_i)
    np.testing.assert_allclose(quat_rotate(q_ib, [0.0, 0.0, 1.0]), d_i, atol=1e-12)
    _, valid, flags = star_tracker_model(np.arange(n) * 1.0, q_ib, np.random.default_rng(0),
                                         r_i_m=r_i, earth_limb_exclusion_rad=margin)
    np.testing.assert_array_equal(valid, [False, False, False, True, True, True])
    assert np.all(flags[:3] == STAR_TRACKER_FLAGS["earth"])


def test_random_outages_match_the_renewal_fraction_and_mean_duration():
    dt = 2.0
    t = np.arange(1_000_001) * dt                                   # 2e6 s
    q_ib = np.tile([1.0, 0.0, 0.0, 0.0], (t.size, 1))
    lam, mu = 1.0 / 600.0, 120.0
    _, valid, flags = star_tracker_model(t, q_ib, np.random.default_rng(7),
                                         outage_rate_hz=lam, outage_mean_s=mu)
    out = ~valid
    assert np.all(flags[out] == STAR_TRACKER_FLAGS["outage"])
    assert out.mean() == pytest.approx(lam * mu / (1 + lam * mu), abs=0.015)   # 0.167
    edges = np.diff(np.concatenate([[0], out.astype(int), [0]]))
    lengths = (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)) * dt
    assert lengths.mean() == pytest.approx(mu, rel=0.1)
    assert lengths.size == pytest.approx(2e6 / (1 / lam + mu), rel=0.1)


def test_scheduled_outage_windows_are_honoured_exactly():
    t = np.arange(1001) * 0.1
    q_ib = _rotating(t, [0.0, 0.01, 0.0])
    windows = [[10.0, 20.0], [50.05, 60.0]]
    _, valid, flags = star_tracker_model(t, q_ib, np.random.default_rng(0),
                                         outage_windows_s=windows)
    inside = ((t >= 10.0) & (t < 20.0)) | ((t >= 50.05) & (t < 60.0))
    np.testing.assert_array_equal(valid, ~inside)
    np.testing.assert_array_equal(flags, np.where(inside, STAR_TRACKER_FLAGS["outage"], 0))
    with pytest.raises(InputError) as err:
        star_tracker_model(t, q_ib, np.random.default_rng(0), outage_windows_s=[[5.0, 1.0]])
    assert err.value.field == "outage_windows_s"


@pytest.mark.parametrize(("kw", "field"), [
    ({"boresight_b": (0.0, 0.0, 0.0)}, "boresight_b"),
    ({"noise_cross_rad": -1e-5}, "noise_cross_rad"),
    ({"noise_about_rad": -1e-5}, "noise_about_rad"),
    ({"rate_hz": 0.0}, "rate_hz"),
    ({"rate_hz": -5.0}, "rate_hz"),
    ({"latency_s": -0.1}, "latency_s"),
    ({"sun_exclusion_rad": float("nan")}, "sun_exclusion_rad"),
])
def test_bad_input_names_the_field(kw, field):
    t = np.arange(5) * 1.0
    with pytest.raises(InputError) as err:
        star_tracker_model(t, np.tile([1.0, 0, 0, 0], (5, 1)), np.random.default_rng(0), **kw)
    assert err.value.field == field


# ----------------------------------------------------------------- scenarios
def test_star_tracker_is_off_in_the_seed_presets_and_adds_nothing():
    for name in ("seed000", "seed001"):
        assert load_scenario(name).config["sensors"]["star_tracker"]["enabled"] is False
    rec = simulate(load_scenario("seed001").replace({"duration_s": 60.0}))
    assert not any(k.startswith("st_") for k in rec.extra)


def test_enabling_the_star_tracker_leaves_every_other_output_bit_for_bit():
    sc = load_scenario("seed001").replace({"duration_s": 300.0})
    a = simulate(sc)
    b = simulate(sc.replace({"sensors.star_tracker.enabled": True}))
    for name in ("t", "gyro", "mag", "sun", "sun_valid", "q_true"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert set(b.extra) - set(a.extra) == {"st_q_ib", "st_valid", "st_flags", "st_boresight_b"}
    for key, value in a.extra.items():
        np.testing.assert_array_equal(value, b.extra[key], err_msg=key)


@pytest.mark.parametrize(("key", "value"), [
    ("sensors.star_tracker.boresight_b", [0.0, 0.0, 0.0]),
    ("sensors.star_tracker.noise_cross_arcsec", -1.0),
    ("sensors.star_tracker.noise_about_arcsec", -1.0),
    ("sensors.star_tracker.rate_hz", 0.0),
    ("sensors.star_tracker.rate_hz", 10.0),             # faster than step_s = 0.2 s
    ("sensors.star_tracker.outage_windows_s", [[10.0, 5.0]]),
    ("sensors.star_tracker.outage_windows_s", [10.0, 20.0]),
])
def test_scenario_block_is_validated(key, value):
    sc = load_scenario("smallsat-star-tracker")
    with pytest.raises(InputError) as err:
        sc.replace({key: value})
    assert err.value.field == key


def test_smallsat_preset_simulates_and_round_trips_through_hdf5(tmp_path):
    sc = load_scenario("smallsat-star-tracker").replace({"duration_s": 300.0})
    assert Scenario.from_dict(yaml.safe_load(sc.to_yaml())).config == sc.config
    st = sc.config["sensors"]["star_tracker"]
    assert sc.config["step_s"] == 0.2 and st["rate_hz"] == 5.0
    rec = simulate(sc)
    x = rec.extra
    n = len(rec)
    assert x["st_q_ib"].shape == (n, 4) and x["st_valid"].dtype == bool
    assert x["st_flags"].dtype == np.uint8 and x["st_boresight_b"].shape == (n, 3)
    v = x["st_valid"]
    assert not v[0] and x["st_flags"][0] == STAR_TRACKER_FLAGS["no_history"]  # latency 0.2 s
    assert v[1:].all() and np.isnan(x["st_q_ib"][~v]).all()
    # measured at t_k = attitude at t_(k-1) (latency one step) times the noise
    q_ib = quat_mul(x["q_io"], rec.q_true)
    d_b = rotvec_from_quat(quat_mul(quat_conj(q_ib[:-1]), x["st_q_ib"][1:]))
    z = x["st_boresight_b"][0]
    u, w = _perpendicular_basis(z)
    std = np.stack([d_b @ u, d_b @ w, d_b @ z], axis=1).std(axis=0) / ARCSEC
    np.testing.assert_allclose(std, [10.0, 10.0, 60.0], rtol=0.1)
    path = io.write(tmp_path / "st.h5", rec)
    back = io.read(path)
    for key in ("st_q_ib", "st_valid", "st_flags", "st_boresight_b"):
        assert back.extra[key].dtype == x[key].dtype, key
        np.testing.assert_array_equal(back.extra[key], x[key], err_msg=key)


def test_smallsat_preset_scheduled_outage_is_ten_minutes():
    sc = load_scenario("smallsat-star-tracker").replace({"duration_s": 3700.0,
                                                         "sensors.gyro.arw_deg_rt_h": 0.0})
    rec = simulate(sc)
    t, v = rec.t, rec.extra["st_valid"]
    inside = (t >= 3000.0) & (t < 3600.0)
    assert not v[inside].any() and v[~inside][1:].all()
    assert inside.sum() * 0.2 == pytest.approx(600.0)
