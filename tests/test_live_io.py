"""Live I/O on loopback only (127.0.0.1, ports chosen by the system): MAVLink IMU messages
from a sender in the test (HIGHRES_IMU, SCALED_IMU*, RAW_IMU) equal to the batch run on the
samples the messages carry, ATTITUDE_QUATERNION back (``--mavlink-out``) against an
independent frame formula, a serial port on a pseudo-terminal (garbage, partial lines, a
device that vanishes and comes back or not), and the MCAP file read back with ``mcap``."""

import json
import os
import socket
import struct
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import gnomon
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.live import Malformed, open_source, run_live
from gnomon.live.mavlink import MavlinkOutSink, MavlinkSource, enu_flu_to_ned_frd
from gnomon.live.sinks import estimate_rows
from gnomon.recording import Recording

pytest.importorskip("pymavlink")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v10 import all as mavlink1  # noqa: E402
from pymavlink.dialects.v20 import all as mavlink2  # noqa: E402

BROAD = sorted(bundled("broad").glob("*.hdf5"))[0]
#: FLU <-> FRD, written here from the frames' definitions (x kept, y and z reversed)
FLIP = np.array([1.0, -1.0, -1.0])
G0 = 9.80665  # m/s² per g (MAVLink's mG)
#: R_NED_ENU: x_ned = y_enu (north), y_ned = x_enu (east), z_ned = -z_enu
R_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
R_FLU_FRD = np.diag(FLIP)


@pytest.fixture(scope="module")
def rec():
    """1000 gyro samples (3.5 s) of a BROAD trial, with motion."""
    return gnomon.read(BROAD).slice(2000, 3000)


@pytest.fixture(autouse=True)
def pymavlink_globals():
    """pymavlink switches the whole process to MAVLink 2 when it first reads a MAVLink 2
    packet (an environment variable and its module's dialect): undo it after each test."""
    env, module, dialect = os.environ.get("MAVLINK20"), mavutil.mavlink, mavutil.current_dialect
    yield
    if env is None:
        os.environ.pop("MAVLINK20", None)
    else:
        os.environ["MAVLINK20"] = env
    mavutil.mavlink, mavutil.current_dialect = module, dialect


class Collect:
    """A sink that keeps every chunk."""

    def __init__(self):
        self.chunks = []

    def write(self, est, arrivals=None):
        self.chunks.append(est)

    def close(self):
        pass

    def describe(self):
        return {"sink": "collect"}

    @property
    def t(self):
        return np.concatenate([c.t for c in self.chunks])

    @property
    def q(self):
        return np.concatenate([c.q for c in self.chunks])


def _angle(q1, q2):
    """The angle (rad) between two attitudes, sign-safe."""
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def _free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_in_thread(src, sinks, **kw):
    out = {}
    th = threading.Thread(target=lambda: out.update(
        run=run_live(src, gnomon.make_filter("mahony"), sinks, duration_s=60.0, **kw)))
    th.start()
    return th, out


# ---------------------------------------------------------------- what senders send
def _highres(rec, mag_every=1):
    """HIGHRES_IMU fields (FRD, float32; mag in gauss; µs) and the recording the receiver
    must rebuild from them (FLU, float64 of the float32 values, µT). The magnetometer is
    flagged new (fields_updated) on every ``mag_every``-th message only."""
    us = np.round(rec.t * 1e6).astype(np.int64)
    acc = (rec.accel * FLIP).astype(np.float32)
    gyro = (rec.gyro * FLIP).astype(np.float32)
    mag = (rec.mag * FLIP / 100.0).astype(np.float32)
    with_mag = np.arange(len(rec)) % mag_every == 0
    expected = Recording(t=us * 1e-6, gyro=gyro.astype(float) * FLIP,
                         accel=acc.astype(float) * FLIP,
                         mag=mag[with_mag].astype(float) * 100.0 * FLIP,
                         mag_t=(us * 1e-6)[with_mag], mag_unit="uT",
                         frames={"reference": "ENU", "body": "FLU"})

    def fields(k):
        bits = 0x1FF if with_mag[k] else 0x03F
        m = mag[k] if with_mag[k] else np.float32([7.0, 7.0, 7.0])  # stale: not to be used
        return (int(us[k]), *map(float, acc[k]), *map(float, gyro[k]), *map(float, m),
                1013.0, 0.0, 0.0, 20.0, bits | 0x200)

    return fields, expected


def _scaled(rec, time_unit="ms"):
    """SCALED_IMU/RAW_IMU fields (FRD, int16: mG, mrad/s, mgauss; ms or µs) and the
    recording the receiver must rebuild."""
    stamp = np.round(rec.t * (1e3 if time_unit == "ms" else 1e6)).astype(np.int64)
    acc = np.round(rec.accel * FLIP / G0 * 1000.0).astype(np.int16)
    gyro = np.round(rec.gyro * FLIP * 1000.0).astype(np.int16)
    mag = np.round(rec.mag * FLIP * 10.0).astype(np.int16)
    t = stamp * (1e-3 if time_unit == "ms" else 1e-6)
    expected = Recording(t=t, gyro=gyro / 1000.0 * FLIP, accel=acc * G0 / 1000.0 * FLIP,
                         mag=mag / 10.0 * FLIP, mag_unit="uT",
                         frames={"reference": "ENU", "body": "FLU"})

    def fields(k):
        return (int(stamp[k]), *map(int, acc[k]), *map(int, gyro[k]), *map(int, mag[k]))

    return fields, expected


def _other_imu(rec):
    """A second IMU: the same motion with a gyro offset of 0.02 rad/s."""
    import dataclasses

    return dataclasses.replace(rec, gyro=rec.gyro + 0.02)


def _case(name, rec):
    """(URL query, MAVLink version, send(mav, k), the stream chosen, expected recording,
    how many malformed items the stream holds)."""
    if name == "highres":  # MAVLink 1, with noise around it
        fields, expected = _highres(rec, mag_every=2)
        other, _ = _scaled(_other_imu(rec))

        def send(mav, k):
            mav.highres_imu_send(*fields(k))
            if k % 10 == 3:
                mav.scaled_imu2_send(*other(k), 2500)  # another IMU: ignored
            if k % 100 == 7:
                mav.heartbeat_send(2, 3, 0, 0, 4)
                mav.highres_imu_send(*fields(k)[:1], *[float("nan")] * 9, 0, 0, 0, 0, 0x1FF)
                mav.file.write(b"\x00\x01 garbage bytes \x10\x20")
                bad = bytearray(mavlink1.MAVLink_highres_imu_message(*fields(k)).pack(
                    mavlink1.MAVLink(None, 1, 1)))
                bad[20] ^= 0x55  # a payload byte: the checksum fails
                mav.file.write(bytes(bad))
                mav.highres_imu_send(*fields(k)[:14], 0x200)  # only the pressure: no sample

        return "", 1, send, ("HIGHRES_IMU", 0), expected, 3 * len(range(7, len(rec), 100))
    if name == "highres-id":  # MAVLink 2: HIGHRES_IMU's id chooses the IMU
        f0, _ = _highres(_other_imu(rec))
        f1, expected = _highres(rec)

        def send(mav, k):
            mav.highres_imu_send(*f0(k), 0)
            mav.highres_imu_send(*f1(k), 1)

        return "?instance=1", 2, send, ("HIGHRES_IMU", 1), expected, 0
    if name == "scaled":  # ArduPilot: RAW_IMU and SCALED_IMU of IMU 0: the first seen read
        fields, expected = _scaled(rec)
        raw, _ = _scaled(rec, "us")

        def send(mav, k):
            mav.scaled_imu_send(*fields(k))
            mav.raw_imu_send(*raw(k))

        return "", 1, send, ("SCALED_IMU", 0), expected, 0
    if name == "scaled2":
        f0, _ = _scaled(_other_imu(rec))
        f1, expected = _scaled(rec)

        def send(mav, k):
            mav.scaled_imu_send(*f0(k))
            mav.scaled_imu2_send(*f1(k))

        return "?instance=1", 1, send, ("SCALED_IMU2", 1), expected, 0
    assert name == "raw"
    f0, _ = _scaled(_other_imu(rec))
    raw, expected = _scaled(rec, "us")

    def send(mav, k):
        mav.scaled_imu_send(*f0(k))
        mav.raw_imu_send(*raw(k))

    return "?message=RAW_IMU", 1, send, ("RAW_IMU", 0), expected, 0


def _sender(port: int, version: int):
    tx = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1,
                                    source_component=1)
    if version == 2:  # this connection only, not pymavlink's process-wide default
        tx.mav = mavlink2.MAVLink(tx, srcSystem=1, srcComponent=1)
    tx.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)  # the answers
    return tx


def _receive_attitudes(tx, stop: threading.Event, got: list) -> threading.Thread:
    def loop():
        while True:
            m = tx.recv_match(type="ATTITUDE_QUATERNION", blocking=True, timeout=0.2)
            if m is not None:
                got.append(m)
            elif stop.is_set():
                return

    th = threading.Thread(target=loop, daemon=True)
    th.start()
    return th


@pytest.mark.slow(reason="8 s (2 cores): builds and runs the C export")
@pytest.mark.parametrize("case", ["highres", "highres-id", "scaled", "scaled2", "raw"])
def test_mavlink_imu_stream_equals_the_batch_run_and_answers(rec, case):
    """A sender streams IMU messages of a recording (with other IMUs, garbage, a broken
    checksum, NaN and other messages among them); the estimates equal the batch run on
    the samples the chosen messages carry (their units and precision), every malformed
    item is counted, and each estimate comes back as ATTITUDE_QUATERNION."""
    query, version, send, stream, expected, n_bad = _case(case, rec)
    src = open_source(f"mavlink://udpin:127.0.0.1:0{query}", give_up_s=1.0)
    host, port = src.address
    assert host == "127.0.0.1" and port > 0
    collect = Collect()
    th, result = _run_in_thread(src, [collect, MavlinkOutSink(src)])
    tx = _sender(port, version)
    got, stop = [], threading.Event()
    rx = _receive_attitudes(tx, stop, got)
    for k in range(len(rec)):
        send(tx.mav, k)
        if k % 10 == 9:
            time.sleep(0.001)  # a sender at a few kHz, not a flood
    th.join(timeout=60)
    stop.set()
    rx.join(timeout=5)
    run = result["run"]

    # the estimates: the batch run on the samples the messages carry
    ref = gnomon.make_filter("mahony").run(expected)
    assert run.samples == len(rec) and run.dropped == 0, run.to_dict()
    assert run.malformed == n_bad, run.malformed_reasons
    assert run.ended_by == "end of stream: no MAVLink message for 1 s"
    assert src.stream == stream and stream[0] in " ".join(src.assumed)
    np.testing.assert_array_equal(collect.t, expected.t)
    assert _angle(collect.q, ref.q).max() < 1e-9

    # ATTITUDE_QUATERNION: q_NED_FRD, time_boot_ms, the gyro less the bias (FRD)
    assert len(got) == len(rec)
    ms = np.array([m.time_boot_ms for m in got])
    np.testing.assert_array_equal(ms, np.round(expected.t * 1000).astype(np.int64))
    q_mav = np.array([[m.q1, m.q2, m.q3, m.q4] for m in got])  # w, x, y, z
    R_got = Rotation.from_quat(q_mav[:, [1, 2, 3, 0]]).as_matrix()
    R_want = R_NED_ENU @ Rotation.from_quat(ref.q[:, [1, 2, 3, 0]]).as_matrix() @ R_FLU_FRD
    assert np.abs(R_got - R_want).max() < 1e-6  # float32 on the wire
    rates = np.array([[m.rollspeed, m.pitchspeed, m.yawspeed] for m in got])
    want = (expected.gyro - ref.signals["bias_rad_s"]) * FLIP
    np.testing.assert_allclose(rates, want, rtol=1e-6, atol=1e-7)


def _packets(fields, n, version=1) -> list[bytes]:
    mod = mavlink1 if version == 1 else mavlink2
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    return [bytes(mod.MAVLink_highres_imu_message(*fields(k)).pack(mav)) for k in range(n)]


def test_mavlink_udpout_and_tcp_client_links(rec):
    """``udpout:`` sends a HEARTBEAT so the vehicle (a plain socket here) knows where to
    answer; ``tcp:`` connects to a server; both read the IMU stream, and a TCP server that
    goes away ends the run in one line."""
    part = rec.slice(0, 300)
    fields, expected = _highres(part)
    packets = _packets(fields, len(part))
    ref = gnomon.make_filter("mahony").run(expected)

    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(10.0)
    src = open_source(f"mavlink://udpout:127.0.0.1:{vehicle.getsockname()[1]}", give_up_s=0.5)
    hello, gnomon_at = vehicle.recvfrom(1024)
    assert mavlink2.MAVLink(None).decode(bytearray(hello)).get_type() == "HEARTBEAT"
    collect = Collect()
    th, result = _run_in_thread(src, [collect])
    for k, packet in enumerate(packets):
        vehicle.sendto(packet, gnomon_at)
        if k % 10 == 9:
            time.sleep(0.001)
    th.join(timeout=60)
    vehicle.close()
    assert result["run"].samples == len(part)
    assert _angle(collect.q, ref.q).max() < 1e-9

    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    src = open_source(f"mavlink://tcp:127.0.0.1:{server.getsockname()[1]}", give_up_s=0.5)
    conn, _ = server.accept()
    server.close()  # no reconnecting to it
    collect = Collect()
    th, result = _run_in_thread(src, [collect])
    for k in range(0, len(packets), 10):
        conn.sendall(b"".join(packets[k:k + 10]))
        time.sleep(0.001)
    time.sleep(0.3)
    conn.close()
    th.join(timeout=60)
    run = result["run"]
    assert run.samples == len(part) and run.malformed == 0
    assert "lost and not back after 0.5 s" in run.ended_by
    assert _angle(collect.q, ref.q).max() < 1e-9


def test_mavlink_message_units_and_frames_one_by_one():
    """A level vehicle at rest facing north, as MAVLink senders put it: FRD accelerometer
    -g on z, the field north and down; gnomon's samples are FLU (+g up), SI, µT."""
    src = MavlinkSource("mavlink://udpin:127.0.0.1:0")
    m = mavutil.mavlink
    hi = src.samples(m.MAVLink_highres_imu_message(
        1_500_000, 0.0, 0.0, -9.81, 0.01, -0.02, 0.03, 0.2, 0.0, 0.45, 0, 0, 0, 0, 0x1FF))
    assert [s[0] for s in hi] == ["accel", "mag", "gyro"]  # the gyro last (parse.py)
    assert all(s[1] == pytest.approx(1.5, abs=1e-12) for s in hi)
    np.testing.assert_allclose(hi[0][2], [0.0, 0.0, 9.81])
    np.testing.assert_allclose(hi[1][2], [20.0, 0.0, -45.0])  # µT: north, up = -down
    np.testing.assert_allclose(hi[2][2], [0.01, 0.02, -0.03])
    only_gyro = src.samples(m.MAVLink_highres_imu_message(
        2_000_000, 1, 2, 3, 0.1, 0.2, 0.3, 4, 5, 6, 0, 0, 0, 0, 0x038))
    assert [s[0] for s in only_gyro] == ["gyro"]
    sc = src.samples(m.MAVLink_scaled_imu_message(2500, 0, 0, -1000, 10, 20, -30, 200, 0,
                                                  450))
    assert sc[0][1] == 2.5
    np.testing.assert_allclose(sc[0][2], [0.0, 0.0, G0])
    np.testing.assert_allclose(sc[1][2], [20.0, 0.0, -45.0])
    np.testing.assert_allclose(sc[2][2], [0.01, -0.02, 0.03])
    no_compass = src.samples(m.MAVLink_raw_imu_message(3_000_000, 0, 0, -1000, 1, 2, 3, 0, 0,
                                                       0))
    assert [s[0] for s in no_compass] == ["accel", "gyro"] and no_compass[0][1] == 3.0
    with pytest.raises(Malformed, match="not finite"):
        src.samples(m.MAVLink_highres_imu_message(1, *[float("nan")] * 3, *[0.0] * 10, 0x1FF))
    with pytest.raises(Malformed, match="garbage"):
        src.samples(m.MAVLink_bad_data(b"\x00\x01", "Bad prefix"))
    with pytest.raises(Malformed, match="checksum"):
        src.samples(m.MAVLink_bad_data(b"\xfe\x01", "invalid MAVLink CRC in msgID 105"))


def test_mavlink_urls_listen_on_loopback_and_refuse_bad_options():
    assert MavlinkSource("mavlink://udpin:14550").device == "udpin:127.0.0.1:14550"
    assert MavlinkSource("mavlink://udpin::14550").device == "udpin:127.0.0.1:14550"
    assert MavlinkSource("mavlink://udpin:0.0.0.0:14550").device == "udpin:0.0.0.0:14550"
    dev = MavlinkSource("mavlink:///dev/ttyACM0?baud=57600&instance=2")
    assert (dev.device, dev.baud, dev.instance, dev.out_hz) == ("/dev/ttyACM0", 57600, 2, 50.0)
    for bad in ("mavlink://udpin:127.0.0.1:port", "mavlink://udpin:1:70000",
                "mavlink://udpin:1:14550?bogus=1", "mavlink://udpin:1:14550?message=GPS",
                "mavlink://", "mavlink:///dev/x?baud=fast"):
        with pytest.raises(InputError):
            MavlinkSource(bad)
    with pytest.raises(InputError, match="cannot open"):
        open_source("mavlink:///dev/gnomon-no-such-device")


def test_attitude_quaternion_frames_round_trip_and_north_facing_is_identity():
    """gnomon's q_ENU_FLU to MAVLink's q_NED_FRD, against scipy's matrices; a level body
    facing north is the identity in NED/FRD; the readers' conversion undoes it."""
    from gnomon.io._common import ned_frd_to_enu_flu

    q = Rotation.random(200, random_state=3).as_quat()[:, [3, 0, 1, 2]]
    q_ned = enu_flu_to_ned_frd(q)
    want = R_NED_ENU @ Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix() @ R_FLU_FRD
    got = Rotation.from_quat(q_ned[:, [1, 2, 3, 0]]).as_matrix()
    assert np.abs(got - want).max() < 1e-12
    assert _angle(ned_frd_to_enu_flu(q_ned), q).max() < 1e-12
    north = Rotation.from_euler("z", 90, degrees=True).as_quat()[[3, 0, 1, 2]]  # FLU x north
    assert _angle(enu_flu_to_ned_frd(north)[None], np.array([[1.0, 0, 0, 0]]))[0] < 1e-12
    # and the identity in ENU/FLU (facing east) is yaw 90° in NED
    east = Rotation.from_quat(enu_flu_to_ned_frd([1.0, 0, 0, 0])[[1, 2, 3, 0]])
    np.testing.assert_allclose(east.as_euler("ZYX", degrees=True), [90.0, 0.0, 0.0],
                               atol=1e-9)


# ---------------------------------------------------------------- serial (a pseudo-terminal)
def _line(rec, k) -> bytes:
    row = [rec.t[k], *rec.gyro[k], *rec.accel[k], *rec.mag[k]]
    return (",".join(repr(float(x)) for x in row) + "\n").encode()


HEADER = b"t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n"


def _write_slowly(fd, data: bytes, pieces: int = 2):
    """``data`` in ``pieces`` writes: lines arrive cut in parts, as from a serial port."""
    step = max(1, len(data) // pieces)
    for i in range(0, len(data), step):
        os.write(fd, data[i:i + step])


def test_serial_lines_with_garbage_and_a_device_that_vanishes(rec):
    """CSV lines through a pseudo-terminal, cut in pieces, with garbage bytes (a run longer
    than a line can be, binary bytes, wrong field counts, NaN) among them: every sample
    estimated as the batch run, each bad item counted once; the device vanishes (its
    master closed): waited for, then the run ends saying so in one line."""
    master, slave = os.openpty()
    try:
        src = open_source(f"serial://{os.ttyname(slave)}?baud=115200", give_up_s=0.5)
        collect = Collect()
        th, result = _run_in_thread(src, [collect])
        os.write(master, HEADER)
        bad = 0
        for k in range(len(rec)):
            _write_slowly(master, _line(rec, k), pieces=3)
            if k % 150 == 20:
                os.write(master, b"\x01\x02 binary \xff\xfe garbage without an end " * 200)
                os.write(master, b",9,9\n")  # its end: one item, not two
                os.write(master, b"\xff\xfe\x00\n1,2,3\n1,2,3,4,5,6,7,8,9,10,11\n")
                os.write(master, b"0.5,nan,1,2,3,4,5,6,7,8\n")
                bad += 5
            if k % 25 == 0:
                time.sleep(0.002)
        time.sleep(0.3)
        os.write(master, b"1.0,2.0,3")  # a partial line, then the device is gone
        time.sleep(0.2)
        os.close(master)
        master = None
        th.join(timeout=60)
    finally:
        if master is not None:
            os.close(master)
        os.close(slave)
    run = result["run"]
    ref = gnomon.make_filter("mahony").run(rec)
    assert run.samples == len(rec) and run.dropped == 0
    assert run.malformed == bad + 1, run.malformed_reasons
    assert run.malformed_reasons["a line longer than 4096 bytes"] == bad // 5
    assert run.malformed_reasons["a partial line (the device vanished)"] == 1
    assert run.ended_by.startswith("end of stream: /dev/") and "vanished" in run.ended_by
    np.testing.assert_array_equal(collect.t, rec.t)
    assert _angle(collect.q, ref.q).max() < 1e-12


def test_a_serial_device_that_comes_back_is_reopened(rec, tmp_path):
    """The device (a link, as /dev/serial/by-id/ has) vanishes mid-stream and reappears
    as another pseudo-terminal: the source reopens it and the run goes on; the line it cut
    is counted; the estimates are the batch run's."""
    link = tmp_path / "ttyGNOMON"
    m1, s1 = os.openpty()
    os.symlink(os.ttyname(s1), link)
    half = len(rec) // 2
    src = open_source(f"serial://{link}?baud=57600", give_up_s=5.0)
    src.retry_s = 0.05
    collect = Collect()
    th, result = _run_in_thread(src, [collect])
    os.write(m1, HEADER)
    for k in range(half):
        os.write(m1, _line(rec, k))
        if k % 25 == 0:
            time.sleep(0.002)
    os.write(m1, _line(rec, half)[:12])  # cut by the unplugging
    time.sleep(0.3)
    os.close(m1)
    os.close(s1)
    deadline = time.time() + 10
    while src.lost_at is None and time.time() < deadline:
        time.sleep(0.01)
    m2, s2 = os.openpty()
    tmp = tmp_path / "new"
    os.symlink(os.ttyname(s2), tmp)
    os.replace(tmp, link)  # plugged in again
    while src.reconnects == 0 and time.time() < deadline:
        time.sleep(0.01)
    assert src.reconnects == 1
    try:
        for k in range(half, len(rec)):
            os.write(m2, _line(rec, k))
            if k % 25 == 0:
                time.sleep(0.002)
        time.sleep(0.3)
        src.give_up_s = 0.3
        os.close(m2)
        th.join(timeout=60)
    finally:
        os.close(s2)
    run = result["run"]
    ref = gnomon.make_filter("mahony").run(rec)
    assert run.samples == len(rec) and run.malformed == 1, run.malformed_reasons
    assert "(1 reconnects before)" in run.ended_by
    np.testing.assert_array_equal(collect.t, rec.t)
    assert _angle(collect.q, ref.q).max() < 1e-12


def test_mavlink_on_a_serial_device(rec):
    """MAVLink packets (and garbage) through a pseudo-terminal: ``mavlink://DEVICE?baud=N``
    reads them; the device vanishes and the run ends in one line."""
    part = rec.slice(0, 400)
    fields, expected = _highres(part)
    packets = _packets(fields, len(part))
    master, slave = os.openpty()
    try:
        src = open_source(f"mavlink://{os.ttyname(slave)}?baud=57600", give_up_s=0.5)
        assert src.out_hz == 50.0  # a serial link: the answers rate-limited by default
        collect = Collect()
        th, result = _run_in_thread(src, [collect])
        for k, packet in enumerate(packets):
            _write_slowly(master, packet, pieces=2)
            if k == 200:
                os.write(master, b"\x00\x01\x02 line noise \x03")
            if k % 20 == 0:
                time.sleep(0.002)
        time.sleep(0.3)
        os.close(master)
        master = None
        th.join(timeout=60)
    finally:
        if master is not None:
            os.close(master)
        os.close(slave)
    run = result["run"]
    ref = gnomon.make_filter("mahony").run(expected)
    assert run.samples == len(part) and run.malformed == 1
    assert "lost and not back" in run.ended_by
    np.testing.assert_array_equal(collect.t, expected.t)
    assert _angle(collect.q, ref.q).max() < 1e-9


# ---------------------------------------------------------------- MCAP
def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, i


def _wire(buf: bytes) -> list:
    """Protobuf's wire format: ``[(field number, wire type, value)]``."""
    i, out = 0, []
    while i < len(buf):
        key, i = _varint(buf, i)
        num, kind = key >> 3, key & 7
        if kind == 0:
            v, i = _varint(buf, i)
        elif kind == 1:
            v, i = struct.unpack_from("<d", buf, i)[0], i + 8
        elif kind == 2:
            n, i = _varint(buf, i)
            v, i = bytes(buf[i:i + n]), i + n
        elif kind == 5:
            v, i = struct.unpack_from("<f", buf, i)[0], i + 4
        else:
            raise ValueError(f"wire type {kind}")
        out.append((num, kind, v))
    return out


def _descriptors(file_descriptor_set: bytes) -> dict:
    """``{".package.Message": {field number: (name, type name or None)}}`` from a
    FileDescriptorSet (descriptor.proto's numbers: set.file 1; file.package 2, message_type
    4; message.name 1, field 2; field.name 1, number 3, type_name 6)."""
    out = {}
    for num, _, f in _wire(file_descriptor_set):
        if num != 1:
            continue
        parts = _wire(f)
        package = next((v.decode() for n, _, v in parts if n == 2), "")
        for n, _, msg in parts:
            if n != 4:
                continue
            m = _wire(msg)
            name = next(v.decode() for k, _, v in m if k == 1)
            fields = {}
            for k, _, fld in m:
                if k == 2:
                    d = {a: v for a, _, v in _wire(fld)}
                    fields[d[3]] = (d[1].decode(), d[6].decode() if 6 in d else None)
            out[f".{package}.{name}"] = fields
    return out


def _decode(types: dict, name: str, buf: bytes) -> dict:
    """A message as a dict (proto3: fields at their default are absent)."""
    out = {}
    for num, _, v in _wire(buf):
        field, sub = types[name][num]
        out[field] = _decode(types, sub, v) if sub in types else \
            v.decode() if isinstance(v, bytes) else v
    return out


def _read_mcap(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = {}
        for schema, channel, message in reader.iter_messages():
            msgs.setdefault(channel.topic, []).append((schema, channel, message))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    return summary, msgs, meta


def _quat(d: dict) -> np.ndarray:
    return np.array([d.get("w", 0.0), d.get("x", 0.0), d.get("y", 0.0), d.get("z", 0.0)])


def test_mcap_round_trip_with_foxglove_schemas(rec, tmp_path):
    """The estimates in chunks into an MCAP file; read back with ``mcap`` and decoded from
    the file's own schemas: the pose and transform quaternions, the stamps (the estimate's
    t) and the JSON state equal the estimate."""
    from gnomon.live.mcap import McapSink
    from gnomon.live.runner import _head

    pytest.importorskip("foxglove")
    est = gnomon.make_filter("mahony").run(rec)
    path = tmp_path / "live.mcap"
    path.write_bytes(b"an old file")  # replaced, as --out replaces
    sink = McapSink(path)
    start = 0
    for size in (101, 1, 7, 300, len(rec)):  # chunks as the live loop makes them
        stop = min(len(rec), start + size)
        part = _head(est, stop)
        sink.write(type(est)(t=part.t[start:], q=part.q[start:], estimator=est.estimator,
                             params=est.params, frames=est.frames,
                             signals={k: v[start:] for k, v in part.signals.items()}))
        start = stop
    sink.close()
    assert sink.describe()["rows"] == len(rec)

    summary, msgs, meta = _read_mcap(path)
    if sink.metadata_written:  # foxglove-sdk 0.10 writes no metadata records
        assert meta["gnomon"]["reference_frame"] == "enu"
    n = len(rec)
    assert {t: len(v) for t, v in msgs.items()} == {"/gnomon/pose": n, "/gnomon/transform": n,
                                                    "/gnomon/state": n}
    ns = np.round(est.t * 1e9).astype(np.int64)
    pick = [0, 1, 100, 101, 500, n - 1]
    for topic, schema_name in (("/gnomon/pose", "foxglove.PoseInFrame"),
                               ("/gnomon/transform", "foxglove.FrameTransform")):
        schema, channel, _ = msgs[topic][0]
        assert schema.name == schema_name and schema.encoding == "protobuf"
        assert channel.message_encoding == "protobuf"
        types = _descriptors(schema.data)
        assert [m.log_time for _, _, m in msgs[topic]] == ns.tolist()
        for k in pick:
            message = msgs[topic][k][2]
            d = _decode(types, "." + schema_name, message.data)
            stamp = d.get("timestamp", {})
            assert stamp.get("seconds", 0) * 10**9 + stamp.get("nanos", 0) == ns[k]
            if topic == "/gnomon/pose":
                assert d["frame_id"] == "enu"
                assert d["pose"].get("position", {}) == {}  # all zero
                q = _quat(d["pose"]["orientation"])
            else:
                assert (d["parent_frame_id"], d["child_frame_id"]) == ("enu", "body")
                q = _quat(d["rotation"])
            np.testing.assert_array_equal(q, est.q[k])
    schema, channel, _ = msgs["/gnomon/state"][0]
    assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
    props = json.loads(schema.data)["properties"]
    assert props["acc_skipped"] == {"type": "boolean"} and props["bias_rad_s"]["type"] == "array"
    rows = list(estimate_rows(est))
    for k in pick:
        assert json.loads(msgs["/gnomon/state"][k][2].data) == rows[k]


def test_mcap_of_a_stream_that_starts_before_zero(tmp_path):
    from gnomon.live.mcap import McapSink

    pytest.importorskip("foxglove")
    rec = gnomon.read(BROAD).slice(0, 300)
    import dataclasses

    est = gnomon.make_filter("mahony").run(dataclasses.replace(rec, t=rec.t - 0.5))
    sink = McapSink(tmp_path / "neg.mcap")
    sink.write(est)
    sink.close()
    _, msgs, meta = _read_mcap(tmp_path / "neg.mcap")
    times = [m.log_time for _, _, m in msgs["/gnomon/pose"]]
    assert times[0] == 0 and np.all(np.diff(times) > 0)
    assert sink.describe()["time_offset_s"] == 0.5
    if sink.metadata_written:
        assert float(meta["gnomon"]["time_offset_s"]) == 0.5


# ---------------------------------------------------------------- the command
def test_gnomon_live_mavlink_with_mavlink_out_and_mcap(rec, tmp_path, capsys):
    """``gnomon live mavlink://udpin:... --mavlink-out --mcap FILE --max-samples N --json``:
    the sender hears ATTITUDE_QUATERNION, the MCAP file holds N poses, the summary says
    which sinks wrote what."""
    from gnomon.cli import main

    port = _free_port()
    fields, _ = _highres(rec)
    n = 600
    stop, heard = threading.Event(), []

    def sender():
        tx = _sender(port, 1)
        rounds = 0
        while not stop.is_set():  # until the command listens and has estimated n
            for k in range(len(rec)):
                f = fields(k)
                tx.mav.highres_imu_send(f[0] + rounds * 10_000_000, *f[1:])
                if k % 10 == 9:
                    time.sleep(0.001)
                    while (m := tx.recv_match(type="ATTITUDE_QUATERNION")) is not None:
                        heard.append(m)
                if stop.is_set():
                    break
            rounds += 1
        while (m := tx.recv_match(type="ATTITUDE_QUATERNION", blocking=True,
                                  timeout=0.3)) is not None:
            heard.append(m)

    th = threading.Thread(target=sender, daemon=True)
    th.start()
    mcap_path = tmp_path / "live.mcap"
    try:
        code = main(["live", f"mavlink://udpin:127.0.0.1:{port}", "--filter", "mahony",
                     "--mavlink-out", "--mcap", str(mcap_path), "--max-samples", str(n),
                     "--duration", "60", "--json"])
    finally:
        stop.set()
        th.join(timeout=10)
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["samples"] == n and summary["ended_by"] == "max samples"
    sinks = {s["sink"]: s for s in summary["sinks"]}
    assert sinks["mavlink"]["sent"] == n and sinks["mcap"]["rows"] == n
    assert len(heard) == n
    _, msgs, _ = _read_mcap(mcap_path)
    assert len(msgs["/gnomon/pose"]) == n
