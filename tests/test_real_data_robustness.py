"""Robustness seen on real phone data (the tyrex data set), and its simulated stand-ins.

Two failures measured with default parameters against the motion capture:

* an uncalibrated gyro biased by 5.5-6 deg/s (the iPhone 5) beyond the 2 deg/s bound of
  robust-ahrs' bias estimate, which then sat at the bound without saying so;
* the ESKF's bias estimate running to 14-19 deg/s on walking, swinging and running data
  whose bias is below 1 deg/s (the tilt error it had corrected stayed in its
  accelerometer low-pass and was measured, and corrected, again and again).

The simulated cases run everywhere; the real trials run when the data set is present
(``gnomon.datasets.tyrex_dir``, the ``full_tyrex`` fixture) and are skipped with the
reason otherwise.
"""

import dataclasses
import json

import numpy as np
import pytest

from gnomon.estimators import registry
from gnomon.metrics import compare, score
from gnomon.rotation import dcm_from_quat
from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

D2R = np.pi / 180.0


def _with_bias(rec, bias_deg_s):
    return dataclasses.replace(rec, gyro=rec.gyro + np.radians(bias_deg_s))


def _pedestrian(seed: int, duration_s: float = 90.0):
    """A phone swung in the hand of a walker: body rates of 1 rad/s RMS at 0.3-1 Hz and a
    periodic specific-force disturbance at the step frequency (1.8 Hz: 2 and 3.5 m/s²
    forward and vertical, 1 m/s² sideways at the stride frequency); gyro bias
    (0.5, -0.3, 0.4) deg/s. RMS of | |a| - g |: 2.5 m/s²."""
    p = AhrsSimParams(duration_s=duration_s, rate_hz=100.0, rate_rms=1.0,
                      rate_band_hz=(0.3, 1.0), gyro_bias_std=0.0, bias_rw=0.0)
    rec = simulate_ahrs(p, np.random.default_rng(seed))
    w = 2 * np.pi * 1.8 * rec.t
    a_n = np.stack([2.0 * np.sin(w), 1.0 * np.sin(0.5 * w + 1.0), 3.5 * np.sin(w + 0.7)], 1)
    c_bn = np.swapaxes(dcm_from_quat(rec.q_true), -1, -2)
    rec = dataclasses.replace(rec, accel=rec.accel + np.einsum("nij,nj->ni", c_bn, a_n))
    return _with_bias(rec, [0.5, -0.3, 0.4])


# ---------------------------------------------------------------- ESKF: no runaway bias
@pytest.mark.parametrize("seed", [1, 3])
@pytest.mark.parametrize("name", ["eskf-r3", "eskf-r6"])
def test_eskf_bias_stays_small_on_a_simulated_pedestrian(name, seed):
    """Before: the bias estimate reached 9-15 deg/s (true: 0.5) and the attitude error
    26-79 deg at its worst; now below 5 deg/s and 17 deg."""
    rec = _pedestrian(seed)
    est = registry.create(name).run(rec)
    b = np.degrees(est.signals["bias_rad_s"])
    assert np.abs(b).max() < 6.0
    np.testing.assert_allclose(b[-1], [0.5, -0.3, 0.4], atol=0.3)
    s = score(rec.q_true, est.q)
    assert s["total_deg"] < 8.0 and s["max_deg"] < 25.0, s
    assert not est.signals["bias_at_limit"].any()


def test_eskf_bias_is_held_under_sustained_linear_acceleration():
    """While the RMS of | |a| - g | exceeds ``bias_gate`` the corrections leave the bias
    alone (a Schmidt update), and the bias estimate stays within ``bias_limit``."""
    rec = _with_bias(simulate_ahrs(AhrsSimParams(duration_s=20.0, linear_accel_rms=6.0,
                                                 gyro_bias_std=0.0, bias_rw=0.0),
                                   np.random.default_rng(5)), [1.0, 0.0, 0.0])
    held = registry.create("eskf-r3", bias_gate=3.0).run(rec)  # off by default
    shut = rec.t > 10.0  # the RMS over bias_gate_tau = 3 s is above 3 m/s² by then
    b = held.signals["bias_rad_s"][shut]
    assert np.all(b == b[0])
    pbb = held.signals["cov_diag"][shut, 3:]
    assert np.all(np.diff(pbb, axis=0) > 0)  # only the random walk: it grows
    free = registry.create("eskf-r3", bias_gate=0.0, bias_limit=0.001).run(rec)
    assert np.abs(free.signals["bias_rad_s"]).max() == pytest.approx(0.001)
    assert free.signals["bias_at_limit"].any()


# ---------------------------------------------------------------- robust-ahrs: large bias
@pytest.mark.parametrize("bias", [[6.0, -3.0, 8.0], [10.0, 0.0, -10.0]])
def test_robust_ahrs_estimates_a_large_bias_at_rest(bias):
    """15 s at rest then motion: a steady rate beyond ``rest_th_rate_deg_s`` counts as rest
    after ``rest_min_large_bias_s`` and the rest measurement converges at once."""
    sim = AhrsSimParams(duration_s=40.0, rest_s=15.0, gyro_bias_std=0.0, bias_rw=0.0)
    rec = _with_bias(simulate_ahrs(sim, np.random.default_rng(1)), bias)
    est = registry.create("robust-ahrs").run(rec)
    b = np.degrees(est.signals["bias_rad_s"])
    assert est.signals["rest"][rec.t < 15.0].mean() > 0.6
    k = np.searchsorted(rec.t, 14.9)
    np.testing.assert_allclose(b[k], bias, atol=0.2)
    np.testing.assert_allclose(b[-1], bias, atol=0.2)
    assert not est.signals["bias_at_limit"].any()


@pytest.mark.parametrize("bias, tol", [([0.3, -0.2, 0.4], 0.1), ([6.0, -1.0, 1.0], 1.0),
                                       ([10.0, 0.0, -10.0], 2.0)])
def test_robust_ahrs_bias_converges_in_motion(bias, tol):
    """No rest at all: the inclination correction alone (Huber-weighted) brings a bias of
    up to 10 deg/s near its value within two minutes; a small bias as before."""
    sim = AhrsSimParams(duration_s=120.0, gyro_bias_std=0.0, bias_rw=0.0)
    rec = _with_bias(simulate_ahrs(sim, np.random.default_rng(2)), bias)
    est = registry.create("robust-ahrs").run(rec)
    b = np.degrees(est.signals["bias_rad_s"])
    assert np.abs(b[-1] - bias).max() < tol
    assert not est.signals["bias_at_limit"].any()


def test_bias_at_its_bound_is_a_signal_and_a_warning(tmp_path, capsys):
    """A bound below the true bias: ``bias_at_limit`` says when; ``gnomon estimate`` prints
    one line (the bound, when first, how long) and ``--json`` has a ``warnings`` list."""
    from gnomon.cli import main
    from gnomon.io import write

    sim = AhrsSimParams(duration_s=40.0, gyro_bias_std=0.0, bias_rw=0.0)
    rec = _with_bias(simulate_ahrs(sim, np.random.default_rng(3)), [6.0, 0.0, 0.0])
    est = registry.create("robust-ahrs", bias_clip_deg_s=2.0).run(rec)
    flag = est.signals["bias_at_limit"]
    assert flag.any() and not flag[0]
    assert np.abs(np.degrees(est.signals["bias_rad_s"][flag])).max(1) == pytest.approx(2.0)
    path = write(tmp_path / "biased.h5", rec)
    assert main(["estimate", str(path), "--filter", "robust-ahrs",
                 "--param", "bias_clip_deg_s=2"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "warning" in ln]
    assert len(lines) == 1 and "±2 deg/s (bias_clip_deg_s)" in lines[0], lines
    assert main(["estimate", str(path), "--filter", "robust-ahrs", "--param",
                 "bias_clip_deg_s=2", "--json"]) == 0
    (w,) = json.loads(capsys.readouterr().out)["warnings"]
    assert w["signal"] == "bias_at_limit" and w["limit"] == 2.0
    assert w["first_s"] == pytest.approx(rec.t[np.argmax(flag)] - rec.t[0])
    assert 0.0 < w["duration_s"] <= rec.t[-1] - rec.t[0]
    assert main(["estimate", str(path), "--filter", "eskf-r3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []


# ---------------------------------------------------------------- the real trials
def _trial(root, platform: str, name: str):
    """A whole trial of the data set at ``root`` (the ``full_tyrex`` fixture)."""
    folder = root / "datasets" / platform / name
    if not folder.is_dir():
        pytest.skip(f"tyrex trial {platform}/{name} not found (set GNOMON_TYREX_DIR)")
    import gnomon

    rec = gnomon.read(str(folder))
    if rec.q_true is None:
        pytest.skip(f"no motion-capture reference next to {name}")
    return rec


@pytest.mark.parametrize("trial, max_err_deg", [
    ("Guillaume_Nexus5_NoDist_Swinging", 15.0), ("Guillaume_Nexus5_Dist_Swinging", 25.0),
    ("Guillaume_Nexus5_Dist_FrontPocket", 25.0), ("Guillaume_Nexus5_NoDist_RunningHand", 45.0)])
@pytest.mark.parametrize("name", ["eskf-r3", "eskf-r6"])
def test_eskf_on_android_walking_trials(name, trial, max_err_deg, full_tyrex):
    """Nexus 5 (calibrated gyro, bias below 1 deg/s): before, eskf-r3 ended 86-103 deg
    from the motion capture on three of these with its bias at 13-29 deg/s."""
    rec = _trial(full_tyrex, "android", trial)
    est = registry.create(name).run(rec)
    b = np.degrees(est.signals["bias_rad_s"])
    late = rec.t - rec.t[0] > 30.0
    assert np.abs(b[late]).max() < 10.0
    assert np.isfinite(est.q).all()
    assert compare(rec.q_true, est.q)["total_deg"] < max_err_deg


@pytest.mark.parametrize("trial", ["Guillaume_iPhone5_NoDist_Texting",
                                   "Guillaume_iPhone5_Dist_Phoning"])
def test_robust_ahrs_on_the_biased_iphone(trial, full_tyrex):
    """iPhone 5 raw gyro: about 5.5-6 deg/s on x. Before, the estimate sat at its 2 deg/s
    bound (Dist_Phoning: 68.7 deg from the motion capture)."""
    rec = _trial(full_tyrex, "ios", trial)
    est = registry.create("robust-ahrs").run(rec)
    b = np.degrees(est.signals["bias_rad_s"])
    assert 3.5 < b[-1, 0] < 7.0
    assert not est.signals["bias_at_limit"].any()
    assert compare(rec.q_true, est.q)["total_deg"] < 35.0
