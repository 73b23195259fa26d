"""Fuzzing the readers: arbitrary bytes and mutated real files end in ``InputError`` or a
valid ``Recording`` — never another exception (bounded: a few hundred examples each)."""

import io as _io
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gnomon.errors import InputError
from gnomon.io import read
from gnomon.recording import Recording

DATA = Path(__file__).parent / "data"
MAT = DATA / "broad" / "01_undisturbed_slow_rotation_A_excerpt.mat"
H5 = DATA / "broad" / "32_disturbed_attached_magnet_1cm_excerpt.hdf5"
FUZZ = settings(max_examples=120, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


def read_or_input_error(path, **kw):
    try:
        rec = read(path, **kw)
    except InputError as e:
        assert str(e)  # one line that says something
        assert "\n" not in str(e)
        return None
    assert isinstance(rec, Recording)
    return rec


CSV_HEADER = "t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n"
cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                 st.sampled_from(["", "nan", "x", "1e999", "--1", " ", "0x10", "1,2"]),
                 st.integers(-10**6, 10**6).map(str))


@FUZZ
@given(rows=st.lists(st.lists(cell, min_size=0, max_size=12), max_size=12),
       header=st.sampled_from([CSV_HEADER, "", "t,gyr_x\n", "# " + CSV_HEADER]))
def test_csv_rows(tmp_path, rows, header):
    path = tmp_path / "f.csv"
    path.write_text(header + "\n".join(",".join(r) for r in rows))
    read_or_input_error(path)


@FUZZ
@given(blob=st.binary(max_size=2000), suffix=st.sampled_from([".csv", ".h5", ".mat", ".hdf5"]))
def test_arbitrary_bytes(tmp_path, blob, suffix):
    path = tmp_path / f"f{suffix}"
    path.write_bytes(blob)
    read_or_input_error(path)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)),
                                               max_size=20))
@pytest.mark.parametrize("src", [MAT, H5], ids=["mat", "hdf5"])
def test_truncated_and_corrupted_broad_files(tmp_path, src, cut, flips):
    data = bytearray(src.read_bytes())
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    data = data[: max(1, int(cut * len(data)))] if cut < 1.0 else data
    path = tmp_path / src.name
    path.write_bytes(bytes(data))
    read_or_input_error(path)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(drop=st.sampled_from(["imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", None]),
       shape=st.sampled_from([(0, 3), (5,), (10, 2), (7143, 4), None]),
       value=st.sampled_from([np.nan, np.inf, 0.0, 1e300, None]))
def test_mutated_broad_fields(tmp_path, drop, shape, value):
    path = tmp_path / "m.hdf5"
    shutil.copy(H5, path)
    with h5py.File(path, "r+") as f:
        if drop is not None:
            del f[drop]
        if shape is not None and "imu_gyr" in f:
            del f["imu_gyr"]
            f["imu_gyr"] = np.zeros(shape)
        if value is not None and "imu_acc" in f and f["imu_acc"].shape[0] > 10:
            a = f["imu_acc"][()]
            a[10] = value
            f["imu_acc"][...] = a
    read_or_input_error(path)


@FUZZ
@given(text=st.text(max_size=400))
def test_scenario_yaml_text(tmp_path, text):
    from gnomon.scenarios import load_scenario

    path = tmp_path / "s.yaml"
    path.write_text(text)
    try:
        load_scenario(path)
    except InputError as e:
        assert "\n" not in str(e)


@FUZZ
@given(key=st.sampled_from(["duration_s", "step_s", "spacecraft.inertia_kg_m2", "orbit",
                            "sensors.gyro", "seed", "epoch", "orbit.altitude_km"]),
       value=st.one_of(st.none(), st.floats(allow_nan=True), st.integers(-10, 10**9),
                       st.text(max_size=5), st.lists(st.floats(-1e3, 1e3), max_size=4)))
def test_scenario_overrides(key, value):
    from gnomon.scenarios import load_scenario

    try:
        load_scenario("seed001").replace({key: value})
    except InputError as e:
        assert "\n" not in str(e)


def test_yaml_is_loaded_safely(tmp_path):
    """A YAML tag that would construct a Python object is refused, not executed."""
    from gnomon.scenarios import load_scenario

    marker = tmp_path / "pwned"
    path = tmp_path / "evil.yaml"
    path.write_text(f"!!python/object/apply:os.system ['touch {marker}']\n")
    with pytest.raises(InputError):
        load_scenario(path)
    assert not marker.exists()
    _io.StringIO()  # keep the import used
