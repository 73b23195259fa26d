"""Magnetometer calibration (``gnomon.calibration``, ``gnomon calibrate mag``): synthetic
ellipsoids with known offsets and soft iron, partial coverage and noise; an independent
reference fit on the same points; refusals; bad input; the command line. The tyrex data
set is needed only by the tests that say so (they skip without it)."""

import json
import math

import numpy as np
import pytest
from scipy.optimize import minimize

from gnomon.calibration import (
    COVERAGE_CELLS,
    MIN_COVERAGE,
    MagCalibration,
    apply_mag_calibration,
    calibrate_mag,
    coverage_cells,
    fit_mag,
    gyro_offset_uT,
    igrf_field_uT,
    load_mag_calibration,
    save_mag_calibration,
    sphere_coverage,
)
from gnomon.calibration.fit import _ellipsoid_fit
from gnomon.cli import main
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

B_UT = 50.0  # field magnitude of the synthetic cases, uT
FIELD_ENU_UT = np.array([0.0, 20.0, -45.0])


def soft_iron(rng, amplitude=0.08):
    """A symmetric positive-definite soft iron near the identity (eigenvalue ratio <~1.3)."""
    A = np.eye(3) + amplitude * rng.standard_normal((3, 3))
    A = 0.5 * (A + A.T)
    w, V = np.linalg.eigh(A)
    return (V * np.abs(w)) @ V.T


def directions(rng, n, kind="all", extent=1.0, rotate=True):
    """n unit vectors: over the whole sphere, in a band |z| < extent, or a cap z > 1 -
    2 extent (area fraction extent), about a random axis (``rotate``) or z."""
    out = np.empty((0, 3))
    while len(out) < n:
        d = rng.standard_normal((4 * n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        if kind == "band":
            d = d[np.abs(d[:, 2]) < extent]
        elif kind == "cap":
            d = d[d[:, 2] > 1 - 2 * extent]
        out = np.vstack([out, d])
    R = np.linalg.qr(rng.standard_normal((3, 3)))[0] if rotate else np.eye(3)
    return out[:n] @ R.T


def raw_samples(rng, h, S, o, noise_rel=0.01):
    """Raw readings m = S^-1 h + o + noise (noise std noise_rel * B per axis)."""
    return h @ np.linalg.inv(S).T + o + rng.normal(0, noise_rel * B_UT, h.shape)


def errors(cal, S, o):
    """(offset error / B, relative Frobenius error of the soft iron)."""
    return (np.linalg.norm(cal.offset_uT - o) / B_UT,
            np.linalg.norm(cal.soft_iron - S) / np.linalg.norm(S))


# ---------------------------------------------------------------------- coverage
def test_coverage_cells_have_equal_area_and_count():
    edges, counts = coverage_cells(COVERAGE_CELLS)
    assert counts.sum() == COVERAGE_CELLS and counts[0] == counts[-1] == 1
    # zone areas 2π (cos θa - cos θb) equal (cells per zone) x 4π/n
    zone_area = 2 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    np.testing.assert_allclose(zone_area / counts, 4 * np.pi / COVERAGE_CELLS, rtol=1e-9)
    rng = np.random.default_rng(0)
    d = directions(rng, 1_000_000)
    from gnomon.calibration.coverage import _cell_index

    hits = np.bincount(_cell_index(d), minlength=COVERAGE_CELLS)
    assert hits.size == COVERAGE_CELLS
    # uniform directions: every cell holds 1/100 of them (binomial std 0.3 %)
    np.testing.assert_allclose(hits / d.shape[0], 1 / COVERAGE_CELLS, rtol=0.05)
    assert sphere_coverage(d) == 1.0
    hemi = d[d[:, 2] > 0]
    assert 0.45 <= sphere_coverage(hemi @ np.diag([1, 1, 1])) <= 0.62
    assert sphere_coverage(np.tile([[0, 0, 1.0]], (10, 1))) == 1 / COVERAGE_CELLS


# ---------------------------------------------------------------------- recovery
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_full_sphere_recovers_offset_and_soft_iron(seed):
    rng = np.random.default_rng(seed)
    S, o = soft_iron(rng), rng.uniform(-300, 300, 3)
    m = raw_samples(rng, B_UT * directions(rng, 2000), S, o)
    cal = fit_mag(m, field_uT=B_UT)
    assert cal.ok and cal.model == "full" and cal.coverage == 1.0
    e_o, e_S = errors(cal, S, o)
    assert e_o < 0.003 and e_S < 0.003  # noise 1 % of B, 2000 samples
    assert cal.residual_uT == pytest.approx(math.sqrt(3) * 0.01 * B_UT / math.sqrt(3), rel=0.2)
    assert cal.condition < 5
    np.testing.assert_allclose(cal.soft_iron, cal.soft_iron.T)
    assert np.linalg.eigvalsh(cal.soft_iron).min() > 0


@pytest.mark.slow(reason="4 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_thirty_percent_coverage_meets_the_one_percent_targets(seed):
    """Target of issue 19: offset within 1 % of |B| and soft iron within 1 % (relative
    Frobenius) at 30 % coverage and noise 1 % of |B|, 3000 samples. The directions: a
    band |z| < 0.3 (30 % of the sphere's area, the field of a device turned about x and y
    through +-17 deg of a great circle; 32-34 of the 100 cells). The geometry matters as
    much as the number: a cap of the same area does not determine the 9 parameters to 1 %
    (next test), and a band tilted across the cells touches more of them."""
    rng = np.random.default_rng(100 + seed)
    S, o = soft_iron(rng), rng.uniform(-300, 300, 3)
    h = B_UT * directions(rng, 3000, "band", 0.3, rotate=False)
    cal = fit_mag(raw_samples(rng, h, S, o), field_uT=B_UT)
    assert 0.28 <= cal.coverage <= 0.36
    assert cal.ok and cal.model == "full", cal.reason
    e_o, e_S = errors(cal, S, o)
    assert e_o < 0.01 and e_S < 0.01, (e_o, e_S)


def test_without_the_field_magnitude_the_shape_is_recovered_up_to_scale():
    rng = np.random.default_rng(7)
    S, o = soft_iron(rng), np.array([40.0, -70.0, 410.0])
    cal = fit_mag(raw_samples(rng, B_UT * directions(rng, 2000), S, o))
    assert cal.field_source == "data"
    assert np.linalg.det(cal.soft_iron) == pytest.approx(1.0, rel=1e-9)
    S_unit = S / np.cbrt(np.linalg.det(S))
    assert np.linalg.norm(cal.soft_iron - S_unit) / np.linalg.norm(S_unit) < 0.003
    assert np.linalg.norm(cal.offset_uT - o) / B_UT < 0.003
    assert cal.field_uT == pytest.approx(B_UT / np.cbrt(np.linalg.det(S)), rel=0.003)


def test_small_cap_falls_back_to_the_offset_and_says_so():
    """A cap of 20 % of the sphere does not determine the 9 parameters: the fit falls
    back to a model with fewer and names it. The offset it finds is biased by the soft
    iron it cannot see (2 % here): within 8 % of |B| (3-6 % on these seeds)."""
    rng = np.random.default_rng(3)
    S, o = soft_iron(rng, 0.02), rng.uniform(-100, 100, 3)
    h = B_UT * directions(rng, 2000, "cap", 0.2)
    cal = fit_mag(raw_samples(rng, h, S, o), field_uT=B_UT)
    assert cal.ok
    assert cal.model in ("scale", "offset")
    assert [t["model"] for t in cal.tried][0] == "full" and cal.tried[0]["why_not"]
    assert np.linalg.norm(cal.offset_uT - o) / B_UT < 0.08


def test_agrees_with_an_independent_geometric_fit():
    """fit_mag with plain least squares (no balance, no Huber) against a direct
    scipy.optimize.minimize of the same geometric cost, from a sphere start."""
    rng = np.random.default_rng(11)
    S, o = soft_iron(rng), rng.uniform(-200, 200, 3)
    m = raw_samples(rng, B_UT * directions(rng, 1500, "band", 0.5), S, o)
    cal = fit_mag(m, field_uT=B_UT, model="full", balance=False, huber_rel=1e6)

    def cost(p):
        Sp = np.array([[p[3], p[8], p[7]], [p[8], p[4], p[6]], [p[7], p[6], p[5]]])
        return np.sum((np.linalg.norm((m - p[:3]) @ Sp.T, axis=1) - B_UT) ** 2)

    c = m.mean(axis=0)
    r = np.mean(np.linalg.norm(m - c, axis=1))
    ref = minimize(cost, np.r_[c, [B_UT / r] * 3, 0, 0, 0], method="BFGS",
                   options={"gtol": 1e-10, "maxiter": 10_000})
    S_ref = np.array([[ref.x[3], ref.x[8], ref.x[7]], [ref.x[8], ref.x[4], ref.x[6]],
                      [ref.x[7], ref.x[6], ref.x[5]]])
    np.testing.assert_allclose(cal.offset_uT, ref.x[:3], atol=1e-3 * B_UT)
    np.testing.assert_allclose(cal.soft_iron, S_ref, atol=1e-4)
    assert cost(np.r_[cal.offset_uT, np.diag(cal.soft_iron), cal.soft_iron[1, 2],
                      cal.soft_iron[0, 2], cal.soft_iron[0, 1]]) <= ref.fun * (1 + 1e-6)


def test_algebraic_start_is_exact_on_an_exact_ellipsoid():
    """Li & Griffiths' fit returns an exact ellipsoid's centre and matrix (no noise)."""
    rng = np.random.default_rng(5)
    S, o = soft_iron(rng, 0.15), rng.normal(0, 0.3, 3)
    x = directions(rng, 500) @ np.linalg.inv(S).T + o  # (x - o)^T S^2 (x - o) = 1
    x += rng.normal(0, 1e-7, x.shape)  # exact data: the eigenvalue sought is 0 (+-rounding)
    centre, M = _ellipsoid_fit(x, np.ones(len(x)))
    np.testing.assert_allclose(centre, o, atol=1e-5)
    np.testing.assert_allclose(M, S @ S, atol=1e-5)


# ---------------------------------------------------------------------- refusals
def test_refused_below_the_coverage_limit():
    rng = np.random.default_rng(2)
    h = B_UT * directions(rng, 1000, "cap", 0.02)  # 2 % of the sphere
    m = raw_samples(rng, h, np.eye(3), np.array([10.0, 20.0, 30.0]))
    cal = fit_mag(m, field_uT=B_UT)
    assert not cal.ok and cal.coverage < MIN_COVERAGE["offset"]
    assert "coverage" in cal.reason
    with pytest.raises(InputError, match="refused.*coverage") as e:
        fit_mag(m, field_uT=B_UT, require_ok=True)
    assert e.value.field == "mag"
    rec = Recording(t=np.arange(len(m)) * 0.02, gyro=np.zeros((len(m), 3)), mag=m)
    with pytest.raises(InputError, match="refused"):
        apply_mag_calibration(rec, cal)


def test_a_circle_is_refused_as_ambiguous_or_undetermined():
    """A device turned only about one axis: the field traces a circle, which two centres
    (mirror images) fit equally well."""
    rng = np.random.default_rng(4)
    a = rng.uniform(0, 2 * np.pi, 2000)
    h = B_UT * np.column_stack([0.5 * np.cos(a), 0.5 * np.sin(a), np.full_like(a, -0.866)])
    cal = fit_mag(raw_samples(rng, h, np.eye(3), np.array([30.0, -20.0, 100.0])),
                  field_uT=B_UT)
    assert not cal.ok
    assert any(w in cal.reason for w in ("ambiguous", "coverage", "condition"))


# ---------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case, match, row", [
    ("nan", "non-finite", 3), ("shape", r"shape \(N, 3\)", None), ("few", "too few", None),
    ("zero", "zero vector", 5), ("flat", "did not move", None)])
def test_bad_input_names_the_field_and_value(case, match, row):
    m = np.random.default_rng(0).normal(0, 50, (100, 3))
    if case == "nan":
        m[3, 1] = np.nan
    elif case == "shape":
        m = m[:, :2]
    elif case == "few":
        m = m[:10]
    elif case == "zero":
        m[5] = 0.0
    elif case == "flat":
        m[:] = [1.0, 2.0, 3.0]
    with pytest.raises(InputError, match=match) as e:
        fit_mag(m)
    assert e.value.field == "mag" and e.value.row == row


def test_bad_options_are_named():
    m = np.random.default_rng(0).normal(0, 50, (100, 3))
    with pytest.raises(InputError, match="positive field") as e:
        fit_mag(m, field_uT=-1.0)
    assert e.value.field == "field_uT"
    with pytest.raises(InputError, match="unknown model") as e:
        fit_mag(m, model="ellipse")
    assert e.value.field == "model"
    with pytest.raises(InputError, match="latitude"):
        igrf_field_uT(95.0, 0.0)


def test_load_rejects_a_bad_file(tmp_path):
    p = tmp_path / "cal.json"
    p.write_text(json.dumps({"offset_uT": [1, 2], "soft_iron": np.eye(3).tolist()}))
    with pytest.raises(InputError, match="3 finite numbers") as e:
        load_mag_calibration(p)
    assert e.value.field == "offset_uT" and e.value.file == str(p)
    p.write_text(json.dumps({"offset_uT": [1, 2, 3], "soft_iron": (-np.eye(3)).tolist()}))
    with pytest.raises(InputError, match="positive definite") as e:
        load_mag_calibration(p)
    assert e.value.field == "soft_iron"
    p.write_text("{not json")
    with pytest.raises(InputError, match="not a calibration JSON"):
        load_mag_calibration(p)


# ---------------------------------------------------------------------- field, gyro
def test_igrf_magnitude_matches_ppigrf():
    import datetime as dt

    import ppigrf

    be, bn, bu = ppigrf.igrf(5.726945, 45.187778, 0.2, dt.datetime(2016, 5, 31, 12))
    ref = float(np.sqrt(be ** 2 + bn ** 2 + bu ** 2).item()) / 1000
    assert igrf_field_uT(45.187778, 5.726945, 200.0, "2016-05-31") == pytest.approx(
        ref, abs=0.005)  # uT: ppigrf's geodetic conversion and epoch, 5 nT


def tumbling(n=3000, fs=50.0, offset=(40.0, -60.0, 400.0), S=None, noise_uT=0.5,
             seed=0, mag_every=1):
    """A body turning about an axis that itself turns (all directions visited), with a
    raw magnetometer m = S^-1 h + o (+ noise); the magnetometer every mag_every-th
    sample on its own time stamps."""
    rng = np.random.default_rng(seed)
    S = np.eye(3) if S is None else S
    t = np.arange(n) / fs
    w = 1.5 * np.column_stack([np.sin(0.31 * t), np.cos(0.23 * t), np.sin(0.17 * t + 1.0)])
    q = np.empty((n, 4))
    q[0] = [1.0, 0, 0, 0]
    for k in range(1, n):
        q[k] = quat_mul(q[k - 1], quat_from_rotvec(0.5 * (w[k - 1] + w[k]) / fs))
    q_bn = quat_conj(q)
    h = quat_rotate(q_bn, FIELD_ENU_UT)
    m = h @ np.linalg.inv(S).T + np.asarray(offset) + rng.normal(0, noise_uT, h.shape)
    acc = quat_rotate(q_bn, np.array([0.0, 0.0, 9.81]))
    sl = slice(None, None, mag_every)
    return Recording(t=t, gyro=w, accel=acc, mag=m[sl], mag_t=t[sl], q_true=q,
                     source="tumbling")


def test_gyro_offset_recovers_the_hard_iron():
    rec = tumbling(mag_every=2)
    o = gyro_offset_uT(rec)
    np.testing.assert_allclose(o, [40.0, -60.0, 400.0], atol=0.5)
    still = Recording(t=rec.t, gyro=np.zeros_like(rec.gyro), mag=rec.mag, mag_t=rec.mag_t)
    assert gyro_offset_uT(still) is None  # no rotation: nothing determined


def test_calibrate_and_apply_a_multirate_recording_in_nanotesla():
    rng = np.random.default_rng(1)
    S = soft_iron(rng, 0.04)
    rec_uT = tumbling(S=S, mag_every=2)
    rec = Recording(t=rec_uT.t, gyro=rec_uT.gyro, mag=rec_uT.mag * 1000, mag_t=rec_uT.mag_t,
                    mag_unit="nT", source="tumbling")
    cal = calibrate_mag(rec, field_uT=float(np.linalg.norm(FIELD_ENU_UT)))
    assert cal.ok and cal.model == "full"
    np.testing.assert_allclose(cal.offset_uT, [40.0, -60.0, 400.0], atol=0.3)
    assert np.linalg.norm(cal.soft_iron - S) / np.linalg.norm(S) < 0.01
    out = apply_mag_calibration(rec, cal)
    assert out.mag_unit == "uT" and out.mag_t is rec.mag_t or np.array_equal(out.mag_t,
                                                                                rec.mag_t)
    norm = np.linalg.norm(out.mag, axis=1)
    assert np.abs(norm - np.linalg.norm(FIELD_ENU_UT)).max() < 3.0
    assert out.meta["mag_calibration"]["model"] == "full"
    np.testing.assert_array_equal(out.gyro, rec.gyro)


def test_save_and_load_round_trip(tmp_path):
    rng = np.random.default_rng(9)
    S, o = soft_iron(rng), rng.uniform(-50, 50, 3)
    cal = fit_mag(raw_samples(rng, B_UT * directions(rng, 800), S, o), field_uT=B_UT)
    back = load_mag_calibration(save_mag_calibration(tmp_path / "c.json", cal))
    assert isinstance(back, MagCalibration)
    np.testing.assert_allclose(back.offset_uT, cal.offset_uT)
    np.testing.assert_allclose(back.soft_iron, cal.soft_iron)
    assert (back.ok, back.model, back.coverage) == (cal.ok, cal.model, cal.coverage)


# ---------------------------------------------------------------------- command line
def _write_csv(path, rec):
    cols = np.column_stack([rec.t, rec.gyro, rec.accel, rec.mag])
    header = "t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"
    np.savetxt(path, cols, delimiter=",", header=header, comments="", fmt="%.6f")
    return path


def test_cli_calibrate_mag_json_out_and_plot(tmp_path, capsys):
    csv = _write_csv(tmp_path / "tumble.csv", tumbling())
    out, plot = tmp_path / "cal.json", tmp_path / "cal.png"
    assert main(["calibrate", "mag", csv, "--out", out, "--plot", plot, "--json",
                 "--location", "45.19,5.73,200", "--date", "2016-05-31"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert {"offset_uT", "soft_iron", "residual_uT", "coverage", "ok"} <= set(report)
    assert len(report["offset_uT"]) == 3 and np.shape(report["soft_iron"]) == (3, 3)
    assert report["ok"] is True and report["coverage"] > 0.8
    assert isinstance(report["residual_uT"], float) and report["residual_uT"] < 2.0
    np.testing.assert_allclose(report["offset_uT"], [40.0, -60.0, 400.0], atol=0.5)
    assert report["field_uT"] == pytest.approx(igrf_field_uT(45.19, 5.73, 200, "2016-05-31"))
    saved = json.loads(out.read_text())
    assert saved["offset_uT"] == report["offset_uT"]
    assert plot.stat().st_size > 20_000
    # the calibration applied by estimate, and a self-calibration
    assert main(["estimate", csv, "--filter", "mahony", "--mag-calibration", out,
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["mag_calibration"]["from"] == str(out)
    assert main(["estimate", csv, "--filter", "mahony", "--mag-calibration", "self",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mag_calibration"]["ok"] is True


def test_cli_reads_a_phones_raw_magnetometer_for_a_calibration(capsys):
    """A phone export holds the OS-calibrated and the raw magnetometer; a calibration is
    fitted to (and corrects) the raw one, so ``calibrate mag`` and ``estimate
    --mag-calibration`` read it unless told otherwise (the bundled Nexus 5 excerpt: its raw
    offset is about (61, -53, 409) uT, Android's own estimate; too short to calibrate, so
    the report is a refusal, with the gyro's offset)."""
    trial = bundled("logs", "tyrex", "android", "Guillaume_Nexus5_NoDist_Texting_excerpt")
    offsets = {}
    for extra in ([], ["--phone-mag", "calibrated"]):
        assert main(["calibrate", "mag", str(trial), "--json", *extra]) == 1  # refused
        out = capsys.readouterr()
        offsets[bool(extra)] = json.loads(out.out)["offset_uT"]
        assert ("raw magnetometer" in out.err) is not bool(extra)
    np.testing.assert_allclose(offsets[False], [61.0, -53.0, 409.0], atol=10.0)
    assert np.linalg.norm(offsets[True]) < 10.0


def test_cli_refusal_and_bad_input(tmp_path, capsys):
    rec = tumbling()
    yaw = Recording(t=rec.t, gyro=np.column_stack([0 * rec.t, 0 * rec.t, 0.5 + 0 * rec.t]),
                    accel=rec.accel, mag=None)
    a = 0.5 * yaw.t
    h = np.column_stack([20 * np.cos(a), -20 * np.sin(a), np.full_like(a, -45.0)])
    yaw = Recording(t=rec.t, gyro=yaw.gyro, accel=rec.accel, mag=h + [40.0, -60.0, 400.0])
    csv = _write_csv(tmp_path / "yaw.csv", yaw)
    assert main(["calibrate", "mag", csv, "--json", "--no-gyro"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False and report["reason"]
    assert main(["calibrate", "mag", csv, "--location", "45,5"]) == 2
    assert "--date" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"offset_uT": [0, 0, 0]}))
    assert main(["estimate", csv, "--mag-calibration", bad]) == 2
    assert "soft_iron" in capsys.readouterr().err


def test_benchmark_calibration_options_are_checked():
    from gnomon.benchmark import run_tyrex

    with pytest.raises(InputError, match="raw") as e:
        run_tyrex("/nonexistent", mag="calibrated", mag_calibration="self")
    assert e.value.field == "mag_calibration"
    with pytest.raises(InputError, match="self or recording"):
        run_tyrex("/nonexistent", mag="raw", mag_calibration="both")
    assert main(["benchmark", "broad", "--data", "x", "--mag-calibration", "self"]) == 2


# ---------------------------------------------------------------------- tyrex (data set)
def test_tyrex_calibration_recording_matches_android_own_estimate(full_tyrex):
    from gnomon.io.phone import read_tyrex
    from gnomon.io.tyrex import datasets_dir

    folder = datasets_dir(full_tyrex) / "android" / "calib_mag_Nexus5_d2"
    cal = calibrate_mag(read_tyrex(folder, mag="raw", reference=False), field_uT=47.07)
    assert cal.ok and cal.model == "full" and cal.coverage > 0.9
    assert cal.residual_uT < 1.0  # the Nexus 5's noise is ~0.65 uT per axis
    android = np.median(np.loadtxt(folder / "magnetometer.txt")[:, 4:7], axis=0)
    np.testing.assert_allclose(cal.offset_uT, android, atol=2.0)


def test_tyrex_every_trial_has_its_calibration_recording(full_tyrex):
    from gnomon.benchmark import TYREX_MAG_CALIBRATION
    from gnomon.io.tyrex import datasets_dir, tyrex_trials

    trials, _ = tyrex_trials(full_tyrex)
    assert trials
    for p in trials:
        assert (datasets_dir(full_tyrex) / TYREX_MAG_CALIBRATION[p.name] / "magnetometer.txt"
                ).is_file()
