"""The "Your own satellite" tutorial (docs/tutorial-own-satellite.md): its scenario file
simulates and estimates, a short campaign on it writes its report, the validation errors
it describes name their key, and every command it quotes exists."""

import argparse
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

from gnomon.cli import build_parser, main
from gnomon.errors import InputError
from gnomon.scenarios import Scenario, load_scenario, simulate

ROOT = Path(__file__).resolve().parents[1]
YAML_PATH = ROOT / "examples" / "own_satellite.yaml"
TUTORIAL = ROOT / "docs" / "tutorial-own-satellite.md"
ISS_1 = "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927"
ISS_2 = "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537"


def _short_yaml(tmp_path, duration_s):
    """The tutorial's scenario with a shorter duration, as a file."""
    d = yaml.safe_load(YAML_PATH.read_text("utf-8"))
    d["duration_s"] = duration_s
    p = tmp_path / "own_short.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False), "utf-8")
    return p


def test_tutorial_scenario_loads_and_simulates():
    sc = load_scenario(YAML_PATH)
    assert sc.get("orbit.kind") == "tle"
    assert sc.get("epoch") == "2026-03-20T00:00:00Z"               # the TLE's epoch
    rec = simulate(sc.replace({"duration_s": 300.0}))
    assert len(rec) == 301
    alt_km = (np.linalg.norm(rec.extra["r_i_m"], axis=1) - 6378137.0) / 1e3
    assert np.all((540 < alt_km) & (alt_km < 575))                 # ~550 km, e = 0.0012
    assert np.any(rec.extra["st_valid"])                            # the star tracker is on


def test_gnomon_estimate_on_the_tutorial_scenario(tmp_path, capsys):
    rec_path, plot = tmp_path / "own.h5", tmp_path / "own.png"
    assert main(["simulate", str(_short_yaml(tmp_path, 1200.0)), "--out", str(rec_path)]) == 0
    capsys.readouterr()
    assert main(["estimate", str(rec_path), "--plot", str(plot), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["filter"] == "mekf"  # with the star tracker
    # 20 min, started from the star tracker: the full orbit gives 0.013 deg RMS (tutorial)
    assert 0.0 < out["errors"]["total_deg"] < 0.1
    assert plot.stat().st_size > 10_000


def test_five_run_campaign_with_report(tmp_path):
    out = tmp_path / "mc_own"
    assert main(["campaign", str(_short_yaml(tmp_path, 900.0)), "--runs", "5", "--out",
                 str(out), "--report", "--quiet", "--filter", "mekf-spacecraft",
                 "--vary", "sensors.magnetometer.noise_nT=uniform(60,120)",
                 "--vary", "spacecraft.inertia_error_pct=uniform(0,10)"]) == 0
    text = (out / "report.html").read_text("utf-8")
    assert "mekf-spacecraft" in text and "sensors.magnetometer.noise_nT" in text


def _raises(d, field, *words):
    with pytest.raises(InputError) as err:
        Scenario.from_dict(d)
    assert err.value.field == field
    for w in words:
        assert w in str(err.value), str(err.value)


def test_non_symmetric_inertia_names_key_and_elements():
    _raises({"spacecraft": {"inertia_kg_m2": [[0.164, -0.0021, 0.0013], [0.0021, 0.1256, 0.0028],
                                              [0.0013, 0.0028, 0.0584]]}},
            "spacecraft.inertia_kg_m2", "symmetric", "[0][1] = -0.0021", "[1][0] = 0.0021")


def test_triangle_inequality_violation_names_key_and_moments():
    _raises({"spacecraft": {"inertia_kg_m2": [0.05, 0.06, 0.164]}},
            "spacecraft.inertia_kg_m2", "triangle", "0.05 + 0.06 < 0.164")


def test_inertia_in_kg_mm2_is_refused():
    _raises({"spacecraft": {"mass_kg": 12.0, "inertia_kg_m2": [164000.0, 125600.0, 58400.0]}},
            "spacecraft.inertia_kg_m2", "kg mm^2", "radius of gyration")


def _tle(line1=ISS_1, line2=ISS_2, epoch="2008-09-20T12:25:40Z"):
    return {"epoch": epoch, "orbit": {"kind": "tle", "tle_line1": line1, "tle_line2": line2}}


def test_a_valid_tle_passes():
    Scenario.from_dict(_tle())


@pytest.mark.parametrize("line1,line2,field,words", [
    (ISS_1[:-1] + "8", ISS_2, "orbit.tle_line1", ("checksum", "'8'", "sums to 7")),
    (ISS_1, ISS_2[:-1] + "0", "orbit.tle_line2", ("checksum", "'0'", "sums to 7")),
    (ISS_1.replace(" 0  2927", " 0 2927"), ISS_2, "orbit.tle_line1", ("69 characters", "got 68")),
    (ISS_2, ISS_1, "orbit.tle_line1", ("swapped",)),
    (ISS_1, "", "orbit.tle_line2", ("missing",)),
])
def test_bad_tle_names_its_line(line1, line2, field, words):
    _raises(_tle(line1, line2), field, *words)


def test_tle_of_another_object_is_refused():
    line2 = "2 00005  34.2682 348.7242 1859667 331.7664  19.3264 10.82419157413667"
    _raises(_tle(ISS_1, line2), "orbit.tle_line2", "catalogue number", "'00005'", "'25544'")


def test_tle_far_from_the_epoch_is_refused():
    _raises(_tle(epoch="2026-03-20T00:00:00Z"), "epoch", "days from the TLE's epoch",
            "2008-09-20")


def test_tle_lines_without_kind_tle_are_refused():
    _raises({"orbit": {"tle_line1": ISS_1, "tle_line2": ISS_2}}, "orbit.kind", "set kind: tle")


@pytest.mark.parametrize("d,field,suggestion", [
    ({"sensors": {"magnetometer": {"noise_nt": 85.0}}}, "sensors.magnetometer.noise_nt",
     "'sensors.magnetometer.noise_nT'"),
    ({"sensors": {"gyro": {"arw_deg_rt_hr": 0.15}}}, "sensors.gyro.arw_deg_rt_hr",
     "'sensors.gyro.arw_deg_rt_h'"),
    ({"sensors": {"gyro": {"noise_nT": 85.0}}}, "sensors.gyro.noise_nT",
     "'sensors.magnetometer.noise_nT'"),                              # the wrong section
    ({"spacecaft": {}}, "spacecaft", "'spacecraft'"),
])
def test_misspelt_key_gets_a_suggestion(d, field, suggestion):
    _raises(d, field, "unknown scenario key", f"did you mean {suggestion}")


def test_misspelt_dotted_override_gets_a_suggestion():
    with pytest.raises(InputError, match="did you mean 'sensors.gyro.bias_deg_s'"):
        load_scenario(YAML_PATH).replace({"sensors.gyro.bias_deg": 0.01})


def test_magnetometer_noise_in_pT_is_refused():
    _raises({"sensors": {"magnetometer": {"noise_nT": 85000.0 * 1000}}},
            "sensors.magnetometer.noise_nT", "pT")


def _bash_commands(text):
    """The commands of the ```bash blocks of a markdown text (continuations joined)."""
    cmds = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line:
                cmds.append(shlex.split(line))
    return cmds


def _subcommands():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return set(sub.choices)


def test_tutorial_commands_exist_and_name_real_files():
    cmds = _bash_commands(TUTORIAL.read_text("utf-8"))
    assert len(cmds) >= 4
    subs = _subcommands()
    produced: set[str] = set()
    for argv in cmds:
        assert argv[0] == "gnomon", argv
        assert argv[1] in subs, f"gnomon {argv[1]} is not a subcommand"
        for i, arg in enumerate(argv[2:], start=2):
            if argv[i - 1] in ("--out", "--plot"):
                produced.add(arg)
                continue
            if arg.startswith("-") or argv[i - 1] in ("--vary", "--set", "--runs", "--param"):
                continue
            # a positional argument: a file in the repository or produced above
            assert (ROOT / arg).exists() or arg in produced, f"{arg!r} in {' '.join(argv)}"
    assert {"own.h5", "own.png", "mc_own"} <= produced
    # the scenario the tutorial describes is the one shipped, and it is valid
    assert "examples/own_satellite.yaml" in {a for argv in cmds for a in argv}
    assert "1 99022U 26900A   26079.00000000" in TUTORIAL.read_text("utf-8")
    load_scenario(YAML_PATH)
