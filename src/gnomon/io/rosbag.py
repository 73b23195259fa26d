"""Reader for ROS 1 bags (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml`` and
sqlite3 ``.db3`` or ``.mcap`` storage), through ``rosbags``' ``AnyReader`` (optional extra
``logs``).

==================================  ====================================  ===============
what                                message and fields                    option
==================================  ====================================  ===============
gyro + accelerometer                ``sensor_msgs/Imu``:                  ``topic``
                                    ``angular_velocity`` (rad/s),
                                    ``linear_acceleration`` (m/s²)
magnetometer                        ``sensor_msgs/MagneticField``:        ``mag_topic``
                                    ``magnetic_field`` (tesla → µT)
the device's own estimate           ``sensor_msgs/Imu.orientation``       ``onboard``
                                    (x, y, z, w order) unless
                                    ``orientation_covariance[0] == -1``
==================================  ====================================  ===============

The default topic is the ``Imu`` (``MagneticField``) topic with the most messages (ties:
the first by name); ``meta["available"]`` lists every such topic with its message count
and ``frame_id``. A ``MagneticField`` topic without messages gives no magnetometer, said
in ``meta["assumed"]`` when it was picked by default and an :class:`InputError` when
``mag_topic`` names it. Time stamps are the messages' ``header.stamp`` (``stamps="header"``,
the default: when the sensor sampled) or the bag's receive times (``stamps="bag"``).

Frames and units (REP-103, REP-145): ``sensor_msgs/Imu`` is in the IMU's own frame
``header.frame_id``, FLU by REP-103, with ``linear_acceleration`` the specific force (+g
up at rest) — taken as is, ``frames = {"reference": "ENU", "body": <frame_id>}``; its
``orientation`` is the IMU frame relative to an ENU world frame (REP-103/145), reordered
from ROS's x, y, z, w to gnomon's ``[w, x, y, z]`` and slerped onto the gyro time stamps
(a comparison series). All-zero orientations (an unset field) are taken as none, and so
is a constant one (a driver's identity placeholder, e.g. on ``/imu/data_raw``;
:func:`gnomon.io._common.own_estimate_absent`): ``meta["onboard_absent"]`` says why.
``MagneticField`` is in tesla (converted to µT) in its own ``frame_id``: a differing
``frame_id`` from the IMU's is stated in ``meta["assumed"]`` (no extrinsic is applied).
"""

from __future__ import annotations

import os
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import as_path, build, onboard_on, optional_import, series
from gnomon.recording import Recording

__all__ = ["read_rosbag", "is_ros2_bag_dir", "ROSBAG1_MAGIC", "IMU_TYPE", "MAG_TYPE"]

ROSBAG1_MAGIC = b"#ROSBAG V2.0\n"
IMU_TYPE = "sensor_msgs/msg/Imu"
MAG_TYPE = "sensor_msgs/msg/MagneticField"


def is_ros2_bag_dir(path: Path) -> bool:
    """A ROS 2 bag directory: ``metadata.yaml`` naming a rosbag2 bag."""
    meta = path / "metadata.yaml"
    if not (path.is_dir() and meta.is_file()):
        return False
    try:
        return "rosbag2_bagfile_information" in meta.read_text(encoding="utf-8",
                                                              errors="replace")[:4000]
    except OSError:
        return False


def _stamp(msg) -> float:
    s = msg.header.stamp
    return float(s.sec) + 1e-9 * float(s.nanosec)


def read_rosbag(path: str | os.PathLike, *, topic: str | None = None,
                mag_topic: str | None = None, onboard: bool = True,
                stamps: str = "header") -> Recording:
    """Read ``sensor_msgs/Imu`` (and ``MagneticField``) from a ROS 1 or ROS 2 bag
    (module docstring: topics, frames, units).

    Parameters
    ----------
    path : a ROS 1 ``.bag`` file, or a ROS 2 bag directory (or a ``.db3``/``.mcap`` file
        inside one).
    topic : the Imu topic (default: the one with the most messages).
    mag_topic : the MagneticField topic, or ``"none"`` (default: the one with the most).
    onboard : keep ``Imu.orientation`` as ``q_onboard``.
    stamps : ``"header"`` (``header.stamp``) or ``"bag"`` (the bag's receive time).
    """
    path = as_path(path)
    highlevel = optional_import("rosbags.highlevel", "rosbags>=0.9.20", path, "ROS bags")
    typesys = optional_import("rosbags.typesys", "rosbags>=0.9.20", path, "ROS bags")
    if stamps not in ("header", "bag"):
        raise InputError(f"expected header or bag, got {stamps!r}", file=str(path),
                         field="stamps")
    bag = _scan(path, highlevel, typesys, topic, mag_topic, stamps)
    assumed: list[str] = []
    imu_topic, m_topic = bag.imu_topic, bag.mag_topic
    t, gyro, accel, q_onboard, onboard_desc, absent = _imu(path, bag, stamps, onboard,
                                                           assumed)
    imu_frame = sorted(bag.frames_seen[imu_topic])
    if m_topic is None and mag_topic is None:
        assumed.append(f"No {MAG_TYPE} topic in the bag: the recording has no magnetometer.")
    t_m, mag, m_topic = _mag(path, bag, mag_topic, imu_frame, assumed)
    body = imu_frame[0] if len(imu_frame) == 1 and imu_frame[0] else "imu"
    assumed[:0] = [
        "sensor_msgs/Imu in REP-103 axes (FLU body, ENU world) with linear_acceleration the "
        "specific force (REP-145); taken without conversion.",
        f"Time stamps from {'header.stamp' if stamps == 'header' else 'the bag receive time'}"
        " in s; MagneticField tesla converted to uT.",
    ]
    meta = {
        "format": "rosbag", "assumed": assumed, "topic": imu_topic, "mag_topic": m_topic,
        "frame_id": imu_frame, "onboard": onboard_desc, "stamps": stamps,
        "onboard_heading_reference": None if q_onboard is None else (
            "the driver's: REP-103/145 fix ENU but not whether north is magnetic or true"),
        "available": {"imu": bag.by_type[IMU_TYPE], "mag": bag.by_type[MAG_TYPE],
                      "topics": {n: sorted({c.msgtype for c in cs})
                                 for n, cs in bag.conns.items()}},
        "bag_duration_s": bag.duration_s, **({"onboard_absent": absent} if absent else {}),
    }
    names = {"t": f"{imu_topic}.header.stamp", "gyro": f"{imu_topic}.angular_velocity",
             "accel": f"{imu_topic}.linear_acceleration", "mag": f"{m_topic}.magnetic_field",
             "mag_t": f"{m_topic}.header.stamp", "q_onboard": f"{imu_topic}.orientation"}
    return build(path, names, t=t, gyro=gyro, accel=accel, mag=mag, mag_t=t_m, mag_unit="uT",
                 q_onboard=q_onboard, frames={"reference": "ENU", "body": body},
                 source=f"{Path(path).stem} (ROS bag)", meta=meta)


@dataclass
class _Scan:
    """What one pass over the bag gave: the topics, the chosen Imu and MagneticField
    topics' messages as rows of ``array('d')`` (8 bytes a value: no per-message object is
    kept) and up to 4 ``frame_id`` per topic."""

    conns: dict  # topic -> its connections
    by_type: dict  # message type -> {topic: message count}
    imu_topic: str
    mag_topic: str | None
    imu_rows: array  # t, angular_velocity, linear_acceleration, orientation w x y z, cov[0]
    mag_rows: array  # t, magnetic_field
    frames_seen: dict  # topic (str(None) without a magnetometer) -> set of frame_id
    duration_s: float


def _scan(path: Path, highlevel, typesys, topic: str | None, mag_topic: str | None,
          stamps: str) -> _Scan:
    """Choose the topics and read their messages (an InputError on any failure of the
    library)."""
    bag = path
    if path.is_file() and path.suffix.lower() in (".db3", ".mcap") and \
            is_ros2_bag_dir(path.parent):
        bag = path.parent
    try:
        store = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
        with highlevel.AnyReader([bag], default_typestore=store) as reader:
            conns = {}
            for c in reader.connections:
                conns.setdefault(c.topic, []).append(c)
            by_type = _counts(conns)
            imu_topic = _choose(path, conns, by_type, IMU_TYPE, topic, "topic")
            if imu_topic is None:
                all_topics = {n: sorted({c.msgtype for c in cs}) for n, cs in conns.items()}
                raise InputError(f"no {IMU_TYPE} topic in the bag; it has "
                                 f"{all_topics or 'no topic'}", file=str(path), field="topic")
            m_topic = _choose(path, conns, by_type, MAG_TYPE, mag_topic, "mag_topic")
            sel = [c for c in conns[imu_topic] if c.msgtype == IMU_TYPE]
            if m_topic is not None:
                sel += [c for c in conns[m_topic] if c.msgtype == MAG_TYPE]
            imu_rows, mag_rows, frames_seen = _collect(reader, sel, imu_topic, m_topic, stamps)
            duration_s = (reader.duration or 0) * 1e-9
    except InputError:
        raise
    except Exception as err:  # rosbags' failures are many (ReaderError, struct, sqlite, ...)
        raise InputError(f"cannot read as a ROS bag (rosbags: {type(err).__name__}: {err})",
                         file=str(path)) from None
    return _Scan(conns, by_type, imu_topic, m_topic, imu_rows, mag_rows, frames_seen,
                 duration_s)


def _counts(conns: dict) -> dict[str, dict[str, int]]:
    """Imu and MagneticField: topic -> message count."""
    by_type: dict[str, dict[str, int]] = {IMU_TYPE: {}, MAG_TYPE: {}}
    for name, cs in conns.items():
        for c in cs:
            if c.msgtype in by_type:
                by_type[c.msgtype][name] = by_type[c.msgtype].get(name, 0) + int(c.msgcount)
    return by_type


def _choose(path: Path, conns: dict, by_type: dict, kind: str, wanted: str | None,
            option: str) -> str | None:
    """The topic of message type ``kind`` named by option ``option`` (checked), else the
    one with the most messages (ties: the first by name); None when there is none."""
    have = by_type[kind]
    if wanted is None:
        if not have:
            return None
        return sorted(have, key=lambda n: (-have[n], n))[0]
    if wanted == "none" and kind == MAG_TYPE:
        return None
    if wanted not in conns:
        raise InputError(f"no topic {wanted!r} in the bag; {kind} topics: "
                         f"{', '.join(sorted(have)) or 'none'}", file=str(path),
                         field=option)
    types = sorted({c.msgtype for c in conns[wanted]})
    if kind not in types:
        raise InputError(f"topic {wanted!r} holds {', '.join(types)}, not {kind}",
                         file=str(path), field=option)
    return wanted


def _collect(reader, sel: list, imu_topic: str, m_topic: str | None, stamps: str) -> tuple:
    """The messages of the connections ``sel`` deserialised into ``(imu rows, mag rows,
    topic -> frame_id seen)``."""
    imu_rows = array("d")  # 8 bytes a value: no per-message object is kept
    mag_rows = array("d")
    frames_seen: dict[str, set] = {imu_topic: set(), str(m_topic): set()}
    for conn, t_bag, raw in reader.messages(connections=sel):
        msg = reader.deserialize(raw, conn.msgtype)
        t = _stamp(msg) if stamps == "header" else t_bag * 1e-9
        if conn.msgtype == IMU_TYPE:
            w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
            imu_rows.extend((t, w.x, w.y, w.z, a.x, a.y, a.z, q.w, q.x, q.y, q.z,
                             float(msg.orientation_covariance[0])))
            if len(frames_seen[imu_topic]) < 4:
                frames_seen[imu_topic].add(msg.header.frame_id)
        else:
            f = msg.magnetic_field
            mag_rows.extend((t, f.x, f.y, f.z))
            if len(frames_seen[str(m_topic)]) < 4:
                frames_seen[str(m_topic)].add(msg.header.frame_id)
    return imu_rows, mag_rows, frames_seen


def _imu(path: Path, bag: _Scan, stamps: str, onboard: bool, assumed: list) -> tuple:
    """``(t, gyro, accel, q_onboard, onboard description, why there is none)``: at least 2
    messages; the orientation (unless its covariance says none, or all zero) slerped onto
    ``t``."""
    imu_topic = bag.imu_topic
    imu = np.frombuffer(bag.imu_rows, dtype=float).reshape(-1, 12)
    if imu.shape[0] < 2:
        raise InputError(f"{imu.shape[0]} message(s) on {imu_topic}; at least 2 needed",
                         file=str(path), field=imu_topic)
    if stamps == "header" and np.all(imu[:, 0] == 0):
        raise InputError("every header.stamp is zero; read with stamps='bag'",
                         file=str(path), field=f"{imu_topic}.header.stamp")
    t, v = series(path, f"{imu_topic} (angular_velocity, linear_acceleration)", imu[:, 0],
                  imu[:, 1:], width=11, assumed=assumed)
    gyro, accel, q, cov0 = v[:, 0:3], v[:, 3:6], v[:, 6:10], v[:, 10]
    q_onboard = None
    onboard_desc = None
    absent = None
    has_q = (cov0 != -1) & (np.abs(q).sum(axis=1) > 0)
    if onboard and has_q.any():
        q_onboard = onboard_on(path, f"{imu_topic}.orientation", t[has_q], q[has_q], t)
        onboard_desc = f"{imu_topic}.orientation (x, y, z, w reordered to w, x, y, z), " \
                       "slerped onto the gyro time stamps"
    elif onboard:
        absent = (f"{imu_topic}.orientation: orientation_covariance[0] = -1 in "
                  f"{int((cov0 == -1).sum())} and an all-zero orientation in "
                  f"{int(((cov0 != -1) & ~has_q).sum())} of {t.size} messages (REP-145: "
                  "no orientation estimate)")
    return t, gyro, accel, q_onboard, onboard_desc, absent


def _mag(path: Path, bag: _Scan, mag_topic: str | None, imu_frame: list, assumed: list
         ) -> tuple:
    """``(t_mag, mag in µT, the topic)``; (None, None, None) without a magnetometer (a
    topic without messages: said, or an error when ``mag_topic`` named it)."""
    m_topic = bag.mag_topic
    if m_topic is None:
        return None, None, None
    a = np.frombuffer(bag.mag_rows, dtype=float).reshape(-1, 4)
    if a.shape[0] == 0:
        if mag_topic is not None:  # named by the user: not silently left out
            raise InputError(f"topic {m_topic!r} has no messages", file=str(path),
                             field="mag_topic")
        assumed.append(f"The magnetometer topic {m_topic!r} ({MAG_TYPE}) has no "
                       "messages: the recording has no magnetometer.")
        return None, None, None
    t_m, mag = series(path, f"{m_topic}.magnetic_field", a[:, 0], a[:, 1:], assumed=assumed)
    mag = mag * 1e6
    mag_frame = sorted(bag.frames_seen[str(m_topic)])
    if mag_frame != imu_frame:
        assumed.append(f"The magnetometer's frame_id {mag_frame} differs from the "
                       f"IMU's {imu_frame}; no extrinsic rotation was applied.")
    return t_m, mag, m_topic
