"""The filter ``gnomon estimate`` runs when none is named: chosen from what the recording
holds (``registry.default_for``), and said."""

import dataclasses
import json

import numpy as np
import pytest

from gnomon.cli import main
from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.io import write
from gnomon.scenarios import load_scenario, simulate
from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs


@pytest.fixture(scope="module")
def spacecraft():
    """Ten minutes of seed 001 (gyro, magnetometer, sun sensor, the field and sun models in
    the orbit frame)."""
    return simulate(load_scenario("seed001").replace({"duration_s": 600.0}), rng_seed=1)


@pytest.fixture(scope="module")
def imu():
    return simulate_ahrs(AhrsSimParams(duration_s=10.0), np.random.default_rng(0))


def _without(rec, *names):
    kw = {n: None for n in names if not n.startswith("extra.")}
    extra = {k: v for k, v in rec.extra.items() if f"extra.{k}" not in names}
    return dataclasses.replace(rec, extra=extra, **kw)


def test_the_default_follows_the_sensors(spacecraft, imu):
    """Each default is the first of the registry's order whose inputs the recording has."""
    assert registry.default_for(spacecraft)[0] == "mekf"
    no_sun = _without(spacecraft, "sun", "sun_valid", "extra.s_o")
    assert registry.default_for(no_sun)[0] == "mekf"  # the one MEKF takes what there is
    assert registry.default_for(imu)[0] == "robust-ahrs"
    name, why = registry.default_for(_without(imu, "mag"))
    assert name == "tilt-cf"
    assert "gyro, accel" in why and "robust-ahrs" in why  # what it holds, what it lacked
    assert "mekf" not in why  # not the spacecraft filters an IMU log was never meant for
    assert registry.default_for(imu, offline=True)[0] == "eskf-offline"
    # whatever is chosen runs on the recording
    for rec in (spacecraft, no_sun, imu, _without(imu, "mag")):
        registry.create(registry.default_for(rec)[0]).run(rec)


def test_no_default_says_what_the_recording_holds(imu):
    with pytest.raises(InputError, match="holds gyro, accel") as err:
        registry.default_for(_without(imu, "mag"), offline=True)
    assert "eskf-offline needs gyro, accel, mag" in str(err.value)
    assert err.value.field == "--filter"


def test_estimate_on_a_spacecraft_recording_takes_the_spacecraft_mekf(tmp_path, capsys,
                                                                      spacecraft):
    """The issue's case: ``gnomon estimate rec.h5`` on a simulated spacecraft recording
    used to stop with "filter 'robust-ahrs' needs accel"."""
    path = write(tmp_path / "sc.h5", spacecraft)
    assert main(["estimate", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["filter"] == "mekf"
    assert "sun" in out["filter_chosen_because"]
    assert out["errors"]["total_deg"] < 1.0
    assert main(["estimate", str(path)]) == 0
    assert "default filter" in capsys.readouterr().out
    # a named filter is run as named, with no reason given
    assert main(["estimate", str(path), "--filter", "mekf-delayed", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["filter"] == "mekf-delayed" and "filter_chosen_because" not in out
