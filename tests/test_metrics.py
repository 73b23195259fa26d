"""Metrics on hand-computed cases."""

import dataclasses

import numpy as np
import pytest

from gnomon import metrics
from gnomon.rotation import quat_from_euler, quat_from_rotvec, quat_mul

DEG = np.pi / 180


def test_pure_heading_error_is_heading_only():
    q_true = quat_from_euler([0.2, -0.3, 1.0])
    # rotate the estimate by 5 deg about the reference (ENU) vertical: q_est = q_z ⊗ q_true
    q_est = quat_mul(quat_from_rotvec([0, 0, 5 * DEG]), q_true)
    e = metrics.broad_errors_rad(q_true, q_est)
    assert e["total"] == pytest.approx(5 * DEG, abs=1e-12)
    assert e["heading"] == pytest.approx(5 * DEG, abs=1e-12)
    assert e["inclination"] == pytest.approx(0.0, abs=1e-7)


def test_pure_inclination_error():
    q_true = quat_from_euler([0.1, 0.2, -2.0])
    q_est = quat_mul(quat_from_rotvec([3 * DEG, 0, 0]), q_true)  # about the reference x axis
    e = metrics.broad_errors_rad(q_true, q_est)
    assert e["total"] == pytest.approx(3 * DEG, abs=1e-12)
    assert e["inclination"] == pytest.approx(3 * DEG, abs=1e-12)
    assert e["heading"] == pytest.approx(0.0, abs=1e-12)


def test_broad_definitions_by_hand():
    # q_err = [cos 15°, 0, sin 15° sin a, sin 15° cos a] etc.: check the three formulas directly
    w, x, y, z = 0.9, 0.1, -0.3, 0.2
    qe = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
    e = metrics.broad_errors_rad([1.0, 0, 0, 0], qe)
    w, x, y, z = qe
    assert e["total"] == pytest.approx(2 * np.arccos(abs(w)), abs=1e-14)
    assert e["heading"] == pytest.approx(2 * np.arctan(abs(z / w)), abs=1e-14)
    assert e["inclination"] == pytest.approx(2 * np.arccos(np.sqrt(w * w + z * z)), abs=1e-14)


def test_axis_errors_small_angles_in_body_frame():
    q_true = quat_from_euler([0.3, 0.4, 0.5])
    small = np.array([0.01, -0.02, 0.03])
    q_est = quat_mul(q_true, quat_from_euler(small))
    np.testing.assert_allclose(metrics.axis_errors_rad(q_true, q_est), small, atol=1e-12)


def test_nan_rows_propagate_and_rms_masks():
    q_true = np.array([[1.0, 0, 0, 0], [np.nan] * 4, [1.0, 0, 0, 0]])
    q_est = np.array([quat_from_rotvec([0.1, 0, 0]), [1.0, 0, 0, 0],
                      quat_from_rotvec([0, 0.3, 0])])
    a = metrics.error_angle_rad(q_true, q_est)
    assert np.isnan(a[1])
    assert metrics.rms(a, [True, False, True]) == pytest.approx(np.sqrt((0.01 + 0.09) / 2))
    with pytest.raises(ValueError, match="non-finite"):
        metrics.rms(a)
    s = metrics.score(q_true, q_est)
    assert s["samples"] == 2
    assert s["total_deg"] == pytest.approx(np.degrees(np.sqrt(0.05)))
    assert s["max_deg"] == pytest.approx(np.degrees(0.3))


def _scored_recording(frames, with_sun):
    """Ten samples at 1 s, truth identity, estimate rotated 0.01·k rad (k = 0..9) about x."""
    from gnomon.recording import Recording

    n = 10
    t = np.arange(n, dtype=float)
    q_est = quat_from_rotvec(np.outer(0.01 * np.arange(n), [1.0, 0.0, 0.0]))
    sun = None
    if with_sun:
        sun = np.tile([1.0, 0.0, 0.0], (n, 1))
        sun[6:] = np.nan                                           # eclipse from t = 6 s
    rec = Recording(t=t, gyro=np.zeros((n, 3)), sun=sun, q_true=np.tile([1.0, 0, 0, 0], (n, 1)),
                    frames=frames)
    return rec, q_est


def test_score_run_is_the_campaign_formula():
    """Degrees first, then RMS / max / mean over the samples from ``settle_s`` on."""
    rec, q_est = _scored_recording({"reference": "o", "body": "b"}, with_sun=True)
    s = metrics.score_run(rec, q_est, settle_s=2.0)
    err = np.degrees(metrics.error_angle_rad(rec.q_true, q_est))
    x, lit, dark = err[2:], err[2:6], err[6:]
    assert s == {"rms_deg": float(np.sqrt(np.mean(x * x))), "max_deg": float(x.max()),
                 "mean_deg": float(x.mean()),
                 "sunlit_rms_deg": float(np.sqrt(np.mean(lit * lit))),
                 "eclipse_rms_deg": float(np.sqrt(np.mean(dark * dark))),
                 "eclipse_max_deg": float(dark.max())}
    assert s["max_deg"] == pytest.approx(np.degrees(0.09), abs=1e-12)
    late = metrics.score_run(rec, q_est, settle_s=100.0)            # nothing left to score
    assert all(np.isnan(v) for v in late.values())


def test_score_run_splits_heading_and_inclination_on_a_vertical_reference():
    rec, q_est = _scored_recording({"reference": "ENU", "body": "sensor"}, with_sun=False)
    s = metrics.score_run(rec, q_est)
    assert set(s) == {"rms_deg", "max_deg", "mean_deg", "heading_rms_deg",
                      "inclination_rms_deg"}
    assert s["heading_rms_deg"] == pytest.approx(0.0, abs=1e-12)   # about x: tilt only
    assert s["inclination_rms_deg"] == pytest.approx(s["rms_deg"], rel=1e-9)


def test_score_broad_over_the_score_mask():
    from gnomon.errors import InputError

    rec, q_est = _scored_recording({"reference": "ENU", "body": "sensor"}, with_sun=False)
    s = metrics.score_broad(rec, q_est)
    e = metrics.broad_errors_rad(rec.q_true, q_est)
    assert s == {f"{k}_deg": metrics.rms_deg(e[k]) for k in ("total", "heading", "inclination")}
    with pytest.raises(InputError, match="no sample"):
        metrics.score_broad(dataclasses.replace(rec, mask=np.zeros(len(rec), bool)), q_est)


def test_compare_removes_a_constant_heading_offset_and_reports_it():
    from gnomon.metrics import compare, heading_offset_rad
    from gnomon.rotation import quat_from_euler, quat_from_rotvec, quat_mul

    rng = np.random.default_rng(21)
    q = quat_from_euler(rng.uniform(-1.0, 1.0, (500, 3)))
    decl = np.radians(7.5)  # e.g. true vs magnetic north
    tilt = quat_from_rotvec(np.column_stack([rng.normal(0, 0.01, 500), np.zeros(500),
                                             np.zeros(500)]))  # 0.57 deg rms about x
    est = quat_mul(quat_from_rotvec([0.0, 0.0, decl]), quat_mul(q, tilt))
    assert heading_offset_rad(q, est) == pytest.approx(decl, abs=2e-3)
    with_match = compare(q, est)
    assert with_match["heading_offset_deg"] == pytest.approx(7.5, abs=0.1)
    assert with_match["total_deg"] < 1.0 and with_match["samples"] == 500
    without = compare(q, est, match_heading=False)
    assert without["heading_deg"] == pytest.approx(7.5, abs=0.2)
    ref = q.copy()
    ref[:100] = np.nan  # rows where the device has no estimate are not scored
    assert compare(ref, est)["samples"] == 400
