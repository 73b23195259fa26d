"""Reader for ArduPilot DataFlash logs (``.BIN``), through ``pymavlink``'s ``DFReader``
(optional extra ``logs``).

=====================  =====================================================  ===============
what                   messages and fields (ArduPilot units)                  option
=====================  =====================================================  ===============
gyro + accelerometer   ``IMU``: ``GyrX..Z`` (rad/s), ``AccX..Z`` (m/s²) at    ``instance``
                       ``TimeUS``; instance = field ``I`` (current firmware)
                       or the message ``IMU``/``IMU2``/``IMU3`` (older)
magnetometer           ``MAG``: ``MagX..Z`` (milligauss, offsets applied by   ``mag_instance``
                       ArduPilot) at ``TimeUS``; instances as for ``IMU``
the device's own       ``ATT`` (default: the active EKF's ``Roll, Pitch,      ``onboard``
estimate               Yaw``, degrees) or ``AHR2`` (the backup DCM; its
                       quaternion ``Q1..Q4`` when logged, else its angles)
=====================  =====================================================  ===============

Frames and units: ArduPilot's body frame is FRD, its reference NED; vectors become FLU
(``[x, -y, -z]``), attitudes ``q_ENU_FLU = q_ENU_NED ⊗ q_NED_FRD ⊗ q_FRD_FLU`` with
``q_NED_FRD`` from the z-y'-x'' Euler angles (``R = Rz(yaw) Ry(pitch) Rx(roll)``);
``frames = {"reference": "ENU", "body": "FLU"}``. The accelerometer is specific force
(−g on FRD z at rest). Magnetometer milligauss → µT (×0.1). Time: ``TimeUS`` (µs since
boot; ``TimeMS`` in ms on old logs) in s. ``ATT`` is logged in centidegrees (0.01°
resolution). The estimate is slerped onto the gyro time stamps (a comparison series); its
heading refers to true north when ArduPilot has a declination (``COMPASS_DEC``, set from
the GPS position with ``COMPASS_AUTODEC``), else magnetic north: said, with the log's
parameters, in ``meta["onboard_heading_reference"]``.

Errors: a file pymavlink cannot parse, or in which it skipped bad bytes (corruption in
the middle), is an :class:`~gnomon.errors.InputError` unless ``allow_corrupt=True``
(then stated in ``meta["assumed"]``). A file cut off inside its last message (as a log
cut at power-off, or pymavlink's 64 KiB ``test.BIN``) reads up to the last complete
message; ``meta["assumed"]`` and ``meta["truncated"]`` say where it was cut and up to
which time stamp the data go (``gnomon inspect`` prints it).
"""

from __future__ import annotations

import os
from array import array
from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import (
    as_path,
    build,
    cut_short,
    frd_to_flu,
    ned_frd_to_enu_flu,
    onboard_on,
    optional_import,
    quiet,
    quiet_fd2,
    series,
)
from gnomon.recording import Recording
from gnomon.rotation import quat_from_euler

__all__ = ["read_dataflash", "DATAFLASH_HEAD", "ONBOARD_MESSAGES"]

DATAFLASH_HEAD = b"\xa3\x95"
ONBOARD_MESSAGES = ("ATT", "AHR2")
_MGAUSS_TO_UT = 0.1
_CORRUPT = ("bad header", "Skipped", "unknown msg type", "Failed to parse", "bad msg")


def _time_field(fmt, path="") -> tuple[str, float]:
    if "TimeUS" in fmt.columns:
        return "TimeUS", 1e-6
    if "TimeMS" in fmt.columns:
        return "TimeMS", 1e-3
    raise InputError(f"message {fmt.name} has no TimeUS/TimeMS field", file=str(path),
                     field=fmt.name)


def _heading_reference(params: dict) -> str:
    """Which north ArduPilot's estimate refers heading to: true north when it applies a
    declination (``COMPASS_DEC``, rad; set from the GPS position with
    ``COMPASS_AUTODEC = 1``), magnetic north when the declination is 0."""
    dec = params.get("COMPASS_DEC")
    auto = params.get("COMPASS_AUTODEC")
    if dec is None and auto is None:
        return ("true north if ArduPilot had a declination (COMPASS_DEC, COMPASS_AUTODEC), "
                "else magnetic north; the log records neither parameter")
    deg = np.degrees(float(dec or 0.0))
    if auto:
        return (f"true north (ArduPilot sets the declination from its GPS position, "
                f"COMPASS_AUTODEC = {auto:g}; COMPASS_DEC = {deg:.2f} deg in the log)")
    if deg != 0.0:
        return f"true north (ArduPilot applies COMPASS_DEC = {deg:.2f} deg)"
    return "magnetic north (COMPASS_DEC = 0 and COMPASS_AUTODEC = 0: no declination applied)"


def read_dataflash(path: str | os.PathLike, *, instance: int = 0, mag_instance: int = 0,
                   onboard: str = "ATT", allow_corrupt: bool = False) -> Recording:
    """Read an ArduPilot DataFlash ``.BIN`` log (module docstring: messages, frames, units).

    Parameters
    ----------
    path : the ``.BIN`` file.
    instance : IMU instance (0 = the first IMU).
    mag_instance : magnetometer instance.
    onboard : ``"ATT"``, ``"AHR2"`` or ``"none"``: which estimate becomes ``q_onboard``.
    allow_corrupt : read a file in which pymavlink skipped bad bytes (stated in meta).
    """
    path = as_path(path)
    dfreader = optional_import("pymavlink.DFReader", "pymavlink>=2.4.30", path,
                               "ArduPilot DataFlash logs")
    _check_options(path, onboard, instance, mag_instance)
    assumed: list[str] = []
    scan = _scan(path, dfreader, instance, mag_instance, onboard)
    _corruption(path, scan, allow_corrupt, assumed)
    t, gyro, accel = _imu(path, scan, instance, assumed)
    truncated = None if scan.cut is None else cut_short(*scan.cut, t, assumed)
    t_m, mag, mag_desc = _mag(path, scan, assumed)
    q_onboard, onboard_desc = _onboard(path, scan, onboard, t, assumed)
    heading_ref = _heading_reference(scan.params) if q_onboard is not None else None
    assumed[:0] = [
        "ArduPilot body frame FRD converted to FLU ([x, -y, -z]); NED to ENU "
        "(q_ENU_FLU = q_ENU_NED * q_NED_FRD * q_FRD_FLU).",
        "IMU gyro rad/s and accelerometer m/s^2 (specific force); MAG milligauss "
        "converted to uT (x0.1).",
        "Time is ArduPilot's TimeUS (us since boot) in s.",
    ]
    meta = {
        "format": "dataflash", "assumed": assumed,
        "device": {"messages": scan.messages},
        "imu": scan.imu_name + (f" I={scan.imu_i}" if scan.imu_i is not None else ""),
        "instance": instance, "mag": mag_desc, "mag_instance": mag_instance,
        "onboard": onboard_desc,
        "available": {k: scan.counts[k] for k in sorted(scan.counts)
                      if k.startswith(("IMU", "MAG", "ATT", "AHR", "ACC", "GYR"))},
        "params": len(scan.params), "truncated": truncated,
        "onboard_heading_reference": heading_ref,
    }
    names = {"t": f"{scan.imu_name}.TimeUS", "gyro": f"{scan.imu_name}.GyrX..Z",
             "accel": f"{scan.imu_name}.AccX..Z", "mag": str(scan.mag_name),
             "q_onboard": str(onboard)}
    return build(path, names, t=t, gyro=gyro, accel=accel, accel_t=None, mag=mag, mag_t=t_m,
                 mag_unit="uT", q_onboard=q_onboard, frames={"reference": "ENU", "body": "FLU"},
                 source=f"{path.stem} (ArduPilot DataFlash)", meta=meta)


def _check_options(path, onboard: str, instance, mag_instance) -> None:
    if onboard not in ONBOARD_MESSAGES + ("none",):
        raise InputError(f"expected ATT, AHR2 or none, got {onboard!r}", file=str(path),
                         field="onboard")
    for name, value in (("instance", instance), ("mag_instance", mag_instance)):
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 0:
            raise InputError(f"expected an instance number >= 0, got {value!r}",
                             file=str(path), field=name)


@dataclass
class _Scan:
    """What one pass of pymavlink over the log gave: the wanted fields of every wanted
    message as rows of ``array('d')`` (8 bytes a value, no message kept), and the facts
    about the file the rest of the reader needs."""

    formats: dict  # message name -> pymavlink's format
    imu_name: str
    imu_i: int | None  # the value of field I of the IMU instance; None: by message name
    mag_name: str
    mag_i: int | None
    rows: dict  # message name -> array('d') of its rows, ``cols[name]`` values each
    cols: dict  # message name -> the fields kept, time first (I last when instanced)
    messages: list  # the first 5 MSG texts
    cut: tuple | None  # (start, size, bytes present) of a message cut off by the end
    skipped: int  # bytes the indexer found in no message
    counts: dict  # message name -> count
    params: dict
    printed: str  # what pymavlink printed

    def table(self, n: str, want_i: int | None) -> np.ndarray:
        """The rows of message ``n`` as an (N, len(cols[n])) view (those of instance
        ``want_i``, field I dropped, when given)."""
        a = np.frombuffer(self.rows[n], dtype=float).reshape(-1, len(self.cols[n])) \
            if n in self.rows else np.zeros((0, 1))
        if want_i is not None and a.size:
            a = a[a[:, -1] == want_i][:, :-1]
        return a


def _scan(path, dfreader, instance: int, mag_instance: int, onboard: str) -> _Scan:
    """Read the log once through pymavlink (its output captured): an InputError on any
    failure of the library."""
    try:
        with quiet() as printed, quiet_fd2():
            log = dfreader.DFReader_binary(str(path), zero_time_base=False)
            formats = {f.name: f for f in log.formats.values()}
            imu_name, imu_i = _pick(formats, "IMU", instance)
            mag_name, mag_i = _pick(formats, "MAG", mag_instance)
            wanted = [n for n in (imu_name, mag_name, onboard) if n in formats]
            cols = {n: _fields(path, formats[n], imu_name, imu_i, mag_name, mag_i)
                    for n in wanted}
            rows, messages = _collect(log, wanted, cols, "MSG" in formats)
            cut, skipped = _cut_and_skipped(log)
            counts = {log.id_to_name[i]: int(c) for i, c in enumerate(log.counts)
                      if c and i in log.id_to_name}
            params = dict(log.params) if hasattr(log, "params") else {}
    except InputError:
        raise
    except Exception as err:  # pymavlink's failures are not enumerated: the file is unreadable
        raise InputError(f"cannot read as DataFlash (pymavlink: {type(err).__name__}: {err})",
                         file=str(path)) from None
    return _Scan(formats, imu_name, imu_i, mag_name, mag_i, rows, cols, messages, cut,
                 skipped, counts, params, printed.getvalue())


def _pick(formats: dict, kind: str, inst: int) -> tuple[str, int | None]:
    """(message name, value of field I or None) of instance ``inst``."""
    fmt = formats.get(kind)
    if fmt is not None and "I" in fmt.columns:
        return kind, inst
    return (kind if inst == 0 else f"{kind}{inst + 1}"), None


def _fields(path, fmt, imu_name: str, imu_i: int | None, mag_name: str, mag_i: int | None
            ) -> list[str]:
    """The fields to keep of message ``fmt`` (the IMU's, the magnetometer's or an
    estimate's): time first, ``I`` last when the instance is a field; a missing one
    raises."""
    n = fmt.name
    tf, _ = _time_field(fmt, path)
    if n == imu_name:
        fields = [tf, "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"]
    elif n == mag_name:
        fields = [tf, "MagX", "MagY", "MagZ"]
    elif n == "AHR2" and "Q1" in fmt.columns:
        fields = [tf, "Q1", "Q2", "Q3", "Q4"]
    else:
        fields = [tf, "Roll", "Pitch", "Yaw"]
    if (n == imu_name and imu_i is not None) or (n == mag_name and mag_i is not None):
        fields = fields + ["I"]
    missing = [c for c in fields if c not in fmt.columns]
    if missing:
        raise InputError(f"message {n} has no field {missing[0]} (it has "
                         f"{', '.join(fmt.columns)})", file=str(path),
                         field=f"{n}.{missing[0]}")
    return fields


def _collect(log, wanted: list, cols: dict, has_msg: bool) -> tuple[dict, list]:
    """Every message of the ``wanted`` types, its fields ``cols[name]`` appended to that
    type's ``array('d')``; and the first 5 ``MSG`` texts."""
    rows = {n: array("d") for n in wanted}
    messages: list[str] = []
    types = wanted + (["MSG"] if has_msg else [])
    while wanted:
        m = log.recv_match(type=types)
        if m is None:
            break
        n = m.get_type()
        if n == "MSG":
            if len(messages) < 5:
                messages.append(str(m.Message))
            continue
        rows[n].extend([getattr(m, c) for c in cols[n]])
    return rows, messages


def _cut_and_skipped(log) -> tuple[tuple | None, int]:
    """From pymavlink's index: the message cut off by the end of the file ((its start, its
    size, bytes present) or None) and the bytes in no message found (skipped as bad)."""
    last = max(((log.offsets[i][-1], i) for i in range(len(log.offsets))
                if log.offsets[i] and i in log.formats), default=None)
    left = 0  # bytes of an incomplete last message (the indexer counts it)
    cut = None  # (its start, its size, bytes present)
    if last is not None and last[0] + log.formats[last[1]].len > log.data_len:
        left = int(log.data_len - last[0])
        cut = (int(last[0]), int(log.formats[last[1]].len), left)
    # bytes in messages the indexer found; fewer than the file holds: it skipped some
    covered = sum(len(log.offsets[i]) * log.formats[i].len
                  for i in range(len(log.offsets)) if log.offsets[i] and i in log.formats)
    skipped = int(log.data_len - covered - (left - log.formats[last[1]].len
                                             if left else 0))
    return cut, skipped


def _corruption(path, scan: _Scan, allow_corrupt: bool, assumed: list) -> None:
    """Refuse a log in which pymavlink found corruption, or bytes in no message, unless
    ``allow_corrupt`` (said)."""
    text = scan.printed
    if scan.skipped > 0 and not any(k in text for k in _CORRUPT):
        text += f"\nSkipped {scan.skipped} bad bytes (messages found cover fewer bytes than " \
                "the file)"
    if any(k in text for k in _CORRUPT):
        line = next(ln for ln in text.splitlines() if any(k in ln for k in _CORRUPT))
        if not allow_corrupt:
            raise InputError(f"pymavlink found corruption ({line.strip()}); pass "
                             "allow_corrupt=True to read what it recovered", file=str(path))
        assumed.append(f"pymavlink found corruption ({line.strip()}); what it recovered was "
                       "read (allow_corrupt=True).")


def _imu(path, scan: _Scan, instance: int, assumed: list) -> tuple:
    """``(t, gyro, accel)`` of the IMU instance, FLU; at least 2 messages."""
    imu_name, imu_i = scan.imu_name, scan.imu_i
    imu_inst = [k for k in scan.counts
                if k == "IMU" or (k.startswith("IMU") and k[3:].isdigit())]
    if imu_name not in scan.formats:
        raise InputError(f"no {imu_name} message (IMU instance {instance}); the log has "
                         f"{', '.join(sorted(imu_inst)) or 'no IMU message'}", file=str(path),
                         field=imu_name)
    imu = scan.table(imu_name, imu_i)
    scale = _time_field(scan.formats[imu_name])[1]
    if imu.shape[0] < 2:
        raise InputError(f"{imu.shape[0]} {imu_name} message(s) for instance {instance}; at "
                         "least 2 needed", file=str(path), field=imu_name)
    t, v = series(path, f"{imu_name}.GyrX..AccZ", imu[:, 0] * scale, imu[:, 1:7], width=6,
                  assumed=assumed)
    return t, frd_to_flu(v[:, :3]), frd_to_flu(v[:, 3:])


def _mag(path, scan: _Scan, assumed: list) -> tuple:
    """``(t_mag, mag in µT FLU, description)``; (None, None, why) without a message."""
    mag_name, mag_i = scan.mag_name, scan.mag_i
    if mag_name in scan.formats:
        a = scan.table(mag_name, mag_i)
        if a.shape[0]:
            t_m, mag = series(path, f"{mag_name}.MagX..Z",
                              a[:, 0] * _time_field(scan.formats[mag_name])[1], a[:, 1:4],
                              assumed=assumed)
            mag = frd_to_flu(mag) * _MGAUSS_TO_UT
            return t_m, mag, f"{mag_name}" + (f" I={mag_i}" if mag_i is not None else "")
    return None, None, "none in the log"


def _onboard(path, scan: _Scan, onboard: str, t: np.ndarray, assumed: list) -> tuple:
    """``(q_onboard, description)``: ATT's angles or AHR2's quaternion (or angles) as
    ``q_ENU_FLU`` slerped onto the gyro time stamps ``t``; (None, None) when absent."""
    if onboard == "none" or onboard not in scan.formats:
        return None, None
    a = scan.table(onboard, None)
    if a.shape[0] < 2:
        return None, None
    t_q = a[:, 0] * _time_field(scan.formats[onboard])[1]
    if a.shape[1] == 5:
        q_nf = a[:, 1:5]
        desc = f"{onboard} quaternion Q1..Q4 (q_NED_FRD)"
    else:
        q_nf = quat_from_euler(np.deg2rad(a[:, 1:4]))
        desc = f"{onboard} Roll, Pitch, Yaw (deg, z-y'-x'' NED/FRD)"
    t_q, q_nf = series(path, onboard, t_q, q_nf, width=4, assumed=assumed)
    q_onboard = onboard_on(path, onboard, t_q, ned_frd_to_enu_flu(q_nf), t)
    return q_onboard, desc + ", slerped onto the gyro time stamps"
