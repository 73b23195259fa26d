"""Maps for tables of unknown layout (gnomon.io.mapping): files of each layout written with
known names, units, quaternion order, frames and lag, and the proposed map must find them;
read with the map, the recording must give back the motion that made them."""

import json
import math

import numpy as np
import pandas as pd
import pytest
import scipy.io
from logfiles import MAG_ENU_UT, G, motion

from gnomon.cli import main
from gnomon.errors import InputError
from gnomon.io import read
from gnomon.io.mapping import load_map, missing, propose_map, read_mapped, write_map
from gnomon.io.units import quat_order
from gnomon.rotation import (
    dcm_from_quat,
    error_angle,
    quat_conj,
    quat_from_dcm,
    quat_from_rotvec,
    quat_mul,
    quat_rotate,
)

FS = 100.0


def tumble(t: np.ndarray):
    """A body whose rate axis wanders (the component order of a quaternion is decidable
    from the rate only then): ``q_ENU_body`` integrated exactly over each interval of the
    piecewise-constant rate ``w`` (rad/s, body), specific force (m/s²), field (µT)."""
    w = np.column_stack([0.8 * np.sin(0.7 * t), 0.6 * np.cos(0.5 * t),
                         0.5 * np.sin(0.3 * t + 1.0)])
    steps = quat_from_rotvec(w[:-1] * np.diff(t)[:, None])
    q = np.empty((t.size, 4))
    q[0] = quat_from_rotvec(np.array([0.3, -0.2, 0.5]))
    for k in range(t.size - 1):
        q[k + 1] = quat_mul(q[k], steps[k])
    q_bn = quat_conj(q)
    return q, w, quat_rotate(q_bn, np.array([0.0, 0.0, G])), quat_rotate(q_bn, MAG_ENU_UT)


def _yup_world() -> np.ndarray:
    """``q_W_ENU`` of a motion-capture world with y up (x east, z south), turned 30° about
    its up axis."""
    r = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # rows: E, U, S
    yaw = quat_from_rotvec(np.array([0.0, math.radians(30.0), 0.0]))
    return quat_mul(yaw, quat_from_dcm(r))


Q_SENSOR_MARKER = quat_from_rotvec(np.radians([12.0, -8.0, 15.0]))  # 21 deg


def _mocap_csv(path, n=2000, lag=3, single_axis=False):
    """The issue's mocap layout: ``Timestamp`` ms, ``gyro_x..z`` rad/s, ``acc_x..z`` g,
    ``mag_x..z`` gauss, ``cam_qx, cam_qy, cam_qz, cam_qw`` (scalar last) of the marker in
    a y-up world, ``lag`` samples late, and ``isTracked`` (every 50th row lost: zeros).
    Returns the truth ``q_W_marker`` [w, x, y, z] written."""
    t = np.arange(n + lag) / FS
    q, w, acc, mag = motion(t) if single_axis else tumble(t)
    q_wm = quat_mul(quat_mul(_yup_world(), q), Q_SENSOR_MARKER)
    q_wm = np.concatenate([q_wm[:1].repeat(lag, 0), q_wm[:-lag]])[:n] if lag else q_wm[:n]
    tracked = (np.arange(n) % 50 != 7).astype(int)
    cam = np.where(tracked[:, None] == 1, q_wm, 0.0)
    pd.DataFrame({"Timestamp": 1000.0 * t[:n] + 1.7e12,
                  **{f"gyro_{a}": w[:n, i] for i, a in enumerate("xyz")},
                  **{f"acc_{a}": acc[:n, i] / G for i, a in enumerate("xyz")},
                  **{f"mag_{a}": mag[:n, i] / 100.0 for i, a in enumerate("xyz")},
                  "cam_qx": cam[:, 1], "cam_qy": cam[:, 2], "cam_qz": cam[:, 3],
                  "cam_qw": cam[:, 0], "isTracked": tracked}).to_csv(path, index=False)
    return q_wm, tracked


def test_mocap_csv_map_found_from_names_and_data(tmp_path):
    path = tmp_path / "mocap.csv"
    q_wm, tracked = _mocap_csv(path)
    m = propose_map(path)
    assert missing(m) == []
    assert m["time"] == {"column": "Timestamp", "unit": "ms"}
    assert m["gyro"] == {"columns": ["gyro_x", "gyro_y", "gyro_z"], "unit": "rad/s",
                         "axes": ["x", "y", "z"]}
    assert m["accel"]["unit"] == "g" and m["mag"]["unit"] == "gauss"
    assert m["truth"]["columns"] == ["cam_qx", "cam_qy", "cam_qz", "cam_qw"]
    assert m["truth"]["order"] == "xyzw"
    assert m["truth"]["valid"] == "isTracked"
    assert m["truth"]["frame"] == "unknown"  # y up, turned, marker off the sensor's axes
    evidence = " ".join(m["evidence"]["truth"])
    assert "order xyzw from the data" in evidence
    # the fitted rotation between the reference's rate and the gyro is the marker's
    fitted = float(evidence.split("xyzw residual")[1].split("rotation ")[1].split(" deg")[0])
    assert fitted == pytest.approx(math.degrees(2 * math.acos(Q_SENSOR_MARKER[0])), abs=1.0)
    rec = read_mapped(path, m)
    assert rec.sample_rate_hz == pytest.approx(FS, rel=1e-5)  # s since 1970: ulp 0.2 us
    assert rec.t[0] == pytest.approx(1.7e9)
    assert np.median(np.linalg.norm(rec.accel, axis=1)) == pytest.approx(G, rel=1e-9)
    assert rec.mag_unit == "uT"
    assert np.median(np.linalg.norm(rec.mag, axis=1)) == pytest.approx(
        np.linalg.norm(MAG_ENU_UT), rel=1e-9)
    lost = tracked == 0
    assert np.isnan(rec.q_true[lost]).all() and np.isfinite(rec.q_true[~lost]).all()
    assert error_angle(q_wm[~lost], rec.q_true[~lost]).max() < 1e-9
    assert rec.frames == {"reference": "ENU", "body": "sensor", "truth": "unknown"}
    assert any("--align" in a for a in rec.meta["assumed"])


def test_one_axis_motion_leaves_the_order_to_the_names(tmp_path):
    """Rotation about one fixed axis: both orders fit the gyro, the data cannot decide."""
    path = tmp_path / "mocap.csv"
    _mocap_csv(path, n=400, lag=0, single_axis=True)
    m = propose_map(path)
    evidence = " ".join(m["evidence"]["truth"])
    assert "about one axis only" in evidence and "order xyzw from the names" in evidence
    assert m["truth"]["order"] == "xyzw"


@pytest.mark.parametrize("version", ["5", "7.3"])
def test_matlab_robot_reference_arrays_named(tmp_path, version):
    """The issue's .mat: SENSgyro, SENSacc, SENSmag 3xN, MATLABtime datenum days,
    ABBquaternion 4xN scalar first (truth in ENU, the sensor on the robot's flange); v5
    (scipy) and v7.3 (HDF5, stored transposed as MATLAB does)."""
    from logfiles import write_mat73

    t = np.arange(1500) / FS
    q, w, acc, mag = tumble(t)
    path = tmp_path / "robot.mat"
    variables = {"SENSgyro": w.T, "SENSacc": acc.T, "SENSmag": mag.T * 1e3,
                 "MATLABtime": (738000.25 + t / 86400.0)[None, :], "ABBquaternion": q.T}
    if version == "5":
        scipy.io.savemat(path, {**variables, "note": "abc"})
    else:
        write_mat73(path, variables)
    m = propose_map(path)
    assert m["kind"] == "mat"
    assert m["time"] == {"column": "MATLABtime", "unit": "datenum"}
    assert (m["gyro"]["array"], m["accel"]["array"], m["mag"]["array"]) == (
        "SENSgyro", "SENSacc", "SENSmag")
    assert (m["gyro"]["unit"], m["accel"]["unit"], m["mag"]["unit"]) == ("rad/s", "m/s^2", "nT")
    assert m["truth"]["array"] == "ABBquaternion" and m["truth"]["order"] == "wxyz"
    assert m["truth"]["frame"] == "ENU"
    assert "3xN" in m["evidence"]["gyro"][0]
    rec = read_mapped(path, m)
    assert rec.t[0] == 0.0
    assert np.abs(rec.t - t).max() < 2e-5  # a double near 7.4e5 days resolves ~10 us
    np.testing.assert_allclose(rec.gyro, w, atol=1e-12)
    assert error_angle(q, rec.q_true).max() < 1e-9


def test_npz_in_degrees_found_from_magnitudes(tmp_path, capsys):
    """N x 3 arrays in deg/s and m/s², no reference: the gyro unit from its magnitudes."""
    t = np.arange(1000) / 200.0
    _, w, acc, _ = tumble(t)
    path = tmp_path / "imu.npz"
    np.savez(path, timestamps=t * 1e9, gyroscope=np.degrees(w), accelerometer=acc)
    m = propose_map(path)
    assert m["kind"] == "npz"
    assert m["time"]["unit"] == "ns"
    assert m["gyro"]["unit"] == "deg/s" and m["accel"]["unit"] == "m/s^2"
    assert "mag" not in m and "truth" not in m
    rec = read_mapped(path, m)
    assert rec.sample_rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(rec.gyro, w, atol=1e-12)
    assert main(["inspect", path, "--json"]) == 0  # no reader knows .npz: proposed
    assert json.loads(capsys.readouterr().out)["proposed_map"]["gyro"]["unit"] == "deg/s"


def test_parquet_and_tsv_variants(tmp_path):
    """phyphox-like names with units in brackets (Parquet) and ROS-like dotted names with
    time in microseconds (TSV)."""
    t = np.arange(800) / FS
    q, w, acc, mag = tumble(t)
    frame = pd.DataFrame({"Time (s)": t,
                          **{f"Gyroscope {a.upper()} (deg/s)": np.degrees(w[:, i])
                             for i, a in enumerate("xyz")},
                          **{f"Acceleration {a.upper()} (m/s^2)": acc[:, i]
                             for i, a in enumerate("xyz")},
                          **{f"Magnetic field {a.upper()} (µT)": mag[:, i]
                             for i, a in enumerate("xyz")}})
    pq = tmp_path / "phone.parquet"
    frame.to_parquet(pq)
    m = propose_map(pq)
    assert m["kind"] == "parquet" and m["time"] == {"column": "Time (s)", "unit": "s"}
    assert m["gyro"]["unit"] == "deg/s" and m["mag"]["unit"] == "uT"
    np.testing.assert_allclose(read_mapped(pq, m).gyro, w, atol=1e-12)

    tsv = tmp_path / "ros.tsv"
    pd.DataFrame({"header.stamp": (1e6 * t).round() + 5e12,
                  **{f"angular_velocity.{a}": w[:, i] for i, a in enumerate("xyz")},
                  **{f"linear_acceleration.{a}": acc[:, i] for i, a in enumerate("xyz")},
                  **{f"orientation.{a}": q[:, i] for i, a in enumerate("wxyz")}}
                 ).to_csv(tsv, sep="\t", index=False)
    m = propose_map(tsv)
    assert m["delimiter"] == "\t"
    assert m["time"] == {"column": "header.stamp", "unit": "us"}
    assert m["gyro"]["columns"][0] == "angular_velocity.x"
    assert m["accel"]["columns"][2] == "linear_acceleration.z"
    assert m["truth"]["order"] == "wxyz" and m["truth"]["frame"] == "unknown"  # no mag
    rec = read_mapped(tsv, m)
    assert error_angle(q, rec.q_true).max() < 1e-9


@pytest.mark.parametrize("stored", ["wxyz", "xyzw"])
def test_quaternion_order_only_from_the_data(tmp_path, stored):
    """``q1..q4`` say nothing about where the scalar is: the rate fit decides, with the
    gyro in deg/s (the scale of the fit, 57.3, says so)."""
    t = np.arange(1500) / FS
    q, w, acc, _ = tumble(t)
    cols = q if stored == "wxyz" else q[:, [1, 2, 3, 0]]
    path = tmp_path / "q.csv"
    pd.DataFrame({"t": t, **{f"q{i + 1}": cols[:, i] for i in range(4)},
                  **{f"w{a}": np.degrees(w[:, i]) for i, a in enumerate("xyz")},
                  **{f"a{a}": acc[:, i] for i, a in enumerate("xyz")}}).to_csv(path,
                                                                             index=False)
    m = propose_map(path)
    assert m["truth"]["columns"] == ["q1", "q2", "q3", "q4"]
    assert m["truth"]["order"] == stored
    assert m["gyro"]["unit"] == "deg/s"
    assert "57.3 x the reference's rate" in " ".join(m["evidence"]["gyro"])
    assert error_angle(q, read_mapped(path, m).q_true).max() < 1e-9


def test_quat_order_fit_against_an_independent_rotation():
    """The fitted rotation of the right order is the body rotation between the two
    (a known 40° turn of the gyro's axes), its residual near zero; the wrong order's is
    large."""
    t = np.arange(2000) / FS
    q, w, _, _ = tumble(t)
    q_turn = quat_from_rotvec(np.radians([0.0, 40.0, 0.0]))
    gyro = quat_rotate(q_turn, w)  # the gyro mounted turned by q_turn
    order, fits, _ = quat_order(q, t, gyro, window_s=0.01, max_lag_s=0.0)
    assert order == "wxyz"
    assert fits["wxyz"]["residual"] < 0.01 and fits["xyzw"]["residual"] > 0.2
    np.testing.assert_allclose(fits["wxyz"]["R"], dcm_from_quat(q_turn), atol=0.01)


def test_axis_remap_round_trip(tmp_path):
    """A sensor mounted turned 180° about x writes ``[x, -y, -z]`` of the body's axes; the
    map's ``axes: [x, -y, -z]`` gives the body's back. The map survives YAML."""
    t = np.arange(500) / FS
    q, w, acc, mag = tumble(t)
    flip = np.array([1.0, -1.0, -1.0])
    path = tmp_path / "mounted.csv"
    pd.DataFrame({"time": t, **{f"gyr_{a}": w[:, i] * flip[i] for i, a in enumerate("xyz")},
                  **{f"acc_{a}": acc[:, i] * flip[i] for i, a in enumerate("xyz")},
                  **{f"mag_{a}": mag[:, i] for i, a in enumerate("xyz")}}).to_csv(path,
                                                                               index=False)
    m = propose_map(path)
    m["gyro"]["axes"] = m["accel"]["axes"] = ["x", "-y", "-z"]
    yaml_path = write_map(tmp_path / "map.yaml", m)
    text = yaml_path.read_text()
    assert "axes: [x, -y, -z]" in text and "evidence:" in text
    back = load_map(yaml_path)
    assert {k: back[k] for k in ("time", "gyro", "accel", "mag")} == {
        k: m[k] for k in ("time", "gyro", "accel", "mag")}
    rec = read_mapped(path, yaml_path)
    np.testing.assert_allclose(rec.gyro, w, atol=1e-12)
    np.testing.assert_allclose(rec.accel, acc, atol=1e-12)
    np.testing.assert_allclose(rec.mag, mag, atol=1e-12)  # not remapped
    assert any("gyro axes remapped" in a for a in rec.meta["assumed"])


@pytest.mark.parametrize("change, key", [
    (lambda m: m["gyro"].update(axes=["x", "x", "z"]), "gyro.axes"),
    (lambda m: m["gyro"].update(unit="rpm"), "gyro.unit"),
    (lambda m: m["accel"].update(unti="g"), "accel.unti"),
    (lambda m: m.pop("time"), "time"),
    (lambda m: m.update(version=2), "version"),
    (lambda m: m["gyro"].update(columns=["a", "b"]), "gyro.columns"),
])
def test_a_bad_map_names_the_key(tmp_path, change, key):
    m = {"version": 1, "kind": "csv", "time": {"column": "t", "unit": "s"},
         "gyro": {"columns": ["a", "b", "c"], "unit": "rad/s"},
         "accel": {"columns": ["d", "e", "f"], "unit": "g"}}
    load_map(m)
    change(m)
    with pytest.raises(InputError) as err:
        load_map(m)
    assert err.value.field == key


def _enu_mat(path, seconds, start, seed):
    t = start + np.arange(int(seconds * FS)) / FS
    q, w, acc, mag = tumble(t)
    rng = np.random.default_rng(seed)
    scipy.io.savemat(path, {"SENSgyro": (w + rng.normal(0, 0.005, w.shape)).T,
                            "SENSacc": (acc + rng.normal(0, 0.03, acc.shape)).T / G,
                            "SENSmag": (mag + rng.normal(0, 0.3, mag.shape)).T / 100.0,
                            "MATLABtime": 738000.25 + t / 86400.0, "ABBquaternion": q.T})


def test_cli_write_map_estimate_and_benchmark_a_folder(tmp_path, capsys):
    """``inspect --write-map`` (exit 0, the file), ``estimate --map`` and ``benchmark DIR
    --map --json`` on two files of one layout whose truth is in ENU: small errors."""
    data = tmp_path / "trials"
    data.mkdir()
    _enu_mat(data / "a.mat", 20.0, 0.0, 1)
    _enu_mat(data / "b.mat", 20.0, 7.0, 2)
    (data / "notes.md").write_text("not a trial")
    mp = tmp_path / "robot.yaml"
    assert main(["inspect", data / "a.mat", "--write-map", mp]) == 0
    out = capsys.readouterr().out
    assert "SENSgyro" in out and "wrote" in out and mp.is_file()
    m = load_map(mp)
    assert (m["accel"]["unit"], m["mag"]["unit"], m["truth"]["frame"]) == ("g", "gauss", "ENU")
    assert main(["estimate", data / "b.mat", "--map", mp, "--filter", "mahony",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["samples"] == 2000
    assert summary["errors"]["total_deg"] < 3.0
    assert main(["benchmark", data, "--map", mp, "--filters", "mahony", "--anchors", "vqf",
                 "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {r["trial"] for r in res["trials"]} == {"a", "b"}
    for method in ("mahony", "vqf"):
        assert set(res["mean"][method]) >= {"total_deg", "heading_deg", "inclination_deg"}
        assert res["mean"][method]["trials"] == 2
        assert res["mean"][method]["total_deg"] < 3.0
    assert read(data / "a.mat", map=mp).frames["truth"] == "ENU"


def test_cli_inspect_proposes_for_an_unknown_layout_and_names_what_is_missing(tmp_path,
                                                                               capsys):
    path = tmp_path / "mocap.csv"
    _mocap_csv(path, n=300)
    assert main(["inspect", path, "--json"]) == 0  # gnomon's CSV reader refuses it
    info = json.loads(capsys.readouterr().out)
    assert info["proposed_map"]["truth"]["valid"] == "isTracked"
    assert "missing column" in info["known_layout_error"]
    assert info["sensors"][0]["samples"] == 300
    no_gyro = tmp_path / "accel_only.csv"
    pd.DataFrame({"time": np.arange(50) / FS, "acc_x": 0.0, "acc_y": 0.0,
                  "acc_z": 9.8}).to_csv(no_gyro, index=False)
    assert main(["inspect", no_gyro, "--write-map", tmp_path / "m.yaml"]) == 2
    err = capsys.readouterr().err
    assert "field 'gyro'" in err and "no gyro found" in err
    assert not (tmp_path / "m.yaml").exists()


def test_map_on_calibrate_and_live(tmp_path, capsys):
    """``calibrate mag --map`` fits the file's field (its magnitude: |MAG_ENU_UT|);
    ``live replay://FILE --map`` reads the file with it; CSV lines take the map's column
    names and units; a map with options that are not its own is refused naming them."""
    from gnomon.io.mapping import live_options

    _enu_mat(tmp_path / "a.mat", 20.0, 0.0, 1)
    mp = write_map(tmp_path / "m.yaml", propose_map(tmp_path / "a.mat"))
    assert main(["calibrate", "mag", tmp_path / "a.mat", "--map", mp, "--json"]) == 0
    cal = json.loads(capsys.readouterr().out)
    assert cal["field_uT"] == pytest.approx(np.linalg.norm(MAG_ENU_UT), rel=0.01)
    assert main(["live", f"replay://{tmp_path / 'a.mat'}?speed=0", "--map", mp, "--filter",
                 "mahony", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 2000
    with pytest.raises(InputError, match="CSV or JSON lines") as err:
        live_options(mp)
    assert err.value.field == "kind"
    csv_path = tmp_path / "mocap.csv"
    _mocap_csv(csv_path, n=200)
    opts = live_options(propose_map(csv_path))
    assert opts["columns"]["t"] == "Timestamp" and opts["columns"]["gyr_y"] == "gyro_y"
    assert (opts["time_unit"], opts["accel_unit"], opts["mag_unit"]) == ("ms", "g", "gauss")
    assert main(["estimate", tmp_path / "a.mat", "--map", mp, "--gyro-unit", "deg/s"]) == 2
    assert "field '--gyro-unit'" in capsys.readouterr().err


def test_real_broad_trial_mapped_reads_as_its_own_reader():
    """A real recording the map was not written for: the bundled BROAD excerpt (.mat; no
    time, a sample rate; Nx3 arrays; opt_quat wxyz in ENU; movement) and its gnomon CSV.
    Proposed and read with the map, it is the recording BROAD's and the CSV reader give."""
    from gnomon.datasets import bundled

    for path in (bundled() / "broad" / "01_undisturbed_slow_rotation_A_excerpt.mat",
                 bundled() / "broad_01_excerpt.csv"):
        m = propose_map(path)
        assert m["truth"]["order"] == "wxyz" and m["truth"]["frame"] == "ENU"
        assert "order wxyz from the data" in " ".join(m["evidence"]["truth"])
        assert (m["gyro"]["unit"], m["accel"]["unit"], m["mag"]["unit"]) == (
            "rad/s", "m/s^2", "uT")
        mapped, own = read_mapped(path, m), read(path)
        np.testing.assert_allclose(mapped.t - mapped.t[0], own.t - own.t[0], atol=1e-9)
        for name in ("gyro", "accel", "mag"):
            np.testing.assert_array_equal(getattr(mapped, name), getattr(own, name))
        np.testing.assert_allclose(mapped.q_true, own.q_true, atol=1e-12)  # renormalised
        np.testing.assert_array_equal(mapped.score_mask, own.score_mask)


def test_csv_with_metadata_lines_and_a_units_row(tmp_path, capsys):
    """An export with lines of metadata above the header and a row of units below it:
    the header is the first line with as many cells as the data, the units join the
    names (``gyro_x (deg/s)``) and decide the unit."""
    src = tmp_path / "mocap.csv"
    _mocap_csv(src, n=600)
    frame = pd.read_csv(src)
    frame[["gyro_x", "gyro_y", "gyro_z"]] *= 180.0 / math.pi
    path = tmp_path / "export.csv"
    units = ["ms", "deg/s", "deg/s", "deg/s", "g", "g", "g", "G", "G", "G", "", "", "", "", ""]
    with open(path, "w") as fh:
        fh.write("Trial,42\nFrame Rate,100\n\n" + ",".join(frame.columns) + "\n"
                 + ",".join(units) + "\n")
        frame.to_csv(fh, header=False, index=False)
    assert main(["inspect", path, "--write-map", tmp_path / "m.yaml"]) == 0
    m = load_map(tmp_path / "m.yaml")
    assert m["gyro"] == {"columns": ["gyro_x (deg/s)", "gyro_y (deg/s)", "gyro_z (deg/s)"],
                         "unit": "deg/s", "axes": ["x", "y", "z"]}
    assert m["time"] == {"column": "Timestamp (ms)", "unit": "ms"}
    rec = read(path, map=tmp_path / "m.yaml")
    np.testing.assert_allclose(rec.gyro, tumble(np.arange(603) / FS)[1][:600], atol=1e-9)


def test_missing_samples_do_not_stop_the_proposal(tmp_path):
    """Empty cells (NaN) in the sensors and the reference: the proposal is the same."""
    path = tmp_path / "mocap.csv"
    _mocap_csv(path, n=800)
    frame = pd.read_csv(path)
    frame.loc[[3, 100, 101], ["gyro_y", "acc_x", "mag_z"]] = np.nan
    frame.loc[[5, 400], ["cam_qw"]] = np.nan
    frame.to_csv(path, index=False)
    m = propose_map(path)
    assert (m["gyro"]["unit"], m["accel"]["unit"], m["mag"]["unit"]) == ("rad/s", "g", "gauss")
    assert m["truth"]["order"] == "xyzw" and m["truth"]["frame"] == "unknown"
