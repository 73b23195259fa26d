"""The command line: JSON contracts, and bad input as one line with file, field and row."""

import json
import subprocess
import sys

import numpy as np
import pytest

from gnomon.cli import main
from gnomon.datasets import bundled

DATA = bundled()
EXCERPTS = DATA / "broad"


def run_cli(*args):
    """Run ``gnomon`` in a subprocess: exit code, stdout, stderr."""
    p = subprocess.run([sys.executable, "-m", "gnomon.cli", *map(str, args)],
                       capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout, p.stderr


def test_version_and_filters(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("gnomon ")
    assert main(["filters", "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    mahony = next(f for f in table if f["name"] == "mahony")
    assert {p["name"] for p in mahony["params"]} >= {"kp_acc_rad_s", "ki_rad_s2"}


def test_benchmark_broad_json_contract(capsys):
    assert main(["benchmark", "broad", "--data", EXCERPTS, "--filters", "mahony",
                 "--anchors", "vqf", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["metric"] == "broad"
    assert {(r["trial"], r["method"]) for r in out["trials"]} == {
        (t, m) for t in ("01_undisturbed_slow_rotation_A_excerpt",
                         "32_disturbed_attached_magnet_1cm_excerpt") for m in ("mahony", "vqf")}
    for r in out["trials"]:
        assert set(r) >= {"trial", "method", "total_deg", "heading_deg", "inclination_deg"}
    for m in ("mahony", "vqf"):
        mean = out["mean"][m]
        assert mean["trials"] == 2
        per = [r["total_deg"] for r in out["trials"] if r["method"] == m]
        assert mean["total_deg"] == pytest.approx(np.mean(per))
    assert out["groups"]["vqf"]["attached_magnet"]["trials"] == 1


@pytest.mark.slow(reason="10 s (2 cores): long runs or a first compilation")
def test_estimate_with_truth_writes_outputs(tmp_path, capsys):
    trial = EXCERPTS / "01_undisturbed_slow_rotation_A_excerpt.mat"
    out_csv, out_h5, plot = tmp_path / "e.csv", tmp_path / "e.h5", tmp_path / "e.png"
    assert main(["estimate", trial, "--filter", "mahony", "--param", "kp_acc_rad_s=0.5",
                 "--out", out_csv,
                 "--plot", plot, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["params"]["kp_acc_rad_s"] == 0.5
    assert 0 < summary["errors"]["total_deg"] < 10
    data = np.loadtxt(out_csv, delimiter=",", skiprows=1)
    assert data.shape[1] >= 5
    np.testing.assert_allclose(np.linalg.norm(data[:, 1:5], axis=1), 1, atol=1e-8)
    assert plot.stat().st_size > 10_000
    assert main(["estimate", trial, "--out", out_h5]) == 0
    assert "inclination" in capsys.readouterr().out


def _csv(path, rows, header="t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"):
    path.write_text(header + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return path


GOOD = [[i * 0.01, 0, 0, 0, 0, 0, 9.81, 0, 20, -40] for i in range(20)]


@pytest.mark.slow(reason="3 s (2 cores): runs the command line in new processes")
@pytest.mark.parametrize(
    "case, expect",
    [
        ("nan", ["bad.csv", "gyr_y", "row 6"]),
        ("time", ["bad.csv", "'t'", "row 9"]),
        ("column", ["bad.csv", "acc_z"]),
        ("missing", ["nope.csv", "no such file"]),
        ("broad_field", ["broken.hdf5", "imu_mag"]),
    ],
)
def test_bad_input_is_one_line_without_traceback(tmp_path, case, expect):
    rows = [list(r) for r in GOOD]
    if case == "nan":
        rows[5][2] = "nan"
        path = _csv(tmp_path / "bad.csv", rows)
    elif case == "time":
        rows[8][0] = rows[7][0]
        path = _csv(tmp_path / "bad.csv", rows)
    elif case == "column":
        path = _csv(tmp_path / "bad.csv", [r[:6] + r[7:] for r in rows],
                    header="t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,mag_x,mag_y,mag_z")
    elif case == "missing":
        path = tmp_path / "nope.csv"
    else:
        import h5py

        path = tmp_path / "broken.hdf5"
        with h5py.File(EXCERPTS / "32_disturbed_attached_magnet_1cm_excerpt.hdf5") as src, \
                h5py.File(path, "w") as dst:
            for k in src:
                if k != "imu_mag":
                    src.copy(k, dst)
            dst.attrs.update(dict(src.attrs))
    code, out, err = run_cli("estimate", path, *(["--strict"] if case == "nan" else []))
    assert code == 2
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    for word in expect:
        assert word in lines[0], (word, lines[0])


def test_unknown_filter_and_param(tmp_path):
    trial = EXCERPTS / "01_undisturbed_slow_rotation_A_excerpt.mat"
    code, _, err = run_cli("estimate", trial, "--filter", "nosuch")
    assert code == 2 and "nosuch" in err and "Traceback" not in err
    code, _, err = run_cli("estimate", trial, "--filter", "mahony", "--param", "kp=1")
    assert code == 2 and "'kp'" in err


@pytest.mark.slow(reason="reads a full data set: vqf 2 s, imufusion 5 s, ahrs-madgwick (pure "
                         "Python) 165 s on 2 cores; one test per library")
@pytest.mark.parametrize("anchor, published", [("vqf", 2.67), ("imufusion", 14.1),
                                               ("ahrs-madgwick", 5.62)])
def test_reference_libraries_match_published_broad_scores(full_broad, anchor, published):
    """The metric and the adapters: published means on the 15 trials within 0.05 deg."""
    from gnomon.benchmark import run_broad

    res = run_broad(full_broad, filters=[], anchors=[anchor])
    assert len({r["trial"] for r in res["trials"]}) == 15
    assert res["mean"][anchor]["total_deg"] == pytest.approx(published, abs=0.05)


def test_scenarios_and_simulate_write_a_readable_recording(tmp_path, capsys):
    from gnomon.io import read

    assert main(["scenarios", "--json"]) == 0
    names = {r["name"] for r in json.loads(capsys.readouterr().out)}
    assert {"seed000", "seed001"} <= names
    out = tmp_path / "rec.h5"
    assert main(["simulate", "seed001", "--out", out, "--set", "duration_s=600",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    rec = read(out)
    assert len(rec) == summary["samples"] == 601
    assert rec.frames["reference"] == "o" and rec.q_true is not None
    code, _, err = run_cli("simulate", "seed001", "--out", tmp_path / "x.h5",
                           "--set", "spacecraft.nosuch=1")
    assert code == 2 and "nosuch" in err and "Traceback" not in err


def test_campaign_command_json_and_bad_vary(tmp_path, capsys):
    assert main(["campaign", "seed001", "--runs", "3", "--out", tmp_path / "c",
                 "--vary", "duration_s=300", "--filter", "mekf-spacecraft",
                 "--executor", "serial", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows"] == 3 and summary["failed_total"] == 0
    assert summary["metrics"]["mekf-spacecraft.rms_deg"]["max"] < 1.0
    code, _, err = run_cli("campaign", "seed001", "--runs", "2", "--out", tmp_path / "d",
                           "--vary", "spacecraft.nosuch=normal(0,1)")
    assert code == 2 and "nosuch" in err and "Traceback" not in err


@pytest.mark.slow(reason="70 s (2 cores): long runs or a first compilation")
def test_bench_json_contract(capsys):
    """``gnomon bench --json`` keys (the speed itself is measured, not asserted)."""
    assert main(["bench", "--samples", "3000", "--repeats", "1", "--runs", "16",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == 3000 and out["repeats"] == 1
    names = set(out["results"])
    assert {"mahony", "eskf-r3", "robust-ahrs", "gnomon-batch-mahony-R16"} <= names
    if "vqf-batch" in names:
        assert out["results"]["vqf-batch"]["ratio_to_vqf_batch"] == pytest.approx(1.0)
    for r in out["results"].values():
        assert r["samples_per_s"] > 0 and "ratio_to_vqf_batch" in r


def test_bad_column_map_is_one_line_not_a_traceback(capsys):
    csv = DATA / "broad_01_excerpt.csv"
    assert main(["estimate", csv, "--columns", "tt"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "gnomon: error: field '--columns': expected KEY=VALUE, got 'tt'"
    assert main(["estimate", csv, "--columns", "t=tt"]) == 2
    assert "field 'tt': missing column" in capsys.readouterr().err


def test_a_filter_refuses_a_recording_in_another_reference_frame(capsys):
    from gnomon.io import read

    rec = read(EXCERPTS / "01_undisturbed_slow_rotation_A_excerpt.mat")
    from dataclasses import replace

    ned = replace(rec, frames={"reference": "NED", "body": "sensor"})
    from gnomon.errors import InputError
    from gnomon.estimators import registry

    for name in registry.names("imu"):
        with pytest.raises(InputError, match="estimates against ENU") as err:
            registry.create(name).run(ned)
        assert err.value.field == "frames.reference"


def test_estimate_compare_onboard_json_contract(tmp_path, capsys):
    """``--compare onboard``: BROAD's metric against the device's own estimate (PX4's), its
    heading reference matched, on a real PX4 log whose magnetometer runs at 50 Hz."""
    log = DATA / "logs" / "px4" / "sample_log_small_imu.ulg"
    plot = tmp_path / "px4.png"
    assert main(["estimate", log, "--compare", "onboard", "--plot", plot, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    onboard = out["onboard"]
    assert set(onboard) >= {"total_deg", "heading_deg", "inclination_deg", "samples",
                            "heading_reference"}
    assert onboard["samples"] > 0.9 * out["samples"]
    assert onboard["inclination_deg"] < 1.0  # both level the vehicle from gravity
    assert "heading offset" in onboard["heading_reference"]
    assert plot.stat().st_size > 10_000
    # no own estimate: said, not an error (issue 33)
    assert main(["estimate", DATA / "broad_01_excerpt.csv", "--compare", "onboard"]) == 0
    assert "no comparison with the device's own estimate: the recording holds no attitude " \
        "estimate" in capsys.readouterr().out
