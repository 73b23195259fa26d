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


def _write_bag(tmp, kind, t_i, t_m, q, gyro, accel, mag, extra_imu_topic):
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
                   orientation_covariance=np.zeros(9),
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
