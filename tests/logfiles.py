"""Log files made with each format's own writer (or its documented layout) for the reader tests.

One known motion for all of them (``motion``): a body turning about a fixed tilted axis at a
constant rate, so each file's gyro, accelerometer, magnetometer and the device's own attitude
are consistent by construction, and every reader's frames can be checked against it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

G = 9.80665
MAG_ENU_UT = np.array([0.0, 22.0, -42.0])  # a northern-hemisphere field, µT
Q0 = quat_from_rotvec(np.array([0.3, -0.2, 0.5]))  # q_ENU_body at t = 0
W_BODY = np.array([0.4, -0.3, 0.6])  # rad/s, constant, in body axes


def motion(t: np.ndarray):
    """Truth at times ``t`` (s): ``q_ENU_body`` (N, 4), gyro (N, 3) rad/s, specific force
    (N, 3) m/s², magnetic field (N, 3) µT, all in body axes (FLU-like, +g up at rest)."""
    t = np.asarray(t, dtype=float)
    q = quat_mul(Q0, quat_from_rotvec(t[:, None] * W_BODY))
    gyro = np.tile(W_BODY, (t.size, 1))
    accel = quat_rotate(quat_conj(q), np.array([0.0, 0.0, G]))
    mag = quat_rotate(quat_conj(q), MAG_ENU_UT)
    return q, gyro, accel, mag


def write_rosbags(tmp: Path, *, imu_hz=200.0, mag_hz=50.0, seconds=2.0, t0=100.0,
                  extra_imu_topic=False) -> dict[str, Path]:
    """A ROS 1 ``.bag``, a ROS 2 sqlite3 bag and a ROS 2 mcap bag (rosbags' own writers)
    with ``/imu/data`` (sensor_msgs/Imu at ``imu_hz``, orientation filled) and ``/imu/mag``
    (MagneticField at ``mag_hz``, tesla). Returns ``{"ros1", "sqlite3", "mcap"}`` paths."""
    t_i = t0 + np.arange(int(seconds * imu_hz)) / imu_hz
    t_m = t0 + 0.0013 + np.arange(int(seconds * mag_hz)) / mag_hz
    q, gyro, accel, _ = motion(t_i - t0)
    _, _, _, mag = motion(t_m - t0)
    out = {}
    for kind in ("ros1", "sqlite3", "mcap"):
        out[kind] = _write_bag(tmp, kind, t_i, t_m, q, gyro, accel, mag, extra_imu_topic)
    return out


def write_ros1_bag(tmp: Path, *, imu_hz=200.0, mag_hz=50.0, seconds=2.0, t0=100.0,
                   mag_nan=0, orientation=None, cov0=0.0) -> Path:
    """One ROS 1 ``.bag`` as :func:`write_rosbags` makes it, imperfect on request: the first
    ``mag_nan`` MagneticField messages NaN (a driver before its magnetometer is up, as in
    imu_tools' ``phidgets_imu_upside_down.bag``), ``orientation`` a constant ``[w, x, y,
    z]`` in every Imu message instead of the motion's (a raw driver's placeholder, as on
    ``/imu/data_raw`` of ``sparkfun_razor.bag``) and ``orientation_covariance[0] = cov0``."""
    t_i = t0 + np.arange(int(seconds * imu_hz)) / imu_hz
    t_m = t0 + 0.0013 + np.arange(int(seconds * mag_hz)) / mag_hz
    q, gyro, accel, _ = motion(t_i - t0)
    _, _, _, mag = motion(t_m - t0)
    mag[:mag_nan] = np.nan
    if orientation is not None:
        q = np.tile(np.asarray(orientation, dtype=float), (t_i.size, 1))
    return _write_bag(tmp, "ros1", t_i, t_m, q, gyro, accel, mag, False, cov0=cov0)


def _write_bag(tmp, kind, t_i, t_m, q, gyro, accel, mag, extra_imu_topic, cov0=0.0):
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    Imu = store.types["sensor_msgs/msg/Imu"]
    Mag = store.types["sensor_msgs/msg/MagneticField"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    V3 = store.types["geometry_msgs/msg/Vector3"]
    Q = store.types["geometry_msgs/msg/Quaternion"]

    def header(t, frame, seq):
        sec = int(math.floor(t))
        stamp = Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))
        if kind == "ros1":
            return Header(seq=seq, stamp=stamp, frame_id=frame)
        return Header(stamp=stamp, frame_id=frame)

    def imu_msg(k):
        return Imu(header=header(t_i[k], "imu_link", k),
                   orientation=Q(x=q[k, 1], y=q[k, 2], z=q[k, 3], w=q[k, 0]),
                   orientation_covariance=np.array([cov0] + [0.0] * 8),
                   angular_velocity=V3(x=gyro[k, 0], y=gyro[k, 1], z=gyro[k, 2]),
                   angular_velocity_covariance=np.zeros(9),
                   linear_acceleration=V3(x=accel[k, 0], y=accel[k, 1], z=accel[k, 2]),
                   linear_acceleration_covariance=np.zeros(9))

    def mag_msg(k):
        return Mag(header=header(t_m[k], "imu_link", k),
                   magnetic_field=V3(x=mag[k, 0] * 1e-6, y=mag[k, 1] * 1e-6,
                                     z=mag[k, 2] * 1e-6),
                   magnetic_field_covariance=np.zeros(9))

    events = sorted([(t, 0, k) for k, t in enumerate(t_i)] +
                    [(t, 1, k) for k, t in enumerate(t_m)])
    if kind == "ros1":
        path = tmp / "imu.bag"
        writer = Writer1(path)
        ser = store.serialize_ros1
    else:
        path = tmp / f"bag_{kind}"
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(path, version=8, storage_plugin=plugin)
        ser = store.serialize_cdr
    with writer:
        c_imu = writer.add_connection("/imu/data", Imu.__msgtype__, typestore=store)
        c_mag = writer.add_connection("/imu/mag", Mag.__msgtype__, typestore=store)
        c_x = None
        if extra_imu_topic:
            c_x = writer.add_connection("/other/imu", Imu.__msgtype__, typestore=store)
        for t, which, k in events:
            stamp_ns = int(round((t + 0.002) * 1e9))  # received 2 ms later
            if which == 0:
                writer.write(c_imu, stamp_ns, ser(imu_msg(k), Imu.__msgtype__))
                if c_x is not None and k % 4 == 0:
                    writer.write(c_x, stamp_ns, ser(imu_msg(k), Imu.__msgtype__))
            else:
                writer.write(c_mag, stamp_ns, ser(mag_msg(k), Mag.__msgtype__))
    return path


def _times(rate_hz: float, seconds: float, start: float = 0.0, jitter: float = 0.0,
           seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = start + np.arange(int(seconds * rate_hz)) / rate_hz
    return t + rng.uniform(0, jitter, t.size) if jitter else t


def write_sensorlogger(dst: Path, *, platform="android", zipped=True, seconds=2.0,
                       standardised=False) -> Path:
    """A Sensor Logger export from its documented layout (awesome-sensor-logger UNITS.md,
    COORDINATES.md): ``time`` ns since the epoch, ``seconds_elapsed``, columns ``z,y,x``;
    gyro 100 Hz, accelerometer 100 Hz (other time stamps), magnetometer 50 Hz,
    orientation 50 Hz (``qz,qy,qx,qw,roll,pitch,yaw``). iOS: AccelerometerUncalibrated in g
    with iOS's sign; Android: TotalAcceleration in m/s^2."""
    import zipfile

    from gnomon.io._common import Q_ENU_NWU

    epoch_ns = 1_700_000_000_000_000_000
    files = {}

    def table(name, t, cols, values):
        lines = ["time,seconds_elapsed," + ",".join(cols)]
        for ti, v in zip(t, values, strict=True):
            lines.append(f"{epoch_ns + int(round(ti * 1e9))},{ti:.9f}," +
                         ",".join(f"{x:.9g}" for x in v))
        files[name] = "\n".join(lines) + "\n"

    t_g, t_a, t_m, t_q = (_times(100, seconds, 0.0), _times(100, seconds, 0.004),
                          _times(50, seconds, 0.007), _times(50, seconds, 0.001))
    _, gyro, _, _ = motion(t_g)
    _, _, accel, _ = motion(t_a)
    _, _, _, mag = motion(t_m)
    q, _, _, _ = motion(t_q)
    table("Gyroscope.csv", t_g, ["z", "y", "x"], gyro[:, ::-1])
    table("Magnetometer.csv", t_m, ["z", "y", "x"], mag[:, ::-1])
    if platform == "android":
        table("TotalAcceleration.csv", t_a, ["z", "y", "x"], accel[:, ::-1])
        q_file = q
    else:
        a = accel if standardised else accel / -G
        table("AccelerometerUncalibrated.csv", t_a, ["z", "y", "x"], a[:, ::-1])
        q_file = quat_mul(quat_conj(Q_ENU_NWU), q)  # CoreMotion: relative to x-north z-up
    table("Accelerometer.csv", t_a, ["z", "y", "x"], np.zeros_like(accel))  # no gravity
    rpy = np.zeros((t_q.size, 3))
    table("Orientation.csv", t_q, ["qz", "qy", "qx", "qw", "roll", "pitch", "yaw"],
          np.column_stack([q_file[:, 3], q_file[:, 2], q_file[:, 1], q_file[:, 0], rpy]))
    files["Metadata.csv"] = ("version,device name,recording epoch time,recording time,"
                             "recording timezone,platform,appVersion,device id,sensors,"
                             "sampleRateMs,standardisation,platform version\n"
                             f"3,Test Phone,{epoch_ns // 10**6},2023-11-14_22-13-20,UTC,"
                             f"{platform},1.30.0,abc,Gyroscope|Accelerometer,10,"
                             f"{'true' if standardised else 'false'},14\n")
    if zipped:
        path = dst / "sensorlogger.zip"
        with zipfile.ZipFile(path, "w") as z:
            for name, text in files.items():
                z.writestr(f"2023-11-14_22-13-20/{name}", text)
        return path
    path = dst / "sensorlogger"
    path.mkdir(exist_ok=True)
    for name, text in files.items():
        (path / name).write_text(text)
    return path


def write_phyphox(dst: Path, *, zipped=True, seconds=2.0, delimiter=",") -> Path:
    """A phyphox CSV export from its documented layout: one CSV per sensor, header
    ``"Time (s)","Acceleration x (m/s^2)",...`` (gyroscope 200 Hz, accelerometer 100 Hz,
    magnetometer 50 Hz); ``delimiter=";"`` writes phyphox's decimal-comma variant."""
    import zipfile

    sets = {"Accelerometer.csv": ("Acceleration {} (m/s^2)", _times(100, seconds, 0.002), 2),
            "Gyroscope.csv": ("Gyroscope {} (rad/s)", _times(200, seconds, 0.0), 1),
            "Magnetometer.csv": ("Magnetic field {} (µT)", _times(50, seconds, 0.003), 3),
            "Linear Acceleration.csv": ("Linear Acceleration {} (m/s^2)",
                                        _times(100, seconds), 2)}
    files = {}
    for name, (label, t, k) in sets.items():
        v = motion(t)[k]
        if name.startswith("Linear"):
            v = np.zeros_like(v)
        head = ['"Time (s)"'] + [f'"{label.format(a)}"' for a in "xyz"]
        lines = [delimiter.join(head)]
        for ti, row in zip(t, v, strict=True):
            cells = [f"{ti:.9E}"] + [f"{x:.9E}" for x in row]
            if delimiter == ";":
                cells = [c.replace(".", ",") for c in cells]
            lines.append(delimiter.join(cells))
        files[name] = "\n".join(lines) + "\n"
    files["meta/device.csv"] = '"property","value"\n"deviceModel","Test"\n'
    if zipped:
        path = dst / "phyphox.zip"
        with zipfile.ZipFile(path, "w") as z:
            for name, text in files.items():
                z.writestr(name, text)
        return path
    path = dst / "phyphox"
    (path / "meta").mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (path / name).write_text(text)
    return path


def write_xsens(dst: Path, *, seconds=2.0, system="ENU", empty="") -> Path:
    """An MT Manager text export from its documented layout: ``//`` header lines, a tab-
    separated table with PacketCounter, SampleTimeFine (10 kHz), Acc/Gyr at 100 Hz,
    Mag at 25 Hz (other rows empty, or ``empty="NaN"``), Quat_q0..q3 (``q_LS``)."""
    from gnomon.io._common import Q_ENU_NED, Q_ENU_NWU, Q_FRD_FLU, frd_to_flu

    t = _times(100, seconds)
    q, gyro, accel, mag = motion(t)
    if system == "NED":
        q = quat_mul(quat_mul(quat_conj(Q_ENU_NED), q), quat_conj(Q_FRD_FLU))
        gyro, accel, mag = frd_to_flu(gyro), frd_to_flu(accel), frd_to_flu(mag)
    elif system == "NWU":
        q = quat_mul(quat_conj(Q_ENU_NWU), q)
    lines = ["// General information:", "//  MT Manager version: 2022.2.0",
             "// Device information:", "//  DeviceId: 00B42D4F", "//  ProductCode: MTi-630",
             "// Device settings:", "//  Filter Profile: general", "// Update Rate: 100.0Hz",
             f"// Coordinate system: {system}",
             "\t".join(["PacketCounter", "SampleTimeFine", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X",
                        "Gyr_Y", "Gyr_Z", "Mag_X", "Mag_Y", "Mag_Z", "Quat_q0", "Quat_q1",
                        "Quat_q2", "Quat_q3"])]
    start = 2**32 - 5000  # SampleTimeFine wraps inside the file
    for k in range(t.size):
        fine = (start + k * 100) % 2**32
        m = [f"{x:.6f}" for x in mag[k] / 50.0] if k % 4 == 0 else [empty] * 3
        cells = [str(k % 65536), str(fine)] + [f"{x:.6f}" for x in accel[k]] + \
            [f"{x:.6f}" for x in gyro[k]] + m + [f"{x:.8f}" for x in q[k]]
        lines.append("\t".join(cells))
    path = dst / "MT_00B42D4F_000.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def write_multirate_csv(dst: Path, *, seconds=2.0) -> Path:
    """gnomon's CSV with the gyro at 200 Hz, accelerometer 100 Hz, magnetometer 50 Hz, each
    row one time stamp; empty cells where a sensor has no sample."""
    t_g, t_a, t_m = _times(200, seconds), _times(100, seconds, 0.0025), \
        _times(50, seconds, 0.0013)
    rows = {}
    for t, k, key in ((t_g, 1, "g"), (t_a, 2, "a"), (t_m, 3, "m")):
        for ti, v in zip(t, motion(t)[k], strict=True):
            rows.setdefault(round(ti, 7), {})[key] = v
    lines = ["t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"]
    for ti in sorted(rows):
        r = rows[ti]
        cells = [f"{ti:.7f}"]
        for key in "gam":
            cells += [f"{x:.12g}" for x in r[key]] if key in r else ["", "", ""]
        lines.append(",".join(cells))
    path = dst / "multirate.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def write_mat73(path: Path, variables: dict) -> Path:
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 with a 512-byte user block starting
    ``MATLAB 7.3 MAT-file``, each variable stored transposed (MATLAB is column-major)."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            a = np.asarray(v)
            f[k] = a.T if a.ndim == 2 else a
            f[k].attrs["MATLAB_class"] = np.bytes_("double" if a.dtype.kind == "f" else
                                                   "logical")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 "
    header += b"HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(header.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM")
    return path


def write_dataflash(dst: Path, *, seconds=2.0) -> Path:
    """An ArduPilot DataFlash log as current firmware writes it (instances in a field ``I``),
    from the documented binary layout: ``0xA3 0x95 <type>`` then the packed fields; ``FMT``
    (type 128) describes every message. IMU I=0 (the motion) and I=1 (the motion with a
    0.01 rad/s gyro offset) at 100 Hz, MAG I=0 at 25 Hz in milligauss, ATT at 25 Hz in
    centidegrees — all in ArduPilot's FRD body and NED frames."""
    import struct

    from gnomon.io._common import Q_ENU_NED, Q_FRD_FLU, frd_to_flu
    from gnomon.rotation import euler_from_quat

    formats = {128: ("FMT", "BBnNZ", "Type,Length,Name,Format,Columns"),
               129: ("IMU", "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
               130: ("MAG", "QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
               131: ("ATT", "QccC", "TimeUS,Roll,Pitch,Yaw")}
    codes = {"Q": "Q", "B": "B", "f": "f", "h": "h", "c": "h", "C": "H", "n": "4s", "N": "16s",
             "Z": "64s"}
    packers = {k: struct.Struct("<" + "".join(codes[c] for c in f)) for k, (_, f, _) in
               formats.items()}
    out = bytearray()

    def msg(kind, *values):
        out.extend(b"\xa3\x95" + bytes([kind]) + packers[kind].pack(*values))

    for kind, (name, fmt, cols) in formats.items():
        msg(128, kind, 3 + packers[kind].size, name.encode(), fmt.encode(), cols.encode())
    t = _times(100, seconds)
    q, gyro, accel, mag = motion(t)
    g_frd, a_frd, m_frd = frd_to_flu(gyro), frd_to_flu(accel), frd_to_flu(mag)
    q_ned_frd = quat_mul(quat_mul(quat_conj(Q_ENU_NED), q), quat_conj(Q_FRD_FLU))
    rpy = np.degrees(euler_from_quat(q_ned_frd))
    for k, tk in enumerate(t):
        us = 5_000_000 + int(round(tk * 1e6))
        msg(129, us, 0, *g_frd[k], *a_frd[k])
        msg(129, us + 50, 1, *(g_frd[k] + 0.01), *a_frd[k])
        if k % 4 == 0:
            msg(130, us + 300, 0, *[int(round(x * 10)) for x in m_frd[k]])  # µT -> mGauss
            msg(131, us + 600, *[int(round(x * 100)) for x in (rpy[k, 0], rpy[k, 1],
                                                                 rpy[k, 2] % 360.0)])
    path = dst / "current.BIN"
    path.write_bytes(bytes(out))
    return path
