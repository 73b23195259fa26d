"""Reader for MATLAB ``.mat`` files, v5/v7 (``scipy.io.loadmat``) and v7.3 (HDF5, ``h5py``).

A file with BROAD's fields (``imu_gyr``, ``imu_acc``, ``imu_mag``, ``opt_quat``,
``movement``, ``sampling_rate``) reads exactly as :func:`~gnomon.io.broad.read_broad`,
in both versions. Otherwise the variables are found by name (case-insensitive; at the top
level, or inside the one struct the file holds):

=============  ==============================================================  ==========
field          accepted names                                                  unit
=============  ==============================================================  ==========
gyro           ``imu_gyr gyr gyro gyroscope omega w``                          rad/s
accelerometer  ``imu_acc acc accel accelerometer a``                           m/s²
magnetometer   ``imu_mag mag magnetometer m``                                  µT
time           ``t time timestamp timestamps time_s``                          s
sample rate    ``sampling_rate fs rate sample_rate freq`` (when no time)       Hz
own times      ``acc_t accel_t`` / ``mag_t`` (each sensor at its own rate)     s
truth          ``opt_quat quat q q_true quaternion orientation``               1
mask           ``movement mask``                                               bool
=============  ==============================================================  ==========

Arrays may be stored N×3 or 3×N (MATLAB users write both; v7.3 files are transposed by
HDF5's row-major order — both are recognised by their length-3 axis). The truth is
``[w, x, y, z]`` ``q_ENU_sensor`` (BROAD's convention); NaN rows are missing samples.
Units: ``gyro_unit`` (``rad/s``/``deg/s``), ``accel_unit`` (``m/s^2``/``g``), ``mag_unit``
options as for CSV. ``frames = {"reference": "ENU", "body": "sensor"}``.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import as_path, build, series
from gnomon.io.broad import BROAD_FIELDS, broad_from_fields
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording

__all__ = ["read_mat", "mat_version", "MAT_NAMES"]

MAT_NAMES = {
    "gyro": ("imu_gyr", "gyr", "gyro", "gyroscope", "omega", "w"),
    "accel": ("imu_acc", "acc", "accel", "accelerometer", "a"),
    "mag": ("imu_mag", "mag", "magnetometer", "m"),
    "t": ("t", "time", "timestamp", "timestamps", "time_s"),
    "rate": ("sampling_rate", "fs", "rate", "sample_rate", "freq"),
    "accel_t": ("acc_t", "accel_t"),
    "mag_t": ("mag_t",),
    "q_true": ("opt_quat", "quat", "q", "q_true", "quaternion", "orientation"),
    "mask": ("movement", "mask"),
}
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def mat_version(head: bytes) -> str | None:
    """``"5"`` or ``"7.3"`` from a file's first 128 bytes, or None (not a MAT file).

    v7.3: the header text ``MATLAB 7.3`` (an HDF5 file with a 512-byte user block). v5 (and
    v6, v7: the same level-5 format): what the MAT-file spec defines, not the text — bytes
    124-125 hold the version 0x0100 and bytes 126-127 the endian indicator ``IM`` (written
    little-endian) or ``MI`` (big-endian). The 116-byte text is free: MATLAB writes
    ``MATLAB 5.0 MAT-file``, other programs their own (Qualisys QTM: ``QTM_ver ...``)."""
    if head.startswith(b"MATLAB 7.3"):
        return "7.3"
    if len(head) < 128:
        return None
    order = {b"IM": "little", b"MI": "big"}.get(bytes(head[126:128]))
    if order is not None and int.from_bytes(head[124:126], order) == 0x0100:
        return "5"
    return None


def _load_v5(path: Path) -> dict:
    import scipy.io

    try:
        d = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=False)
    except NotImplementedError:
        return _load_v73(path)
    except (OSError, ValueError, TypeError, KeyError, IndexError, EOFError, zlib.error,
            AttributeError, scipy.io.matlab.MatReadError) as err:
        raise InputError(f"cannot read as MATLAB .mat ({err})", file=str(path)) from None
    d = {k: v for k, v in d.items() if not k.startswith("__")}
    structs = [v for v in d.values() if isinstance(v, np.ndarray) and v.dtype == object
               and v.size == 1 and hasattr(v.item(), "_fieldnames")]
    if not _has_any(d) and len(structs) == 1:
        s = structs[0].item()
        d = {f: getattr(s, f) for f in s._fieldnames}
    return {k: np.asarray(v) for k, v in d.items()
            if isinstance(v, np.ndarray) and v.dtype != object}


def _load_v73(path: Path) -> dict:
    import h5py

    def arrays(group) -> dict:
        out = {}
        for k, v in group.items():
            if isinstance(v, h5py.Dataset) and v.dtype.kind in "biuf":
                a = v[()]
                out[k] = a.T if a.ndim == 2 else a  # HDF5 row-major: MATLAB's N×3 is 3×N
        return out

    try:
        with h5py.File(path, "r") as f:
            d = arrays(f)
            groups = [v for k, v in f.items() if isinstance(v, h5py.Group) and k != "#refs#"]
            if not _has_any(d) and len(groups) == 1:
                d = arrays(groups[0])
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as err:
        raise InputError(f"cannot read as MATLAB v7.3 (HDF5) ({err})", file=str(path)) from None
    return d


def _has_any(d: dict) -> bool:
    low = {k.lower() for k in d}
    return any(n in low for n in MAT_NAMES["gyro"])


def _find(d: dict, key: str) -> tuple[str, np.ndarray] | None:
    low = {k.lower(): k for k in d}
    for n in MAT_NAMES[key]:
        if n in low:
            return low[n], np.asarray(d[low[n]])
    return None


def _rows(path, name: str, a: np.ndarray, width: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 2 and a.shape[1] != width and a.shape[0] == width:
        a = a.T
    if a.ndim != 2 or a.shape[1] != width:
        raise InputError(f"expected N x {width} (or {width} x N), got {a.shape}",
                         file=str(path), field=name)
    return a


def _vector(path, name: str, a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 2 and 1 in a.shape:
        a = a.reshape(-1)
    if a.ndim != 1:
        raise InputError(f"expected a vector, got shape {a.shape}", file=str(path), field=name)
    return a


def read_mat(path: str | os.PathLike, *, gyro_unit: str = "rad/s", accel_unit: str = "m/s^2",
             mag_unit: str = "uT") -> Recording:
    """Read a MATLAB ``.mat`` file (v5 or v7.3; module docstring: names, shapes, units)."""
    path = as_path(path)
    if gyro_unit not in ("rad/s", "deg/s"):
        raise InputError(f"expected rad/s or deg/s, got {gyro_unit!r}", field="gyro_unit")
    if accel_unit not in ("m/s^2", "g"):
        raise InputError(f"expected m/s^2 or g, got {accel_unit!r}", field="accel_unit")
    if mag_unit not in MAG_UNITS_TO_TESLA:
        raise InputError(f"unknown unit {mag_unit!r}", field="mag_unit")
    with open(path, "rb") as fh:
        head = fh.read(128)
    version = mat_version(head)
    if version is None and not head.startswith(_HDF5_MAGIC):
        raise InputError("not a MATLAB .mat file (no v5 version 0x0100 with endian 'IM'/'MI' "
                         "at bytes 124-127, no 'MATLAB 7.3' header, not HDF5)", file=str(path))
    d = _load_v73(path) if version in ("7.3", None) else _load_v5(path)
    if all(k in d for k in BROAD_FIELDS):
        rec = broad_from_fields(d, path)
        meta = dict(rec.meta, format="mat", version=version or "hdf5",
                    assumed=["BROAD's fields and conventions (see gnomon.io.broad)."])
        return build(path, {}, **{**_fields(rec), "meta": meta})
    found = {k: _find(d, k) for k in MAT_NAMES}
    if found["gyro"] is None:
        raise InputError(f"no gyro variable (one of {', '.join(MAT_NAMES['gyro'])}); the file "
                         f"has {', '.join(sorted(d)) or 'no numeric variable'}",
                         file=str(path), field="gyro")
    if found["accel"] is None:
        raise InputError(f"no accelerometer variable (one of {', '.join(MAT_NAMES['accel'])})",
                         file=str(path), field="accel")
    gname, gyro = found["gyro"][0], _rows(path, found["gyro"][0], found["gyro"][1], 3)
    n = gyro.shape[0]
    assumed = [f"Variables: {', '.join(f'{k}={v[0]}' for k, v in found.items() if v)}."]
    if found["t"] is not None:
        t = _vector(path, found["t"][0], found["t"][1]).astype(float)
    elif found["rate"] is not None:
        fs = np.asarray(found["rate"][1], dtype=float)
        if fs.size != 1 or not np.isfinite(fs.item()) or fs.item() <= 0:
            raise InputError(f"expected one positive rate in Hz, got {fs.tolist()}",
                             file=str(path), field=found["rate"][0])
        t = np.arange(n) / fs.item()
        assumed.append(f"t = arange(N) / {found['rate'][0]} ({fs.item():g} Hz).")
    else:
        raise InputError("no time (t, time, ...) and no sample rate (fs, sampling_rate, ...)",
                         file=str(path), field="t")
    if t.size != n:
        raise InputError(f"{t.size} time stamps for {n} gyro samples", file=str(path),
                         field=found["t"][0] if found["t"] else "t")
    t, gyro = series(path, gname, t, gyro, assumed=assumed)
    if gyro_unit == "deg/s":
        gyro = np.deg2rad(gyro)

    def own(key: str, tkey: str):
        if found[key] is None:
            return None, None
        name, a = found[key]
        v = _rows(path, name, a, 3)
        if found[tkey] is not None:
            tt = _vector(path, found[tkey][0], found[tkey][1]).astype(float)
            if tt.size != v.shape[0]:
                raise InputError(f"{tt.size} time stamps for {v.shape[0]} samples",
                                 file=str(path), field=found[tkey][0])
            return series(path, name, tt, v, assumed=assumed)
        if v.shape[0] != n:
            raise InputError(f"{v.shape[0]} samples, gyro has {n} (give {tkey} for its own "
                             "time stamps)", file=str(path), field=name)
        return None, v

    t_a, acc = own("accel", "accel_t")
    t_m, mag = own("mag", "mag_t")
    if accel_unit == "g":
        acc = acc * 9.80665
    q_true = mask = None
    if found["q_true"] is not None:
        q_true = _rows(path, found["q_true"][0], found["q_true"][1], 4)
        q_true[~np.isfinite(q_true).all(axis=1)] = np.nan
    if found["mask"] is not None:
        mask = _vector(path, found["mask"][0], found["mask"][1]).astype(bool)
    names = {"gyro": gname, "t": found["t"][0] if found["t"] else "t"}
    names.update({k: v[0] for k, v in found.items() if v})
    return build(path, names, t=t, gyro=gyro, accel=acc, accel_t=t_a, mag=mag, mag_t=t_m,
                 mag_unit=mag_unit, q_true=q_true, mask=mask,
                 frames={"reference": "ENU", "body": "sensor"}, source=path.stem,
                 meta={"format": "mat", "version": version or "hdf5", "assumed": assumed})


def _fields(rec: Recording) -> dict:
    return {k: getattr(rec, k) for k in ("t", "gyro", "accel", "accel_t", "mag", "mag_t",
                                         "mag_unit", "q_true", "mask", "frames", "source",
                                         "extra", "q_onboard")}
