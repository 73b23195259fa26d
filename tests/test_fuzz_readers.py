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

from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.io import read
from gnomon.recording import Recording

DATA = bundled()
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


# ------------------------------------------------------------------ log readers
LOGS = DATA / "logs"
TYREX_ANDROID = LOGS / "tyrex" / "android" / "Guillaume_Nexus5_NoDist_Texting_excerpt"
TYREX_IOS = LOGS / "tyrex" / "ios" / "Guillaume_iPhone5_NoDist_Texting_excerpt"


def one_line_naming(err: InputError, path, field: str | None = None) -> None:
    text = str(err)
    assert "\n" not in text and str(path) in text, text
    if field is not None:
        assert f"field '{field}" in text, text


@pytest.fixture(scope="module")
def log_files(tmp_path_factory):
    """One file of every single-file format: real excerpts and generated files."""
    import logfiles as L

    d = tmp_path_factory.mktemp("logs")
    bags = L.write_rosbags(d, seconds=0.5)
    files = {
        "ulog": LOGS / "px4" / "sample_log_small_imu.ulg",
        "dataflash": LOGS / "ardupilot" / "test.BIN",
        "ros1": bags["ros1"],
        "mcap": next(bags["mcap"].glob("*.mcap")),
        "db3": next(bags["sqlite3"].glob("*.db3")),
        "xsens": L.write_xsens(d, seconds=0.5),
        "dataflash_current": L.write_dataflash(d, seconds=0.5),
        "csv_multirate": L.write_multirate_csv(d, seconds=0.5),
    }
    (d / "sl").mkdir()
    files["sensorlogger"] = L.write_sensorlogger(d / "sl", seconds=0.5)
    (d / "ph").mkdir()
    files["phyphox"] = L.write_phyphox(d / "ph", seconds=0.5)
    t = np.arange(100) / 100.0
    files["mat73"] = L.write_mat73(d / "m73.mat", {"t": t, "gyr": np.zeros((100, 3)),
                                                    "acc": np.tile([0, 0, 9.8], (100, 1))})
    return files


LOG_KINDS = ["ulog", "dataflash", "dataflash_current", "ros1", "mcap", "db3", "xsens",
             "csv_multirate", "sensorlogger", "phyphox", "mat73"]


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)),
                                               max_size=12))
@pytest.mark.parametrize("kind", LOG_KINDS)
def test_truncated_and_corrupted_logs(tmp_path, log_files, kind, cut, flips):
    src = log_files[kind]
    data = bytearray(src.read_bytes())
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    data = data[: max(1, int(cut * len(data)))] if cut < 1.0 else data
    path = tmp_path / src.name
    path.write_bytes(bytes(data))
    try:
        rec = read(path)
    except InputError as e:
        one_line_naming(e, path.name)
        return
    assert isinstance(rec, Recording)
    if kind == "ulog" and not flips and len(data) not in _ulog_boundaries(src):
        # cut inside a message: an error or said (a cut between two messages looks whole)
        assert rec.meta["truncated"] is not None, len(data)
        assert rec.meta["truncated"]["at_byte"] < len(data)
        assert any("cut short" in s for s in rec.meta["assumed"])


def _ulog_boundaries(src: Path) -> frozenset:
    """Byte offsets at which a message of the ULog file ``src`` ends (and the next starts)."""
    import struct

    raw = src.read_bytes()
    ends, pos = {16}, 16
    while pos + 3 <= len(raw):
        pos += 3 + struct.unpack_from("<H", raw, pos)[0]
        ends.add(pos)
    return frozenset(ends)


def test_truncated_ulog_at_every_kind_of_cut(tmp_path):
    """Cuts inside a message header, inside a payload and between two messages of the
    data section: the first two are said, the last reads as a complete (shorter) log."""
    src = DATA / "logs" / "px4" / "sample_log_small_imu.ulg"
    raw = src.read_bytes()
    ends = sorted(_ulog_boundaries(src))
    boundary = ends[int(0.7 * len(ends))]
    for cut, said in ((boundary + 1, True), (boundary + 3, True), (boundary + 7, True),
                      (boundary, False)):
        path = tmp_path / f"cut{cut}.ulg"
        path.write_bytes(raw[:cut])
        rec = read(path)
        assert (rec.meta["truncated"] is not None) == said, cut
        if said:
            assert rec.meta["truncated"]["at_byte"] == boundary


def test_ulog_cut_seen_near_the_end_as_when_watching_every_read(tmp_path, monkeypatch):
    """The ULog reader watches pyulog's reads only within ``_TAIL`` bytes of the end of the
    file (free on long logs): the same cut record and errors as watching every read, for
    cuts and damaged bytes anywhere (small buffers: many fills before the end)."""
    import random

    from gnomon.io import ulog

    raw = (DATA / "logs" / "px4" / "sample_log_small_imu.ulg").read_bytes()
    rng = random.Random(7)
    tail = ulog._TAIL
    monkeypatch.setattr(ulog, "_BUFFER", 4096)
    path = tmp_path / "cut.ulg"
    for k in range(40):
        data = bytearray(raw[: rng.randrange(tail + 1, len(raw) + 1)])
        for _ in range(k % 3):  # damaged bytes (message sizes up to 64 KiB) in a third
            data[rng.randrange(16, len(data))] = rng.randrange(256)
        path.write_bytes(bytes(data))
        seen = []
        for watched in (tail, len(data)):  # near the end / every read
            monkeypatch.setattr(ulog, "_TAIL", watched)
            try:
                seen.append(read(path, allow_corrupt=True).meta["truncated"])
            except InputError as e:
                seen.append(str(e))
        assert seen[0] == seen[1], (len(data), k)
        assert k % 3 or seen[0] is None or isinstance(seen[0], str) or (
            seen[0]["at_byte"] + seen[0]["bytes_present"] == len(data))


def test_ulog_cut_watch_after_a_seek_near_the_end(tmp_path):
    """A seek to within ``_TAIL`` bytes of the end starts the watch (the read after it may
    run past the end before any buffer fill reports where it got to)."""
    from gnomon.io.ulog import _TAIL, _CutWatch

    path = tmp_path / "f.ulg"
    path.write_bytes(bytes(4 * _TAIL))
    with _CutWatch(path) as watch:
        assert watch.read(3) == bytes(3) and watch.cut is None
        watch.seek(4 * _TAIL - 7)  # (a message's 3-byte header before it)
        assert watch.read(20) == bytes(7)
        assert watch.cut == (4 * _TAIL - 10, 23, 10)  # (message start, size, present)
        assert watch.read(3) == b"" and watch.cut == (4 * _TAIL - 10, 23, 10)


@pytest.mark.parametrize("kind", LOG_KINDS)
def test_logs_with_the_wrong_format_forced(tmp_path, log_files, kind):
    """A file read as every other format: one line, never another exception."""
    from gnomon.io import FORMATS

    for fmt in FORMATS[1:]:
        try:
            read(log_files[kind], format=fmt)
        except InputError as e:
            one_line_naming(e, log_files[kind].name)


def _ulog_variant(tmp_path, change) -> Path:
    from pyulog import ULog

    u = ULog(str(LOGS / "px4" / "sample_log_small_imu.ulg"))
    change({(d.name, d.multi_id): d for d in u.data_list})
    path = tmp_path / "changed.ulg"
    u.write_ulog(str(path))
    return path


def _ulog_patch_timestamp(src: Path, dst: Path, topic: str, index: int, value_us: int) -> Path:
    """Overwrite the timestamp of the ``index``-th data message of ``topic`` in the bytes
    (pyulog's writer sorts messages by time, so a backward stamp must be made by hand)."""
    import struct

    raw = bytearray(src.read_bytes())
    pos, msg_id, seen = 16, None, 0  # ULog: 16-byte file header, then size/type/payload
    while pos + 3 <= len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        body = pos + 3
        if kind == ord("A") and raw[body + 3:body + size].decode() == topic:
            msg_id = struct.unpack_from("<H", raw, body + 1)[0]
        elif kind == ord("D") and struct.unpack_from("<H", raw, body)[0] == msg_id:
            if seen == index:
                struct.pack_into("<Q", raw, body + 2, value_us)
                break
            seen += 1
        pos = body + size
    dst.write_bytes(bytes(raw))
    return dst


def test_ulog_backward_repeated_nan_and_empty(tmp_path):
    def backward(data):
        pass  # made in the bytes below

    def repeated(data):
        ts = data[("sensor_combined", 0)].data["timestamp"]
        ts[11] = ts[10]

    def nan(data):
        data[("sensor_combined", 0)].data["gyro_rad[1]"][7] = np.nan

    def empty(data):
        d = data[("sensor_combined", 0)]
        d.data = {k: v[:1] for k, v in d.data.items()}

    for change, field, what in ((backward, "sensor_combined.gyro_rad", "backward"),
                                (repeated, "sensor_combined.gyro_rad", "repeats"),
                                (nan, "sensor_combined.gyro_rad", "non-finite"),
                                (empty, "sensor_combined.gyro_rad", "at least 2")):
        path = _ulog_variant(tmp_path, change)
        if change is backward:
            path = _ulog_patch_timestamp(path, tmp_path / "back.ulg", "sensor_combined", 10,
                                         1000)
        with pytest.raises(InputError, match=what) as e:
            read(path, strict=True)
        one_line_naming(e.value, path, field)
        if change is nan:  # not strict: that gyro sample dropped and counted
            assert read(path).meta["dropped"] == {"gyro": 1}
        else:
            with pytest.raises(InputError, match=what):
                read(path)


def test_dataflash_backward_and_nan(tmp_path):
    import struct

    from pymavlink import DFReader

    src = LOGS / "ardupilot" / "test.BIN"
    log = DFReader.DFReader_binary(str(src))
    imu = log.name_to_id["IMU"]
    offsets = log.offsets[imu]
    raw = bytearray(src.read_bytes())
    back = bytearray(raw)
    struct.pack_into("<Q", back, offsets[5] + 3, 1)  # TimeUS of the 6th IMU message: 1 us
    nan = bytearray(raw)
    struct.pack_into("<f", nan, offsets[3] + 3 + 8, float("nan"))  # its GyrX
    for data, what, field in ((back, "backward", "IMU.GyrX..AccZ"),
                              (nan, "non-finite", "IMU.GyrX..AccZ")):
        path = tmp_path / "t.BIN"
        path.write_bytes(bytes(data))
        with pytest.raises(InputError, match=what) as e:
            read(path, strict=True)
        one_line_naming(e.value, path, field)
    assert read(path).meta["dropped"] == {"gyro": 1}  # not strict: dropped and counted


def test_rosbag_backward_nan_and_empty_topic(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    Imu, Mag = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/MagneticField"]

    def msg(t, w=0.0):
        h = T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
            sec=int(t), nanosec=int((t % 1) * 1e9)), frame_id="imu")
        v = T["geometry_msgs/msg/Vector3"]
        return Imu(header=h, orientation=T["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1),
                   orientation_covariance=np.zeros(9), angular_velocity=v(x=w, y=0, z=0),
                   angular_velocity_covariance=np.zeros(9),
                   linear_acceleration=v(x=0, y=0, z=9.8),
                   linear_acceleration_covariance=np.zeros(9))

    def bag(name, stamps, values, with_empty_mag=False):
        path = tmp_path / name
        with Writer(path) as w:
            c = w.add_connection("/imu", Imu.__msgtype__, typestore=store)
            if with_empty_mag:
                w.add_connection("/mag", Mag.__msgtype__, typestore=store)
            for i, (t, v) in enumerate(zip(stamps, values, strict=True)):
                w.write(c, 10**9 + i, store.serialize_ros1(msg(t, v), Imu.__msgtype__))
        return path

    t = 1.0 + np.arange(10) * 0.01
    back = t.copy()
    back[6] = back[2]
    nan = np.zeros(10)
    nan[4] = np.nan
    cases = ((bag("back.bag", back, np.zeros(10)), "backward", "/imu"),
             (bag("nan.bag", t, nan), "non-finite", "/imu"),
             (bag("empty.bag", t[:1], [0.0]), "at least 2", "/imu"))
    for path, what, field in cases:
        with pytest.raises(InputError, match=what) as e:
            read(path, strict=True)
        one_line_naming(e.value, path, field)
    assert read(cases[1][0]).meta["dropped"] == {"gyro": 1}  # not strict: dropped, counted
    path = bag("emptymag.bag", t, np.zeros(10), with_empty_mag=True)
    rec = read(path)  # picked by default, without messages: no magnetometer, and said so
    assert rec.mag is None and any("'/mag'" in s and "no messages" in s
                                   for s in rec.meta["assumed"])
    with pytest.raises(InputError, match="no messages") as e:  # named: an error
        read(path, mag_topic="/mag")
    one_line_naming(e.value, path, "mag_topic")
    with pytest.raises(InputError, match="zero") as e:  # unset header stamps
        read(bag("zero.bag", np.zeros(10), np.zeros(10)))


@pytest.mark.parametrize("trial", [TYREX_ANDROID, TYREX_IOS], ids=["android", "ios"])
def test_tyrex_mutated_files(tmp_path, trial):
    cases = {
        "bad number": lambda lines: lines.__setitem__(5, lines[5].replace(" ", " x", 1)),
        "backward": lambda lines: lines.__setitem__(9, lines[2]),
        "nan": lambda lines: lines.__setitem__(4, " ".join(lines[4].split()[:1] + ["nan"] * 3)),
        "ragged": lambda lines: lines.__setitem__(3, lines[3].split()[0]),
        "empty": lambda lines: lines.clear(),
    }
    for name, change in cases.items():
        d = tmp_path / f"{trial.name}_{name.replace(' ', '_')}"
        shutil.copytree(trial, d)
        f = d / "accelerometer.txt"
        lines = f.read_text().splitlines()
        change(lines)
        f.write_text("\n".join(lines) + ("\n" if lines else ""))
        with pytest.raises(InputError) as e:
            read(d, strict=True)
        one_line_naming(e.value, d)
        if name == "nan":  # not strict: that accelerometer sample dropped, counted
            assert read(d).meta["dropped"] == {"accel": 1}


def test_xsens_and_phyphox_partial_rows(tmp_path, log_files):
    text = log_files["xsens"].read_text().splitlines()
    i = next(k for k, ln in enumerate(text) if ln.startswith("0\t") or ln.split("\t")[0] == "0")
    cells = text[i].split("\t")
    cells[9] = ""  # Mag_Y empty, Mag_X and Mag_Z filled
    text[i] = "\t".join(cells)
    path = tmp_path / "x.txt"
    path.write_text("\n".join(text))
    with pytest.raises(InputError, match="empty cell") as e:
        read(path)
    one_line_naming(e.value, path, "Mag_Y")
