"""Imperfect logs kept (issue 33, part 3): a non-finite sample is dropped from its own sensor
and counted, ``--strict`` refuses it naming the field and the row, an own estimate that is
constant or marked absent is no own estimate, and ``gnomon estimate`` shows every note of
the reader (truncated, dropped, assumed).

The files are generated (logfiles.py: rosbags' own writer; CSV by hand) from one known
motion, so the drops, the kept samples and the estimate's error are checked against it.
"""

from __future__ import annotations

import json

import logfiles as L
import numpy as np
import pytest

from gnomon import cli
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.io import inspect, read
from gnomon.io._common import drop_nonfinite, own_estimate_absent
from gnomon.rotation import error_angle

T0 = 100.0  # s, the bags' first stamp
PX4_SMALL = bundled("logs") / "px4" / "sample_log_small_imu.ulg"


def settled_rms_deg(rec) -> float:
    """RMS error (deg) of the default filter against the known motion over the second half
    of the log (after the filter has settled)."""
    name, _ = registry.default_for(rec, False)
    est = registry.create(name, {}).run(rec)
    q, *_ = L.motion(rec.t - T0)
    e = np.degrees(error_angle(q, est.q))
    return float(np.sqrt(np.mean(e[e.size // 2:] ** 2)))


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    made = {}
    for name, kw in (("clean", {"seconds": 4.0}), ("nan", {"seconds": 4.0, "mag_nan": 5}),
                     ("identity", {"orientation": [1.0, 0.0, 0.0, 0.0]}),
                     ("cov", {"cov0": -1.0})):
        made[name] = L.write_ros1_bag(tmp_path_factory.mktemp(name), **kw)
    return made


def test_bag_whose_magnetometer_starts_with_nan_reads_and_estimates(bags, capsys):
    """Like imu_tools' phidgets_imu_upside_down.bag: 5 NaN MagneticField messages first.
    Only those 5 are dropped (counted), the gyro and the accelerometer keep every sample,
    and the estimate is as good as on the same bag without the NaN."""
    clean, rec = read(bags["clean"]), read(bags["nan"])
    assert rec.meta["dropped"] == {"mag": 5} and "dropped" not in clean.meta
    assert len(rec) == len(clean) == 800 and rec.accel.shape == clean.accel.shape
    assert rec.mag.shape[0] == clean.mag.shape[0] - 5
    assert np.array_equal(rec.mag_t, clean.mag_t[5:]) and np.array_equal(rec.mag, clean.mag[5:])
    said = [s for s in rec.meta["assumed"] if "non-finite" in s]
    assert len(said) == 1 and "mag (/imu/mag.magnetic_field) 5" in said[0]
    e_nan, e_clean = settled_rms_deg(rec), settled_rms_deg(clean)
    assert e_nan < 1.0 and e_nan < e_clean + 0.05, (e_nan, e_clean)  # 0.27 vs 0.26 deg
    with pytest.raises(InputError, match="non-finite") as err:
        read(bags["nan"], strict=True)
    assert "field '/imu/mag.magnetic_field'" in str(err.value) and "row 0" in str(err.value)

    assert cli.main(["estimate", bags["nan"], "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["dropped"] == {"mag": 5} and said[0] in out["notes"]
    assert cli.main(["estimate", bags["nan"]]) == 0
    assert f"note: {said[0]}" in capsys.readouterr().out
    assert cli.main(["estimate", bags["clean"], "--json"]) == 0
    assert "dropped" not in json.loads(capsys.readouterr().out)
    assert cli.main(["estimate", bags["nan"], "--strict"]) == 2
    assert "field '/imu/mag.magnetic_field', row 0: non-finite" in capsys.readouterr().err


def test_inspect_counts_the_drops(bags, capsys):
    info = inspect(bags["nan"])
    assert info["dropped"] == {"mag": 5}
    assert {s["name"]: s["dropped"] for s in info["sensors"]} == {"gyro": 0, "accel": 0,
                                                                   "mag": 5}
    assert {s["name"]: s["samples"] for s in info["sensors"]}["mag"] == 195
    assert inspect(bags["clean"])["dropped"] is None
    assert cli.main(["inspect", bags["nan"]]) == 0
    assert "dropped: mag 5 (samples with a non-finite value" in capsys.readouterr().out
    assert cli.main(["inspect", bags["nan"], "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["dropped"] == {"mag": 5}
    assert cli.main(["inspect", bags["nan"], "--strict"]) == 2
    assert "non-finite" in capsys.readouterr().err


@pytest.mark.parametrize("which, why", [("identity", "constant (the identity) over all 400"),
                                        ("cov", "orientation_covariance[0] = -1 in 400")])
def test_constant_or_absent_orientation_is_no_own_estimate(bags, capsys, which, why):
    """sparkfun_razor.bag's /imu/data_raw holds the identity in every message; a driver
    without an orientation sets orientation_covariance[0] = -1 (REP-145). Neither is an
    estimate: no q_onboard, and ``--compare onboard`` says why instead of comparing."""
    rec = read(bags[which])
    assert rec.q_onboard is None and why in rec.meta["onboard_absent"]
    assert rec.meta["onboard"] is None
    info = inspect(bags[which])
    assert info["onboard"] is None and why in info["onboard_absent"]
    assert cli.main(["estimate", bags[which], "--compare", "onboard", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["onboard"] is None and why in out["onboard_absent"]
    assert cli.main(["estimate", bags[which], "--compare", "onboard"]) == 0
    text = capsys.readouterr().out
    assert "no comparison with the device's own estimate" in text and why in text
    assert cli.main(["estimate", bags["clean"], "--compare", "onboard", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["onboard"]["samples"] == 800  # a real one


def test_own_estimate_absent_only_when_constant_or_empty():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    assert own_estimate_absent(q, "q") is None and own_estimate_absent(None, "q") is None
    still = np.tile([0.0, 0.6, 0.8, 0.0], (50, 1))
    still[1::2] *= -1  # the same rotation either sign
    still[10] = np.nan
    assert "constant ([w, x, y, z] = [0.0, 0.6, 0.8, 0.0]) over all 49" in \
        own_estimate_absent(still, "q")
    near = still.copy()
    near[20] = [0.0, 0.6, 0.8, 1e-5]  # 2e-5 rad away: an estimate at rest, not a constant
    near[20] /= np.linalg.norm(near[20])
    assert own_estimate_absent(near, "q") is None
    assert "no finite sample" in own_estimate_absent(np.full((5, 4), np.nan), "q")


def write_csv(path, t, gyro, accel, mag, q_true=None):
    cols = ["t", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y",
            "mag_z"]
    data = [t[:, None], gyro, accel, mag]
    if q_true is not None:
        cols += ["q_w", "q_x", "q_y", "q_z"]
        data.append(q_true)
    rows = np.hstack(data)
    path.write_text(",".join(cols) + "\n" +
                    "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    return path


def test_csv_with_nan_gyro_and_accel_rows_counted_per_sensor(tmp_path, capsys):
    t = np.arange(300) / 100.0
    q, gyro, accel, mag = L.motion(t)
    gyro[[40, 41]] = np.nan
    accel[[7, 100, 250], 1] = np.nan
    accel[100, 2] = np.inf
    path = write_csv(tmp_path / "imu.csv", t, gyro, accel, mag, q)
    rec = read(path)
    assert rec.meta["dropped"] == {"gyro": 2, "accel": 3}
    assert np.array_equal(rec.t, np.delete(t, [40, 41]))
    assert np.array_equal(rec.q_true, np.delete(q, [40, 41], axis=0))
    # the accelerometer keeps its samples of the dropped gyro rows, at their own stamps
    assert np.array_equal(rec.accel_t, np.delete(t, [7, 100, 250]))
    assert np.abs(rec.accel - np.delete(accel, [7, 100, 250], axis=0)).max() < 1e-12
    assert np.isfinite(rec.on_time_base("accel")[40 - 1:41]).all()  # rows 40, 41 arrive
    est = registry.create("mahony", {}).run(rec)
    assert np.degrees(error_angle(q[-1], est.q[-1])) < 2.0
    with pytest.raises(InputError) as err:
        read(path, strict=True)
    assert (err.value.field, err.value.row) == ("gyr_x", 41)  # 1-based data row
    assert cli.main(["estimate", path, "--strict"]) == 2
    assert "field 'gyr_x', row 41" in capsys.readouterr().err
    assert cli.main(["estimate", path, "--filter", "mahony", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["dropped"] == {"gyro": 2, "accel": 3} and out["samples"] == 298
    assert any("gyro 2 (the first at t = 0.4 s)" in s for s in out["notes"])


def test_benchmark_dir_keeps_or_with_strict_skips_a_log_with_nan(tmp_path, capsys):
    t = np.arange(300) / 100.0
    q, gyro, accel, mag = L.motion(t)
    gyro[5] = np.nan
    write_csv(tmp_path / "nan.csv", t, gyro, accel, mag, q)
    args = ["benchmark", str(tmp_path), "--filters", "mahony", "--anchors", "none", "--json"]
    assert cli.main(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert [r["trial"] for r in res["trials"]] == ["nan"] and res["skipped"] == []
    assert cli.main(args + ["--strict"]) == 2  # the only trial is refused: none left
    assert "no recording with a truth" in capsys.readouterr().err


def test_drop_nonfinite_takes_the_rows_of_a_gyro_sample_and_names_an_empty_sensor():
    t = np.arange(6) * 0.1
    gyro = np.zeros((6, 3))
    gyro[2, 0] = np.nan
    mag = np.ones((3, 3))
    fields = {"t": t, "gyro": gyro, "accel": np.ones((6, 3)), "mag": mag,
              "mag_t": [0.05, 0.15, 0.25], "mask": np.arange(6) % 2 == 0,
              "q_onboard": np.tile([1.0, 0, 0, 0], (6, 1)), "extra": {"k": np.arange(6)}}
    out, counts, first = drop_nonfinite(fields)
    assert counts == {"gyro": 1} and first == {"gyro": pytest.approx(0.2)}
    assert np.array_equal(out["t"], np.delete(t, 2))
    assert np.array_equal(out["extra"]["k"], [0, 1, 3, 4, 5])
    assert np.array_equal(out["mask"], [True, False, False, True, False])
    assert out["q_onboard"].shape == (5, 4)
    assert np.array_equal(out["accel_t"], t) and out["accel"].shape == (6, 3)
    assert out["mag"] is mag  # untouched: its own stamps, all finite
    with pytest.raises(InputError, match="all 6 samples are not finite") as err:
        drop_nonfinite({**fields, "accel": np.full((6, 3), np.nan)})
    assert err.value.field == "accel"
    with pytest.raises(InputError, match="fewer than 2 left") as err:
        drop_nonfinite({**fields, "gyro": np.full((6, 3), np.nan)})
    assert err.value.field == "gyro"


def test_truncated_log_is_said_by_estimate(tmp_path, capsys):
    """A PX4 log cut short (a crash): ``estimate`` says so, as ``inspect`` does."""
    raw = PX4_SMALL.read_bytes()
    path = tmp_path / "cut.ulg"
    path.write_bytes(raw[: int(0.6 * len(raw))])
    cut = read(path).meta["truncated"]
    assert cut is not None
    assert cli.main(["estimate", path, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["truncated"] == cut
    assert any(f"at byte {cut['at_byte']}" in s and "cut short" in s for s in out["notes"])
    assert cli.main(["estimate", path]) == 0
    assert f"note: The file ends inside a message at byte {cut['at_byte']}" in \
        capsys.readouterr().out
    assert cli.main(["estimate", PX4_SMALL, "--json"]) == 0
    assert "truncated" not in json.loads(capsys.readouterr().out)
