"""Reader for Xsens MT Manager text exports (``.txt``/``.csv``, "Export to ASCII").

Layout (as MT Manager writes it): comment lines starting with ``//`` (``// Update Rate:
100.0Hz``, ``// Coordinate system: ENU``, device and filter information), then a header
row and one row per data packet, separated by tabs (or ``,``/``;``). Columns by name:

=========================================  ============================================
column                                     becomes
=========================================  ============================================
``SampleTimeFine``                         time: 10 kHz ticks (0.1 ms), unwrapped at 2³²
``Time`` / ``SampleTimeCoarse`` (s)        time, when there is no ``SampleTimeFine``
``PacketCounter`` + ``// Update Rate``     time, when there is neither (unwrapped at 2¹⁶)
``Acc_X, Acc_Y, Acc_Z``                    accelerometer, m/s² (specific force)
``Gyr_X, Gyr_Y, Gyr_Z``                    gyro, rad/s (``gyro_unit="deg/s"`` if exported
                                           so)
``Mag_X, Mag_Y, Mag_Z``                    magnetometer in a.u. (normalised to the field
                                           at the magnetic calibration) × ``mag_au_uT``
                                           µT (default 50 µT, a mid-latitude field; only
                                           its direction is measured)
``Quat_q0..q3`` or ``Roll, Pitch, Yaw``    ``q_onboard``: the MTi's own ``q_LS`` (sensor S
                                           to local frame L), ``[w, x, y, z]``; Euler
                                           z-y'-x'' in degrees
=========================================  ============================================

Local frame L from ``// Coordinate system:`` (ENU, Xsens' default when not stated; NED
or NWU are turned to ENU: ``q_ENU_NED ⊗ q``, ``q_ENU_NWU ⊗ q``; with NED the sensor
frame is taken as Xsens' NED-compatible x, −y, −z and converted back to FLU). An empty
or ``NaN`` cell means no sample of that sensor in that packet (sensors at different
output rates); a partly filled sensor is an error naming the column and row.
``frames = {"reference": "ENU", "body": "xsens"}`` (the MTi's sensor frame S).
"""

from __future__ import annotations

import csv as _csv
import io
import os
import re
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import (
    Q_ENU_NED,
    Q_ENU_NWU,
    Q_FRD_FLU,
    as_path,
    build,
    frd_to_flu,
    onboard_on,
    series,
)
from gnomon.recording import Recording
from gnomon.rotation import quat_from_euler, quat_mul

__all__ = ["read_xsens", "is_xsens_text"]

_GROUPS = {"accel": ("Acc_X", "Acc_Y", "Acc_Z"), "gyro": ("Gyr_X", "Gyr_Y", "Gyr_Z"),
           "mag": ("Mag_X", "Mag_Y", "Mag_Z"), "quat": ("Quat_q0", "Quat_q1", "Quat_q2",
                                                         "Quat_q3"),
           "euler": ("Roll", "Pitch", "Yaw")}


def is_xsens_text(head: str) -> bool:
    """Whether the first kilobytes of a text file look like an MT Manager export."""
    lines = head.splitlines()
    comments = [ln for ln in lines if ln.startswith("//")]
    header = next((ln for ln in lines if ln.strip() and not ln.startswith("//")), "")
    return bool(re.search(r"\b(PacketCounter|SampleTimeFine)\b", header)) and (
        bool(comments) or "Acc_X" in header or "Gyr_X" in header)


def read_xsens(path: str | os.PathLike, *, gyro_unit: str = "rad/s", mag_au_uT: float = 50.0,
               onboard: bool = True) -> Recording:
    """Read an MT Manager text export (module docstring: columns, units, frames).

    Parameters
    ----------
    path : the exported text file.
    gyro_unit : ``"rad/s"`` (MT Manager's default) or ``"deg/s"``.
    mag_au_uT : µT that 1 a.u. of ``Mag_*`` stands for (the field strength where the MTi
        was calibrated; default 50 µT).
    onboard : keep the MTi's orientation as ``q_onboard``.
    """
    path = as_path(path)
    _check_options(path, gyro_unit, mag_au_uT)
    info, table = _parse(path)
    assumed: list[str] = []
    tname, t_all = _time_stamps(table, info, assumed)
    system = _coordinate_system(path, info, assumed)
    got = {k: _sensor(table, k, t_all, tname, assumed) for k in ("gyro", "accel", "mag")}
    for k in ("gyro", "accel"):
        if got[k] is None:
            raise InputError(f"no {' '.join(_GROUPS[k])} columns", file=str(path),
                             field=_GROUPS[k][0])
    t, w = got["gyro"]
    t_a, acc = got["accel"]
    t_m, m = got["mag"] if got["mag"] is not None else (None, None)
    w, acc, m = _to_si_flu(w, acc, m, gyro_unit, mag_au_uT, system, assumed)
    q_onboard, onboard_desc = (_onboard(table, t_all, t, system, assumed) if onboard
                               else (None, None))
    assumed[:0] = ["Xsens sensor frame S; Acc m/s^2 (specific force), Gyr " + gyro_unit + "."]
    meta = {"format": "xsens", "assumed": assumed, "coordinate_system": system,
            "device": {k: info[k] for k in info if k in ("DeviceId", "ProductCode",
                                                          "Firmware Version", "Filter Profile",
                                                          "Update Rate", "MT Manager version")},
            "onboard": onboard_desc,
            "onboard_heading_reference": None if q_onboard is None else (
                "magnetic north (the MTi's default; true north only if a declination was "
                "set in the device)")}
    return build(path, {"t": tname, "gyro": "Gyr_X", "accel": "Acc_X", "mag": "Mag_X",
                        "q_onboard": "Quat_q0"},
                 t=t, gyro=w, accel=acc, accel_t=t_a, mag=m, mag_t=t_m, mag_unit="uT",
                 q_onboard=q_onboard, frames={"reference": "ENU", "body": "xsens"},
                 source=f"{path.stem} (Xsens MT Manager)", meta=meta)


def _check_options(path: Path, gyro_unit: str, mag_au_uT) -> None:
    if gyro_unit not in ("rad/s", "deg/s"):
        raise InputError(f"expected rad/s or deg/s, got {gyro_unit!r}", file=str(path),
                         field="gyro_unit")
    if not (isinstance(mag_au_uT, int | float) and np.isfinite(mag_au_uT) and mag_au_uT > 0):
        raise InputError(f"expected a positive field strength in uT, got {mag_au_uT!r}",
                         file=str(path), field="mag_au_uT")


class _Table:
    """The data rows of an export as strings (each as long as the header), by column name."""

    def __init__(self, path: Path, header: list[str], rows: list[list[str]]):
        self.path, self.rows = path, rows
        self.cols = {name: j for j, name in enumerate(header)}

    def __contains__(self, name: str) -> bool:
        return name in self.cols

    def column(self, name: str) -> np.ndarray:
        """One column as float: an empty or ``NaN`` cell is NaN, another non-number raises
        naming the column and the data row (1-based)."""
        j = self.cols[name]
        out = np.empty(len(self.rows))
        for i, r in enumerate(self.rows):
            c = r[j].strip()
            if c == "" or c.lower() == "nan":
                out[i] = np.nan
                continue
            try:
                out[i] = float(c)
            except ValueError:
                raise InputError(f"not a number: {c!r}", file=str(self.path), field=name,
                                 row=i + 1) from None
        return out

    def group(self, key: str) -> tuple[np.ndarray, np.ndarray] | None:
        """The columns of ``_GROUPS[key]`` as (rows with a sample, (N, k) values), None when
        the file has none of them; an incomplete group or a partly filled row raises."""
        names = _GROUPS[key]
        present = [n in self.cols for n in names]
        if not any(present):
            return None
        if not all(present):
            raise InputError(f"the group {', '.join(names)} is incomplete", file=str(self.path),
                             field=names[present.index(False)])
        v = np.column_stack([self.column(n) for n in names])
        filled = np.isfinite(v)
        partial = filled.any(axis=1) & ~filled.all(axis=1)
        if partial.any():
            i = int(np.argmax(partial))
            raise InputError("empty cell (the other axes have a value)", file=str(self.path),
                             field=names[int(np.argmax(~filled[i]))], row=i + 1)
        keep = filled.all(axis=1)
        return keep, v


def _parse(path: Path) -> tuple[dict, _Table]:
    """The ``// key: value`` comment lines (as a dict) and the table under them."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise InputError(f"not a UTF-8 text file ({err.reason} at byte {err.start})",
                         file=str(path)) from None
    lines = text.splitlines()
    comments = [ln[2:].strip() for ln in lines if ln.startswith("//")]
    body = [ln for ln in lines if ln.strip() and not ln.startswith("//")]
    if not body:
        raise InputError("no header row after the // comment lines", file=str(path))
    delim = "\t" if "\t" in body[0] else (";" if ";" in body[0] else ",")
    rows = list(_csv.reader(io.StringIO("\n".join(body)), delimiter=delim))
    header = [c.strip() for c in rows[0]]
    data = rows[1:]
    if not data:
        raise InputError("no data rows after the header", file=str(path))
    for i, r in enumerate(data):
        if len(r) < len(header):
            r.extend([""] * (len(header) - len(r)))  # MT Manager drops trailing empty cells
        elif len(r) > len(header):
            raise InputError(f"{len(r)} cells, header has {len(header)}", file=str(path),
                             row=i + 1)
    info = {}
    for c in comments:
        if ":" in c:
            k, v = c.split(":", 1)
            info[k.strip()] = v.strip()
    return info, _Table(path, header, data)


def _time_stamps(table: _Table, info: dict, assumed: list) -> tuple[str, np.ndarray]:
    """(the column the time comes from, the time of every row in s, NaN where empty)."""
    if "SampleTimeFine" in table:
        t_all = _unwrapped(table.column("SampleTimeFine"), 32) * 1e-4
        assumed.append("Time from SampleTimeFine (10 kHz ticks, unwrapped at 2^32).")
        return "SampleTimeFine", t_all
    if "Time" in table or "SampleTimeCoarse" in table:
        tname = "Time" if "Time" in table else "SampleTimeCoarse"
        t_all = table.column(tname)
        assumed.append(f"Time from {tname} (s).")
        return tname, t_all
    if "PacketCounter" in table:
        m = re.search(r"([\d.]+)\s*Hz", info.get("Update Rate", ""))
        if not m:
            raise InputError("no time column (SampleTimeFine, Time) and no '// Update Rate:' "
                             "line to time the PacketCounter", file=str(table.path),
                             field="SampleTimeFine")
        rate = float(m.group(1))
        t_all = _unwrapped(table.column("PacketCounter"), 16) / rate
        assumed.append(f"Time from PacketCounter at the update rate {rate:g} Hz.")
        return "PacketCounter", t_all
    raise InputError("no time column (SampleTimeFine, Time, SampleTimeCoarse or "
                     "PacketCounter)", file=str(table.path), field="SampleTimeFine")


def _unwrapped(counter: np.ndarray, bits: int) -> np.ndarray:
    """A ``bits``-bit counter (NaN where empty) unwrapped: 2^bits added at each step back by
    more than half the range."""
    ok = np.isfinite(counter)
    k = counter[ok].astype(np.int64)
    wraps = np.concatenate([[0], np.cumsum(np.diff(k) < -2**(bits - 1))])
    out = np.full(counter.size, np.nan)
    out[ok] = k + wraps * 2**bits
    return out


def _coordinate_system(path: Path, info: dict, assumed: list) -> str:
    """The local frame L of ``// Coordinate system:`` (ENU when not stated)."""
    system = info.get("Coordinate system", "ENU").strip().upper() or "ENU"
    if system not in ("ENU", "NED", "NWU"):
        raise InputError(f"unknown coordinate system {system!r} (ENU, NED or NWU)",
                         file=str(path), field="Coordinate system")
    if "Coordinate system" not in info:
        assumed.append("No '// Coordinate system:' line: ENU (Xsens' default) assumed.")
    return system


def _sensor(table: _Table, key: str, t_all: np.ndarray, tname: str, assumed: list
            ) -> tuple[np.ndarray, np.ndarray] | None:
    """One sensor's own samples and time stamps (:func:`series`), None when the file has
    none of its columns; a sample in a row without a time stamp raises."""
    g = table.group(key)
    if g is None:
        return None
    keep, v = g
    if np.any(keep & ~np.isfinite(t_all)):
        i = int(np.argmax(keep & ~np.isfinite(t_all)))
        raise InputError("no time stamp for a sample", file=str(table.path), field=tname,
                         row=i + 1)
    return series(table.path, _GROUPS[key][0], t_all[keep], v[keep], width=v.shape[1],
                  assumed=assumed)


def _to_si_flu(w: np.ndarray, acc: np.ndarray, m: np.ndarray | None, gyro_unit: str,
               mag_au_uT: float, system: str, assumed: list) -> tuple:
    """Gyro in rad/s, magnetometer a.u. in µT and, with NED, the sensor axes x, -y, -z
    back to FLU."""
    if gyro_unit == "deg/s":
        w = np.deg2rad(w)
    if m is not None:
        m = m * float(mag_au_uT)
        assumed.append(f"Magnetometer a.u. (normalised at calibration) x {mag_au_uT:g} uT.")
    if system == "NED":
        w, acc = frd_to_flu(w), frd_to_flu(acc)
        m = None if m is None else frd_to_flu(m)
        assumed.append("Coordinate system NED: sensor axes x, -y, -z converted to FLU.")
    return w, acc, m


def _onboard(table: _Table, t_all: np.ndarray, t: np.ndarray, system: str, assumed: list
             ) -> tuple[np.ndarray | None, str | None]:
    """The MTi's own ``q_LS`` (``Quat_q0..q3``, else ``Roll, Pitch, Yaw``) with L turned to
    ENU, slerped onto the gyro time stamps ``t``, and its description; (None, None) when
    the file has neither."""
    if "Quat_q0" in table:
        keep, v = table.group("quat")
        t_q, qq = series(table.path, "Quat_q0", t_all[keep], v[keep], width=4, assumed=assumed)
        desc = "Quat_q0..q3 (q_LS)"
    elif "Roll" in table:
        keep, v = table.group("euler")
        t_q, e = series(table.path, "Roll", t_all[keep], v[keep], assumed=assumed)
        qq = quat_from_euler(np.deg2rad(e))
        desc = "Roll, Pitch, Yaw (deg, z-y'-x'', q_LS)"
    else:
        return None, None
    if system == "NED":
        qq = quat_mul(quat_mul(Q_ENU_NED, qq), Q_FRD_FLU)
    elif system == "NWU":
        qq = quat_mul(Q_ENU_NWU, qq)
    q_onboard = onboard_on(table.path, desc.split(" ")[0], t_q, qq, t)
    return q_onboard, desc + f", local frame {system} turned to ENU, slerped onto the gyro " \
        "time stamps"

