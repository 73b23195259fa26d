"""Readers and writers: gnomon HDF5 round trip, BROAD (.hdf5, .mat), CSV, auto-detection, bad input.

Real data: the BROAD excerpts shipped in gnomon/data (README there; BROAD,
Laidig et al. 2021, doi:10.3390/data6070072, CC BY 4.0). Tests against the full
BROAD trials run when the data directory exists: ``$GNOMON_BROAD_DIR``, else
``../shared/data/broad`` relative to the repository root (or one level further
up, for git worktrees under ``wt/``).
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

from gnomon.datasets import broad_dir, bundled
from gnomon.errors import InputError
from gnomon.io import (
    UnitWarning,
    broad_groups,
    broad_trials,
    detect_format,
    read,
    read_broad,
    read_csv,
    read_recording,
    write,
    write_recording,
)
from gnomon.recording import Recording

DATA = bundled()
MAT = DATA / "broad" / "01_undisturbed_slow_rotation_A_excerpt.mat"
H5 = DATA / "broad" / "32_disturbed_attached_magnet_1cm_excerpt.hdf5"
CSV = DATA / "broad_01_excerpt.csv"
CSV_SLICE = slice(1714, 1714 + 1429)  # rows of the .mat excerpt in the CSV (make_fixtures.py)
FS_HZ = 2000.0 / 7.0  # BROAD's sampling rate, 285.714... Hz
HEADER = "t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"


def full_broad_dir() -> Path | None:
    return broad_dir()


def needs_full_broad() -> Path:
    d = full_broad_dir()
    if d is None:
        pytest.skip("full BROAD data not found: set GNOMON_BROAD_DIR or put it in "
                    "../shared/data/broad (relative to the repository root)")
    return d


def assert_same_recording(a: Recording, b: Recording) -> None:
    """Every field equal, exactly (NaN == NaN), with the same dtypes."""
    for name in ("t", "gyro", "accel", "accel_t", "mag", "mag_t", "sun", "sun_valid",
                 "q_true", "q_onboard", "mask"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype, name
            assert x.shape == y.shape, name
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
    assert a.mag_unit == b.mag_unit
    assert a.frames == b.frames
    assert a.source == b.source
    assert a.meta == b.meta
    assert sorted(a.extra) == sorted(b.extra)
    for key in a.extra:
        assert a.extra[key].dtype == b.extra[key].dtype, key
        assert np.array_equal(a.extra[key], b.extra[key], equal_nan=True), key


def full_recording(rng: np.random.Generator, n: int = 500) -> Recording:
    t = np.cumsum(rng.uniform(0.009, 0.011, n))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[[3, n - 2]] = np.nan
    sun = rng.normal(size=(n, 3))
    sun /= np.linalg.norm(sun, axis=1, keepdims=True)
    valid = rng.uniform(size=n) > 0.3
    sun[~valid] = np.nan
    return Recording(
        t=t, gyro=rng.normal(size=(n, 3)), accel=rng.normal(size=(n, 3)),
        mag=rng.normal(scale=3e4, size=(n, 3)), mag_unit="nT", sun=sun, sun_valid=valid,
        q_true=q, mask=rng.uniform(size=n) > 0.5,
        frames={"reference": "ECI", "body": "B", "note": "Hamilton, [w,x,y,z]"},
        source="unit test: Gauß, 25 °C",
        extra={"b_o_nT": rng.normal(size=(n, 3)), "eclipse": rng.uniform(size=n) > 0.9,
               "mode": rng.integers(0, 4, n), "rate_truth": rng.normal(size=(n, 3)).astype(
                   np.float32)},
    )


# ----------------------------------------------------------------- gnomon HDF5
def test_hdf5_round_trip_every_field(tmp_path):
    rec = full_recording(np.random.default_rng(1))
    path = write_recording(tmp_path / "rec.h5", rec)
    back = read_recording(path)
    assert_same_recording(rec, back)
    with h5py.File(path) as f:  # the documented layout
        assert f.attrs["format"] == "gnomon-recording"
        assert int(f.attrs["format_version"]) == 2
        assert f["mag"].attrs["unit"] == "nT"
        assert f["gyro"].attrs["unit"] == "rad/s"
        assert f["q_true"].shape == (500, 4)
        assert f["sun_valid"].dtype == bool and f["mask"].dtype == bool
        assert sorted(f["extra"]) == ["b_o_nT", "eclipse", "mode", "rate_truth"]


@pytest.mark.parametrize("compression", ["gzip", None])
def test_hdf5_round_trip_minimal_and_uncompressed(tmp_path, compression):
    rng = np.random.default_rng(2)
    rec = Recording(t=np.arange(5) * 0.1, gyro=rng.normal(size=(5, 3)), mag_unit="gauss")
    back = read_recording(write_recording(tmp_path / "m.h5", rec, compression=compression))
    assert_same_recording(rec, back)
    assert back.accel is None and back.q_true is None and back.extra == {}


def test_hdf5_round_trip_multi_rate(tmp_path):
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.004, 0.006, 400))  # gyro ~200 Hz, irregular
    mag_t = np.arange(t[0], t[-1], 0.02) + 0.001  # ~50 Hz, its own clock
    acc_t = np.cumsum(rng.uniform(0.009, 0.011, 180)) + t[0]
    q = rng.normal(size=(t.size, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:10] = np.nan
    rec = Recording(t=t, gyro=rng.normal(size=(t.size, 3)), accel=rng.normal(size=(180, 3)),
                    accel_t=acc_t, mag=rng.normal(size=(mag_t.size, 3)), mag_t=mag_t,
                    q_onboard=q, meta={"assumed": ["body FRD converted to FLU"], "n": 2})
    path = write_recording(tmp_path / "multi.h5", rec)
    back = read_recording(path)
    assert_same_recording(rec, back)
    assert not back.single_rate and back.mag.shape == (mag_t.size, 3)


def test_hdf5_reads_format_version_1(tmp_path):
    """A version 1 file (written before sensors had their own rates) reads as before."""
    rec = full_recording(np.random.default_rng(8), 50)
    path = write_recording(tmp_path / "v1.h5", rec)
    with h5py.File(path, "a") as f:  # what gnomon 0.1 wrote: no meta, version 1
        f.attrs["format_version"] = 1
        del f.attrs["meta"]
    back = read_recording(path)
    assert_same_recording(rec, back)
    assert back.single_rate and back.meta == {}


def test_hdf5_round_trip_real_broad(tmp_path):
    rec = read_broad(MAT)
    back = read(write(tmp_path / "broad01.h5", rec))
    assert_same_recording(rec, back)
    assert np.isnan(back.q_true).all(axis=1).sum() == 33


def test_hdf5_rejects_other_files(tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(InputError, match="not a gnomon recording") as e:
        read_recording(foreign)
    assert str(foreign) in str(e.value) and "'format'" in str(e.value)

    rec = full_recording(np.random.default_rng(3), 20)
    newer = write_recording(tmp_path / "newer.h5", rec)
    with h5py.File(newer, "a") as f:
        f.attrs["format_version"] = 3
    with pytest.raises(InputError, match="format_version 3"):
        read_recording(newer)

    nogyro = write_recording(tmp_path / "nogyro.h5", rec)
    with h5py.File(nogyro, "a") as f:
        del f["gyro"]
    with pytest.raises(InputError, match="field 'gyro'") as e:
        read_recording(nogyro)
    assert "nogyro.h5" in str(e.value)

    degrees = write_recording(tmp_path / "deg.h5", rec)
    with h5py.File(degrees, "a") as f:
        f["gyro"].attrs["unit"] = "deg/s"
    with pytest.raises(InputError, match="field 'gyro'.*deg/s"):
        read_recording(degrees)

    with pytest.raises(InputError, match="cannot write") as e:
        write_recording(tmp_path / "no_dir" / "r.h5", rec)
    assert "no_dir" in str(e.value)

    with pytest.raises(InputError, match="extra.label"):
        write_recording(tmp_path / "s.h5", Recording(t=[0, 1], gyro=np.zeros((2, 3)),
                                                     extra={"label": np.array(["a", "b"])}))


def test_hdf5_bad_values_name_file_field_row(tmp_path):
    rec = full_recording(np.random.default_rng(4), 20)
    path = write_recording(tmp_path / "nan.h5", rec)
    with h5py.File(path, "a") as f:
        f["gyro"][7, 1] = np.nan
    with pytest.raises(InputError) as e:  # read strictly: refused, named
        read(path, strict=True)
    assert "nan.h5" in str(e.value) and "field 'gyro'" in str(e.value) and "row 7" in str(e.value)
    kept = read_recording(path)  # else that gyro row is dropped, with its truth row, counted
    assert kept.meta["dropped"] == {"gyro": 1} and len(kept) == len(rec) - 1
    assert np.array_equal(kept.t, np.delete(rec.t, 7))
    assert np.array_equal(kept.q_true, np.delete(rec.q_true, 7, axis=0), equal_nan=True)
    assert np.array_equal(kept.extra["mode"], np.delete(rec.extra["mode"], 7))
    # the accelerometer keeps its sample of that row, at its own time stamp
    assert np.array_equal(kept.accel, rec.accel) and np.array_equal(kept.accel_t, rec.t)


def test_truncated_and_garbage_hdf5_raise_input_error(tmp_path):
    good = write_recording(tmp_path / "good.h5", full_recording(np.random.default_rng(5)))
    raw = good.read_bytes()
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(raw[: len(raw) // 2])
    garbage = tmp_path / "garbage.hdf5"
    garbage.write_bytes(np.random.default_rng(6).bytes(4096))
    for path in (truncated, garbage):
        for reader in (read_recording, read):
            with pytest.raises(InputError, match="cannot read as HDF5") as e:
                reader(path)
            assert str(path) in str(e.value)
    bad_broad = tmp_path / "broad_truncated.hdf5"
    bad_broad.write_bytes(H5.read_bytes()[:50_000])
    with pytest.raises(InputError, match="broad_truncated.hdf5"):
        read_broad(bad_broad)
    bad_mat = tmp_path / "broad_truncated.mat"
    bad_mat.write_bytes(MAT.read_bytes()[:50_000])
    with pytest.raises(InputError, match="broad_truncated.mat"):
        read(bad_mat)


# ----------------------------------------------------------------------- BROAD
def test_read_broad_mat_excerpt():
    rec = read_broad(MAT)
    raw = scipy.io.loadmat(MAT)
    n = raw["imu_gyr"].shape[0]
    assert n == 7143 and len(rec) == n
    assert raw["movement"].shape == (n, 1) and raw["movement"].dtype == np.uint8
    np.testing.assert_allclose(rec.t[1] - rec.t[0], 1 / FS_HZ, rtol=1e-12)
    assert rec.t[0] == 0.0 and rec.t[-1] == pytest.approx((n - 1) / FS_HZ, rel=1e-12)
    assert np.array_equal(rec.gyro, raw["imu_gyr"])
    assert np.array_equal(rec.accel, raw["imu_acc"])
    assert np.array_equal(rec.mag, raw["imu_mag"]) and rec.mag_unit == "uT"
    assert np.array_equal(rec.extra["pos_m"], raw["opt_pos"], equal_nan=True)
    assert rec.mask.dtype == bool and np.array_equal(rec.mask, raw["movement"][:, 0] == 1)
    assert np.argmax(rec.mask) / FS_HZ == pytest.approx(8.0, abs=1 / FS_HZ)  # 8 s of rest
    lost = np.isnan(raw["opt_quat"]).any(axis=1)
    assert lost.sum() == 33 and np.isnan(rec.q_true[lost]).all()
    assert np.array_equal(rec.q_true[~lost], raw["opt_quat"][~lost])
    assert rec.frames == {"reference": "ENU", "body": "sensor"}
    assert rec.source == "01_undisturbed_slow_rotation_A_excerpt"
    # at rest, the accelerometer reads +g up and the gyro is near zero (physics, not format)
    rest = slice(0, int(7 * FS_HZ))
    assert np.linalg.norm(rec.accel[rest].mean(axis=0)) == pytest.approx(9.81, abs=0.15)
    assert np.abs(rec.gyro[rest].mean(axis=0)).max() < 0.02  # rad/s


def test_read_broad_hdf5_excerpt():
    rec = read_broad(H5)
    with h5py.File(H5) as f:
        assert f["movement"].dtype == bool
        fs = float(f.attrs["sampling_rate"])
        for ours, theirs in (("gyro", "imu_gyr"), ("accel", "imu_acc"), ("mag", "imu_mag"),
                             ("q_true", "opt_quat"), ("mask", "movement")):
            assert np.array_equal(getattr(rec, ours), f[theirs][()]), ours
    assert fs == pytest.approx(FS_HZ, rel=1e-12)
    assert np.array_equal(rec.t, np.arange(len(rec)) / fs)
    # the magnet moves with the IMU: the measured field magnitude swings by tens of uT
    # (undisturbed trial 01: 39-47 uT), so the magnetometer really is in uT and disturbed
    field_ut = np.linalg.norm(rec.mag, axis=1)
    assert field_ut.max() - field_ut.min() > 40
    undisturbed_ut = np.linalg.norm(read_broad(MAT).mag, axis=1)
    assert 35 < undisturbed_ut.min() and undisturbed_ut.max() < 55
    assert rec.source == "32_disturbed_attached_magnet_1cm_excerpt"


def test_broad_formats_give_the_same_layout():
    a, b = read_broad(MAT), read_broad(H5)
    for name in ("t", "gyro", "accel", "mag", "q_true", "mask"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape[1:] == y.shape[1:], name
    assert a.sun is None and b.sun is None
    assert (a.mag_unit, a.frames, sorted(a.extra)) == (b.mag_unit, b.frames, sorted(b.extra))


def test_broad_partial_nan_quaternion_row_becomes_all_nan(tmp_path):
    path = tmp_path / "partial.hdf5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        q = f["opt_quat"][()]
        q[10, 2] = np.nan
        f["opt_quat"][...] = q
    rec = read_broad(path)
    assert np.isnan(rec.q_true[10]).all()
    assert np.isfinite(rec.q_true[[9, 11]]).all()
    assert not rec.score_mask[10]


def _broad_without(src: Path, dst: Path, field: str) -> Path:
    if src.suffix == ".mat":
        d = {k: v for k, v in scipy.io.loadmat(src).items() if not k.startswith("__")}
        del d[field]
        scipy.io.savemat(dst, d)
    else:
        shutil.copy(src, dst)
        with h5py.File(dst, "a") as f:
            if field in f:
                del f[field]
            else:
                del f.attrs[field]
    return dst


@pytest.mark.parametrize("src,field", [(H5, "imu_mag"), (H5, "sampling_rate"), (H5, "movement"),
                                       (MAT, "opt_quat"), (MAT, "sampling_rate")])
def test_broad_missing_field_names_file_and_field(tmp_path, src, field):
    path = _broad_without(src, tmp_path / f"no_{field}{src.suffix}", field)
    with pytest.raises(InputError, match="missing") as e:
        read(path)
    assert str(path) in str(e.value) and f"field '{field}'" in str(e.value)


def test_broad_bad_values_name_field_and_row(tmp_path):
    path = tmp_path / "nan_gyr.hdf5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        f["imu_gyr"][123, 0] = np.nan
    with pytest.raises(InputError) as e:
        read(path, strict=True)
    msg = str(e.value)
    assert "nan_gyr.hdf5" in msg and "field 'imu_gyr'" in msg and "row 123" in msg
    whole, kept = read_broad(H5), read_broad(path)  # not strict: that sample dropped
    assert kept.meta["dropped"] == {"gyro": 1} and len(kept) == len(whole) - 1
    assert np.array_equal(kept.t, np.delete(whole.t, 123))

    short = tmp_path / "short_acc.hdf5"
    shutil.copy(H5, short)
    with h5py.File(short, "a") as f:
        acc = f["imu_acc"][:-1]
        del f["imu_acc"]
        f["imu_acc"] = acc
    with pytest.raises(InputError, match="field 'imu_acc'.*expected shape"):
        read_broad(short)


def test_broad_trials_and_groups(tmp_path):
    assert [p.name for p in broad_trials(DATA / "broad")] == [MAT.name, H5.name]
    groups = broad_groups(DATA / "broad")
    assert groups[MAT.stem] == ["all_trials", "undisturbed", "rotation", "slow", "no_breaks"]
    assert "attached_magnet" in groups[H5.stem] and "disturbed" in groups[H5.stem]
    for name in ("b.mat", "a.mat", "a.hdf5", "c.txt", "trials.json", "d.mat"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in broad_trials(tmp_path)] == ["a.hdf5", "b.mat", "d.mat"]
    assert broad_groups(tmp_path / "nowhere") == {}
    with pytest.raises(InputError, match="trials.json"):
        broad_groups(tmp_path)  # empty trials.json is not JSON
    with pytest.raises(InputError, match="no such directory"):
        broad_trials(tmp_path / "nowhere")


def test_full_broad_both_formats_and_excerpts_match():
    d = needs_full_broad()
    trials = broad_trials(d)
    suffixes = {p.suffix for p in trials}
    assert suffixes == {".hdf5", ".mat"}, "the full data set ships both formats"
    groups = broad_groups(d)
    assert all(p.stem in groups for p in trials)
    full_mat = read_broad(d / "01_undisturbed_slow_rotation_A.mat")
    full_h5 = read_broad(d / "32_disturbed_attached_magnet_1cm.hdf5")
    for name in ("t", "gyro", "accel", "mag", "q_true", "mask"):
        x, y = getattr(full_mat, name), getattr(full_h5, name)
        assert x.dtype == y.dtype and x.ndim == y.ndim and x.shape[1:] == y.shape[1:], name
    assert full_mat.sample_rate_hz == pytest.approx(full_h5.sample_rate_hz, rel=1e-12)
    assert (full_mat.mag_unit, full_mat.frames, sorted(full_mat.extra)) == \
        (full_h5.mag_unit, full_h5.frames, sorted(full_h5.extra))
    # the bundled excerpts are exact cuts of the full trials (make_fixtures.py)
    for full, excerpt, start in ((full_mat, read_broad(MAT), 7370),
                                 (full_h5, read_broad(H5), 9521)):
        cut = full.slice(start, start + len(excerpt))
        for name in ("gyro", "accel", "mag", "q_true", "mask"):
            assert np.array_equal(getattr(cut, name), getattr(excerpt, name), equal_nan=True)


# ------------------------------------------------------------------------- CSV
def test_read_csv_default_layout_matches_broad_excerpt():
    rec = read_csv(CSV)
    ref = read_broad(MAT).slice(CSV_SLICE.start, CSV_SLICE.stop)
    assert len(rec) == 1429 and rec.source == "broad_01_excerpt"
    np.testing.assert_allclose(rec.t, np.arange(1429) / FS_HZ, rtol=1e-8, atol=1e-12)
    for name in ("gyro", "accel", "mag", "q_true"):  # 9 significant digits in the file
        np.testing.assert_allclose(getattr(rec, name), getattr(ref, name), rtol=1e-8, atol=1e-12)
    assert np.array_equal(rec.mask, ref.mask) and rec.mask.any() and not rec.mask.all()
    assert rec.mag_unit == "uT" and rec.frames == {"reference": "ENU", "body": "sensor"}
    assert np.array_equal(read(CSV).gyro, rec.gyro)


def _write(path: Path, header: str, rows, delimiter=",") -> Path:
    lines = [header] + [delimiter.join(str(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _table(n=6, seed=7):
    rng = np.random.default_rng(seed)
    # t (s), gyro (rad/s), accel (m/s^2, +g up), mag (uT)
    return np.column_stack([np.arange(n) * 0.01, rng.normal(size=(n, 3)),
                            rng.normal(size=(n, 3)) + [0.0, 0.0, 9.81],
                            rng.normal(scale=20.0, size=(n, 3))])


def test_read_csv_column_map_delimiter_and_units(tmp_path):
    tab = _table()
    tab[:, 0] = np.arange(6) * 10.0  # ms
    path = _write(tmp_path / "log.txt", "time_ms;wx;wy;wz;ax;ay;az;bx;by;bz",
                  [[repr(v) for v in row] for row in tab.tolist()], delimiter=";")
    names = dict(zip(HEADER.split(","), "time_ms;wx;wy;wz;ax;ay;az;bx;by;bz".split(";"),
                     strict=True))
    rec = read(path, columns=names, delimiter=";", time_unit="ms", gyro_unit="deg/s",
               accel_unit="g", mag_unit="nT")
    np.testing.assert_array_equal(rec.t, tab[:, 0] * 1e-3)
    np.testing.assert_allclose(rec.gyro, tab[:, 1:4] * np.pi / 180, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(rec.accel, tab[:, 4:7] * 9.80665)
    np.testing.assert_array_equal(rec.mag, tab[:, 7:10])
    assert rec.mag_unit == "nT"
    np.testing.assert_allclose(rec.mag_tesla, tab[:, 7:10] * 1e-9, rtol=1e-15)


@pytest.mark.parametrize("option,unit,column,factor", [
    ("time_unit", "s", 0, 1.0), ("time_unit", "ms", 0, 1e-3), ("time_unit", "us", 0, 1e-6),
    ("time_unit", "ns", 0, 1e-9),
    ("gyro_unit", "rad/s", 1, 1.0), ("gyro_unit", "deg/s", 1, np.pi / 180),
    ("accel_unit", "m/s^2", 4, 1.0), ("accel_unit", "g", 4, 9.80665),
])
def test_read_csv_each_unit(tmp_path, option, unit, column, factor):
    tab = _table()
    rec = read_csv(_write(tmp_path / "u.csv", HEADER, tab.tolist()), **{option: unit})
    got = {0: rec.t, 1: rec.gyro[:, 0], 4: rec.accel[:, 0]}[column]
    np.testing.assert_allclose(got, tab[:, column] * factor, rtol=2e-16, atol=0)


@pytest.mark.parametrize("unit,tesla", [("T", 1.0), ("mT", 1e-3), ("uT", 1e-6), ("nT", 1e-9),
                                        ("gauss", 1e-4)])
def test_read_csv_mag_units(tmp_path, unit, tesla):
    tab = _table()
    rec = read_csv(_write(tmp_path / "m.csv", HEADER, tab.tolist()), mag_unit=unit)
    assert rec.mag_unit == unit
    np.testing.assert_array_equal(rec.mag, tab[:, 7:10])
    np.testing.assert_allclose(rec.mag_tesla, tab[:, 7:10] * tesla, rtol=1e-15)


def test_read_csv_optional_columns(tmp_path):
    tab = _table()
    no_mag = read_csv(_write(tmp_path / "a.csv", ",".join(HEADER.split(",")[:7]),
                             tab[:, :7].tolist()))
    assert no_mag.mag is None and no_mag.q_true is None and no_mag.mask is None
    q = np.tile([1.0, 0, 0, 0], (6, 1))
    rows = [list(r) + list(qq) + [m] for r, qq, m in
            zip(tab.tolist(), q.tolist(), ["1", "0", "true", "False", "yes", "n"], strict=True)]
    rows[2][10:14] = ["", "", "", ""]  # a lost truth sample
    rows[3][11] = "nan"  # a partly lost one
    rec = read_csv(_write(tmp_path / "b.csv", HEADER + ",q_w,q_x,q_y,q_z,mask", rows))
    assert np.isnan(rec.q_true[[2, 3]]).all() and np.isfinite(rec.q_true[[0, 1, 4, 5]]).all()
    assert rec.mask.tolist() == [True, False, True, False, True, False]
    comment = tmp_path / "c.csv"
    comment.write_text("# exported by a logger\n\n" + (tmp_path / "a.csv").read_text())
    assert np.array_equal(read_csv(comment).gyro, no_mag.gyro)


@pytest.mark.parametrize("option,value", [("gyro_unit", "rpm"), ("accel_unit", "ft/s^2"),
                                          ("mag_unit", "Oe"), ("time_unit", "min")])
def test_read_csv_unknown_unit_names_option_and_value(option, value):
    with pytest.raises(InputError) as e:
        read_csv(CSV, **{option: value})
    assert f"field '{option}'" in str(e.value) and repr(value) in str(e.value)


def _bad(tmp_path, edit, header=HEADER, name="bad.csv"):
    rows = [[repr(v) for v in r] for r in _table().tolist()]
    edit(rows)
    return _write(tmp_path / name, header, rows)


def test_csv_nan_in_sensor_column_names_file_column_row(tmp_path):
    path = _bad(tmp_path, lambda rows: rows[2].__setitem__(2, "nan"))  # gyr_y, 3rd data row
    with pytest.raises(InputError) as e:
        read(path, strict=True)
    msg = str(e.value)
    assert str(path) in msg and "field 'gyr_y'" in msg and "row 3" in msg and "line 4" in msg
    assert (e.value.file, e.value.field, e.value.row) == (str(path), "gyr_y", 3)
    assert read_csv(path).meta["dropped"] == {"gyro": 1}  # not strict: dropped, counted


def test_csv_non_increasing_time_names_file_column_row(tmp_path):
    path = _bad(tmp_path, lambda rows: rows[3].__setitem__(0, rows[2][0]))  # repeat t
    with pytest.raises(InputError, match="increase strictly") as e:
        read_csv(path)
    assert (e.value.file, e.value.field, e.value.row) == (str(path), "t", 4)
    assert "line 5" in str(e.value)
    back = _bad(tmp_path, lambda rows: rows[4].__setitem__(0, "-1.0"), name="back.csv")
    with pytest.raises(InputError, match="row 5"):
        read(back)


def test_csv_missing_column_names_file_and_column(tmp_path):
    path = _bad(tmp_path, lambda rows: [r.pop(6) for r in rows],
                header=HEADER.replace(",acc_z", ""))
    with pytest.raises(InputError, match="missing column") as e:
        read_csv(path)
    assert str(path) in str(e.value) and "field 'acc_z'" in str(e.value)
    assert "line 1" in str(e.value)  # the header line
    commented = tmp_path / "numpy_savetxt.csv"  # np.savetxt's default header is a comment
    np.savetxt(commented, _table(), delimiter=",", header=HEADER)
    with pytest.raises(InputError, match="field 't'.*remove the '#'"):
        read_csv(commented)
    with pytest.raises(InputError, match="field 'gz'"):
        read_csv(CSV, columns={"gyr_z": "gz"})
    with pytest.raises(InputError, match="field 'mag_z'.*incomplete"):
        read_csv(_bad(tmp_path, lambda rows: [r.pop(9) for r in rows], name="partial.csv",
                      header=HEADER.replace(",mag_z", "")))
    with pytest.raises(InputError, match="field 'columns'.*gyro_x"):
        read_csv(CSV, columns={"gyro_x": "wx"})


def test_csv_other_bad_inputs(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(InputError, match="empty file") as e:
        read(empty)
    assert str(empty) in str(e.value)
    header_only = tmp_path / "header.csv"
    header_only.write_text(HEADER + "\n")
    with pytest.raises(InputError, match="no data rows"):
        read_csv(header_only)
    text = _bad(tmp_path, lambda rows: rows[1].__setitem__(5, "abc"), name="text.csv")
    with pytest.raises(InputError, match="not a number: 'abc'") as e:
        read_csv(text)
    assert (e.value.field, e.value.row) == ("acc_y", 2)
    blank = _bad(tmp_path, lambda rows: rows[0].__setitem__(8, " "), name="blank.csv")
    with pytest.raises(InputError, match="empty cell") as e:
        read_csv(blank)
    assert (e.value.field, e.value.row) == ("mag_y", 1)
    ragged = _bad(tmp_path, lambda rows: rows[4].pop(), name="ragged.csv")
    with pytest.raises(InputError, match="9 cells, header has 10") as e:
        read_csv(ragged)
    assert (e.value.field, e.value.row) == ("mag_z", 5)
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00\x81" * 100)
    with pytest.raises(InputError, match="binary.csv"):
        read_csv(binary)
    with pytest.raises(InputError, match="field 'delimiter'"):
        read_csv(CSV, delimiter=";;")


def test_unit_warning_for_deg_s_read_as_rad_s(tmp_path):
    n = 400
    t = np.arange(n) * 0.01
    gyro_deg_s = 200.0 * np.column_stack([np.sin(t), np.cos(t), 0.5 * np.sin(3 * t)])
    tab = np.column_stack([t, gyro_deg_s, np.tile([0.1, 0.2, 9.8], (n, 1)),
                           np.tile([20.0, 0.0, -40.0], (n, 1))])
    path = _write(tmp_path / "deg.csv", HEADER, tab.tolist())
    with pytest.warns(UnitWarning, match="deg/s"):
        read_csv(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_csv(path, gyro_unit="deg/s")  # declared correctly: silent
    assert np.abs(rec.gyro).max() < 3.5  # rad/s
    tab[:, 4:7] /= 9.80665  # accelerometer in g, read as m/s^2
    with pytest.warns(UnitWarning, match="in g"):
        read_csv(_write(tmp_path / "g.csv", HEADER, tab.tolist()), gyro_unit="deg/s")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv(CSV)  # real BROAD data: plausible, silent


# ------------------------------------------------------------------ read/write
def test_read_detects_every_format(tmp_path):
    assert detect_format(CSV) == "csv" and detect_format(MAT) == "broad"
    assert detect_format(H5) == "broad"
    gnomon_h5 = write(tmp_path / "rec.hdf5", read(H5))
    assert detect_format(gnomon_h5) == "hdf5"
    assert_same_recording(read(gnomon_h5), read(H5))
    txt = tmp_path / "log.txt"
    shutil.copy(CSV, txt)
    assert np.array_equal(read(txt).t, read(CSV).t)
    assert read(H5, format="broad").source == H5.stem
    assert read(CSV, format="csv", gyro_unit="rad/s").mask is not None


def test_read_bad_requests(tmp_path):
    missing = tmp_path / "nothing_here.csv"
    for call in (lambda: read(missing), lambda: read_csv(missing), lambda: read_broad(missing),
                 lambda: read_recording(missing), lambda: read(missing, format="hdf5")):
        with pytest.raises(InputError, match="no such file") as e:
            call()
        assert str(missing) in str(e.value)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["something"] = np.zeros(2)
    with pytest.raises(InputError, match="neither a gnomon recording .* nor a BROAD trial"):
        read(other)
    unknown = tmp_path / "log.json"
    unknown.write_text("{}")
    with pytest.raises(InputError, match="suffix '.json'"):
        read(unknown)
    with pytest.raises(InputError, match="field 'format'"):
        read(CSV, format="excel")
    with pytest.raises(InputError, match="field 'gyro_unit'"):
        read(H5, gyro_unit="deg/s")  # CSV options for a BROAD file
    with pytest.raises(InputError, match="field 'gyro_units'"):
        read(CSV, gyro_units="deg/s")  # misspelled option


# ------------------------------------------- frames and units, checked by physics
def test_broad_truth_is_sensor_to_enu_per_vqf():
    """VQF (Laidig & Seel 2023) outputs sensor-to-ENU from rad/s, m/s^2 and any mag unit:
    it agrees with our q_true on the real excerpts only if our frames and units are right."""
    vqf = pytest.importorskip("vqf")
    from gnomon.metrics import broad_errors_rad, rms_deg

    for path, total_max_deg, inclination_max_deg in ((MAT, 4.0, 1.0), (H5, 20.0, 2.0)):
        rec = read(path)
        q_est = vqf.VQF(1.0 / rec.sample_rate_hz).updateBatch(
            np.ascontiguousarray(rec.gyro), np.ascontiguousarray(rec.accel),
            np.ascontiguousarray(rec.mag))["quat9D"]
        m = rec.score_mask
        err = broad_errors_rad(rec.q_true[m], q_est[m])
        assert rms_deg(err["total"]) < total_max_deg, path.name
        assert rms_deg(err["inclination"]) < inclination_max_deg, path.name
        wrong = broad_errors_rad(rec.q_true[m] * [1, -1, -1, -1], q_est[m])  # ENU-to-sensor
        assert rms_deg(wrong["total"]) > 30.0, path.name


def test_a_recording_written_as_csv_reads_back_the_same(tmp_path):
    """gnomon.write(*.csv): one row per gyro sample, the other sensors in their arrival rows
    (empty cells elsewhere), 17 digits: read_csv gives back the same floats, each sensor at
    its own times; extra series are columns (NAME_x..)."""
    import dataclasses

    import gnomon
    from gnomon.datasets import bundled

    rec = gnomon.read(sorted(bundled("broad").glob("*.hdf5"))[0]).slice(0, 500)
    path = gnomon.write(tmp_path / "rec.csv", rec)
    back = gnomon.read(path)
    for name in ("t", "gyro", "accel", "mag", "q_true"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name), err_msg=name)
    multi = dataclasses.replace(rec, accel=rec.accel[::2], accel_t=rec.t[::2],
                                mag=rec.mag[1::5], mag_t=rec.t[1::5],
                                extra={"w_true_b": rec.gyro * 0.5})
    back = gnomon.read(gnomon.write(tmp_path / "multi.csv", multi))
    np.testing.assert_array_equal(back.accel_t, multi.accel_t)
    np.testing.assert_array_equal(back.mag, multi.mag)
    header = (tmp_path / "multi.csv").read_text().splitlines()[0].split(",")
    assert {"w_true_b_x", "w_true_b_y", "w_true_b_z"} <= set(header)


@pytest.mark.parametrize("missing", [False, True])
def test_recording_names_the_first_quaternion_that_is_not_unit(missing):
    """The first row of q_true whose norm is off by more than 1e-3 is named, counted in
    the recording's rows whether or not some rows are missing (all NaN)."""
    from gnomon.recording import Recording

    n = 10
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    if missing:
        q[2] = np.nan
    q[6] *= 1.01
    q[8] *= 0.5
    kw = dict(t=np.arange(n) * 0.01, gyro=np.zeros((n, 3)))
    with pytest.raises(InputError) as e:
        Recording(**kw, q_true=q)
    assert e.value.field == "q_true" and e.value.row == 6 and "norm 1.01" in str(e.value)
    q[6] /= 1.01
    q[8] /= 0.5
    q[3, 1] = np.inf
    with pytest.raises(InputError) as e:
        Recording(**kw, q_true=q)
    assert e.value.field == "q_true" and e.value.row == 3
    q[3, 1] = 0.0
    assert np.array_equal(Recording(**kw, q_true=q).q_true, q, equal_nan=True)
