"""Readers for smartphone exports: the tyrex text layout (Android and iOS trial folders),
the "Sensor Logger" app (zip or folder of CSVs) and phyphox (zip or folder of CSVs).

Body frame of every phone: the device axes of Android and iOS (x to the right of the
screen, y up the screen, z out of the screen), ``frames = {"reference": "ENU", "body":
"device"}``; accelerometer as specific force (+g on z lying face up), gyro rad/s,
magnetometer µT. Each sensor keeps its own samples and time stamps.

tyrex (Michel et al. 2018, "benchmarks-attitude-smartphones"; one folder per trial)
-----------------------------------------------------------------------------------
Space-separated text, first column time (s), one file per sensor:

===========  ====================================  =====================================
platform     file                                  becomes
===========  ====================================  =====================================
Android      ``gyroscope-calibrated.txt`` t x y z  gyro (rad/s; ``gyroscope.txt``, raw,
                                                   with ``gyro="raw"``)
             ``accelerometer.txt`` t x y z         accel (m/s², Android's sign)
             ``magnetometer-calibrated.txt``       mag (µT; ``magnetometer.txt``, raw,
                                                   first three values, ``mag="raw"``)
             ``rotation-vector.txt`` t x y z w a   ``q_onboard``: Android's rotation
                                                   vector is ``q_ENU_device`` (magnetic
                                                   north), x, y, z, w order
             ``record.properties``                 device (``[Device]``)
iOS          ``gyroscope.txt`` t x y z             gyro (rad/s, raw: CoreMotion's gyro)
             ``accelerometer.txt`` t x y z         accel: in g with the opposite sign
                                                   (×−9.80665)
             ``magnetometer-calibrated.txt``       mag (µT; 5th column accuracy dropped;
                                                   rows repeating the previous values
                                                   dropped, below; ``magnetometer.txt``
                                                   with ``mag="raw"``)
             ``attitude.txt`` t w x y z            ``q_onboard``: CoreMotion's attitude
                                                   relative to x-north, z-up (NWU):
                                                   ``q_ENU_device = q_ENU_NWU ⊗ q``
             ``description.txt``                   ``[Time] BootTime`` (s)
===========  ====================================  =====================================

iOS's ``magnetometer-calibrated.txt`` (CoreMotion's device-motion field) comes at the
motion rate, ~94 Hz, but every other row (50-51 % of the rows in every iOS trial of the
data set) repeats the previous row's three values exactly at a new time stamp: CoreMotion
holds the last sample of a magnetometer running at ~47 Hz. Those rows are dropped (the
first arrival kept; the count in ``meta["assumed"]``). No other file shows the pattern
(repeats of the previous row in 0-0.2 % of the rows: a raw ``magnetometer.txt`` at 25 Hz
quantised to 0.18 µT, the gyro, the accelerometer, the attitude), and none is changed.
What remains of that file keeps one magnitude (to 0.01 µT) from sample to sample in
98-99.8 % of the pairs of every iOS trial, changing only in jumps (the Nexus 5's: 2-3 %),
and its direction seen through the motion-capture truth drifts with CoreMotion's own
heading: it behaves as CoreMotion's model of the field, not as a measurement. The
fraction is in ``meta["mag_constant_norm_fraction"]`` and said in ``meta["assumed"]``.

Time: ``timeAlignment.txt`` (s) aligns the phone to the motion-capture clock of the data
set: Android ``t + alignment``, iOS ``t − BootTime + alignment`` (``align_time=False``
keeps the phone's own clock). Checked on the data: the rotation vector and the iOS
attitude rotate the resting accelerometer to +9.7 m/s² up and the magnetometer to north.

Truth: when the data set's motion-capture export of the trial is found
(``../../qualisys/<trial>.mat``, or ``reference=`` a path), it becomes ``q_true``
(``q_ENU_device``, magnetic north) on the gyro time stamps and ``mask`` the scored
window (:func:`gnomon.io.tyrex.reference_on`: frames, declination, lost frames, the
authors' bad intervals); ``reference=False`` reads the phone only.

Sensor Logger (Kelvin Choi's app; zip or folder)
------------------------------------------------
CSV files with a header ``time,seconds_elapsed,z,y,x`` (``time`` ns since the Unix epoch;
columns by name): ``Gyroscope.csv`` (rad/s), ``Magnetometer.csv`` (µT; ``mag="raw"``:
``MagnetometerUncalibrated.csv``), the accelerometer *with* gravity from
``TotalAcceleration.csv`` (Android, m/s²) or ``AccelerometerUncalibrated.csv`` (iOS: g with
iOS's sign unless "Standardise Units & Frames" was on; then m/s² with Android's sign) —
``Accelerometer.csv`` is the acceleration without gravity and is not a measurement a
filter can use. ``Orientation.csv`` (``qx, qy, qz, qw``) becomes ``q_onboard``: iOS's is
CoreMotion's x-north-z-up attitude (→ ``q_ENU_NWU ⊗ q``); Android's is taken as the
rotation vector (``q_ENU_device``) — not checked on a real file (the app documents only
"x-north-z-vertical" and differing yaw signs); ``meta["onboard_gravity_deg"]`` tells how
well it agrees with the accelerometer. ``Metadata.csv`` gives platform and device.
t = (time − the first time stamp of any sensor) in s; the origin in ``meta``.

phyphox (zip or folder)
-----------------------
Every CSV whose header has ``Time (s)`` followed by ``Acceleration x (m/s^2)`` (with g),
``Gyroscope x (rad/s)`` or ``Magnetic field x (µT)`` (each sensor's own time column, as in
a phyphox export; comma, tab or semicolon with decimal comma); "Linear Acceleration"
(without g) is skipped. Axes and signs as on Android (phyphox unifies iOS to them).
"""

from __future__ import annotations

import csv as _csv
import io
import os
import re
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import Q_ENU_NWU, as_path, build, onboard_on, series
from gnomon.recording import Recording
from gnomon.rotation import quat_mul, quat_rotate

__all__ = ["read_tyrex", "read_sensorlogger", "read_phyphox", "tyrex_platform",
           "is_sensorlogger", "is_phyphox", "STANDARD_GRAVITY_M_S2"]

STANDARD_GRAVITY_M_S2 = 9.80665
_FRAMES = {"reference": "ENU", "body": "device"}
_AXES = ("Android/iOS device axes: x right, y up the screen, z out of the screen "
         "(right-handed); accelerometer as specific force (+g on z lying face up).")


def onboard_gravity_deg(rec_q, t, accel_t, accel) -> float | None:
    """Median angle (deg) between up as the device's own estimate sees it and the measured
    specific force, over samples where the accelerometer is near 1 g (a plausibility check
    of the estimate's convention; a few degrees when right, tens when wrong)."""
    if rec_q is None or accel is None or accel.shape[0] < 5:
        return None
    rows = np.clip(np.searchsorted(t, accel_t), 0, t.size - 1)
    q = rec_q[rows]
    norm = np.linalg.norm(accel, axis=1)
    ok = np.isfinite(q).all(axis=1) & (np.abs(norm - STANDARD_GRAVITY_M_S2) < 0.5)
    if ok.sum() < 5:
        return None
    up = quat_rotate(q[ok], accel[ok] / norm[ok, None])
    return float(np.degrees(np.median(np.arccos(np.clip(up[:, 2], -1, 1)))))


# ---------------------------------------------------------------------- tyrex
#: why iOS's calibrated magnetometer repeats: CoreMotion's device-motion field is
#: delivered at the motion rate (~94 Hz) but updated at the sensor's (~47 Hz)
_IOS_HELD = ("CoreMotion holds the last magnetometer sample: the field is delivered at the "
             "device-motion rate but the sensor runs at about half of it")


#: two magnetometer samples whose magnitudes differ by less than this (µT) keep it
_CONST_NORM_UT = 0.01

#: which north the phones' own estimate refers heading to in the tyrex data set
_TYREX_NORTH = {
    "android": "magnetic north (Android's rotation vector: y towards magnetic north)",
    "ios": "magnetic north (the data set's iPhone app records CoreMotion's attitude in the "
           "magnetic-north frame, as the data set's own code states)",
}


def tyrex_platform(path: Path) -> str | None:
    """``"android"`` / ``"ios"`` for a tyrex trial folder, else None."""
    if not path.is_dir() or not (path / "accelerometer.txt").is_file():
        return None
    if (path / "rotation-vector.txt").is_file() or (path / "record.properties").is_file():
        return "android"
    if (path / "attitude.txt").is_file() or (path / "description.txt").is_file():
        return "ios"
    return None


def _ini(path: Path) -> dict:
    """``key = value`` lines of a tyrex properties file (sections flattened)."""
    out = {}
    try:
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
                k, v = line.split("=", 1)
                out[k.strip()] = v.strip()
    except OSError:
        pass
    return out


def _text_table(path: Path, min_cols: int) -> np.ndarray:
    if not path.is_file():
        raise InputError("file missing from the trial folder", file=str(path))
    try:
        with open(path, encoding="utf-8", errors="strict") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: said below as one line
            a = np.loadtxt(fh, ndmin=2)
    except UnicodeDecodeError as err:
        raise InputError(f"not a text file ({err.reason} at byte {err.start})",
                         file=str(path)) from None
    except ValueError as err:
        raise InputError(f"not a table of numbers ({str(err).splitlines()[0][:160]})",
                         file=str(path)) from None
    if a.size == 0:
        raise InputError("no rows", file=str(path))
    if a.shape[1] < min_cols:
        raise InputError(f"expected at least {min_cols} columns, got {a.shape[1]}",
                         file=str(path))
    return a


def _drop_held(t: np.ndarray, v: np.ndarray, field: str, assumed: list, why: str
              ) -> tuple[np.ndarray, np.ndarray]:
    """Rows of one sensor (``t`` (N,) s, ``v`` (N, k)) without those whose values all equal
    the previous kept row's: a sample held by the OS and logged again at a new time stamp
    is not a new measurement (the first arrival is kept). The count dropped goes to
    ``assumed`` with ``why``. Only for a file known to hold samples (see ``read_tyrex``):
    a quantised sensor at rest repeats values legitimately."""
    if t.size < 2:
        return t, v
    held = np.all(v[1:] == v[:-1], axis=1)  # runs of repeats equal the first of the run
    if not held.any():
        return t, v
    keep = np.concatenate([[True], ~held])
    assumed.append(f"{field}: {int(held.sum())} of {t.size} rows repeating the previous "
                   f"row's values at a new time stamp dropped ({why}).")
    return t[keep], v[keep]


def read_tyrex(path: str | os.PathLike, *, gyro: str = "calibrated", mag: str = "calibrated",
               align_time: bool = True, onboard: bool = True,
               reference: bool | str | os.PathLike = True) -> Recording:
    """Read one tyrex trial folder (Android or iOS; module docstring: files, frames, time).

    Parameters
    ----------
    path : the trial folder (``datasets/android/<trial>`` or ``datasets/ios/<trial>``).
    gyro : Android: ``"calibrated"`` (``gyroscope-calibrated.txt``) or ``"raw"``; iOS has
        the raw gyro only.
    mag : ``"calibrated"`` (the OS's calibration) or ``"raw"``.
    align_time : apply ``timeAlignment.txt`` (and iOS's BootTime).
    onboard : keep the phone's own attitude as ``q_onboard``.
    reference : ``True``: attach the truth when the data set's ``../../qualisys/<trial>.mat``
        exists (needs ``align_time``); ``False``: none; a path: that QTM export.
    """
    path = as_path(path)
    platform = tyrex_platform(path)
    if platform is None:
        raise InputError("not a tyrex trial folder (expected accelerometer.txt with "
                         "rotation-vector.txt/record.properties or attitude.txt/"
                         "description.txt)", file=str(path))
    for name, value in (("gyro", gyro), ("mag", mag)):
        if value not in ("calibrated", "raw"):
            raise InputError(f"expected calibrated or raw, got {value!r}", file=str(path),
                             field=name)
    assumed = [_AXES]
    props = _ini(path / ("record.properties" if platform == "android" else "description.txt"))
    offset = _tyrex_offset(path, platform, align_time, props, assumed)
    t, w, t_a, acc = _tyrex_imu(path, platform, gyro, offset, assumed)
    mag_file = "magnetometer-calibrated.txt" if mag == "calibrated" else "magnetometer.txt"
    t_m, m, constant_norm = _tyrex_mag(path, platform, mag_file, offset, assumed)
    q_onboard, onboard_desc = _tyrex_onboard(path, platform, offset, t, assumed) if onboard \
        else (None, None)
    device = {k: props[k] for k in ("Manufacturer", "Model", "OSVersion") if k in props}
    meta = {"format": "tyrex", "platform": platform, "assumed": assumed, "device": device,
            "gyro": gyro if platform == "android" else "raw", "mag": mag,
            "onboard": onboard_desc, "time_offset_s": offset,
            "mag_constant_norm_fraction": constant_norm,
            "onboard_heading_reference": None if q_onboard is None else _TYREX_NORTH[platform],
            "onboard_gravity_deg": onboard_gravity_deg(q_onboard, t, t_a, acc)}
    q_true = mask = None
    ref_file = _tyrex_reference(path, reference, align_time)
    if ref_file is not None:
        from gnomon.io.tyrex import reference_on

        q_true, mask, said, meta["truth"] = reference_on(t, ref_file, path.name)
        assumed.extend(said)
    names = {"t": "gyroscope", "gyro": "gyroscope", "accel": "accelerometer.txt",
             "accel_t": "accelerometer.txt", "mag": mag_file, "mag_t": mag_file}
    return build(path, names, t=t, gyro=w, accel=acc, accel_t=t_a, mag=m, mag_t=t_m,
                 mag_unit="uT", q_onboard=q_onboard, q_true=q_true, mask=mask,
                 frames=_FRAMES, source=f"{path.name} (tyrex {platform})", meta=meta)


def _tyrex_offset(path: Path, platform: str, align_time: bool, props: dict, assumed: list
                  ) -> float:
    """The time shift (s) onto the data set's motion-capture clock: ``timeAlignment.txt``,
    minus iOS's ``BootTime``; 0 without ``align_time``."""
    offset = 0.0
    if align_time:
        a = path / "timeAlignment.txt"
        if a.is_file():
            offset = float(_text_table(a, 1).reshape(-1)[0])
            assumed.append(f"Time shifted by timeAlignment.txt ({offset:+.3f} s) onto the "
                           "data set's motion-capture clock.")
    if platform == "ios" and align_time:
        if "BootTime" not in props:
            raise InputError("no BootTime in description.txt (needed to align time; "
                             "align_time=False keeps the phone's clock)",
                             file=str(path / "description.txt"), field="BootTime")
        try:
            offset -= float(props["BootTime"])
        except ValueError:
            raise InputError(f"BootTime is not a number: {props['BootTime']!r}",
                             file=str(path / "description.txt"), field="BootTime") from None
        assumed.append(f"iOS time: t - BootTime ({props['BootTime']} s) + alignment.")
    return offset


def _tyrex_load(path: Path, name: str, cols: int, offset: float, assumed: list) -> tuple:
    """``(t + offset, values (N, cols))`` of the trial's file ``name`` (:func:`series`)."""
    f = path / name
    a = _text_table(f, cols + 1)
    return series(f, name, a[:, 0] + offset, a[:, 1:cols + 1], width=cols, assumed=assumed)


def _tyrex_imu(path: Path, platform: str, gyro: str, offset: float, assumed: list) -> tuple:
    """``(t, gyro rad/s, t_accel, accel m/s^2 specific force)``; iOS's accelerometer from g
    with the opposite sign."""
    if platform == "android":
        gyro_file = "gyroscope-calibrated.txt" if gyro == "calibrated" else "gyroscope.txt"
        t, w = _tyrex_load(path, gyro_file, 3, offset, assumed)
        t_a, acc = _tyrex_load(path, "accelerometer.txt", 3, offset, assumed)
        assumed.append("Android: gyro rad/s, accelerometer m/s^2, magnetometer uT as logged.")
    else:  # iOS: CoreMotion's raw gyro is the only one here
        t, w = _tyrex_load(path, "gyroscope.txt", 3, offset, assumed)
        t_a, acc = _tyrex_load(path, "accelerometer.txt", 3, offset, assumed)
        acc = acc * -STANDARD_GRAVITY_M_S2
        assumed.append("iOS: accelerometer in g with the opposite sign, converted "
                       "(x -9.80665 m/s^2 per g); gyro rad/s (raw); magnetometer uT.")
    return t, w, t_a, acc


def _tyrex_mag(path: Path, platform: str, mag_file: str, offset: float, assumed: list
               ) -> tuple:
    """``(t_mag, mag µT, fraction of consecutive samples keeping the magnitude)``: iOS's
    calibrated field without the rows CoreMotion held (module docstring); (None, None,
    None) without the file."""
    if not (path / mag_file).is_file():
        assumed.append(f"No {mag_file}: no magnetometer.")
        return None, None, None
    t_m, m = _tyrex_load(path, mag_file, 3, offset, assumed)
    constant_norm = None
    if platform == "ios" and mag_file == "magnetometer-calibrated.txt":
        t_m, m = _drop_held(t_m, m, mag_file, assumed, _IOS_HELD)
        norm = np.linalg.norm(m, axis=1)
        if norm.size > 10:
            const = float(np.mean(np.abs(np.diff(norm)) < _CONST_NORM_UT))
            constant_norm = const
            if const > 0.5:
                assumed.append(
                    f"{mag_file}: consecutive samples keep the same magnitude (within "
                    f"{_CONST_NORM_UT} uT) in {100 * const:.1f} % of the pairs, changing "
                    "only in jumps: CoreMotion's calibrated field behaves as a model "
                    "output (a field of fixed magnitude turned by its own attitude "
                    "estimate), not as a measurement; mag='raw' is the uncalibrated one.")
    return t_m, m, constant_norm


def _tyrex_onboard(path: Path, platform: str, offset: float, t: np.ndarray, assumed: list
                   ) -> tuple:
    """``(q_onboard, description)``: Android's rotation vector or iOS's attitude as
    ``q_ENU_device`` slerped onto the gyro time stamps ``t``; (None, None) without it."""
    if platform == "android" and (path / "rotation-vector.txt").is_file():
        f = path / "rotation-vector.txt"
        t_q, v = _tyrex_load(path, "rotation-vector.txt", 4, offset, assumed)
        q_onboard = onboard_on(f, "rotation-vector.txt", t_q, v[:, [3, 0, 1, 2]], t)
        return q_onboard, "Android rotation vector (q_ENU_device, magnetic north; x, y, z, " \
            "w reordered), slerped onto the gyro time stamps"
    if platform == "ios" and (path / "attitude.txt").is_file():
        f = path / "attitude.txt"
        t_q, v = _tyrex_load(path, "attitude.txt", 4, offset, assumed)
        q_onboard = onboard_on(f, "attitude.txt", t_q, quat_mul(Q_ENU_NWU, v), t)
        return q_onboard, "iOS CoreMotion attitude (w, x, y, z relative to x-north z-up, " \
            "turned to ENU by q_ENU_NWU), slerped onto the gyro time stamps"
    return None, None


def _tyrex_reference(path: Path, reference, align_time: bool) -> Path | None:
    """The motion-capture export to attach as truth, or None (module docstring)."""
    if reference is False or reference is None:
        return None
    from gnomon.io.tyrex import reference_path

    ref_file = reference_path(path) if reference is True else as_path(reference)
    if reference is not True and not align_time:
        raise InputError("the reference is on the data set's motion-capture clock: "
                         "needs align_time=True", file=str(path), field="reference")
    if not ref_file.is_file() or not align_time:
        return None
    return ref_file


# ---------------------------------------------------------------------- CSV bundles
#: what zipfile raises on a damaged archive (NotImplementedError: a damaged method field)
_ZIP_ERRORS = (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError,
               RuntimeError, zlib.error)


class _Bundle:
    """The CSV files of a zip or a folder, by base name (``Gyroscope.csv``)."""

    def __init__(self, path: Path):
        self.path = path
        self.files: dict[str, object] = {}
        if path.is_dir():
            for p in sorted(path.rglob("*.csv")):
                self.files.setdefault(p.name, p)
        else:
            try:
                self.zip = zipfile.ZipFile(path)
                for info in self.zip.infolist():
                    if info.filename.lower().endswith(".csv") and not info.is_dir():
                        self.files.setdefault(Path(info.filename).name, info)
            except _ZIP_ERRORS as err:
                raise InputError(f"cannot read as zip ({err})", file=str(path)) from None

    def where(self, name: str) -> str:
        return f"{self.path}/{name}" if self.path.is_dir() else f"{self.path}!{name}"

    def text(self, name: str) -> str:
        item = self.files[name]
        try:
            raw = item.read_bytes() if isinstance(item, Path) else self.zip.read(item)
            return raw.decode("utf-8-sig")
        except UnicodeDecodeError as err:
            raise InputError(f"not a UTF-8 text file ({err.reason} at byte {err.start})",
                             file=self.where(name)) from None
        except _ZIP_ERRORS as err:
            raise InputError(f"cannot read ({err})", file=self.where(name)) from None

    def header(self, name: str) -> list[str]:
        try:
            first = self.text(name).splitlines()[0]
        except (IndexError, InputError):
            return []
        return [c.strip().strip('"') for c in next(_csv.reader([first]))]


def _columns(where: str, text: str, delimiter: str = ",", decimal_comma: bool = False
             ) -> tuple[list[str], list[list[str]]]:
    rows = [r for r in _csv.reader(io.StringIO(text), delimiter=delimiter) if r and
            "".join(r).strip()]
    if not rows:
        raise InputError("empty file", file=where)
    header = [c.strip().strip('"') for c in rows[0]]
    body = rows[1:]
    if not body:
        raise InputError("no data rows after the header", file=where)
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise InputError(f"{len(r)} cells, header has {len(header)}", file=where,
                             row=i + 1, field=header[min(len(r), len(header) - 1)])
    if decimal_comma:
        body = [[c.replace(",", ".") for c in r] for r in body]
    return header, body


def _numbers(where: str, header, body, name: str, *, allow_empty: bool = False) -> np.ndarray:
    j = header.index(name)
    cells = [r[j].strip() for r in body]
    out = np.empty(len(cells))
    for i, c in enumerate(cells):
        if c == "" or c.lower() == "nan":
            if allow_empty:
                out[i] = np.nan
                continue
            raise InputError("empty cell" if c == "" else "NaN", file=where, field=name,
                             row=i + 1)
        try:
            out[i] = float(c)
        except ValueError:
            raise InputError(f"not a number: {c!r}", file=where, field=name,
                             row=i + 1) from None
    return out


def is_sensorlogger(path: Path) -> bool:
    """A Sensor Logger export: Gyroscope.csv whose header starts ``time,seconds_elapsed``."""
    try:
        b = _Bundle(path)
    except InputError:
        return False
    return "Gyroscope.csv" in b.files and b.header("Gyroscope.csv")[:2] == ["time",
                                                                              "seconds_elapsed"]


def read_sensorlogger(path: str | os.PathLike, *, mag: str = "calibrated",
                      onboard: bool = True) -> Recording:
    """Read a Sensor Logger export, zip or folder (module docstring: files, units, frames).

    Parameters
    ----------
    path : the exported ``.zip`` or its unpacked folder.
    mag : ``"calibrated"`` (``Magnetometer.csv``) or ``"raw"``
        (``MagnetometerUncalibrated.csv``).
    onboard : keep ``Orientation.csv`` as ``q_onboard``.
    """
    path = as_path(path)
    if mag not in ("calibrated", "raw"):
        raise InputError(f"expected calibrated or raw, got {mag!r}", file=str(path),
                         field="mag")
    b = _Bundle(path)
    if "Gyroscope.csv" not in b.files:
        raise InputError(f"no Gyroscope.csv in the export (it has "
                         f"{', '.join(sorted(b.files)) or 'no CSV'})", file=str(path))
    assumed = [_AXES]
    platform, standardised, device = "android", False, {}
    if "Metadata.csv" in b.files:
        h, rows = _columns(b.where("Metadata.csv"), b.text("Metadata.csv"))
        info = dict(zip(h, rows[0], strict=True))
        platform = info.get("platform", "android").strip().lower() or "android"
        standardised = info.get("standardisation", "").strip().lower() in ("true", "1", "yes")
        device = {k: info[k] for k in ("device name", "platform", "platform version",
                                       "appVersion") if k in info}
    else:
        assumed.append("No Metadata.csv: the platform is taken as Android.")
    if platform not in ("android", "ios"):
        raise InputError(f"unknown platform {platform!r}", file=b.where("Metadata.csv"),
                         field="platform")

    def load(name: str, cols=("x", "y", "z")):
        where = b.where(name)
        h, rows = _columns(where, b.text(name))
        for c in ("time",) + tuple(cols):
            if c not in h:
                raise InputError(f"missing column; header has {', '.join(h)}", file=where,
                                 field=c)
        j = h.index("time")
        try:
            t_ns = np.array([int(r[j]) for r in rows], dtype=np.int64)
        except ValueError:
            i = next(i for i, r in enumerate(rows) if not r[j].strip().lstrip("-").isdigit())
            raise InputError(f"not an integer time stamp (ns): {rows[i][j]!r}", file=where,
                             field="time", row=i + 1) from None
        v = np.column_stack([_numbers(where, h, rows, c) for c in cols])
        return t_ns, v, where

    raw = {"gyro": load("Gyroscope.csv")}
    if "TotalAcceleration.csv" in b.files:
        t_ns, v, where = load("TotalAcceleration.csv")
        sign = -1.0 if platform == "ios" and not standardised else 1.0  # iOS's opposite sign
        raw["accel"] = (t_ns, v * sign, where)
        assumed.append("Accelerometer with gravity: TotalAcceleration.csv (m/s^2"
                       + (", iOS sign flipped)." if sign < 0 else ")."))
    elif "AccelerometerUncalibrated.csv" in b.files:
        t_ns, v, where = load("AccelerometerUncalibrated.csv")
        if platform == "ios" and not standardised:
            v = v * -STANDARD_GRAVITY_M_S2
            assumed.append("Accelerometer: AccelerometerUncalibrated.csv, iOS: g with the "
                           "opposite sign, converted (x -9.80665).")
        else:
            assumed.append("Accelerometer: AccelerometerUncalibrated.csv (m/s^2).")
        raw["accel"] = (t_ns, v, where)
    else:
        raise InputError("no accelerometer with gravity (TotalAcceleration.csv or "
                         "AccelerometerUncalibrated.csv); Accelerometer.csv has gravity "
                         "removed", file=str(path), field="TotalAcceleration.csv")
    mag_file = "Magnetometer.csv" if mag == "calibrated" else "MagnetometerUncalibrated.csv"
    if mag_file in b.files:
        raw["mag"] = load(mag_file)
    else:
        assumed.append(f"No {mag_file}: no magnetometer.")
    if onboard and "Orientation.csv" in b.files:
        raw["q"] = load("Orientation.csv", ("qw", "qx", "qy", "qz"))
    t0 = min(int(r[0][0]) for r in raw.values() if r[0].size)
    out = {}
    for key, (t_ns, v, where) in raw.items():
        out[key] = series(where, Path(where.replace("!", "/")).name, (t_ns - t0) * 1e-9, v,
                          width=v.shape[1], assumed=assumed)
    t, w = out["gyro"]
    q_onboard = None
    onboard_desc = None
    if "q" in out:
        t_q, q = out["q"]
        if platform == "ios":
            q = quat_mul(Q_ENU_NWU, q)
            onboard_desc = "Orientation.csv: CoreMotion attitude relative to x-north z-up, " \
                           "turned to ENU by q_ENU_NWU"
        else:
            onboard_desc = "Orientation.csv taken as Android's rotation vector (q_ENU_device)" \
                           " - not checked on a real file"
        q_onboard = onboard_on(b.where("Orientation.csv"), "Orientation.csv", t_q, q, t)
    t_a, acc = out["accel"]
    t_m, m = out.get("mag", (None, None))
    meta = {"format": "sensorlogger", "platform": platform, "standardised": standardised,
            "assumed": assumed, "device": device, "onboard": onboard_desc,
            "onboard_heading_reference": None if q_onboard is None else (
                "x-north of CoreMotion's reference frame: magnetic or true north as the app "
                "requested it (the export does not say)" if platform == "ios" else
                "magnetic north, if Orientation.csv is Android's rotation vector"),
            "time_origin_unix_ns": int(t0), "files": sorted(b.files),
            "onboard_gravity_deg": onboard_gravity_deg(q_onboard, t, t_a, acc)}
    names = {"t": "Gyroscope.csv", "gyro": "Gyroscope.csv", "accel": raw["accel"][2],
             "mag": mag_file, "q_onboard": "Orientation.csv"}
    return build(path, names, t=t, gyro=w, accel=acc, accel_t=t_a, mag=m, mag_t=t_m,
                 mag_unit="uT", q_onboard=q_onboard, frames=_FRAMES,
                 source=f"{path.stem} (Sensor Logger, {platform})", meta=meta)


# ---------------------------------------------------------------------- phyphox
_PHYPHOX = {
    "accel": re.compile(r"^acceleration ([xyz]) \((m/s\^2|m/s²)\)$", re.I),
    "gyro": re.compile(r"^gyroscope ([xyz]) \((rad/s)\)$", re.I),
    "mag": re.compile(r"^magnetic field ([xyz]) \((µt|μt|ut)\)$", re.I),
}
_TIME = re.compile(r"^time \(s\)$", re.I)


def _phyphox_layout(header: list[str]) -> dict[str, tuple[int, list[int]]]:
    """sensor -> (time column, [x, y, z] columns) for one phyphox CSV header."""
    found: dict[str, dict] = {}
    last_time = None
    for j, name in enumerate(header):
        if _TIME.match(name):
            last_time = j
            continue
        for sensor, rx in _PHYPHOX.items():
            m = rx.match(name)
            if m and last_time is not None:
                found.setdefault(sensor, {"t": last_time})[m.group(1).lower()] = j
    return {s: (d["t"], [d[a] for a in "xyz"]) for s, d in found.items()
            if all(a in d for a in "xyz")}


def _sniff(text: str) -> tuple[str, bool]:
    first = text.splitlines()[0] if text else ""
    if first.count("\t") >= 1:
        return "\t", False
    if first.count(";") >= 1:
        return ";", True
    return ",", False


def is_phyphox(path: Path) -> bool:
    """A phyphox export: a CSV whose header has ``Time (s)`` and a sensor's x, y, z."""
    try:
        b = _Bundle(path)
    except InputError:
        return False
    for name in b.files:
        try:
            text = b.text(name)
        except InputError:
            continue
        delim, _ = _sniff(text)
        first = text.splitlines()[0] if text else ""
        header = [c.strip().strip('"') for c in next(_csv.reader([first], delimiter=delim))]
        if _phyphox_layout(header):
            return True
    return False


def read_phyphox(path: str | os.PathLike) -> Recording:
    """Read a phyphox CSV export, zip or folder (module docstring: columns, frames)."""
    path = as_path(path)
    b = _Bundle(path)
    assumed = [_AXES, "phyphox: Acceleration x/y/z (m/s^2) includes gravity; gyroscope "
               "rad/s; magnetic field uT; axes and signs as on Android."]
    got: dict[str, tuple] = {}
    for name in sorted(b.files):
        text = b.text(name)
        delim, comma = _sniff(text)
        first = text.splitlines()[0] if text else ""
        header = [c.strip().strip('"') for c in next(_csv.reader([first], delimiter=delim))]
        layout = _phyphox_layout(header)
        if not layout:
            continue
        where = b.where(name)
        h, rows = _columns(where, text, delim, comma)
        for sensor, (jt, jv) in layout.items():
            if sensor in got:
                assumed.append(f"{sensor}: a second set in {name} was ignored.")
                continue
            t = _numbers(where, h, rows, h[jt], allow_empty=True)
            v = np.column_stack([_numbers(where, h, rows, h[j], allow_empty=True) for j in jv])
            filled = np.isfinite(v)
            partial = filled.any(axis=1) & ~filled.all(axis=1)
            if partial.any():
                i = int(np.argmax(partial))
                col = h[jv[int(np.argmax(~filled[i]))]]
                raise InputError("empty cell (the other axes have a value)", file=where,
                                 field=col, row=i + 1)
            keep = filled.all(axis=1)
            if np.any(keep & ~np.isfinite(t)):
                i = int(np.argmax(keep & ~np.isfinite(t)))
                raise InputError("empty time cell", file=where, field=h[jt], row=i + 1)
            got[sensor] = series(where, f"{name}:{h[jv[0]]}", t[keep], v[keep],
                                 assumed=assumed) + (where,)
    if "gyro" not in got or "accel" not in got:
        missing = "gyroscope" if "gyro" not in got else "acceleration (with g)"
        raise InputError(f"no {missing} columns in the export's CSV files "
                         f"({', '.join(sorted(b.files)) or 'none'})", file=str(path))
    t, w, _ = got["gyro"]
    t_a, acc, _ = got["accel"]
    t_m, m = (got["mag"][0], got["mag"][1]) if "mag" in got else (None, None)
    meta = {"format": "phyphox", "assumed": assumed, "files": sorted(b.files)}
    return build(path, {"t": "Gyroscope", "gyro": "Gyroscope", "accel": "Acceleration",
                        "mag": "Magnetic field"},
                 t=t, gyro=w, accel=acc, accel_t=t_a, mag=m, mag_t=t_m, mag_unit="uT",
                 frames=_FRAMES, source=f"{path.stem} (phyphox)", meta=meta)
