"""Reader for PX4 ULog flight logs (``.ulg``), through ``pyulog`` (optional extra ``logs``).

Which topics (``meta["available"]`` lists every topic and instance in the file):

==========================  ===================================================  ==========
what                        topic and fields (PX4 units)                         option
==========================  ===================================================  ==========
gyro + accelerometer        ``sensor_combined``: ``gyro_rad`` (rad/s) at          ``topic``,
                            ``timestamp``; ``accelerometer_m_s2`` (m/s²) at       ``instance``
                            ``timestamp + accelerometer_timestamp_relative`` —
                            the default (PX4's selected IMU, every firmware);
                            ``vehicle_imu`` [instance]: ``delta_angle /
                            delta_angle_dt`` and ``delta_velocity /
                            delta_velocity_dt`` at ``timestamp_sample``;
                            ``sensor_gyro`` + ``sensor_accel`` [instance]: ``x, y,
                            z`` at ``timestamp_sample``
magnetometer                ``vehicle_magnetometer`` [instance] (calibrated,      ``mag_topic``,
                            ``magnetometer_ga``, gauss) — default when present;   ``mag_instance``
                            else ``sensor_combined.magnetometer_ga`` (older
                            firmware) at ``timestamp +
                            magnetometer_timestamp_relative``; else
                            ``sensor_mag`` [instance] (raw, gauss)
the device's own estimate   ``vehicle_attitude.q`` → ``Recording.q_onboard``      ``onboard``
truth (simulator)           ``vehicle_attitude_groundtruth.q`` → ``q_true``
==========================  ===================================================  ==========

The default IMU topic is ``sensor_combined`` when the file has it and ``instance`` is 0;
with another instance, the per-instance topic with the most messages (``vehicle_imu`` or
``sensor_gyro``/``sensor_accel``). PX4 logs ``vehicle_imu``/``sensor_gyro`` at low rates
(1–2 Hz) by default: ``inspect`` shows the rates.

Frames and units: PX4's body frame is FRD and its reference NED. Vectors become FLU
(``[x, -y, -z]``), attitudes ``q_ENU_FLU = q_ENU_NED ⊗ q_NED_FRD ⊗ q_FRD_FLU``;
``frames = {"reference": "ENU", "body": "FLU"}``. The accelerometer is PX4's specific
force (−g on FRD z at rest, +g on FLU z). Magnetometer gauss → µT (×100). Time: PX4's
µs since boot → s. A time stamp repeated with the same values is one sample logged twice
(``sensor_combined`` carries the latest accelerometer/magnetometer sample in every
message); ``timestamp_sample`` is used when the topic has it and it increases, else
``timestamp``. ``vehicle_attitude`` is slerped onto the gyro time stamps (a comparison
series); its heading refers to true north (EKF2 applies the magnetic declination, from
its world magnetic model at the GPS position or ``EKF2_MAG_DECL``): said, with the log's
declination parameters, in ``meta["onboard_heading_reference"]``.

Errors: a file pyulog cannot parse, or one where it detected corruption (it skips bytes
to resynchronise) is an :class:`~gnomon.errors.InputError` (``allow_corrupt=True`` reads
what pyulog recovered and says so in ``meta["assumed"]``). A file cut off at the end reads
up to its last complete message (pyulog's behaviour; a flight log is often cut at
power-off) and says so: pyulog stops silently at a message that runs past the end of the
file, the reader watches its reads near the end of the file (:class:`_CutWatch`, free on
long logs) and puts where the file was cut and up to which time stamp the data go in
``meta["assumed"]`` and ``meta["truncated"]`` (``gnomon inspect`` prints it). A file cut
exactly between two messages cannot be told from a complete one.
"""

from __future__ import annotations

import io
import os

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import (
    as_path,
    build,
    cut_short,
    ned_frd_to_enu_flu,
    onboard_on,
    optional_import,
    quiet,
    series,
)
from gnomon.recording import Recording

__all__ = ["read_ulog", "ULOG_MAGIC", "IMU_TOPICS", "MAG_TOPICS"]

ULOG_MAGIC = b"ULog\x01\x12\x35"
IMU_TOPICS = ("sensor_combined", "vehicle_imu", "sensor_gyro")
MAG_TOPICS = ("vehicle_magnetometer", "sensor_combined", "sensor_mag")
_OTHER = ("sensor_accel", "vehicle_attitude", "vehicle_attitude_groundtruth")
_INVALID_RELATIVE = 2147483647  # PX4's RELATIVE_TIMESTAMP_INVALID
_GAUSS_TO_UT = 100.0
_MAG = (_GAUSS_TO_UT, -_GAUSS_TO_UT, -_GAUSS_TO_UT)  # FRD gauss -> FLU µT


_KNOWN_TYPES = frozenset(b"FDIMPQARSOLCB")  # pyulog's message types


def _check_definitions(path) -> None:
    """Walk the definitions section as pyulog does and refuse a file on which pyulog would
    not terminate: an unknown message type (pyulog steps one byte on) whose length runs past
    the end of the file makes pyulog seek backwards forever (pyulog 1.x). Cheap: the
    section is the file's first few kilobytes of format and parameter messages."""
    import struct

    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        fh.seek(0)
        raw = fh.read(min(size, 4 << 20))
    pos = 16
    while pos + 3 <= len(raw):
        n, kind = struct.unpack_from("<HB", raw, pos)
        if kind in b"ALC":
            return  # end of the definitions section
        if kind not in _KNOWN_TYPES:
            if pos + 3 + n > size:
                raise InputError(f"corrupted definitions section: unknown message type {kind} "
                                 f"at byte {pos} runs past the end of the file",
                                 file=str(path))
            pos += 1  # pyulog's recovery: one byte on
            continue
        pos += 3 + n


_TAIL = 1 << 16  # >= pyulog's longest read (a message payload: its size is 16 bits)
_BUFFER = 1 << 16  # the buffer pyulog's reads are served from


class _CutWatch:
    """The ``.ulg`` file as pyulog reads it, noting where a read came back short: pyulog
    stops silently at a message cut off by the end of the file (``len(data) <
    msg_size``), this says where. A 3-byte header read that finds nothing is the clean end
    (a file cut exactly between two messages cannot be told from a complete one).

    Free on long logs (pyulog reads twice per message): ``read`` is the buffered file's own
    (C) method until a buffer fill or a ``seek`` gets within ``_TAIL`` bytes of the end of
    the file, and this wrapper's ``_watched`` from then on. A read starting further than
    ``_TAIL`` bytes from the end cannot come back short (no pyulog read is longer: a
    message's size is 16 bits), so every short read is seen, as when watching them all."""

    def __init__(self, path):
        self._raw = raw = _Raw(path, self)
        self._fh = io.BufferedReader(raw, _BUFFER)
        self._size = os.fstat(raw.fileno()).st_size
        self.cut: tuple[int, int, int] | None = None  # (message start, its size, present)
        self.read = self._fh.read  # pyulog looks ``read`` up at every call
        self.tell = self._fh.tell
        self._near(0)

    def _near(self, pos: int) -> None:
        if self._size - pos <= _TAIL:
            self.read = self._watched

    def _watched(self, n: int = -1) -> bytes:
        data = self._fh.read(n)
        if len(data) < n and not (n == 3 and not data):
            header = 0 if n == 3 else 3  # a payload read: its 3-byte header came before
            start = self._fh.tell() - len(data) - header
            self.cut = (start, n + header, len(data) + header)
        return data

    def seek(self, *args) -> int:
        pos = self._fh.seek(*args)
        self._near(pos)
        return pos

    def close(self) -> None:
        self._fh.close()
        self._raw._watch = None  # (no cycle left)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _Raw(io.FileIO):
    """The raw file under :class:`_CutWatch`'s buffer: each fill tells where it got to."""

    def __init__(self, path, watch: _CutWatch):
        super().__init__(path, "rb")
        self._watch = watch

    def readinto(self, b) -> int | None:
        n = super().readinto(b)
        if self._watch is not None:
            self._watch._near(self.tell())
        return n


_FLU = (1.0, -1.0, -1.0)  # FRD -> FLU, applied while the columns are copied


def _vec(d: dict, names, scale=None) -> np.ndarray:
    """Fields ``names`` of a topic as one (N, k) float array, each column times ``scale``
    (one pass, no temporaries: long logs). pyulog's columns are views of one record array:
    fields of one float type side by side in the record are read as one (N, k) view."""
    cols = [d[n] for n in names]
    out = np.empty((cols[0].size, len(names)))
    block = _block(cols)
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf: dropped by build()
        if block is not None:  # the same arithmetic as below (in the fields' type)
            np.multiply(block, np.ones(len(names), block.dtype) if scale is None
                        else np.array(scale, block.dtype), out=out, casting="unsafe")
            return out
        for j, c in enumerate(cols):
            np.multiply(c, 1.0 if scale is None else scale[j], out=out[:, j],
                        casting="unsafe")
    return out


def _block(cols: list):
    """``cols`` (views of one record array: fields of one float type side by side) as one
    (N, k) strided view; None when they are not."""
    first = cols[0]
    ptr, size = first.__array_interface__["data"][0], first.dtype.itemsize
    if first.ndim != 1 or first.dtype.kind != "f" or first.base is None or any(
            c.base is not first.base or c.dtype != first.dtype or c.shape != first.shape
            or c.strides != first.strides or c.__array_interface__["data"][0] != ptr + j * size
            for j, c in enumerate(cols)):
        return None
    return np.lib.stride_tricks.as_strided(first, (first.size, len(cols)),
                                           (first.strides[0], size), writeable=False)


def _shifted(d: dict, rel, t=None):
    """``timestamp + rel`` (µs, ``rel`` a ``*_timestamp_relative`` field or None) in s and
    the rows where ``rel`` is valid (a boolean mask, or ``slice(None)`` when all are: no
    copies on long logs); ``t`` (``timestamp`` in s) itself when every ``rel`` is 0."""
    if rel is None or not rel.any():
        return (d["timestamp"].astype(np.int64) * 1e-6 if t is None else t), slice(None)
    bad = rel == _INVALID_RELATIVE
    ok = slice(None) if not bad.any() else ~bad
    return (d["timestamp"][ok].astype(np.int64) + rel[ok].astype(np.int64)) * 1e-6, ok


def _stamps(d: dict, assumed: list, topic: str) -> np.ndarray:
    """``timestamp_sample`` when present, non-zero and increasing, else ``timestamp`` (s)."""
    ts = d.get("timestamp_sample")
    if ts is not None and ts.size and np.all(ts > 0) and np.all(np.diff(ts.astype(np.int64)) > 0):
        return ts.astype(np.float64) * 1e-6
    if ts is not None:
        assumed.append(f"{topic}: timestamp_sample does not increase; timestamp used.")
    return d["timestamp"].astype(np.float64) * 1e-6


def _heading_reference(params: dict) -> str:
    """Which north ``vehicle_attitude``'s heading refers to, with the log's parameters."""
    if "EKF2_MAG_DECL" in params:
        return (f"true north (PX4's EKF2 applies the magnetic declination; EKF2_MAG_DECL = "
                f"{float(params['EKF2_MAG_DECL']):.2f} deg, EKF2_DECL_TYPE = "
                f"{params.get('EKF2_DECL_TYPE', '?')} in the log)")
    if "ATT_MAG_DECL" in params:
        return (f"true north (PX4's attitude estimator applies the magnetic declination; "
                f"ATT_MAG_DECL = {float(params['ATT_MAG_DECL']):.2f} deg, ATT_MAG_DECL_A = "
                f"{params.get('ATT_MAG_DECL_A', '?')} in the log)")
    return ("true north (PX4's EKF2 applies the magnetic declination, from its world "
            "magnetic model at the GPS position or EKF2_MAG_DECL; the log records no "
            "parameter)")


def read_ulog(path: str | os.PathLike, *, topic: str | None = None, instance: int = 0,
              mag_topic: str | None = None, mag_instance: int = 0, onboard: bool = True,
              allow_corrupt: bool = False) -> Recording:
    """Read a PX4 ULog file (module docstring: topics, frames, units, errors).

    Parameters
    ----------
    path : the ``.ulg`` file.
    topic : IMU topic, one of ``IMU_TOPICS`` (default: see the module docstring).
    instance : multi-instance index of the IMU topic (default 0, the first).
    mag_topic : magnetometer topic, one of ``MAG_TOPICS``, or ``"none"``.
    mag_instance : its instance (default 0).
    onboard : keep ``vehicle_attitude`` as ``q_onboard``.
    allow_corrupt : read a file in which pyulog detected corruption (stated in meta).

    Returns a Recording in ENU/FLU, SI units, ``mag`` in µT, each sensor at its own rate.
    """
    path = as_path(path)
    pyulog = optional_import("pyulog", "pyulog>=1.0", path, "PX4 ULog files")
    if topic is not None and topic not in IMU_TOPICS:
        raise InputError(f"unknown IMU topic {topic!r}; use one of {', '.join(IMU_TOPICS)}",
                         file=str(path), field="topic")
    if mag_topic is not None and mag_topic not in MAG_TOPICS + ("none",):
        raise InputError(f"unknown magnetometer topic {mag_topic!r}; use one of "
                         f"{', '.join(MAG_TOPICS)} or none", file=str(path), field="mag_topic")
    for name, value in (("instance", instance), ("mag_instance", mag_instance)):
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 0:
            raise InputError(f"expected an instance number >= 0, got {value!r}",
                             file=str(path), field=name)
    _check_definitions(path)
    try:
        with quiet() as printed, _CutWatch(path) as watch:
            ulog = pyulog.ULog(watch, list(dict.fromkeys(IMU_TOPICS + MAG_TOPICS + _OTHER)),
                               True)
    except Exception as err:  # pyulog's failures are not enumerated: the file is unreadable
        raise InputError(f"cannot read as ULog (pyulog: {type(err).__name__}: {err})",
                         file=str(path)) from None
    try:
        return _extract(path, ulog, printed, topic, instance, mag_topic, mag_instance, onboard,
                        allow_corrupt, watch.cut)
    except (KeyError, IndexError) as err:  # a field the format definitions should have
        raise InputError(f"the file's format definitions lack {err} (corrupted?)",
                         file=str(path)) from None


def _extract(path, ulog, printed, topic, instance, mag_topic, mag_instance, onboard,
             allow_corrupt, cut) -> Recording:
    """The Recording from what pyulog read (the steps below, in this order)."""
    assumed: list[str] = []
    _corruption(path, ulog, printed, allow_corrupt, assumed)
    data = {(d.name, d.multi_id): d.data for d in ulog.data_list}
    available = _available(data)
    topic = _imu_topic(path, data, topic, instance)
    t_g, gyro, t_a, accel, names, imu_desc = _imu(path, data, topic, instance, assumed)
    mag_topic = _mag_topic(data, mag_topic, mag_instance)
    t_m, mag, mag_desc = _mag(path, data, mag_topic, mag_instance, assumed)
    names.update(mag=str(mag_topic), mag_t=str(mag_topic))
    estimates = _estimates(data, onboard, assumed)
    dropouts = len(ulog.dropouts)
    for d in ulog.data_list:  # pyulog's arrays are copied out: free them before resampling
        d.data = {}
    data.clear()
    q_onboard, q_true, onboard_desc = _resampled(path, estimates, t_g, assumed)
    truncated = None if cut is None else cut_short(*cut, t_g, assumed)
    info = ulog.msg_info_dict
    heading_ref = _heading_reference(ulog.initial_parameters) if q_onboard is not None \
        else None
    assumed[:0] = [
        "PX4 body frame FRD converted to FLU ([x, -y, -z]); NED to ENU "
        "(q_ENU_FLU = q_ENU_NED * q_NED_FRD * q_FRD_FLU).",
        "Accelerometer is PX4's specific force in m/s^2; gyro rad/s; magnetometer gauss "
        "converted to uT (x100).",
        "Time is PX4's time since boot (us) in s.",
    ]
    meta = {
        "format": "ulog", "assumed": assumed,
        "device": {k: str(info[k]) for k in ("sys_name", "ver_hw", "ver_sw", "sys_uuid")
                   if k in info},
        "imu": imu_desc, "topic": topic, "instance": int(instance), "mag": mag_desc,
        "mag_topic": mag_topic, "mag_instance": int(mag_instance), "onboard": onboard_desc,
        "onboard_heading_reference": heading_ref,
        "available": available, "dropouts": dropouts, "truncated": truncated,
    }
    return build(path, names, t=t_g, gyro=gyro, accel=accel,
                 accel_t=t_a, mag=mag, mag_t=t_m, mag_unit="uT", q_onboard=q_onboard,
                 q_true=q_true, frames={"reference": "ENU", "body": "FLU"},
                 source=f"{path.stem} (PX4 ULog)", meta=meta)


def _corruption(path, ulog, printed, allow_corrupt: bool, assumed: list) -> None:
    """Refuse a file in which pyulog detected corruption, unless ``allow_corrupt`` (said)."""
    if ulog.file_corruption:
        if not allow_corrupt:
            raise InputError("pyulog detected corruption in the file (it skipped bytes to "
                             "resynchronise); pass allow_corrupt=True to read what it "
                             "recovered", file=str(path))
        assumed.append("pyulog detected corruption; the samples it recovered were read "
                       f"(allow_corrupt=True){': ' + printed.getvalue().strip()[:200]}.")


def _available(data: dict) -> dict:
    """topic -> {instance: message count} (``meta["available"]``)."""
    available = {}
    for (name, multi), d in sorted(data.items()):
        available.setdefault(name, {})[str(multi)] = int(d["timestamp"].size)
    return available


def _get(path, data: dict, name: str, inst: int, what: str) -> dict:
    """The fields of topic ``name`` instance ``inst``; its absence raises naming the IMU
    and magnetometer topics the file has."""
    if (name, inst) not in data:
        have = sorted(f"{n}[{i}]" for n, i in data if n in IMU_TOPICS + MAG_TOPICS)
        raise InputError(f"the file has no {name}[{inst}] ({what}); it has "
                         f"{', '.join(have) or 'no IMU topic'}", file=str(path),
                         field=name)
    return data[(name, inst)]


def _imu_topic(path, data: dict, topic: str | None, instance: int) -> str:
    """The IMU topic asked for, else the default (module docstring)."""
    if topic is None:
        if instance == 0 and ("sensor_combined", 0) in data:
            topic = "sensor_combined"
        else:
            counts = {n: data[(n, instance)]["timestamp"].size for n in IMU_TOPICS[1:]
                      if (n, instance) in data}
            if not counts:
                _get(path, data, "vehicle_imu", instance, "IMU")  # raises naming what there is
            topic = max(counts, key=counts.get)
    if topic == "sensor_combined" and instance != 0:
        raise InputError("sensor_combined has one instance (PX4's selected IMU); use "
                         "topic vehicle_imu or sensor_gyro for another instance",
                         file=str(path), field="instance")
    return topic


def _imu(path, data: dict, topic: str, instance: int, assumed: list) -> tuple:
    """``(t_gyro, gyro, t_accel, accel, names, description)`` of the IMU topic, FLU, with
    at least 2 gyro and 1 accelerometer samples; ``names``: Recording field -> log field."""
    if topic == "sensor_combined":
        t_g, gyro, t_a, accel = _sensor_combined(path, _get(path, data, topic, 0, "IMU"),
                                                 assumed)
        names = {"gyro": "sensor_combined.gyro_rad",
                 "accel": "sensor_combined.accelerometer_m_s2"}
        imu_desc = "sensor_combined (gyro at timestamp, accelerometer at timestamp + " \
                   "accelerometer_timestamp_relative)"
    elif topic == "vehicle_imu":
        t_g, gyro, t_a, accel = _vehicle_imu(path, _get(path, data, topic, instance, "IMU"),
                                             assumed)
        names = {"gyro": "vehicle_imu.delta_angle", "accel": "vehicle_imu.delta_velocity"}
        imu_desc = f"vehicle_imu[{instance}] (delta_angle / delta_angle_dt, delta_velocity / " \
                   "delta_velocity_dt: the mean rate and specific force over each interval)"
    else:
        t_g, gyro, t_a, accel = _sensor_gyro_accel(
            path, _get(path, data, "sensor_gyro", instance, "gyro"),
            _get(path, data, "sensor_accel", instance, "accelerometer"), assumed)
        names = {"gyro": "sensor_gyro", "accel": "sensor_accel"}
        imu_desc = f"sensor_gyro[{instance}] and sensor_accel[{instance}]"
    names = {"t": f"{topic}.timestamp", **names}
    if t_g.size < 2:
        raise InputError(f"{t_g.size} gyro sample(s); at least 2 needed", file=str(path),
                         field=names["gyro"])
    if t_a.size == 0:
        raise InputError("no accelerometer sample", file=str(path), field=names["accel"])
    return t_g, gyro, t_a, accel, names, imu_desc


def _sensor_combined(path, d: dict, assumed: list) -> tuple:
    """Gyro at ``timestamp``, accelerometer at ``timestamp +
    accelerometer_timestamp_relative`` (rows where that is valid)."""
    t = d["timestamp"].astype(np.int64) * 1e-6
    t_g, gyro = series(path, "sensor_combined.gyro_rad", t,
                       _vec(d, [f"gyro_rad[{k}]" for k in range(3)], _FLU), assumed=assumed)
    t_acc, ok = _shifted(d, d.get("accelerometer_timestamp_relative"), t)
    del t
    t_a, accel = series(path, "sensor_combined.accelerometer_m_s2", t_acc,
                        _vec(d, [f"accelerometer_m_s2[{k}]" for k in range(3)], _FLU)[ok],
                        assumed=assumed)
    return t_g, gyro, t_a, accel


def _vehicle_imu(path, d: dict, assumed: list) -> tuple:
    """Rate and specific force as ``delta_angle / delta_angle_dt`` and ``delta_velocity /
    delta_velocity_dt`` (intervals must be positive)."""
    t = _stamps(d, assumed, "vehicle_imu")
    dt_a = d["delta_angle_dt"].astype(float) * 1e-6
    dt_v = d["delta_velocity_dt"].astype(float) * 1e-6
    if np.any(dt_a <= 0) or np.any(dt_v <= 0):
        bad = np.flatnonzero((dt_a <= 0) | (dt_v <= 0))[0]
        raise InputError("integration interval is not positive", file=str(path),
                         field="vehicle_imu.delta_angle_dt", row=int(bad))
    t_g, gyro = series(path, "vehicle_imu.delta_angle", t,
                       _vec(d, [f"delta_angle[{k}]" for k in range(3)], _FLU) / dt_a[:, None],
                       assumed=assumed)
    t_a, accel = series(path, "vehicle_imu.delta_velocity", t,
                        _vec(d, [f"delta_velocity[{k}]" for k in range(3)], _FLU)
                        / dt_v[:, None], assumed=assumed)
    return t_g, gyro, t_a, accel


def _sensor_gyro_accel(path, dg: dict, da: dict, assumed: list) -> tuple:
    """``sensor_gyro`` and ``sensor_accel``: ``x, y, z`` at their own time stamps."""
    t_g, gyro = series(path, "sensor_gyro", _stamps(dg, assumed, "sensor_gyro"),
                       _vec(dg, "xyz", _FLU), assumed=assumed)
    t_a, accel = series(path, "sensor_accel", _stamps(da, assumed, "sensor_accel"),
                        _vec(da, "xyz", _FLU), assumed=assumed)
    return t_g, gyro, t_a, accel


def _mag_topic(data: dict, mag_topic: str | None, mag_instance: int) -> str:
    """The magnetometer topic asked for, else the default (module docstring) or ``"none"``."""
    if mag_topic is not None:
        return mag_topic
    if ("vehicle_magnetometer", mag_instance) in data:
        return "vehicle_magnetometer"
    if ("sensor_combined", 0) in data and "magnetometer_ga[0]" in data[
            ("sensor_combined", 0)] and mag_instance == 0:
        return "sensor_combined"
    if ("sensor_mag", mag_instance) in data:
        return "sensor_mag"
    return "none"


def _mag(path, data: dict, mag_topic: str, mag_instance: int, assumed: list) -> tuple:
    """``(t_mag, mag in µT FLU, description)``; (None, None, why) without a sample."""
    mag = t_m = None
    mag_desc = "none in the file"
    if mag_topic == "vehicle_magnetometer":
        d = _get(path, data, mag_topic, mag_instance, "magnetometer")
        t_m, mag = series(path, "vehicle_magnetometer.magnetometer_ga",
                          _stamps(d, assumed, mag_topic),
                          _vec(d, [f"magnetometer_ga[{k}]" for k in range(3)], _MAG),
                          assumed=assumed)
        mag_desc = f"vehicle_magnetometer[{mag_instance}] (calibrated by PX4)"
    elif mag_topic == "sensor_combined":
        if mag_instance != 0:
            raise InputError("sensor_combined has one instance", file=str(path),
                             field="mag_instance")
        d = _get(path, data, mag_topic, 0, "magnetometer")
        if "magnetometer_ga[0]" not in d:
            raise InputError("this firmware's sensor_combined has no magnetometer_ga; use "
                             "vehicle_magnetometer or sensor_mag", file=str(path),
                             field="mag_topic")
        t_mag, ok = _shifted(d, d["magnetometer_timestamp_relative"])
        t_m, mag = series(path, "sensor_combined.magnetometer_ga", t_mag,
                          _vec(d, [f"magnetometer_ga[{k}]" for k in range(3)], _MAG)[ok],
                          assumed=assumed)
        del t_mag
        mag_desc = "sensor_combined.magnetometer_ga (older firmware) at timestamp + " \
                   "magnetometer_timestamp_relative"
    elif mag_topic == "sensor_mag":
        d = _get(path, data, mag_topic, mag_instance, "magnetometer")
        t_m, mag = series(path, "sensor_mag", _stamps(d, assumed, mag_topic), _vec(d, "xyz", _MAG),
                          assumed=assumed)
        mag_desc = f"sensor_mag[{mag_instance}] (raw, not calibrated)"
    if mag is not None and mag.shape[0] == 0:  # (already FLU and µT: _MAG)
        mag = t_m = None
        mag_desc = f"{mag_topic}: no valid sample"
    return t_m, mag, mag_desc


def _estimates(data: dict, onboard: bool, assumed: list) -> dict:
    """topic -> (time stamps, ``q_NED_FRD``) of ``vehicle_attitude`` (when ``onboard``) and
    ``vehicle_attitude_groundtruth``, copied out of pyulog's arrays."""
    estimates = {}
    for name in ("vehicle_attitude", "vehicle_attitude_groundtruth"):
        if (name, 0) in data and (onboard or name != "vehicle_attitude"):
            d = data[(name, 0)]
            estimates[name] = (_stamps(d, assumed, name),
                               _vec(d, [f"q[{k}]" for k in range(4)]))
    return estimates


def _resampled(path, estimates: dict, t_g: np.ndarray, assumed: list) -> tuple:
    """``(q_onboard, q_true, onboard description)``: the estimates in ENU/FLU slerped onto
    the gyro time stamps (each popped from ``estimates`` once used: its samples are not
    kept)."""
    q_onboard = q_true = None
    onboard_desc = None
    if "vehicle_attitude" in estimates:
        t_q, q = estimates.pop("vehicle_attitude")
        q_onboard = onboard_on(path, "vehicle_attitude", t_q, ned_frd_to_enu_flu(q), t_g)
        onboard_desc = "vehicle_attitude (PX4's estimator, EKF2 on current firmware), " \
                       "slerped onto the gyro time stamps"
    if "vehicle_attitude_groundtruth" in estimates:
        t_q, q = estimates.pop("vehicle_attitude_groundtruth")
        q_true = onboard_on(path, "vehicle_attitude_groundtruth", t_q, ned_frd_to_enu_flu(q),
                            t_g)
        assumed.append("vehicle_attitude_groundtruth (the simulator's truth) is q_true, "
                       "slerped onto the gyro time stamps.")
    return q_onboard, q_true, onboard_desc
