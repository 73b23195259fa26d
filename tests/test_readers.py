"""Log readers: PX4 ULog, ArduPilot DataFlash, ROS 1/2 bags, tyrex phones, Sensor Logger,
phyphox, Xsens, multi-rate CSV, MATLAB v5/v7.3 — read into a valid Recording, frames and
units checked against something independent of the conversion code.

Real files: excerpts shipped in gnomon/data/logs (README there: PX4 BSD-3, pymavlink LGPL-3, tyrex
CeCILL 2.1). The full sample logs and the tyrex data set are used when found through
``gnomon.datasets`` (``$GNOMON_LOGS_DIR``, ``$GNOMON_TYREX_DIR``; else ``../shared/data``);
the tests say so when they skip. Generated files (logfiles.py) for the formats without a
public sample: rosbags' own writers, Sensor Logger / phyphox / Xsens from their layouts.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import logfiles as L
import numpy as np
import pytest

from gnomon import cli
from gnomon.datasets import bundled, logs_dir, tyrex_dir
from gnomon.errors import InputError
from gnomon.io import detect_format, inspect, read, read_csv, read_recording, write
from gnomon.io._common import onboard_on
from gnomon.recording import Recording
from gnomon.rotation import (
    error_angle,
    quat_conj,
    quat_from_rotvec,
    quat_mul,
    quat_rotate,
    rotvec_from_quat,
)

DATA = bundled("logs")
PX4_SMALL = DATA / "px4" / "sample_log_small_imu.ulg"
PX4_OLD = DATA / "px4" / "sample_imu_113s_6s.ulg"
PX4_SITL = DATA / "px4" / "sitl_groundtruth_4s.ulg"
AP_BIN = DATA / "ardupilot" / "test.BIN"
ANDROID = DATA / "tyrex" / "android" / "Guillaume_Nexus5_NoDist_Texting_excerpt"
IOS = DATA / "tyrex" / "ios" / "Guillaume_iPhone5_NoDist_Texting_excerpt"
G = 9.80665


def up_from_onboard(rec: Recording) -> np.ndarray:
    """The measured specific force turned into ENU by the device's own estimate, (K, 3)."""
    a = rec.on_time_base("accel")
    ok = np.isfinite(a).all(axis=1) & np.isfinite(rec.q_onboard).all(axis=1)
    return quat_rotate(rec.q_onboard[ok], a[ok])


def gyro_vs_onboard(rec: Recording, window_s: float = 0.5):
    """Rotation over each window from the integrated gyro and from the device's own
    estimate (deg, both in body axes): equal only if gyro axes and estimate frames agree."""
    n = max(2, int(window_s * rec.rate_hz("gyro")))
    q, t, w = rec.q_onboard, rec.t, rec.gyro
    pairs = []
    for i0 in range(0, len(t) - n, n):
        i1 = i0 + n
        if not (np.isfinite(q[i0]).all() and np.isfinite(q[i1]).all()):
            continue
        if np.any(np.diff(t[i0:i1 + 1]) > 5 * np.median(np.diff(t))):
            continue
        qi = np.array([1.0, 0, 0, 0])
        for k in range(i0, i1):
            qi = quat_mul(qi, quat_from_rotvec(w[k + 1] * (t[k + 1] - t[k])))
        pairs.append((np.degrees(rotvec_from_quat(quat_mul(quat_conj(q[i0]), q[i1]))),
                      np.degrees(rotvec_from_quat(qi))))
    return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])


# ------------------------------------------------------------------ PX4 ULog
@pytest.mark.parametrize("path", [PX4_SMALL, PX4_OLD, PX4_SITL], ids=["small", "old", "sitl"])
def test_ulog_excerpts_read_with_gravity_up_through_px4s_estimate(path):
    rec = read(path)
    assert detect_format(path) == "ulog"
    assert rec.frames == {"reference": "ENU", "body": "FLU"}
    assert rec.mag is not None and rec.mag_unit == "uT" and not rec.single_rate
    up = np.median(up_from_onboard(rec), axis=0)
    assert abs(up[2] - G) < 0.4 and np.hypot(up[0], up[1]) < 0.2  # +g up in ENU
    field = np.linalg.norm(rec.mag, axis=1)
    assert 20.0 < np.median(field) < 70.0  # gauss -> µT: an Earth field
    assert rec.meta["format"] == "ulog" and rec.meta["assumed"]


def test_ulog_old_firmware_gyro_matches_px4_attitude_and_mag_is_deduplicated():
    rec = read(PX4_OLD)
    assert rec.meta["mag_topic"] == "sensor_combined"  # older firmware: mag in sensor_combined
    assert 90.0 < rec.rate_hz("mag") < 100.0 < rec.rate_hz("gyro")  # each at its own rate
    assert np.all(np.diff(rec.mag_t) > 0)  # the latest sample repeated per message: kept once
    onboard, gyro = gyro_vs_onboard(rec)
    moving = np.linalg.norm(onboard, axis=1) > 1.0
    assert moving.sum() >= 3
    for k in range(3):  # frames agree axis by axis (a flipped axis gives corr -1)
        assert np.corrcoef(onboard[:, k], gyro[:, k])[0, 1] > 0.99
    rms = np.sqrt(np.mean(np.sum((onboard - gyro) ** 2, axis=1)))  # deg per 0.5 s
    assert rms < 0.15 * np.sqrt(np.mean(np.sum(onboard ** 2, axis=1)))  # EKF corrections
    # the magnetic field turned into ENU points north and down (northern-hemisphere flight)
    m = rec.on_time_base("mag")
    ok = np.isfinite(m).all(axis=1) & np.isfinite(rec.q_onboard).all(axis=1)
    m_enu = np.median(quat_rotate(rec.q_onboard[ok], m[ok]), axis=0)
    assert m_enu[1] > 15 and m_enu[2] < -30 and abs(m_enu[0]) < 5


def test_ulog_sitl_truth_agrees_with_the_estimate():
    rec = read(PX4_SITL)
    ok = np.isfinite(rec.q_true).all(axis=1) & np.isfinite(rec.q_onboard).all(axis=1)
    assert ok.mean() > 0.9
    assert np.degrees(np.median(error_angle(rec.q_true[ok], rec.q_onboard[ok]))) < 1.0


def test_ulog_topics_and_instances():
    default = read(PX4_SMALL)
    assert default.meta["topic"] == "sensor_combined"
    assert default.meta["available"]["vehicle_imu"] == {"0": 12, "1": 12, "2": 12}
    for inst in (0, 1, 2):
        rec = read(PX4_SMALL, topic="vehicle_imu", instance=inst)
        assert rec.meta["instance"] == inst and len(rec) == 12
        assert abs(np.median(np.linalg.norm(rec.accel, axis=1)) - G) < 0.5
    rec = read(PX4_SMALL, instance=2)  # another instance: the per-instance topic
    assert rec.meta["topic"] in ("vehicle_imu", "sensor_gyro")
    rec = read(PX4_SMALL, topic="sensor_gyro", instance=1, mag_topic="sensor_mag",
               mag_instance=1)
    assert rec.meta["mag"].startswith("sensor_mag[1]") and len(rec) == 6
    assert read(PX4_SMALL, mag_topic="none").mag is None
    assert read(PX4_SMALL, onboard=False).q_onboard is None
    with pytest.raises(InputError, match="field 'instance'"):
        read(PX4_SMALL, topic="sensor_combined", instance=1)
    with pytest.raises(InputError, match="vehicle_imu\\[7\\]"):
        read(PX4_SMALL, topic="vehicle_imu", instance=7)
    with pytest.raises(InputError, match="field 'topic'"):
        read(PX4_SMALL, topic="sensor_baro")
    with pytest.raises(InputError, match="field 'mag_topic'.*magnetometer_ga"):
        read(PX4_SMALL, mag_topic="sensor_combined")


def test_ulog_cut_short_says_so_in_meta_and_inspect(tmp_path, capsys):
    """pyulog stops silently at a message cut by the end of the file: the reader says where
    and up to which time, and ``gnomon inspect`` prints it (as for DataFlash)."""
    whole = read(PX4_SMALL)
    assert whole.meta["truncated"] is None
    assert not any("cut short" in s for s in whole.meta["assumed"])
    raw = PX4_SMALL.read_bytes()
    path = tmp_path / "cut.ulg"
    path.write_bytes(raw[: int(0.6 * len(raw))])
    rec = read(path)
    cut = rec.meta["truncated"]
    assert cut["at_byte"] < int(0.6 * len(raw)) < cut["at_byte"] + cut["message_bytes"]
    assert cut["at_byte"] + cut["bytes_present"] == int(0.6 * len(raw))
    assert cut["data_up_to_s"] == rec.t[-1] < whole.t[-1] - 1.0
    said = [s for s in rec.meta["assumed"] if "ends inside a message" in s]
    assert len(said) == 1 and f"at byte {cut['at_byte']}" in said[0] and "cut short" in said[0]
    assert cli.main(["inspect", path]) == 0
    out = capsys.readouterr().out
    assert f"truncated: the file ends inside a message at byte {cut['at_byte']}" in out
    assert cli.main(["inspect", path, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["truncated"] == cut
    assert cli.main(["inspect", PX4_SMALL]) == 0
    assert "truncated" not in capsys.readouterr().out


def test_onboard_heading_reference_named_by_the_reader(capsys):
    """Each reader says which north the device's own estimate refers heading to; the
    comparison's ``heading_reference`` carries it."""
    assert read(PX4_SMALL).meta["onboard_heading_reference"].startswith("true north (PX4's EKF2")
    ap = read(AP_BIN).meta["onboard_heading_reference"]
    assert ap.startswith("true north") and "COMPASS_AUTODEC = 1" in ap  # Canberra, 11.8 deg
    assert "11.81 deg" in ap
    assert read(IOS).meta["onboard_heading_reference"].startswith("magnetic north")
    assert read(ANDROID).meta["onboard_heading_reference"].startswith("magnetic north")
    assert read(PX4_SMALL, onboard=False).meta["onboard_heading_reference"] is None
    assert cli.main(["estimate", PX4_SMALL, "--compare", "onboard", "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)["onboard"]["heading_reference"]
    assert "heading offset" in ref and "its north: true north (PX4's EKF2" in ref


def test_full_px4_sample_logs_read():
    d = logs_dir()
    if d is None:
        pytest.skip("sample logs not found: set GNOMON_LOGS_DIR or put them in "
                    "../shared/data/logs")
    for f in sorted((d / "px4").glob("*.ulg")):
        info = inspect(f)
        names = [s["name"] for s in info["sensors"]]
        assert names == ["gyro", "accel", "mag"], f.name
        assert info["onboard"]["coverage"] > 0.9, f.name


# ------------------------------------------------------------------ ArduPilot
def test_dataflash_att_and_ahr2_agree_and_put_gravity_up_and_the_field_south_up():
    rec = read(AP_BIN)
    assert detect_format(AP_BIN) == "dataflash" and len(rec) == 45
    assert rec.frames["body"] == "FLU" and rec.meta["onboard"].startswith("ATT")
    assert any("ends inside a message" in s for s in rec.meta["assumed"])  # 64 KiB cut
    cut = rec.meta["truncated"]  # the same record as a cut ULog's
    assert cut["at_byte"] + cut["bytes_present"] == AP_BIN.stat().st_size
    assert cut["bytes_present"] < cut["message_bytes"]
    assert cut["data_up_to_s"] == rec.t[-1]
    up = np.median(up_from_onboard(rec), axis=0)
    assert abs(up[2] - G) < 0.3 and np.hypot(up[0], up[1]) < 0.6
    ahr2 = read(AP_BIN, onboard="AHR2")  # its own quaternion Q1..Q4, independent of our Euler
    assert "quaternion" in ahr2.meta["onboard"]
    ok = np.isfinite(rec.q_onboard).all(axis=1) & np.isfinite(ahr2.q_onboard).all(axis=1)
    assert np.degrees(error_angle(rec.q_onboard[ok], ahr2.q_onboard[ok])).max() < 0.5
    # Canberra (the log's GPS): the field points north and up (southern hemisphere), ~58 µT
    m = rec.on_time_base("mag")
    ok = np.isfinite(m).all(axis=1) & np.isfinite(rec.q_onboard).all(axis=1)
    m_enu = quat_rotate(rec.q_onboard[ok], m[ok]).mean(axis=0)
    assert m_enu[1] > 15 and m_enu[2] > 40 and 50 < np.linalg.norm(m_enu) < 65


def test_dataflash_instances():
    second = read(AP_BIN, instance=1, mag_instance=2)
    assert second.meta["imu"] == "IMU2" and second.meta["mag"] == "MAG3"
    assert not np.array_equal(second.gyro, read(AP_BIN).gyro)
    with pytest.raises(InputError, match="IMU4"):
        read(AP_BIN, instance=3)
    with pytest.raises(InputError, match="field 'onboard'"):
        read(AP_BIN, onboard="EKF")


def test_dataflash_current_firmware_layout(tmp_path):
    """Instances in field I, ATT yaw as uint16 centidegrees (a log from the documented
    layout, made from the known motion in FRD/NED): the reader undoes both conversions."""
    path = L.write_dataflash(tmp_path)
    rec = read(path)
    assert rec.meta["imu"] == "IMU I=0" and rec.meta["mag"] == "MAG I=0"
    q, gyro, accel, _ = L.motion(rec.t - 5.0)
    assert np.abs(rec.gyro - gyro).max() < 1e-6 and np.abs(rec.accel - accel).max() < 1e-5
    assert np.abs(rec.mag - L.motion(rec.mag_t - 5.0003)[3]).max() < 0.06  # 1 mGauss steps
    ok = np.isfinite(rec.q_onboard).all(axis=1)
    q_att = L.motion(rec.t[ok] - 5.0006)[0]
    assert np.degrees(error_angle(q_att, rec.q_onboard[ok])).max() < 0.02  # centidegrees
    second = read(path, instance=1)
    assert second.meta["imu"] == "IMU I=1"
    assert np.abs(second.gyro - (gyro + [0.01, -0.01, -0.01])).max() < 1e-6  # FRD offset


# ------------------------------------------------------------------ ROS bags
@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    return L.write_rosbags(tmp_path_factory.mktemp("bags"), extra_imu_topic=True)


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_rosbag_imu_and_mag_at_their_own_rates(bags, kind):
    path = bags[kind]
    assert detect_format(path) == "rosbag"
    rec = read(path)
    assert rec.meta["topic"] == "/imu/data" and rec.meta["mag_topic"] == "/imu/mag"
    assert rec.rate_hz("gyro") == pytest.approx(200.0) and rec.rate_hz("mag") == \
        pytest.approx(50.0)
    q, gyro, accel, _ = L.motion(rec.t - 100.0)
    assert np.abs(rec.gyro - gyro).max() < 1e-9 and np.abs(rec.accel - accel).max() < 1e-9
    assert np.degrees(error_angle(q, rec.q_onboard)).max() < 1e-6  # x,y,z,w reordered
    assert np.abs(rec.mag - L.motion(rec.mag_t - 100.0)[3]).max() < 1e-6  # tesla -> µT
    assert rec.frames == {"reference": "ENU", "body": "imu_link"}
    other = read(path, topic="/other/imu", mag_topic="none", stamps="bag")
    assert len(other) == 100 and other.mag is None
    assert other.t[0] == pytest.approx(100.002)  # receive time, 2 ms after the stamp
    if kind != "ros1":  # the storage file alone
        f = next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
        assert len(read(f)) == 400


def test_rosbag_bad_topic_choices(bags):
    with pytest.raises(InputError, match="field 'topic'.*not sensor_msgs/msg/Imu"):
        read(bags["ros1"], topic="/imu/mag")  # a MagneticField topic as IMU
    with pytest.raises(InputError, match="field 'topic'.*no topic '/nope'"):
        read(bags["mcap"], topic="/nope")
    with pytest.raises(InputError, match="field 'stamps'"):
        read(bags["mcap"], stamps="now")


def _bag_with_empty_mag(path: Path, *, full_mag: bool = False) -> Path:
    """A ROS 1 bag with /imu (10 Imu messages), an empty /mag MagneticField topic and,
    with ``full_mag``, a /mag_full topic with 5 messages."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    Imu, Mag, V3 = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/MagneticField"], \
        T["geometry_msgs/msg/Vector3"]

    def header(t):
        return T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
            sec=int(t), nanosec=int(round((t % 1) * 1e9))), frame_id="imu")

    with Writer(path) as w:
        c = w.add_connection("/imu", Imu.__msgtype__, typestore=store)
        w.add_connection("/mag", Mag.__msgtype__, typestore=store)
        c_full = w.add_connection("/mag_full", Mag.__msgtype__, typestore=store) \
            if full_mag else None
        for i in range(10):
            t = 1.0 + 0.01 * i
            imu = Imu(header=header(t), orientation=T["geometry_msgs/msg/Quaternion"](
                x=0, y=0, z=0, w=1), orientation_covariance=np.zeros(9),
                angular_velocity=V3(x=0, y=0, z=0), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=V3(x=0, y=0, z=9.8),
                linear_acceleration_covariance=np.zeros(9))
            w.write(c, 10**9 + i, store.serialize_ros1(imu, Imu.__msgtype__))
            if c_full is not None and i % 2 == 0:
                m = Mag(header=header(t), magnetic_field=V3(x=2e-5, y=0, z=-4e-5),
                        magnetic_field_covariance=np.zeros(9))
                w.write(c_full, 10**9 + i, store.serialize_ros1(m, Mag.__msgtype__))
    return path


def test_rosbag_empty_magnetometer_topic(tmp_path):
    """An empty MagneticField topic: named by the user, an error naming it; picked by
    default, no magnetometer and a sentence saying why; a topic with messages wins."""
    path = _bag_with_empty_mag(tmp_path / "emptymag.bag")
    with pytest.raises(InputError, match="field 'mag_topic'.*topic '/mag' has no messages") as e:
        read(path, mag_topic="/mag")
    assert str(path) in str(e.value)
    rec = read(path)
    assert rec.mag is None and rec.meta["mag_topic"] is None
    assert any("'/mag'" in s and "no messages" in s and "no magnetometer" in s
               for s in rec.meta["assumed"])
    assert cli.main(["inspect", path, "--mag-topic", "/mag"]) == 2
    both = read(_bag_with_empty_mag(tmp_path / "both.bag", full_mag=True))
    assert both.meta["mag_topic"] == "/mag_full" and both.mag.shape == (5, 3)
    assert not any("no messages" in s for s in both.meta["assumed"])
    none = read(path, mag_topic="none")
    assert none.mag is None and not any("no messages" in s for s in none.meta["assumed"])


# ------------------------------------------------------------------ phones
def test_tyrex_android_and_ios_gravity_up_and_mag_north_through_the_phones_estimate():
    for path, platform in ((ANDROID, "android"), (IOS, "ios")):
        rec = read(path)
        assert detect_format(path) == "tyrex" and rec.meta["platform"] == platform
        assert rec.frames == {"reference": "ENU", "body": "device"}
        up = np.median(up_from_onboard(rec), axis=0)
        assert abs(up[2] - G) < 0.5 and np.hypot(up[0], up[1]) < 0.5, platform
        m = rec.on_time_base("mag")
        ok = np.isfinite(m).all(axis=1) & np.isfinite(rec.q_onboard).all(axis=1)
        m_enu = np.median(quat_rotate(rec.q_onboard[ok], m[ok]), axis=0)
        assert m_enu[1] > 15 and m_enu[2] < -25 and abs(m_enu[0]) < 6, platform  # Grenoble
        assert rec.meta["onboard_gravity_deg"] < 10
    ios = read(IOS)
    assert ios.rate_hz("accel") > ios.rate_hz("gyro")  # 101 vs 94 Hz: own time stamps
    raw = read(IOS, mag="raw", align_time=False)
    assert raw.t[0] > 50000  # the phone's own clock
    assert np.median(np.linalg.norm(raw.mag, axis=1)) > 100  # uncalibrated: hard iron


def test_tyrex_ios_drops_the_magnetometer_rows_coremotion_holds():
    """iOS's magnetometer-calibrated.txt repeats every other row's values at a new time
    stamp (CoreMotion's field at ~94 Hz from a ~47 Hz sensor): a held value is not a new
    measurement. The first arrival is kept; the raw file and the other sensors are not
    touched (their rare repeats are quantisation)."""
    table = np.loadtxt(IOS / "magnetometer-calibrated.txt")
    held = np.all(table[1:, 1:4] == table[:-1, 1:4], axis=1)
    assert held.sum() == 235 and table.shape[0] == 473  # the excerpt: half the rows
    rec = read(IOS)
    assert rec.mag.shape[0] == 473 - 235
    assert not np.any(np.all(rec.mag[1:] == rec.mag[:-1], axis=1))
    assert 44.0 < rec.rate_hz("mag") < 50.0 < 90.0 < rec.rate_hz("gyro")  # ~47 vs ~94 Hz
    first = np.concatenate([[True], ~held])  # the first arrival of each value is kept
    assert np.allclose(rec.mag_t - rec.meta["time_offset_s"], table[first, 0], atol=1e-9)
    said = [s for s in rec.meta["assumed"] if "magnetometer-calibrated.txt: 235 of 473" in s]
    assert len(said) == 1 and "CoreMotion holds" in said[0]
    raw = read(IOS, mag="raw")
    assert raw.mag.shape[0] == np.loadtxt(IOS / "magnetometer.txt").shape[0]
    android = read(ANDROID)
    assert android.mag.shape[0] == np.loadtxt(ANDROID / "magnetometer-calibrated.txt").shape[0]
    assert len(read(IOS).t) == np.loadtxt(IOS / "gyroscope.txt").shape[0]


def test_tyrex_ios_held_rows_tiny_case(tmp_path):
    """Runs of held rows collapse to their first arrival; a value that comes back after
    another one is a new sample; the raw magnetometer keeps its repeats."""
    import shutil

    d = tmp_path / "ios_trial"
    shutil.copytree(IOS, d)
    t0 = np.loadtxt(IOS / "gyroscope.txt")[0, 0]
    values = [(1, 2, 3), (1, 2, 3), (4, 5, 6), (4, 5, 6), (4, 5, 6), (7, 8, 9), (1, 2, 3)]
    rows = [f"{t0 + 0.01 * k:.4f} {x} {y} {z} 2" for k, (x, y, z) in enumerate(values)]
    (d / "magnetometer-calibrated.txt").write_text("\n".join(rows) + "\n")
    (d / "magnetometer.txt").write_text("\n".join(r.rsplit(" ", 1)[0] for r in rows) + "\n")
    rec = read(d, align_time=False)
    assert rec.mag.tolist() == [[1, 2, 3], [4, 5, 6], [7, 8, 9], [1, 2, 3]]
    assert np.allclose(rec.mag_t - t0, [0.0, 0.02, 0.05, 0.06])
    assert any("3 of 7 rows" in s for s in rec.meta["assumed"])
    assert read(d, mag="raw", align_time=False).mag.shape[0] == 7


def test_tyrex_full_trials_read():
    d = tyrex_dir()
    if d is None:
        pytest.skip("tyrex data not found: set GNOMON_TYREX_DIR or put it in "
                    "../shared/data/tyrex")
    for trial in (d / "datasets" / "android" / "Guillaume_Nexus5_NoDist_AR",
                  d / "datasets" / "ios" / "Guillaume_iPhone5_NoDist_AR"):
        rec = read(trial)
        assert rec.rate_hz("mag") < rec.rate_hz("gyro") or "ios" in str(trial)
        assert rec.meta["onboard_gravity_deg"] < 10


@pytest.mark.parametrize("platform,zipped,standardised",
                         [("android", True, False), ("android", False, False),
                          ("ios", True, False), ("ios", False, True)])
def test_sensorlogger(tmp_path, platform, zipped, standardised):
    path = L.write_sensorlogger(tmp_path, platform=platform, zipped=zipped,
                                standardised=standardised)
    assert detect_format(path) == "sensorlogger"
    rec = read(path)
    assert rec.meta["platform"] == platform
    assert rec.rate_hz("gyro") == pytest.approx(100.0) and rec.rate_hz("mag") == \
        pytest.approx(50.0)
    assert not rec.single_rate  # accelerometer on its own time stamps
    assert np.abs(rec.accel - L.motion(rec.accel_t)[2]).max() < 1e-6  # g, sign, m/s^2
    assert np.abs(rec.mag - L.motion(rec.mag_t)[3]).max() < 1e-6
    ok = np.isfinite(rec.q_onboard).all(axis=1)
    assert np.degrees(error_angle(L.motion(rec.t[ok])[0], rec.q_onboard[ok])).max() < 1e-4


@pytest.mark.parametrize("zipped,delimiter", [(True, ","), (False, ","), (True, ";")])
def test_phyphox(tmp_path, zipped, delimiter):
    path = L.write_phyphox(tmp_path, zipped=zipped, delimiter=delimiter)
    assert detect_format(path) == "phyphox"
    rec = read(path)
    assert [round(rec.rate_hz(s)) for s in ("gyro", "accel", "mag")] == [200, 100, 50]
    assert np.abs(rec.accel - L.motion(rec.accel_t)[2]).max() < 1e-6  # not Linear Accel.


@pytest.mark.parametrize("system,empty", [("ENU", ""), ("NED", ""), ("NWU", "NaN")])
def test_xsens(tmp_path, system, empty):
    path = L.write_xsens(tmp_path, system=system, empty=empty)
    assert detect_format(path) == "xsens"
    rec = read(path)
    t0 = rec.t[0]
    assert np.all(np.diff(rec.t) == pytest.approx(0.01))  # SampleTimeFine unwrapped
    assert rec.rate_hz("mag") == pytest.approx(25.0)  # empty cells: no sample
    q, gyro, accel, mag = L.motion(rec.t - t0)
    assert np.abs(rec.gyro - gyro).max() < 1e-5 and np.abs(rec.accel - accel).max() < 1e-5
    assert np.degrees(error_angle(q, rec.q_onboard)).max() < 1e-4
    assert np.abs(rec.mag - L.motion(rec.mag_t - t0)[3]).max() < 1e-3  # a.u. x 50 µT


# ------------------------------------------------------------------ CSV and MATLAB
def test_multirate_csv(tmp_path):
    path = L.write_multirate_csv(tmp_path)
    rec = read(path)
    assert [round(rec.rate_hz(s)) for s in ("gyro", "accel", "mag")] == [200, 100, 50]
    assert rec.meta["multi_rate"] and rec.arrivals("mag").sum() == rec.mag.shape[0]
    for k, name in ((1, "gyro"), (2, "accel"), (3, "mag")):
        assert np.abs(getattr(rec, name) - L.motion(rec.times(name))[k]).max() < 1e-9
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    row = 3 if cells[1] else 4
    cells = lines[row].split(",")
    cells[2] = ""  # gyr_y empty, gyr_x and gyr_z filled
    lines[row] = ",".join(cells)
    bad = tmp_path / "partial.csv"
    bad.write_text("\n".join(lines))
    with pytest.raises(InputError, match="empty cell") as e:
        read(bad)
    assert (e.value.field, e.value.row) == ("gyr_y", row)


def test_single_rate_csv_unchanged_and_truth_on_gyro_rows(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z,q_w,q_x,q_y,q_z\n"
                    "0,0,0,0,0,0,9.8,20,0,-40,1,0,0,0\n0.01,0,0,0,0,0,9.8,,,,1,0,0,0\n"
                    "0.02,0,0,0,0,0,9.8,20,0,-40,,,,\n")
    rec = read_csv(path)
    assert rec.mag.shape == (2, 3) and np.array_equal(rec.mag_t, [0.0, 0.02])
    assert np.isnan(rec.q_true[2]).all()
    path.write_text("t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,q_w,q_x,q_y,q_z\n"
                    "0,0,0,0,0,0,9.8,1,0,0,0\n0.01,,,,0,0,9.8,1,0,0,0\n0.02,0,0,0,0,0,9.8,,,,\n")
    with pytest.raises(InputError, match="field 'q_w', row 2: a truth"):
        read_csv(path)


def test_mat_v5_and_v73(tmp_path):
    import scipy.io

    broad = bundled("broad", "01_undisturbed_slow_rotation_A_excerpt.mat")
    d = {k: v for k, v in scipy.io.loadmat(broad).items()
         if not k.startswith("__") and v.dtype.kind in "biuf"}
    v73 = L.write_mat73(tmp_path / "broad73.mat", d)
    assert detect_format(v73) == "mat" and detect_format(broad) == "broad"
    a, b = read(broad), read(v73)
    for name in ("t", "gyro", "accel", "mag", "q_true", "mask"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    n = 300
    t = np.arange(n) / 100.0
    q, gyro, accel, _ = L.motion(t)
    t_m = np.arange(n // 4) / 25.0
    mag = L.motion(t_m)[3]
    for version in ("5", "7.3"):
        fields = {"time": t, "Gyro": np.rad2deg(gyro).T, "acc": accel / G, "mag": mag,
                  "mag_t": t_m, "quat": q}  # gyro stored 3 x N, deg/s; accel in g
        path = tmp_path / f"log{version}.mat"
        if version == "5":
            scipy.io.savemat(path, {"log": fields})  # inside one struct
        else:
            L.write_mat73(path, fields)
        rec = read(path, gyro_unit="deg/s", accel_unit="g")
        assert rec.meta["version"] == version
        assert np.abs(rec.gyro - gyro).max() < 1e-12 and np.abs(rec.accel - accel).max() < 1e-9
        assert np.array_equal(rec.mag_t, t_m) and rec.q_true.shape == (n, 4)
    with pytest.raises(InputError, match="field 'gyro'.*no gyro"):
        scipy.io.savemat(tmp_path / "none.mat", {"x": np.zeros(3)})
        read(tmp_path / "none.mat")


def test_mat_v5_recognised_by_version_and_endian_bytes_not_the_header_text(tmp_path):
    """The MAT-file spec: version 0x0100 and 'IM'/'MI' at bytes 124-127; the 116-byte text
    is free (Qualisys QTM writes 'QTM_ver ...'). v7.3 keeps its 'MATLAB 7.3' text."""
    import scipy.io

    from gnomon.io.matlab import mat_version

    n = 200
    t = np.arange(n) / 100.0
    q, gyro, accel, _ = L.motion(t)
    path = tmp_path / "qtm_like.mat"
    scipy.io.savemat(path, {"t": t, "gyr": gyro, "acc": accel})
    raw = bytearray(path.read_bytes())
    text = b"QTM_ver 2.10 (build 2084), Level 5 MAT-file, Platform: Windows7"
    raw[:116] = text.ljust(116, b" ")
    path.write_bytes(bytes(raw))
    assert detect_format(path) == "mat"
    rec = read(path)
    assert rec.meta["format"] == "mat" and rec.meta["version"] == "5"
    assert np.abs(rec.gyro - gyro).max() < 1e-12
    assert read(path, format="mat").meta["version"] == "5"
    # a v5 file that is not an IMU recording (a motion-capture export): the mat reader's
    # message naming what is missing, not BROAD's
    mocap = tmp_path / "mocap.mat"
    scipy.io.savemat(mocap, {"qtm": {"Frames": 100.0, "FrameRate": 100.0,
                                     "Timestamp": np.zeros(3)}})
    raw = bytearray(mocap.read_bytes())
    raw[:116] = text.ljust(116, b" ")
    mocap.write_bytes(bytes(raw))
    for fmt in ("auto", "mat"):
        with pytest.raises(InputError, match="field 'gyro'.*no gyro variable") as e:
            read(mocap, format=fmt)
        assert str(mocap) in str(e.value)
    head = bytes(116) + bytes(8)
    assert mat_version(head + b"\x00\x01IM") == "5"
    assert mat_version(head + b"\x01\x00MI") == "5"  # written big-endian
    assert mat_version(head + b"\x00\x02IM") is None  # 0x0200 without the 7.3 text
    assert mat_version(head + b"\x01\x00IM") is None
    assert mat_version(b"MATLAB 7.3 MAT-file".ljust(128, b" ")) == "7.3"
    assert mat_version(b"MATLAB 5.0 MAT-file".ljust(128, b" ")) is None  # no version bytes


def test_mat_qualisys_files_of_the_tyrex_data_set():
    d = tyrex_dir()
    if d is None:
        pytest.skip("tyrex data not found: set GNOMON_TYREX_DIR or put it in "
                    "../shared/data/tyrex")
    f = next(iter(sorted((d / "datasets" / "qualisys").glob("*.mat"))), None)
    if f is None:
        pytest.skip("no Qualisys .mat file in the tyrex data set")
    assert detect_format(f) == "mat"
    with pytest.raises(InputError, match="no gyro variable"):
        read(f)


# ------------------------------------------------------------------ shared machinery
def test_onboard_slerp_is_nan_outside_its_span_and_across_gaps():
    t_src = np.array([0.0, 0.1, 0.2, 1.0, 1.1])
    q = quat_from_rotvec(np.outer(t_src, [0, 0, 1.0]))
    t_dst = np.array([-0.05, 0.0, 0.05, 0.5, 1.05, 1.1, 1.2])
    out = onboard_on("x", "q", t_src, q, t_dst)
    assert np.isnan(out[[0, 3, 6]]).all()  # before, inside the 0.8 s gap, after
    assert np.degrees(error_angle(out[[1, 2, 4, 5]], quat_from_rotvec(
        np.outer(t_dst[[1, 2, 4, 5]], [0, 0, 1.0])))).max() < 1e-9


def test_fast_slerp_equals_the_readable_one():
    from gnomon.io._common import _slerp
    from gnomon.rotation import quat_normalize, quat_slerp

    rng = np.random.default_rng(7)
    q0 = quat_normalize(rng.normal(size=(2000, 4)))
    q1 = quat_normalize(rng.normal(size=(2000, 4)))
    q1[:500] = quat_normalize(q0[:500] + 1e-9 * rng.normal(size=(500, 4)))  # tiny angles
    q1[500:600] = -q1[500:600]
    f = rng.uniform(0, 1, 2000)
    assert np.degrees(error_angle(_slerp(q0, q1, f), quat_slerp(q0, q1, f))).max() < 1e-9


def test_missing_library_is_one_line_naming_the_pip_install(monkeypatch, bags):
    for module, path in (("pyulog", PX4_SMALL), ("pymavlink", AP_BIN), ("rosbags", bags["ros1"])):
        for name in list(sys.modules):
            if name == module or name.startswith(module + "."):
                monkeypatch.delitem(sys.modules, name)
        monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
        with pytest.raises(InputError, match=f"pip install '{module}") as e:
            read(path)
        assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_unknown_options_and_formats(tmp_path):
    with pytest.raises(InputError, match="field 'topic'.*do not apply to dataflash"):
        read(AP_BIN, topic="/imu")
    with pytest.raises(InputError, match="field 'columns'"):
        read(PX4_SMALL, columns={})
    folder = tmp_path / "folder"
    folder.mkdir()
    with pytest.raises(InputError, match="a folder, but not"):
        read(folder)


def test_every_reader_output_survives_the_gnomon_hdf5_round_trip(tmp_path, bags):
    for path in (PX4_SMALL, AP_BIN, bags["mcap"], ANDROID, IOS):
        rec = read(path)
        back = read_recording(write(tmp_path / "r.h5", rec))
        for name in ("t", "gyro", "accel", "accel_t", "mag", "mag_t", "q_onboard", "q_true"):
            x, y = getattr(rec, name), getattr(back, name)
            assert (x is None) == (y is None) and (x is None or np.array_equal(
                x, y, equal_nan=True)), (path.name, name)
        assert back.meta == json.loads(json.dumps(rec.meta))


# ------------------------------------------------------------------ command line
def test_cli_inspect_json_contract_and_convert(tmp_path, capsys, bags):
    for path, n_sensors in ((PX4_SMALL, 3), (AP_BIN, 3), (ANDROID, 3), (bags["ros1"], 3)):
        assert cli.main(["inspect", path, "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        assert len(info["sensors"]) == n_sensors
        for s in info["sensors"]:
            assert {"name", "rate_hz", "samples", "unit"} <= set(s)
            assert s["rate_hz"] > 0 and s["samples"] > 0
        assert info["onboard"] is not None
    assert cli.main(["inspect", PX4_SMALL, "--topic", "vehicle_imu", "--instance", "2"]) == 0
    assert "vehicle_imu" in capsys.readouterr().out
    out = tmp_path / "c.h5"
    assert cli.main(["convert", bags["sqlite3"], out, "--topic", "/other/imu"]) == 0
    assert len(read(out)) == 100
    assert cli.main(["inspect", AP_BIN, "--topic", "x"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "field 'topic'" in err


def test_cli_estimate_passes_topic(capsys, bags):
    code = cli.main(["estimate", bags["ros1"], "--topic", "/other/imu", "--mag-topic", "none",
                     "--filter", "tilt-cf", "--json"])
    assert code == 0
    assert json.loads(capsys.readouterr().out)["samples"] == 100
