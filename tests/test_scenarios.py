"""Scenario files, presets and the simulated recording's internal consistency."""

from __future__ import annotations

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.rotation import dcm_from_quat, quat_conj, quat_mul, quat_rotate, rotvec_from_quat
from gnomon.scenarios import Scenario, describe, list_presets, load_scenario, simulate
from gnomon.scenarios.simulator import build_orbit

DEG = np.pi / 180.0


@pytest.fixture(scope="module")
def short000():
    sc = load_scenario("seed000").replace({"duration_s": 1200.0,
                                           "sensors.gyro.step_time_orbits": None,
                                           "sensors.gyro.step_time_s": 600.0})
    return sc, simulate(sc)


def test_presets_are_listed_and_load():
    assert {"seed000", "seed001"} <= set(list_presets())
    for name in list_presets():
        sc = load_scenario(name)
        assert sc.name == name
        if sc.kind == "spacecraft" and name.startswith("seed"):
            assert sc.config["step_s"] == 1.0        # the papers' 1 s sampling
    # the star-tracker preset samples at the tracker's 5 Hz
    assert load_scenario("smallsat-star-tracker").config["step_s"] == 0.2


def test_recording_contract(short000):
    sc, rec = short000
    n = 1201
    assert len(rec) == n and rec.mag_unit == "nT"
    assert rec.frames == {"reference": "o", "body": "b"}
    for key in ("w_ob_b", "w_ib_b", "w_io_o", "b_o_nT", "b_o_model_nT", "s_o", "eclipse",
                "gyro_bias_rad_s", "q_io", "inertia_kg_m2", "inertia_model_kg_m2"):
        assert rec.extra[key].shape[0] == n, key
    np.testing.assert_allclose(np.linalg.norm(rec.q_true, axis=1), 1.0, atol=1e-12)


def test_truth_is_consistent(short000):
    sc, rec = short000
    x = rec.extra
    R_ob = dcm_from_quat(rec.q_true)
    # field and Sun in b are the orbital-frame truth rotated by q_ob
    b_b = np.einsum("nji,nj->ni", R_ob, x["b_o_nT"])
    np.testing.assert_allclose(x["b_b_nT"], b_b, atol=1e-6)
    mag_noise = rec.mag - b_b
    assert np.std(mag_noise) == pytest.approx(300.0, rel=0.05)       # the preset's 300 nT
    s_b = np.einsum("nji,nj->ni", R_ob, x["s_o"])
    np.testing.assert_allclose(rec.sun[rec.sun_valid], s_b[rec.sun_valid], atol=1e-12)
    # rates: w_ib_b = w_ob_b + R_bo w_io_o, and q_ob follows w_ob_b (finite difference)
    np.testing.assert_allclose(x["w_ib_b"], x["w_ob_b"] + np.einsum("nji,nj->ni", R_ob,
                                                                     x["w_io_o"]), atol=1e-15)
    dq = quat_mul(quat_conj(rec.q_true[:-1]), rec.q_true[1:])
    w_mid = 0.5 * (x["w_ob_b"][1:] + x["w_ob_b"][:-1])
    np.testing.assert_allclose(rotvec_from_quat(dq), w_mid, atol=1e-7)
    # orbital rate of a 650 km circular orbit with J2 drift, about y_o:
    # -(dω/dt + dM/dt + dΩ/dt cos i) (node regression projected on the orbit normal)
    orb = build_orbit(sc.config)
    draan, dargp, dm = orb.rates()
    np.testing.assert_allclose(x["w_io_o"][:, 1], -(dargp + dm + draan * np.cos(orb.inc)),
                               rtol=1e-7)
    assert abs(x["w_io_o"][:, 1].mean() + np.sqrt(3.986004418e14 / 7028137.0**3)) < 3e-6
    assert np.max(np.abs(x["w_io_o"][:, [0, 2]])) < 1e-6
    # dawn-dusk preset: the Sun is along -y_o (orbit normal), no eclipse
    assert np.all(x["s_o"][:, 1] < -0.999) and np.all(x["eclipse"] == 1.0)
    # field in o agrees with the field in i rotated by q_io
    b_i = quat_rotate(x["q_io"], x["b_o_nT"])
    assert np.all(np.abs(np.linalg.norm(b_i, axis=1) - np.linalg.norm(x["b_o_nT"], axis=1))
                  < 1e-6)


def test_gyro_step_and_seed_control(short000):
    sc, rec = short000
    err = rec.gyro - rec.extra["w_ib_b"]
    np.testing.assert_allclose(err[:600], 0.0, atol=1e-15)         # paper: no gyro noise
    np.testing.assert_allclose(err[600:], 0.02 * DEG, rtol=1e-12)  # 0.02 deg/s step
    np.testing.assert_allclose(rec.extra["gyro_bias_rad_s"], err, atol=1e-15)
    again = simulate(sc)
    np.testing.assert_array_equal(again.mag, rec.mag)
    other = simulate(sc, rng_seed=99)
    assert not np.array_equal(other.mag, rec.mag)
    np.testing.assert_array_equal(other.q_true, rec.q_true)           # same world


def test_seed000_step_at_1_7_orbits():
    sc = load_scenario("seed000")
    rec = simulate(sc.replace({"duration_s": 11000.0}))
    k = int(np.argmax(np.abs(rec.gyro[:, 0] - rec.extra["w_ib_b"][:, 0]) > 0))
    assert rec.extra["time_orbits"][k] == pytest.approx(1.7, abs=2e-4)


def test_seed001_eclipse_matches_beta_angle():
    rec = simulate(load_scenario("seed001"))
    x = rec.extra
    r, v = x["r_i_m"], x["v_i_m"]
    h = np.cross(r, v)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    s_i = quat_rotate(x["q_io"], x["s_o"])
    beta = np.arcsin(np.mean(np.sum(h * s_i, axis=1)))
    assert 25 * DEG < abs(beta) < 35 * DEG
    rn = np.linalg.norm(r[0])
    alt = rn - 6378137.0
    half = np.arccos(np.sqrt(alt**2 + 2 * 6378137.0 * alt) / (rn * np.cos(beta)))
    period = 2 * np.pi / abs(x["w_io_o"][0, 1])
    in_shadow = np.sum(x["eclipse"] < 0.5) * 1.0                     # s, one eclipse in the run
    assert in_shadow == pytest.approx(2 * half / (2 * np.pi) * period, rel=0.01)
    np.testing.assert_array_equal(rec.sun_valid, x["eclipse"] >= 0.5)


def test_field_model_error_and_inertia_error_overrides():
    sc = load_scenario("seed001").replace({"duration_s": 100.0,
                                           "environment.field_error.kind": "scale",
                                           "environment.field_error.level_pct": 10.0,
                                           "spacecraft.inertia_error_pct": 10.0})
    rec = simulate(sc)
    x = rec.extra
    np.testing.assert_allclose(np.linalg.norm(x["b_o_model_nT"], axis=1),
                               1.1 * np.linalg.norm(x["b_o_nT"], axis=1), rtol=1e-12)
    J, Jm = x["inertia_kg_m2"][0], x["inertia_model_kg_m2"][0]
    assert 0.005 < np.max(np.abs(np.diag(Jm) / np.diag(J) - 1)) < 0.4
    np.testing.assert_allclose(Jm, Jm.T)


def test_yaml_file_and_replace(tmp_path):
    p = tmp_path / "mine.yaml"
    p.write_text("name: mine\nduration_s: 60\norbit:\n  altitude_km: 500\n"
                 "spacecraft:\n  inertia_kg_m2: [1.0, 1.2, 0.8]\n")
    sc = load_scenario(p)
    assert sc.get("orbit.altitude_km") == 500.0
    assert sc.get("spacecraft.inertia_kg_m2")[1][1] == 1.2
    sc2 = sc.replace(sensors__magnetometer__noise_nT=50.0)
    assert sc2.get("sensors.magnetometer.noise_nT") == 50.0
    sc3 = sc.replace({"sensors.gyro.bias_deg_s": np.float64(0.01), "seed": np.int64(3)})
    assert sc3.get("sensors.gyro.bias_deg_s") == [0.01, 0.01, 0.01] and sc3.get("seed") == 3
    assert sc.get("sensors.magnetometer.noise_nT") == 0.0            # original unchanged
    assert len(simulate(sc2)) == 61
    assert any(row[0] == "sensors.gyro.step_time_orbits" for row in describe())
    # a saved scenario reads back to the same configuration
    q = tmp_path / "saved.yaml"
    q.write_text(sc2.to_yaml())
    assert load_scenario(q).config == sc2.config


@pytest.mark.parametrize("text, field, words", [
    ("orbit:\n  altitud_km: 600\n", "orbit.altitud_km", "unknown scenario key"),
    ("spacecraft:\n  inertia_kg_m2: [1.0, -1.0, 1.0]\n", "spacecraft.inertia_kg_m2", "positive"),
    ("spacecraft:\n  inertia_kg_m2: [[1, 2, 0], [2, 1, 0], [0, 0, 1]]\n",
     "spacecraft.inertia_kg_m2", "positive definite"),
    ("orbit:\n  altitude_km: 120\n", "orbit.altitude_km", "atmosphere"),
    ("duration_s: 100\nstep_s: 3\n", "step_s", "does not divide"),
    ("sensors:\n  gyro:\n    bias_deg_s: [1, 2]\n", "sensors.gyro.bias_deg_s", "3 numbers"),
    ("controller:\n  mode: pid\n", "controller.mode", "expected one of"),
    ("epoch: yesterday\n", "epoch", "ISO-8601"),
    ("orbit:\n  inclination_deg: 200\n", "orbit.inclination_deg", "[0, 180]"),
    ("sensors:\n  sun_sensor:\n    boresight_b: [0, 0, 0]\n", "sensors.sun_sensor.boresight_b",
     "non-zero"),
])
def test_bad_scenarios_fail_before_simulating(tmp_path, text, field, words):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        load_scenario(p)
    assert err.value.field == field
    assert words in str(err.value) and str(p) in str(err.value)
    assert "\n" not in str(err.value)


def test_bad_overrides_and_names():
    sc = load_scenario("seed000")
    with pytest.raises(InputError, match="sensors.gyro.bias_deg"):
        sc.replace({"sensors.gyro.bias_deg": 0.1})
    with pytest.raises(InputError, match="spacecraft.inertia_error"):
        sc.replace({"spacecraft.inertia_error": 2.0})
    with pytest.raises(InputError, match="nope"):
        load_scenario("nope")
    with pytest.raises(InputError, match="step_s"):
        Scenario.from_dict({"duration_s": 10.5})


def test_tle_orbit_dipole_field_and_orbit_normal_sun(tmp_path):
    # ISS TLE from the sgp4 documentation; epoch 2008-09-20 12:25:40 UTC, unquoted in YAML
    p = tmp_path / "iss.yaml"
    p.write_text(
        "epoch: 2008-09-20T12:25:40Z\nduration_s: 300\n"
        "orbit:\n  kind: tle\n"
        "  tle_line1: '1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927'\n"
        "  tle_line2: '2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537'\n"
        "environment:\n  field_model: dipole\n  sun_model: orbit_normal\n  shadow: none\n")
    sc = load_scenario(p)
    rec = simulate(sc)
    x = rec.extra
    alt = np.linalg.norm(x["r_i_m"], axis=1) - 6378137.0
    assert np.all((330e3 < alt) & (alt < 380e3))                     # ISS in 2008
    np.testing.assert_allclose(x["s_o"], np.tile([0.0, -1.0, 0.0], (len(rec), 1)), atol=1e-12)
    assert np.all(x["eclipse"] == 1.0)
    # dipole field magnitude at ~350 km: between the equatorial and polar dipole values
    b = np.linalg.norm(x["b_o_nT"], axis=1)
    assert np.all((20000 < b) & (b < 60000))


def test_bdot_then_pointing_detumbles_a_tumbling_satellite():
    sc = load_scenario("seed000").replace({
        "duration_s": 17600.0, "controller.mode": "bdot_then_pd",
        "initial.rate_ob_deg_s": [3.0, -2.0, 2.5], "sensors.gyro.step_deg_s": [0, 0, 0]})
    rec = simulate(sc)
    w = np.degrees(np.linalg.norm(rec.extra["w_ob_b"], axis=1))
    assert w[0] > 4.0
    assert np.max(w[-2000:]) < 0.2                                   # settled near o
    assert np.max(np.abs(rec.extra["m_dipole_b_Am2"])) <= 0.5


def test_imu_scenario_kind():
    """``kind: imu`` scenarios: own schema, own simulator, same validation rules."""
    sc = load_scenario("imu-handheld")
    assert sc.kind == "imu"
    short = sc.replace({"duration_s": 3.0, "imu.rate_hz": 50.0})
    rec = simulate(short, rng_seed=4)
    assert len(rec) == 151 and rec.frames["reference"] == "ENU"
    np.testing.assert_allclose(np.diff(rec.t), 0.02)
    # gravity and the field seen in the body: magnitudes set by the scenario (plus noise)
    assert abs(np.linalg.norm(rec.accel, axis=1).mean() - 9.81) < 0.01
    assert abs(np.linalg.norm(rec.mag, axis=1).mean() - 50.0) < 0.1
    again = simulate(short, rng_seed=4)
    np.testing.assert_array_equal(again.gyro, rec.gyro)
    with pytest.raises(InputError, match="orbit"):
        sc.replace({"orbit.altitude_km": 500.0})  # a spacecraft key
    with pytest.raises(InputError, match="kind"):
        sc.replace({"kind": "spacecraft"})
    with pytest.raises(InputError, match="rate_band_high_hz"):
        sc.replace({"imu.rate_band_high_hz": 0.01})
    with pytest.raises(InputError, match="kind"):
        Scenario.from_dict({"kind": "boat"})
    assert {row[0] for row in describe("imu")} >= {"imu.rate_hz", "settle_s"}
    assert load_scenario("seed001").kind == "spacecraft"
