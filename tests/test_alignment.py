"""``gnomon.alignment``: a motion-capture reference in its own world (y up, any heading),
on a marker rotated from the sensor, late by a clock offset, fitted back from the
sensor's own data (``--align``).

The synthetic recording: a body turning about all three axes (rates from sums of
sines) in ENU, its gyro (with a bias and white noise), accelerometer (gravity plus a
small back-and-forth linear acceleration) and magnetometer made from the truth by
construction; the reference is ``q_wm(t) = q_wr ⊗ q_rs(t - lag) ⊗ q_sm`` with known
``q_wr`` (y up, heading 40°), ``q_sm`` and lag, and untracked rows (NaN). Each fitted
constant is checked against the one put in, and the aligned truth against ``q_rs``.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from gnomon.alignment import (
    MIN_EXCITATION,
    align_truth,
    apply_alignment,
    load_alignment,
    save_alignment,
)
from gnomon.errors import InputError
from gnomon.metrics import error_angle_rad, quat_at
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

G = 9.80665
MAG_ENU_UT = np.array([0.0, 21.0, -43.0])
RATE_HZ = 200.0
LAG_S = 0.037
# the mocap world w from ENU r: y up (x east stays x, ENU up -> w's +y), heading 40 deg
Q_WR = quat_mul(quat_from_rotvec(np.radians([0.0, 40.0, 0.0])),
                quat_from_rotvec(np.radians([-90.0, 0.0, 0.0])))
Q_SM = quat_from_rotvec(np.radians([12.0, -25.0, 70.0]))  # marker m in sensor s axes


def _angle_deg(qa, qb) -> float:
    return float(np.degrees(error_angle_rad(np.asarray(qa)[None], np.asarray(qb)[None])[0]))


def _motion(seconds: float = 60.0, axes: str = "xyz", seed: int = 3):
    """``(t, q_rs, gyro, accel, mag)``: the sensor in ENU turning about ``axes``."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    amp = {"x": 1.1, "y": 0.8, "z": 1.3}
    w = np.zeros((t.size, 3))
    for k, name in enumerate("xyz"):
        if name in axes:
            w[:, k] = amp[name] * (np.sin(2 * np.pi * (0.11 + 0.07 * k) * t + k)
                                   + 0.5 * np.sin(2 * np.pi * (0.37 + 0.05 * k) * t))
    q = np.empty((t.size, 4))
    q[0] = quat_from_rotvec(np.radians([5.0, -8.0, 30.0]))
    for i in range(1, t.size):  # exact for a rate held over each interval
        q[i] = quat_mul(q[i - 1], quat_from_rotvec(0.5 * (w[i - 1] + w[i]) / RATE_HZ))
    lin = 0.4 * np.stack([np.sin(1.3 * t), np.cos(0.9 * t), np.sin(0.5 * t)], axis=1)
    accel = quat_rotate(quat_conj(q), np.array([0.0, 0.0, G]) + lin)
    mag = quat_rotate(quat_conj(q), MAG_ENU_UT)
    gyro = w + np.radians([0.4, -0.3, 0.2]) + rng.normal(0.0, 0.003, w.shape)
    accel = accel + rng.normal(0.0, 0.02, accel.shape)
    return t, q, gyro, accel, mag


def _mocap(t, q_rs, lag_s=LAG_S, inverted=False):
    """The reference as the mocap records it at the gyro's time stamps: ``q_wm(t) =
    q_wr ⊗ q_rs(t - lag) ⊗ q_sm``, untracked (NaN) for 0.5 s every 10 s."""
    q = quat_at(t, q_rs, t - lag_s)
    ok = np.all(np.isfinite(q), axis=1)
    q[ok] = quat_mul(quat_mul(Q_WR, q[ok]), Q_SM)
    q[(t % 10.0) < 0.5] = np.nan
    if inverted:
        q = q * np.array([1.0, -1.0, -1.0, -1.0])
    return q


def _recording(axes="xyz", inverted=False, mag=True, seconds=60.0):
    t, q_rs, gyro, accel, m = _motion(seconds, axes)
    rec = Recording(t=t, gyro=gyro, accel=accel, mag=m if mag else None,
                    q_true=_mocap(t, q_rs, inverted=inverted),
                    frames={"reference": "mocap", "body": "sensor"}, source="mocap")
    return rec, q_rs


def _truth_error_deg(q_al, q_rs) -> float:
    ok = np.all(np.isfinite(q_al), axis=1)
    return float(np.degrees(np.max(error_angle_rad(q_rs[ok], q_al[ok]))))


@pytest.fixture(scope="module")
def mocap():
    return _recording()


def test_auto_finds_the_lag_the_marker_rotation_and_a_y_up_world(mocap):
    rec, q_rs = mocap
    q_al, info = align_truth(rec, "auto")
    assert info["applied"] == ["lag", "body", "world"] and info["refused"] == {}
    assert info["lag_s"] == pytest.approx(LAG_S, abs=1e-3)
    # body_q is q_ms (sensor to marker): the conjugate of the q_sm put in
    assert _angle_deg(info["body_q"], quat_conj(Q_SM)) < 0.1
    # world_q is q_rw: the conjugate of q_wr; the world's up was its +y axis
    assert _angle_deg(info["world_q"], quat_conj(Q_WR)) < 0.3
    assert np.allclose(info["world_up_in_world"], [0.0, 1.0, 0.0], atol=5e-3)
    assert info["world_heading_from"] == "magnetometer"
    assert info["world_magnetic_dip_deg"] == pytest.approx(
        math.degrees(math.atan2(43.0, 21.0)), abs=0.5)
    assert info["rate_correlation"] > 0.999 and info["rate_rms_deg_s"] < 0.5
    assert info["rate_rms_deg_s_before"] > 50.0  # the raw reference's rate is unrelated
    assert info["reference_inverted"] is False
    # the truth aligned equals q_rs wherever it was tracked
    assert _truth_error_deg(q_al, q_rs) < 0.3
    json.dumps(info)  # JSON-able as --json prints it


def test_a_world_to_marker_reference_is_recognised_as_inverted():
    rec, q_rs = _recording(inverted=True, seconds=30.0)
    q_al, info = align_truth(rec, "auto")
    assert info["reference_inverted"] is True
    assert _truth_error_deg(q_al, q_rs) < 0.3


def test_rotation_about_one_axis_refuses_the_body_with_the_reason():
    rec, _ = _recording(axes="z", seconds=30.0)
    _, info = align_truth(rec, "auto")
    assert info["excitation"] < MIN_EXCITATION
    assert "body" in info["refused"] and "one axis" in info["refused"]["body"]
    assert "world" in info["refused"] and info["applied"] == ["lag"]
    with pytest.raises(InputError, match="one axis only"):
        align_truth(rec, ("body",))


def test_without_a_magnetometer_the_world_keeps_its_heading():
    rec, q_rs = _recording(mag=False, seconds=30.0)
    q_al, info = align_truth(rec, "auto")
    assert info["world_heading_from"] == "kept"
    ok = np.all(np.isfinite(q_al), axis=1)
    # inclination exact, heading off by a constant: the world's (40 deg) turned up to z
    err = quat_mul(q_al[ok], quat_conj(q_rs[ok]))
    tilt = np.degrees(2 * np.arccos(np.clip(np.hypot(err[:, 0], err[:, 3]), 0, 1)))
    assert tilt.max() < 0.3
    yaw = np.degrees(2 * np.arctan2(err[:, 3], err[:, 0]))
    assert np.ptp(yaw) < 0.5 and abs(yaw.mean()) > 10.0


def test_the_lag_alone_and_no_alignment_keep_the_named_components(mocap):
    rec, _ = mocap
    q0, info0 = align_truth(rec, ())
    assert info0["applied"] == [] and np.array_equal(q0, rec.q_true, equal_nan=True)
    _, info = align_truth(rec, ("lag",))
    assert info["applied"] == ["lag"]
    with pytest.raises(InputError, match="accelerometer"):
        align_truth(dataclasses.replace(rec, accel=None), ("world",))


def test_a_saved_alignment_applies_the_same_truth(tmp_path, mocap):
    rec, q_rs = mocap
    q_al, info = align_truth(rec, "auto")
    path = save_alignment(tmp_path / "al.json", info)
    again = apply_alignment(rec, load_alignment(path))
    assert np.allclose(again, q_al, equal_nan=True, atol=1e-12)
    q_file, info_file = align_truth(rec, str(path))
    assert info_file["from_file"] and np.allclose(q_file, q_al, equal_nan=True, atol=1e-12)
    (tmp_path / "bad.json").write_text('{"lag_s": 1}')
    with pytest.raises(InputError, match="not a gnomon alignment"):
        load_alignment(tmp_path / "bad.json")


def _write_csv(path, rec):
    """A gnomon CSV (``t, gyr_*, acc_*, mag_*`` SI/µT, truth ``q_*``) of ``rec``."""
    cols = np.column_stack([rec.t, rec.gyro, rec.accel, rec.mag, rec.q_true])
    head = "t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z,q_w,q_x,q_y,q_z"
    np.savetxt(path, cols, delimiter=",", header=head, comments="", fmt="%.9g")
    return path


def test_cli_estimate_and_benchmark_dir_align_auto(tmp_path, mocap, capsys):
    from gnomon.cli import main

    def run_cli(*args):
        assert main(list(args)) == 0
        return json.loads(capsys.readouterr().out)

    rec, _ = mocap
    folder = tmp_path / "trials"
    folder.mkdir()
    csv = _write_csv(folder / "mocap.csv", rec)
    out = run_cli("estimate", str(csv), "--filter", "robust-ahrs", "--json")
    unaligned = out["errors"]["total_deg"]
    out = run_cli("estimate", str(csv), "--filter", "robust-ahrs", "--align", "auto",
                  "--save-alignment", str(tmp_path / "al.json"), "--json")
    a = out["alignment"]
    assert a["applied"] == ["lag", "body", "world"]
    assert a["lag_s"] == pytest.approx(LAG_S, abs=2e-3)
    assert unaligned > 60.0 and out["errors"]["total_deg"] < 3.0
    again = run_cli("estimate", str(csv), "--filter", "robust-ahrs", "--align",
                    str(tmp_path / "al.json"), "--json")
    assert again["errors"]["total_deg"] == pytest.approx(out["errors"]["total_deg"], abs=1e-6)
    res = run_cli("benchmark", str(folder), "--filters", "robust-ahrs", "--anchors", "none",
                  "--align", "auto", "--json")
    assert res["align"] == ["auto"]
    assert [t["trial"] for t in res["alignment"]] == ["mocap"]
    assert res["mean"]["robust-ahrs"]["total_deg"] == pytest.approx(
        out["errors"]["total_deg"], abs=1e-6)


def test_auto_finds_a_clock_offset_beyond_the_first_search():
    t, q_rs, gyro, accel, mag = _motion(40.0)
    rec = Recording(t=t, gyro=gyro, accel=accel, mag=mag,
                    q_true=_mocap(t, q_rs, lag_s=-1.734), source="late")
    with pytest.raises(InputError, match="correlate only"):  # within ±0.25 s
        align_truth(rec, ("lag", "body"))
    q_al, info = align_truth(rec, "auto")
    assert info["lag_s"] == pytest.approx(-1.734, abs=1e-3)
    assert info["applied"] == ["lag", "body", "world"]
    assert _truth_error_deg(q_al, q_rs) < 0.3
