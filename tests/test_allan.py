"""IMU noise from a static log (``gnomon.calibration.allan``, ``imu_noise``,
``noise_params``; ``gnomon calibrate imu``, ``gnomon estimate --noise``): the overlapping
Allan deviation against allantools' ``oadev``; white noise, rate random walk, flicker
(bias instability) and a bias of known size recovered from synthetic logs; a short log
says what it cannot show; a moving log is refused; the command line end to end."""

import json
import math

import numpy as np
import pytest

from gnomon.calibration.allan import (
    BIAS_INSTABILITY_FACTOR,
    allan_deviation,
    cluster_sizes,
    read_noise_terms,
)
from gnomon.calibration.imu_noise import (
    FORMAT,
    G0_M_S2,
    imu_noise,
    load_imu_noise,
    save_imu_noise,
)
from gnomon.calibration.noise_params import noise_params
from gnomon.cli import main
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.recording import Recording

D2R = math.pi / 180.0


def white_and_walk(rng, n, fs, white, walk, bias=0.0, width=3):
    """``n`` samples (n, width) at ``fs`` Hz: ``bias`` + white noise of density ``white``
    (U/√Hz: per-sample std white·√fs) + a random walk of intensity ``walk`` (U/s/√Hz:
    increments of std walk/√fs), the IEEE 952 definitions (σ² = N²/τ + K²τ/3)."""
    w = white * math.sqrt(fs) * rng.standard_normal((n, width))
    k = np.cumsum(walk / math.sqrt(fs) * rng.standard_normal((n, width)), axis=0)
    return np.asarray(bias, float) + w + k


def flicker(rng, n, fs, b, width=3):
    """Flicker noise of bias instability ``b``: one-sided PSD b²/(π f) (the two-sided
    b²/(2π f) of IEEE 952), shaped in the frequency domain (irfft of complex normal
    coefficients of variance S(f)·fs·n/2 per bin)."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    s = np.zeros_like(f)
    s[1:] = b**2 / (math.pi * f[1:])
    c = np.sqrt(s * fs * n / 4.0)[:, None]
    z = c * (rng.standard_normal((f.size, width)) + 1j * rng.standard_normal((f.size, width)))
    return np.fft.irfft(z, n, axis=0)


# ------------------------------------------------------------------ the Allan deviation
def test_overlapping_adev_equals_allantools_oadev():
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(7)
    fs = 50.0
    y = white_and_walk(rng, 6_000, fs, 3e-3, 4e-4, bias=[0.02, -1.5, 9.8])
    tau, adev = allan_deviation(y, fs)
    assert tau[0] == pytest.approx(1 / fs) and 2 * round(tau[-1] * fs) <= len(y)
    for k in range(3):
        t_ref, a_ref, _, _ = allantools.oadev(y[:, k], rate=fs, data_type="freq", taus=tau)
        np.testing.assert_allclose(t_ref, tau, rtol=1e-12)
        np.testing.assert_allclose(adev[:, k], a_ref, rtol=1e-10)
    tau1, adev1 = allan_deviation(y[:, 1], fs)  # one axis alone, (N,)
    np.testing.assert_allclose(adev1, adev[:, 1], rtol=1e-12)


def test_cluster_sizes_are_log_spaced_and_bounded():
    m = cluster_sizes(10_001, per_decade=10)
    assert m[0] == 1 and m[-1] == 5000 and np.all(np.diff(m) > 0)
    assert 35 <= len(m) <= 38  # 10 per decade over 3.7 decades, the first ones merged
    with pytest.raises(InputError, match="at least 3"):
        cluster_sizes(2)


# ------------------------------------------------------------------ the terms recovered
def test_white_noise_and_rate_random_walk_recovered():
    """2 h at 20 Hz, N = 2e-3 rad/s/√Hz, K = 2e-4 rad/s²/√Hz (crossover at √3 N/K =
    17 s, read to 720 s): N within 10 %, K within 30 % on every axis (the issue's
    tolerances; over 60 seeds the scatter of K is 8 %, of N 0.6 %)."""
    fs, n = 20.0, 144_000
    N, K = 2e-3, 2e-4
    y = white_and_walk(np.random.default_rng(3), n, fs, N, K, bias=[0.01, -0.02, 0.003])
    tau, adev = allan_deviation(y, fs)
    for k in range(3):
        terms = read_noise_terms(tau, adev[:, k], n, fs, "rad/s")
        assert terms.white == pytest.approx(N, rel=0.10)
        assert terms.random_walk == pytest.approx(K, rel=0.30)
        assert terms.reasons == {}
        # no flicker here: the minimum is where the two lines cross, sigma_min^2 =
        # 2 N K / sqrt(3), and B is the standard's reading of it
        b_cross = math.sqrt(2 * N * K / math.sqrt(3)) / BIAS_INSTABILITY_FACTOR
        assert terms.bias_instability == pytest.approx(b_cross, rel=0.15)


def test_bias_instability_recovered_from_flicker_noise():
    """Flicker of B = 1e-3 rad/s under white noise N = 2e-3 rad/s/√Hz (2 h at 20 Hz):
    the flat part at 0.664 B is read within 25 % (the minimum sits on the flat part
    where the white line has fallen below it)."""
    fs, n, B = 20.0, 144_000, 1e-3
    rng = np.random.default_rng(2)
    y = white_and_walk(rng, n, fs, 2e-3, 0.0) + flicker(rng, n, fs, B)
    tau, adev = allan_deviation(y, fs)
    for k in range(3):
        terms = read_noise_terms(tau, adev[:, k], n, fs, "rad/s")
        assert terms.bias_instability == pytest.approx(B, rel=0.25)
        assert terms.bias_instability_fit == pytest.approx(B, rel=0.15)
        assert terms.white == pytest.approx(2e-3, rel=0.10)


def test_a_short_log_says_what_it_cannot_show():
    """One minute of white noise: N is there; no flat part and no +1/2 slope, so B and K
    are None with the reason (and the bound on B), not made-up numbers."""
    fs, n = 20.0, 1200
    y = white_and_walk(np.random.default_rng(1), n, fs, 2e-3, 0.0, width=1)[:, 0]
    tau, adev = allan_deviation(y, fs)
    terms = read_noise_terms(tau, adev, n, fs, "rad/s")
    assert terms.white == pytest.approx(2e-3, rel=0.10)
    assert terms.random_walk is None and "record longer" in terms.reasons["random_walk"]
    assert terms.bias_instability is None and "too short" in terms.reasons["bias_instability"]
    # the bound: the lowest sigma read (about N / sqrt(tau_max)) / 0.664
    assert terms.bias_instability_bound == pytest.approx(
        2e-3 / math.sqrt(terms.max_tau_s) / BIAS_INSTABILITY_FACTOR, rel=0.3)


def _static_rec(fs=10.0, duration_s=3600.0, seed=5, bias_g=(0.01, -0.02, 0.004),
                bias_a_z=0.05):
    n = int(duration_s * fs)
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    gyro = white_and_walk(rng, n, fs, 2e-3, 5e-4, bias=bias_g)
    accel = white_and_walk(rng, n, fs, 3e-3, 5e-4, bias=[0.0, 0.0, G0_M_S2 + bias_a_z])
    return Recording(t=t, gyro=gyro, accel=accel, source="synthetic static")


def test_imu_noise_report_rest_biases_and_round_trip(tmp_path):
    """1 h at 10 Hz (K = 5e-4: the +1/2 slope shows by 360 s): the contract's keys,
    the terms, the gyro's mean rate within 4 sigma of the bias (sigma of the mean:
    K sqrt(T/3) of the walk and N / sqrt(T) of the white noise), the accelerometer's
    bias along gravity likewise; saved and loaded back."""
    rec = _static_rec()
    report, curves = imu_noise(rec)
    assert report["duration_s"] == pytest.approx(3600.0, abs=0.2)
    g, a = report["gyro"], report["accel"]
    np.testing.assert_allclose(g["noise_density_rad_s_sqrt_hz"], 2e-3, rtol=0.1)
    np.testing.assert_allclose(g["rate_random_walk_rad_s2_sqrt_hz"], 5e-4, rtol=0.3)
    np.testing.assert_allclose(a["noise_density_m_s2_sqrt_hz"], 3e-3, rtol=0.1)
    np.testing.assert_allclose(a["random_walk_m_s3_sqrt_hz"], 5e-4, rtol=0.3)
    sigma_mean = 5e-4 * math.sqrt(3600 / 3) + 2e-3 / math.sqrt(3600)
    np.testing.assert_allclose(g["bias_rad_s"], [0.01, -0.02, 0.004], atol=4 * sigma_mean)
    assert a["bias_along_gravity_m_s2"] == pytest.approx(0.05, abs=4 * sigma_mean)
    np.testing.assert_allclose(a["up_b"], [0, 0, 1], atol=4 * sigma_mean / G0_M_S2)
    np.testing.assert_allclose(g["angle_random_walk_deg_sqrt_h"],
                               np.array(g["noise_density_rad_s_sqrt_hz"]) / D2R * 60)
    assert set(curves) == {"gyro", "accel"} and curves["gyro"][1].shape[1] == 3
    back = load_imu_noise(save_imu_noise(tmp_path / "noise.json", report))
    assert back["format"] == FORMAT
    assert back["gyro"]["noise_density_rad_s_sqrt_hz"] == g["noise_density_rad_s_sqrt_hz"]


def test_a_moving_log_is_refused():
    rec = _static_rec(duration_s=60.0)
    # a turn about z at 0.3 rad/s for the second half
    gyro = rec.gyro.copy()
    gyro[len(gyro) // 2:, 2] += 0.3
    with pytest.raises(InputError, match=r"gyro's z axis vary by 0\.15 rad/s .* > 0\.05"):
        imu_noise(Recording(t=rec.t, gyro=gyro, accel=rec.accel))
    # a tilt of 10 deg half way: the accelerometer's 1-s means move
    accel = rec.accel.copy()
    accel[len(accel) // 2:] = accel[len(accel) // 2:] @ np.array(
        [[1, 0, 0], [0, math.cos(0.17), -math.sin(0.17)], [0, math.sin(0.17), math.cos(0.17)]])
    with pytest.raises(InputError, match="not a static log: .*accel's y axis"):
        imu_noise(Recording(t=rec.t, gyro=rec.gyro, accel=accel))
    # a steady turn about the vertical: nothing varies but the rate is no rest bias
    with pytest.raises(InputError, match="mean rate is 0.5.. rad/s > 0.2"):
        imu_noise(Recording(t=rec.t, gyro=rec.gyro + [0, 0, 0.5], accel=rec.accel))
    with pytest.raises(InputError, match="at least 10 s"):
        imu_noise(Recording(t=rec.t[:100], gyro=rec.gyro[:100], accel=rec.accel[:100]))


# ------------------------------------------------------------------ filter parameters
NOISE = {"format": FORMAT, "version": 1,
         "gyro": {"noise_density_rad_s_sqrt_hz": [1e-3, 2e-3, None],
                  "rate_random_walk_rad_s2_sqrt_hz": [None, None, None],
                  "bias_instability_rad_s": [None] * 3, "bias_rad_s": [0, 0, 0],
                  "why_none": {"rate_random_walk_rad_s2_sqrt_hz": {"x": "record longer"}}},
         "accel": {"noise_density_m_s2_sqrt_hz": [0.05, 0.05, 0.05],
                   "bias_instability_m_s2": [None] * 3,
                   "random_walk_m_s3_sqrt_hz": [None] * 3}}


def test_noise_params_per_filter():
    """RMS of the axes present; continuous densities taken as they are; the accelerometer
    per sample N √fs when above the filter's default; robust-ahrs' forgetting time from
    K; a missing term and a filter without noise parameters say so."""
    rms = math.sqrt((1e-6 + 4e-6) / 2)
    p, notes = noise_params(NOISE, "eskf-r3", 100.0)
    assert p == {"gyro_noise": pytest.approx(rms), "accel_noise": pytest.approx(0.5)}
    assert any("bias_rw not set" in s and "record longer" in s for s in notes)
    p, _ = noise_params(NOISE, "eskf-r6", 16.0)  # 0.05 * 4 = 0.2 < the default 0.3
    assert "accel_noise" not in p
    p, _ = noise_params(NOISE, "mekf", None)
    assert p == {"arw_rad_rt_s": pytest.approx(rms)}
    with_k = {**NOISE, "gyro": {**NOISE["gyro"],
                                "rate_random_walk_rad_s2_sqrt_hz": [1e-4, 1e-4, 1e-4]}}
    p, _ = noise_params(with_k, "robust-ahrs", 100.0)
    assert p == {"bias_forgetting_s": pytest.approx((0.1 * D2R) ** 2 / 1e-8)}
    p, notes = noise_params(with_k, "mahony", 100.0)
    assert p == {} and "mahony has no parameter an IMU noise report sets" in notes[0]


# ------------------------------------------------------------------ the command line
def _write_csv(path, rec):
    cols = np.column_stack([rec.t, rec.gyro, rec.accel])
    np.savetxt(path, cols, delimiter=",", header="t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z",
               comments="", fmt="%.9g")
    return path


CONTRACT = {"gyro": {"noise_density_rad_s_sqrt_hz", "bias_instability_rad_s",
                     "rate_random_walk_rad_s2_sqrt_hz", "bias_rad_s"},
            "accel": {"noise_density_m_s2_sqrt_hz", "bias_instability_m_s2",
                      "random_walk_m_s3_sqrt_hz"}}


def test_cli_calibrate_imu_then_estimate_with_its_noise(tmp_path, capsys):
    csv = _write_csv(tmp_path / "static.csv", _static_rec(duration_s=1200.0))
    out, plot = tmp_path / "noise.json", tmp_path / "allan.png"
    assert main(["calibrate", "imu", str(csv), "--json", "--out", str(out),
                 "--plot", str(plot)]) == 0
    report = json.loads(capsys.readouterr().out)
    for sensor, keys in CONTRACT.items():
        assert keys <= set(report[sensor])
        for key in keys:
            assert len(report[sensor][key]) == 3
            assert all(isinstance(v, float) for v in report[sensor][key]), key
    assert report["duration_s"] == pytest.approx(1200.0, abs=0.2)
    np.testing.assert_allclose(report["gyro"]["noise_density_rad_s_sqrt_hz"], 2e-3, rtol=0.1)
    assert plot.stat().st_size > 20_000
    saved = json.loads(out.read_text())
    assert saved["gyro"]["rate_random_walk_rad_s2_sqrt_hz"] == \
        report["gyro"]["rate_random_walk_rad_s2_sqrt_hz"]
    # the text form
    assert main(["calibrate", "imu", str(csv)]) == 0
    text = capsys.readouterr().out
    assert "angle random walk" in text and "deg/sqrt(h)" in text

    log = str(bundled("broad_01_excerpt.csv"))
    assert main(["estimate", log, "--filter", "eskf-r3", "--noise", str(out), "--param",
                 "bias_rw=3e-5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    n_rms = math.sqrt(np.mean(np.square(saved["gyro"]["noise_density_rad_s_sqrt_hz"])))
    assert summary["params"]["gyro_noise"] == pytest.approx(n_rms)
    assert summary["noise_params"]["params"]["gyro_noise"] == pytest.approx(n_rms)
    assert summary["params"]["bias_rw"] == 3e-5  # --param wins
    assert summary["noise_params"]["overridden"] == ["bias_rw"]
    assert main(["estimate", log, "--filter", "mahony", "--noise", str(out)]) == 0
    assert "mahony has no parameter an IMU noise report sets" in capsys.readouterr().out


def test_cli_refuses_a_moving_log_and_a_wrong_noise_file(tmp_path, capsys, imu_factory):
    moving = imu_factory([1, 0, 0, 0], [0.4, 0.0, 0.0], n=3000, fs=100.0)  # a roll
    csv = _write_csv(tmp_path / "moving.csv", moving)
    assert main(["calibrate", "imu", str(csv)]) == 2
    err = capsys.readouterr().err
    assert "not a static log" in err and "> 0.2 m/s^2" in err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"offset_uT": [0, 0, 0]}))
    assert main(["estimate", str(csv), "--filter", "eskf-r3", "--noise", str(bad)]) == 2
    assert "gnomon-imu-noise" in capsys.readouterr().err
