"""The smartphone benchmark (tyrex, Michel et al. 2018) and what it is built on.

* ``gnomon.metrics.align_truth``: a known time lag and a known body misalignment put into
  a simulated reference are recovered;
* ``gnomon.io.qualisys`` / ``gnomon.io.tyrex``: QTM's column-major matrices, lost frames,
  the authors' bad intervals, the declination; the frame convention checked physically
  on real excerpts (the resting accelerometer points up through ``q_true``; the gyro
  integrated over short windows turns like the reference);
* the anchors fed multi-rate phone data without invented samples;
* the command line's JSON contract (``gnomon benchmark tyrex``, ``gnomon benchmark DIR``).

Real data: the excerpts shipped in ``gnomon/data/logs/tyrex`` (CeCILL 2.1). Tests of
the full data set find it through ``gnomon.datasets.tyrex_dir`` (``$GNOMON_TYREX_DIR``,
else ``../shared/data/tyrex`` beside the repository) and skip without it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from gnomon.cli import main
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.io import read
from gnomon.io.qualisys import is_qtm_mat, read_qtm
from gnomon.io.tyrex import (
    BAD_INTERVALS_S,
    DECLINATION_DEG,
    reference_on,
    trial_groups,
    trial_info,
    tyrex_trials,
)
from gnomon.metrics import align_truth, error_angle_rad, quat_at
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate, rotvec_from_quat

DATA = bundled("logs", "tyrex")
ANDROID = DATA / "android" / "Guillaume_Nexus5_NoDist_Texting_excerpt"
IOS = DATA / "ios" / "Guillaume_iPhone5_NoDist_Texting_excerpt"
ANCHOR_ROWS = ["vqf", "vqf-offline", "phone", "ahrs-madgwick", "imufusion"]


# ------------------------------------------------------------------ alignment (synthetic)
def _simulated(lag_s: float, rotvec_deg, seed: int = 1):
    """A simulated phone (200 Hz) and its motion capture: a 60 Hz reference that sees the
    motion ``lag_s`` later, on a marker body turned by ``rotvec_deg`` from the sensor,
    slerped onto the gyro's time stamps as the reader does."""
    from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

    rec = simulate_ahrs(AhrsSimParams(duration_s=60.0, rate_hz=200.0, rate_rms=1.0,
                                      rate_band_hz=(0.1, 2.0)), np.random.default_rng(seed))
    q_bs = quat_from_rotvec(np.radians(rotvec_deg))
    t_ref = np.arange(0.0, 60.0, 1.0 / 60.0)
    q_ref = quat_at(rec.t, rec.q_true, t_ref - lag_s)  # q_ENU_body(t) = q_true(t - lag)
    ok = np.isfinite(q_ref).all(axis=1)
    q_ref[ok] = quat_mul(q_ref[ok], quat_conj(q_bs))
    return rec, dataclasses.replace(rec, q_true=quat_at(t_ref, q_ref, rec.t)), q_bs


@pytest.mark.slow(reason="6 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("lag_s,rotvec_deg", [(0.0237, [0.8, -0.6, 1.1]),
                                              (-0.0183, [-1.2, 0.4, -0.3])])
def test_alignment_recovers_a_known_lag_and_body_misalignment(lag_s, rotvec_deg):
    rec, measured, q_bs = _simulated(lag_s, rotvec_deg)
    q, info = align_truth(measured, ("body", "lag"))
    # the simulator's gyro sample k is the rate at the middle of (t[k-1], t[k]]: its
    # stamps are half an interval late, which the lag absorbs
    expected = lag_s - 0.5 / 200.0
    assert info["lag_s"] == pytest.approx(expected, abs=0.5e-3)
    assert info["lag_correlation"] > 0.99 and not info["lag_on_search_edge"]
    err = np.degrees(np.linalg.norm(rotvec_from_quat(quat_mul(
        quat_from_rotvec(np.radians(info["misalignment_rotvec_deg"])), quat_conj(q_bs)))))
    assert err < 0.05
    assert info["misalignment_deg"] == pytest.approx(np.linalg.norm(rotvec_deg), abs=0.05)
    bias = np.degrees(rec.extra["gyro_bias_rad_s"].mean(axis=0))
    assert np.allclose(info["gyro_bias_deg_s"], bias, atol=0.05)
    assert info["rate_rms_deg_s"] < 0.2 * info["rate_rms_deg_s_before"]
    # the aligned truth is the simulated attitude half a gyro interval earlier
    truth = quat_at(rec.t, rec.q_true, rec.t - 0.5 / 200.0)
    e = np.degrees(error_angle_rad(truth, q))
    assert np.nanmax(e[(rec.t > 1.0) & (rec.t < 59.0)]) < 0.1
    before = np.degrees(error_angle_rad(truth, measured.q_true))
    assert np.nanmedian(before) > 1.0  # it did need aligning


def test_alignment_options_apply_only_what_is_asked():
    _, measured, _ = _simulated(0.02, [1.0, 0.0, 0.0], seed=2)
    q0, info0 = align_truth(measured, ())
    assert np.array_equal(q0, measured.q_true, equal_nan=True)  # unchanged, fit reported
    assert info0["align"] == [] and abs(info0["lag_s"] - 0.0175) < 1e-3
    q_lag, _ = align_truth(measured, ("lag",))
    q_body, info_body = align_truth(measured, ("body",))
    ok = np.isfinite(q_lag).all(axis=1) & np.isfinite(q_body).all(axis=1)
    shift = np.degrees(error_angle_rad(measured.q_true[ok], q_lag[ok]))
    turn = np.degrees(error_angle_rad(measured.q_true[ok], q_body[ok]))
    assert np.allclose(turn, info_body["misalignment_deg"], atol=1e-6)  # one constant turn
    assert np.median(shift) > 0.5 and np.std(shift) > 0.1  # a time shift, not a rotation
    # a lag left in biases the body fit (here 1 deg reads 0.7): fit the lag with it
    assert abs(info_body["misalignment_deg"] - 1.0) > 0.1
    _, no_lag, _ = _simulated(0.5 / 200.0, [1.0, 0.0, 0.0], seed=2)  # stamps' half interval
    assert align_truth(no_lag, ("body",))[1]["misalignment_deg"] == pytest.approx(1.0, abs=0.05)
    with pytest.raises(InputError, match="unknown alignment"):
        align_truth(measured, ("heading",))
    with pytest.raises(InputError, match="no truth"):
        align_truth(Recording(t=measured.t, gyro=measured.gyro), ())


# ------------------------------------------------------------------ QTM reader
def _qtm_file(path: Path, matrices: np.ndarray, rate=60.0, start=1.0, header=True,
              **changes) -> Path:
    """A minimal QTM-layout .mat: one rigid body whose frames are ``matrices`` (M, 3, 3)
    stored as QTM stores them (column-major 9-vectors)."""
    m = matrices.shape[0]
    name = np.empty((1, 1), dtype=object)
    name[0, 0] = "phone-body"
    rot = matrices.transpose(0, 2, 1).reshape(m, 9).T[None]  # column-major
    rb = {"Bodies": np.array([[1.0]]), "Name": name,
          "Positions": np.zeros((1, 3, m)), "Rotations": rot}
    s = {"File": "x.qtm", "Timestamp": "2016-06-02", "StartFrame": np.array([[start]]),
         "Frames": np.array([[float(m)]]), "FrameRate": np.array([[rate]]),
         "RigidBodies": rb}
    s.update(changes)
    scipy.io.savemat(path, {"trial": s})
    if header:
        with open(path, "r+b") as fh:
            fh.write(b"QTM_ver test".ljust(116, b" "))
    return path


def test_qtm_reader_reads_column_major_matrices_and_lost_frames(tmp_path):
    rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # body x -> +y
    mats = np.stack([np.eye(3), rz90, np.full((3, 3), np.nan), rz90])
    f = _qtm_file(tmp_path / "a.mat", mats, start=11.0)
    assert is_qtm_mat(f) and not is_qtm_mat(_qtm_file(tmp_path / "b.mat", mats, header=False))
    ref = read_qtm(f)
    assert ref.body == "phone-body" and ref.frame_rate_hz == 60.0
    assert np.allclose(ref.t, (10.0 + np.arange(4)) / 60.0)  # StartFrame keeps the clock
    assert ref.valid.tolist() == [True, True, False, True]
    assert np.allclose(quat_rotate(ref.q[1], [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0])  # R_global_body
    assert np.allclose(np.abs(ref.q[1]), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)])


def test_qtm_reader_names_file_field_and_frame_on_bad_input(tmp_path):
    bad = np.stack([np.eye(3), np.diag([1.0, 1.0, 1.2])])
    with pytest.raises(InputError, match=r"field 'RigidBodies.Rotations'.*row 1|frame 1") as e:
        read_qtm(_qtm_file(tmp_path / "a.mat", bad))
    assert "a.mat" in str(e.value)
    with pytest.raises(InputError, match="FrameRate"):
        read_qtm(_qtm_file(tmp_path / "b.mat", np.stack([np.eye(3)] * 2), rate=-1.0))
    with pytest.raises(InputError, match="Frames"):
        read_qtm(_qtm_file(tmp_path / "c.mat", np.stack([np.eye(3)] * 2),
                           Frames=np.array([[5.0]])))
    with pytest.raises(InputError, match="no rigid body 'nose'"):
        read_qtm(_qtm_file(tmp_path / "d.mat", np.stack([np.eye(3)] * 2)), body="nose")
    scipy.io.savemat(tmp_path / "e.mat", {"x": np.ones(3)})
    with pytest.raises(InputError, match="expected one struct"):
        read_qtm(tmp_path / "e.mat")


# ------------------------------------------------------------------ the data set's facts
def test_trial_names_groups_and_the_bad_intervals():
    info = trial_info("Guillaume_Nexus5_Dist_FrontPocket_excerpt")
    assert info == {"trial": "Guillaume_Nexus5_Dist_FrontPocket", "user": "Guillaume",
                    "phone": "Nexus5", "disturbance": "Dist", "motion": "FrontPocket"}
    assert trial_groups("Guillaume_iPhone5_NoDist_RunningPocket") == [
        "phone:iPhone5", "motion:RunningPocket", "disturbance:NoDist"]
    assert trial_info("calib_mag_Nexus5_d1") is None and trial_groups("calib_mag_x") == []
    assert all(a < b for v in BAD_INTERVALS_S.values() for a, b in v)


def test_reference_nan_in_a_bad_interval_and_turned_to_magnetic_north():
    """The excerpt's capture (16.3-22.3 s) read as the Nexus 5 Dist_FrontPocket trial,
    whose authors marked 21.2-21.6 s bad: NaN there (and up to a frame beyond), the rest
    is the QTM attitude turned by the declination about up."""
    mat = DATA / "qualisys" / f"{ANDROID.name}.mat"
    rec = read(ANDROID, reference=False)
    q, mask, assumed, meta = reference_on(rec.t, mat, "Guillaume_Nexus5_Dist_FrontPocket")
    inside = (rec.t >= 21.2) & (rec.t <= 21.6)
    assert np.isnan(q[inside]).all()
    far = (rec.t < 21.2 - 1 / 60) | (rec.t > 21.6 + 1 / 60)
    assert np.isfinite(q[far]).all() and mask.all()  # the whole excerpt is in 5-120 s
    assert meta["bad_intervals_s"] == [[21.2, 21.6]] and meta["north"] == "magnetic"
    assert any("declination" in s for s in assumed)
    ref = read_qtm(mat)
    raw = quat_at(ref.t, ref.q, rec.t[far])
    e = quat_mul(q[far], quat_conj(raw))  # a rotation about up by +D (east)
    psi = np.degrees(2 * np.arctan2(e[:, 3] * np.sign(e[:, 0]), np.abs(e[:, 0])))
    assert np.allclose(psi, DECLINATION_DEG, atol=1e-6)
    assert np.abs(e[:, 1:3]).max() < 1e-9


def test_declination_is_the_field_model_s():
    ppigrf = pytest.importorskip("ppigrf")
    import datetime

    be, bn, _ = ppigrf.igrf(5.726945, 45.187778, 0.2, datetime.datetime(2016, 5, 31))
    d = np.degrees(np.arctan2(float(np.ravel(be)[0]), float(np.ravel(bn)[0])))
    assert d == pytest.approx(DECLINATION_DEG, abs=0.01)


@pytest.mark.parametrize("trial", [ANDROID, IOS])
def test_truth_frame_physically_on_the_excerpts(trial):
    """Through ``q_true`` the quasi-static specific force points up, and the gyro
    integrated over 0.25 s windows (its constant bias removed) turns as the reference
    does in the body frame — not as it does in the global frame (a transposed matrix)."""
    rec = read(trial)
    assert rec.q_true is not None and rec.meta["truth"]["north"] == "magnetic"
    ta = rec.times("accel")
    qa = quat_at(rec.t, rec.q_true, ta)
    w = np.linalg.norm(np.stack([np.interp(ta, rec.t, rec.gyro[:, k]) for k in range(3)],
                                axis=1), axis=1)
    n = np.linalg.norm(rec.accel, axis=1)
    still = np.isfinite(qa).all(axis=1) & (np.abs(n - 9.81) < 0.5) & (w < 0.5)
    assert still.sum() > 100
    up = quat_rotate(qa[still], rec.accel[still] / n[still, None])
    assert np.degrees(np.median(np.arccos(np.clip(up[:, 2], -1, 1)))) < 6.0
    _, info = align_truth(rec, ())
    bias = np.radians(info["gyro_bias_deg_s"])
    right, wrong = [], []
    for t0 in np.arange(rec.t[0] + 0.2, rec.t[-1] - 0.45, 0.25):
        i0, i1 = np.searchsorted(rec.t, [t0, t0 + 0.25])
        q0, q1 = rec.q_true[i0], rec.q_true[i1]
        g = np.array([1.0, 0.0, 0.0, 0.0])
        for k in range(i0 + 1, i1 + 1):
            g = quat_mul(g, quat_from_rotvec((rec.gyro[k] - bias) * (rec.t[k] - rec.t[k - 1])))
        right.append(error_angle_rad(quat_mul(quat_conj(q0), q1), g))
        wrong.append(error_angle_rad(quat_mul(q1, quat_conj(q0)), g))
    right, wrong = np.degrees(right), np.degrees(wrong)
    assert len(right) >= 15 and np.median(right) < 1.0 and np.median(wrong) > 2 * np.median(right)


def test_excerpt_lag_is_the_residual_of_the_data_set_s_alignment():
    for trial in (ANDROID, IOS):
        _, info = align_truth(read(trial))
        assert -0.040 < info["lag_s"] < -0.005 and info["lag_correlation"] > 0.9


# ------------------------------------------------------------------ anchors, multi-rate
@pytest.fixture(scope="module")
def multi_rate():
    from conftest import synthetic_imu

    from gnomon.rotation import quat_from_euler

    full = synthetic_imu(quat_from_euler([0.3, -0.2, 2.0]), [0.3, -0.4, 0.5], n=6000,
                         fs=200.0, noise=0.002, seed=4)
    ia, im = np.arange(0, len(full), 2), np.arange(1, len(full), 4)
    q_on = full.q_true.copy()
    q_on[:10] = np.nan
    return Recording(t=full.t, gyro=full.gyro, accel=full.accel[ia], accel_t=full.t[ia] - 1e-3,
                     mag=full.mag[im], mag_t=full.t[im] - 1e-3, q_true=full.q_true,
                     q_onboard=q_on, source="multi-rate")


@pytest.mark.parametrize("name", ["vqf", "vqf-offline", "imufusion", "ahrs-madgwick"])
def test_anchors_take_each_sensor_at_its_own_rate(multi_rate, name):
    pytest.importorskip({"ahrs-madgwick": "ahrs"}.get(name, name.split("-")[0]))
    from gnomon import anchors
    from gnomon.metrics import broad_errors_rad

    assert not multi_rate.single_rate
    q = anchors.run_anchor(name, multi_rate)
    e = broad_errors_rad(multi_rate.q_true[-1000:], q[-1000:])
    assert np.degrees(e["inclination"]).max() < 2.0, name
    assert np.degrees(e["heading"]).max() < 3.0, name


def test_vqf_batch_with_zero_rows_equals_the_per_sample_calls(multi_rate):
    pytest.importorskip("vqf")
    from gnomon.anchors import run_vqf, run_vqf_per_row

    assert np.array_equal(run_vqf(multi_rate), run_vqf_per_row(multi_rate))


def test_onboard_anchor_is_the_device_estimate(multi_rate):
    from gnomon import anchors

    q = anchors.run_anchor("onboard", multi_rate)
    assert np.array_equal(q, multi_rate.q_onboard, equal_nan=True)


# ------------------------------------------------------------------ command line
@pytest.mark.slow(reason="20 s (2 cores): long runs or a first compilation")
def test_cli_tyrex_json_contract(capsys, tmp_path):
    plot = tmp_path / "tyrex.png"
    assert main(["benchmark", "tyrex", "--data", DATA, "--filters", "mahony", "--anchors",
                 ",".join(ANCHOR_ROWS), "--plot", plot, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    methods = ["mahony", *ANCHOR_ROWS]
    assert out["benchmark"] == "tyrex" and out["mag"] == "calibrated"
    assert out["align"] == ["body", "lag"] and not out["errors"]
    assert set(out["mean"]) == set(methods)
    for m in methods:
        assert set(out["mean"][m]) == {"total_deg", "heading_deg", "inclination_deg", "trials"}
        assert out["mean"][m]["trials"] == 2
    trials = {ANDROID.name, IOS.name}
    assert {(r["trial"], r["method"]) for r in out["trials"]} == {
        (t, m) for t in trials for m in methods}
    for r in out["trials"]:
        assert {"trial", "method", "total_deg", "heading_deg", "inclination_deg", "samples",
                "lag_s", "misalignment_deg", "phone", "motion", "disturbance"} <= set(r)
    assert {a["trial"] for a in out["alignment"]} == trials
    for a in out["alignment"]:
        assert {"lag_s", "lag_correlation", "misalignment_deg", "misalignment_rotvec_deg",
                "gyro_bias_deg_s", "rate_rms_deg_s_before", "rate_rms_deg_s"} <= set(a)
    g = out["groups"]["mahony"]
    assert {"phone:Nexus5", "phone:iPhone5", "motion:Texting", "disturbance:NoDist"} <= set(g)
    assert g["phone:Nexus5"]["trials"] == 1 and g["motion:Texting"]["trials"] == 2
    assert out["truth"]["north"] == "magnetic"
    assert set(out["alignment_stats"]) == {"all", "phone:Nexus5", "phone:iPhone5"}
    assert plot.stat().st_size > 1000
    assert main(["benchmark", "tyrex", "--data", DATA, "--filters", "mahony", "--anchors",
                 "none", "--mag", "raw", "--align", "none", "--json"]) == 0
    raw = json.loads(capsys.readouterr().out)
    assert raw["mag"] == "raw" and raw["align"] == [] and set(raw["mean"]) == {"mahony"}
    assert all(r["lag_s"] == 0.0 and r["misalignment_deg"] == 0.0 for r in raw["trials"])
    assert len(raw["alignment"]) == 2  # the fit is still reported


def test_cli_tyrex_text_and_bad_options(capsys, monkeypatch, tmp_path):
    assert main(["benchmark", "tyrex", "--data", DATA, "--filters", "mahony", "--anchors",
                 "phone"]) == 0
    text = capsys.readouterr().out
    assert "per phone" in text and "per motion" in text and "lag ms" in text
    assert main(["benchmark", "tyrex", "--data", DATA, "--align", "heading"]) == 2
    assert "unknown alignment" in capsys.readouterr().err
    assert main(["benchmark", "broad", "--data", DATA, "--mag", "raw"]) == 2
    monkeypatch.setenv("GNOMON_TYREX_DIR", str(tmp_path / "absent"))  # no data set anywhere
    assert main(["benchmark", "tyrex"]) == 2
    err = capsys.readouterr().err
    assert "--data" in err and "gnomon datasets fetch tyrex" in err


def test_cli_benchmark_any_folder(capsys):
    assert main(["benchmark", DATA, "--filters", "mahony", "--anchors", "vqf,onboard",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["benchmark"] == "dir" and out["align"] == []
    names = {r["trial"] for r in out["trials"]}
    assert names == {f"android/{ANDROID.name}", f"ios/{IOS.name}"}
    assert set(out["mean"]) == {"mahony", "vqf", "onboard"}
    assert {s["trial"] for s in out["skipped"]} >= {f"qualisys/{ANDROID.name}"}
    assert main(["benchmark", DATA, "--filters", "mahony", "--anchors", "none", "--align",
                 "lag", "--json"]) == 0
    lagged = json.loads(capsys.readouterr().out)
    assert lagged["align"] == ["lag"] and len(lagged["alignment"]) == 2


# ------------------------------------------------------------------ the full data set
def test_full_data_set_trials_and_references(full_tyrex):
    trials, calib = tyrex_trials(full_tyrex)
    assert len(trials) == 28 and len(calib) == 6
    assert {trial_info(p.name)["phone"] for p in trials} == {"Nexus5", "iPhone5"}
    for p in (trials[0], trials[-1]):
        rec = read(p)
        scored = rec.score_mask.sum() / rec.mask.sum()
        assert rec.meta["truth"]["tracked_fraction"] > 0.95 and scored > 0.9


@pytest.mark.parametrize("trial", ["android/Guillaume_Nexus5_NoDist_Phoning",
                                   "ios/Guillaume_iPhone5_NoDist_Phoning"])
def test_full_trial_alignment_and_gravity(trial, full_tyrex):
    """On a whole trial the fit is well determined: the residual lag of the data set's
    10 ms alignment, a phone 1-3 deg off its marker body, the rate residual cut by more
    than 3; at rest (tight thresholds) the specific force through the aligned truth is
    within 2 deg of up (median) — the phone held vertically at the ear."""
    rec = read(full_tyrex / "datasets" / trial)
    q, info = align_truth(rec)
    assert -0.040 < info["lag_s"] < -0.005 and info["lag_correlation"] > 0.95
    assert 0.8 < info["misalignment_deg"] < 3.0
    assert info["rate_rms_deg_s"] < info["rate_rms_deg_s_before"] / 3
    ta = rec.times("accel")
    qa = quat_at(rec.t, q, ta)
    bias = np.radians(info["gyro_bias_deg_s"])
    w = np.linalg.norm(np.stack([np.interp(ta, rec.t, rec.gyro[:, k]) for k in range(3)],
                                axis=1) - bias, axis=1)
    n = np.linalg.norm(rec.accel, axis=1)
    still = np.isfinite(qa).all(axis=1) & (np.abs(n - 9.81) < 0.2) & (w < 0.1)
    up = quat_rotate(qa[still], rec.accel[still] / n[still, None])
    assert still.sum() > 200
    assert np.degrees(np.median(np.arccos(np.clip(up[:, 2], -1, 1)))) < 2.0
    horizontal = np.abs(quat_rotate(qa[still], [0.0, 0.0, 1.0])[:, 2])
    assert np.median(horizontal) < 0.5  # the screen's normal is horizontal: not flat
