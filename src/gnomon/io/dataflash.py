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
    if onboard not in ONBOARD_MESSAGES + ("none",):
        raise InputError(f"expected ATT, AHR2 or none, got {onboard!r}", file=str(path),
                         field="onboard")
    for name, value in (("instance", instance), ("mag_instance", mag_instance)):
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 0:
            raise InputError(f"expected an instance number >= 0, got {value!r}",
                             file=str(path), field=name)
    assumed: list[str] = []
    try:
        with quiet() as printed, quiet_fd2():
            log = dfreader.DFReader_binary(str(path), zero_time_base=False)
            formats = {f.name: f for f in log.formats.values()}
            def pick(kind: str, inst: int) -> tuple[str, int | None]:
                """(message name, value of field I or None) of instance ``inst``."""
                fmt = formats.get(kind)
                if fmt is not None and "I" in fmt.columns:
                    return kind, inst
                return (kind if inst == 0 else f"{kind}{inst + 1}"), None

            imu_name, imu_i = pick("IMU", instance)
            mag_name, mag_i = pick("MAG", mag_instance)
            wanted = [n for n in (imu_name, mag_name, onboard) if n in formats]
            rows = {n: array("d") for n in wanted}  # 8 bytes a value, no message kept
            cols = {}
            messages: list[str] = []
            for n in wanted:
                fmt = formats[n]
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
                cols[n] = fields
            types = wanted + (["MSG"] if "MSG" in formats else [])
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
            counts = {log.id_to_name[i]: int(c) for i, c in enumerate(log.counts)
                      if c and i in log.id_to_name}
            params = dict(log.params) if hasattr(log, "params") else {}
    except InputError:
        raise
    except Exception as err:  # pymavlink's failures are not enumerated: the file is unreadable
        raise InputError(f"cannot read as DataFlash (pymavlink: {type(err).__name__}: {err})",
                         file=str(path)) from None
    text = printed.getvalue()
    if skipped > 0 and not any(k in text for k in _CORRUPT):
        text += f"\nSkipped {skipped} bad bytes (messages found cover fewer bytes than the file)"
    if any(k in text for k in _CORRUPT):
        line = next(ln for ln in text.splitlines() if any(k in ln for k in _CORRUPT))
        if not allow_corrupt:
            raise InputError(f"pymavlink found corruption ({line.strip()}); pass "
                             "allow_corrupt=True to read what it recovered", file=str(path))
        assumed.append(f"pymavlink found corruption ({line.strip()}); what it recovered was "
                       "read (allow_corrupt=True).")

    def table(n: str, want_i: int | None, what: str) -> np.ndarray:
        a = np.frombuffer(rows[n], dtype=float).reshape(-1, len(cols[n])) if n in rows \
            else np.zeros((0, 1))
        if want_i is not None and a.size:
            a = a[a[:, -1] == want_i][:, :-1]
        return a

    imu_inst = [k for k in counts if k == "IMU" or (k.startswith("IMU") and k[3:].isdigit())]
    if imu_name not in formats:
        raise InputError(f"no {imu_name} message (IMU instance {instance}); the log has "
                         f"{', '.join(sorted(imu_inst)) or 'no IMU message'}", file=str(path),
                         field=imu_name)
    imu = table(imu_name, imu_i, "IMU")
    scale = _time_field(formats[imu_name])[1]
    if imu.shape[0] < 2:
        raise InputError(f"{imu.shape[0]} {imu_name} message(s) for instance {instance}; at "
                         "least 2 needed", file=str(path), field=imu_name)
    t, v = series(path, f"{imu_name}.GyrX..AccZ", imu[:, 0] * scale, imu[:, 1:7], width=6,
                  assumed=assumed)
    gyro, accel = frd_to_flu(v[:, :3]), frd_to_flu(v[:, 3:])
    truncated = None if cut is None else cut_short(*cut, t, assumed)
    mag = t_m = None
    mag_desc = "none in the log"
    if mag_name in formats:
        a = table(mag_name, mag_i, "MAG")
        if a.shape[0]:
            t_m, mag = series(path, f"{mag_name}.MagX..Z",
                              a[:, 0] * _time_field(formats[mag_name])[1], a[:, 1:4],
                              assumed=assumed)
            mag = frd_to_flu(mag) * _MGAUSS_TO_UT
            mag_desc = f"{mag_name}" + (f" I={mag_i}" if mag_i is not None else "")
    q_onboard = None
    onboard_desc = None
    if onboard != "none" and onboard in formats:
        a = table(onboard, None, onboard)
        if a.shape[0] >= 2:
            t_q = a[:, 0] * _time_field(formats[onboard])[1]
            if a.shape[1] == 5:
                q_nf = a[:, 1:5]
                onboard_desc = f"{onboard} quaternion Q1..Q4 (q_NED_FRD)"
            else:
                q_nf = quat_from_euler(np.deg2rad(a[:, 1:4]))
                onboard_desc = f"{onboard} Roll, Pitch, Yaw (deg, z-y'-x'' NED/FRD)"
            t_q, q_nf = series(path, onboard, t_q, q_nf, width=4, assumed=assumed)
            q_onboard = onboard_on(path, onboard, t_q, ned_frd_to_enu_flu(q_nf), t)
            onboard_desc += ", slerped onto the gyro time stamps"
    heading_ref = _heading_reference(params) if q_onboard is not None else None
    assumed[:0] = [
        "ArduPilot body frame FRD converted to FLU ([x, -y, -z]); NED to ENU "
        "(q_ENU_FLU = q_ENU_NED * q_NED_FRD * q_FRD_FLU).",
        "IMU gyro rad/s and accelerometer m/s^2 (specific force); MAG milligauss "
        "converted to uT (x0.1).",
        "Time is ArduPilot's TimeUS (us since boot) in s.",
    ]
    meta = {
        "format": "dataflash", "assumed": assumed,
        "device": {"messages": messages},
        "imu": imu_name + (f" I={imu_i}" if imu_i is not None else ""), "instance": instance,
        "mag": mag_desc, "mag_instance": mag_instance, "onboard": onboard_desc,
        "available": {k: counts[k] for k in sorted(counts)
                      if k.startswith(("IMU", "MAG", "ATT", "AHR", "ACC", "GYR"))},
        "params": len(params), "truncated": truncated,
        "onboard_heading_reference": heading_ref,
    }
    names = {"t": f"{imu_name}.TimeUS", "gyro": f"{imu_name}.GyrX..Z",
             "accel": f"{imu_name}.AccX..Z", "mag": str(mag_name), "q_onboard": str(onboard)}
    return build(path, names, t=t, gyro=gyro, accel=accel, accel_t=None, mag=mag, mag_t=t_m,
                 mag_unit="uT", q_onboard=q_onboard, frames={"reference": "ENU", "body": "FLU"},
                 source=f"{path.stem} (ArduPilot DataFlash)", meta=meta)
