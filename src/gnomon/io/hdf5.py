"""gnomon's own recording file: one HDF5 file holds one :class:`~gnomon.recording.Recording`.

Readers of other formats, the simulators and ``gnomon`` itself write and read
this same layout. Every array is stored exactly (no conversion, lossless gzip
by default), so ``read_recording(write_recording(p, rec))`` gives back equal
arrays bit for bit.

Layout (format version 2; version 1 files, which lack ``accel_t``, ``mag_t``,
``q_onboard`` and ``meta``, are read as before)
---------------------------------------------------------------------------------

=====================  ==========  ========  ==========================================
name                   shape       unit      meaning
=====================  ==========  ========  ==========================================
``/t``                 (N,)        s         sample times, strictly increasing
``/gyro``              (N, 3)      rad/s     angular rate of body b w.r.t. inertial
                                             space, in b
``/accel``             (Na, 3)     m/s²      specific force in b; optional
``/accel_t``           (Na,)       s         its own sample times; absent: ``/t``
``/mag``               (Nm, 3)     attr      magnetic field in b; optional; attribute
                                             ``unit`` one of ``T, mT, uT, nT, gauss``
``/mag_t``             (Nm,)       s         its own sample times; absent: ``/t``
``/sun``               (N, 3)      1         sun direction in b (unit vectors);
                                             optional; NaN rows where not valid
``/sun_valid``         (N,)        bool      sun measurement present; with ``/sun``
``/q_true``            (N, 4)      1         truth ``q_rb`` ``[w, x, y, z]`` (body b to
                                             reference r); optional; NaN rows = missing
``/q_onboard``         (N, 4)      1         the device's own estimate ``q_rb``; optional
``/mask``              (N,)        bool      samples that count for scoring; optional
``/extra/<name>``      (N, ...)    SI        further time series (``Recording.extra``),
                                             numeric or bool
=====================  ==========  ========  ==========================================

Root attributes: ``format = "gnomon-recording"``, ``format_version = 2``,
``frames`` (a JSON object, e.g. ``{"reference": "ENU", "body": "sensor"}``),
``source`` (free text: where the data came from), ``mag_unit`` (kept also
when there is no ``/mag``) and ``meta`` (a JSON object: what a reader assumed,
``meta["assumed"]``, and what it read). Datasets ``t``, ``gyro``, ``accel``,
``accel_t``, ``mag_t`` carry a ``unit`` attribute (``s``, ``rad/s``, ``m/s^2``,
``s``, ``s``) that the reader checks; ``mag`` carries its own unit.
Optional datasets are absent, never empty. A reader of a later
``format_version`` than it knows refuses the file with a clear message.
Errors name the file, the dataset and, for bad values, the row as the 0-based
sample index (``gyro[7]`` is row 7).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import build
from gnomon.recording import Recording

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "write_recording", "read_recording",
           "is_gnomon_recording"]

FORMAT_NAME = "gnomon-recording"
FORMAT_VERSION = 2

# dataset -> fixed unit attribute written and checked
_FIXED_UNITS = {"t": "s", "gyro": "rad/s", "accel": "m/s^2", "accel_t": "s", "mag_t": "s"}
_OPTIONAL = ("accel", "accel_t", "mag", "mag_t", "sun", "sun_valid", "q_true", "q_onboard",
             "mask")


def _h5py():
    import h5py  # local: keeps `import gnomon` light

    return h5py


def write_recording(path: str | os.PathLike, rec: Recording, *,
                    compression: str | None = "gzip") -> Path:
    """Write ``rec`` to ``path`` in gnomon's HDF5 recording format (module docstring).

    Parameters
    ----------
    path : file to create (overwritten if it exists).
    rec : the recording; written as is (units and frames as stored in ``rec``).
    compression : HDF5 filter for the datasets (``"gzip"``, lossless) or ``None``.

    Returns the path written. Raises :class:`InputError` for an ``extra`` entry
    that HDF5 cannot hold exactly (non-numeric dtype, or a name with ``/``) and
    when the file cannot be created (e.g. its directory does not exist).
    """
    h5py = _h5py()
    path = Path(path)
    if not isinstance(rec, Recording):
        raise InputError(f"expected a Recording, got {type(rec).__name__}", file=str(path))
    for key, value in rec.extra.items():
        if "/" in key or not key:
            raise InputError("extra names must be non-empty and contain no '/'",
                             file=str(path), field=f"extra.{key}")
        if value.dtype.kind not in "biufc":
            raise InputError(f"dtype {value.dtype} cannot be stored; use numbers or bool",
                             file=str(path), field=f"extra.{key}")

    def put(group, name, data):
        data = np.asarray(data)
        kw = {}
        if compression is not None and data.size > 64:
            kw = {"compression": compression, "shuffle": True}
        return group.create_dataset(name, data=data, **kw)

    try:
        _write(h5py, path, rec, put)
    except OSError as err:
        raise InputError(f"cannot write ({err})", file=str(path)) from None
    return path


def _write(h5py, path: Path, rec: Recording, put) -> None:
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT_NAME
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["frames"] = json.dumps(rec.frames, sort_keys=True)
        f.attrs["source"] = str(rec.source)
        f.attrs["mag_unit"] = rec.mag_unit
        f.attrs["meta"] = json.dumps(rec.meta, sort_keys=True, default=str)
        for name in ("t", "gyro") + _OPTIONAL:
            value = getattr(rec, name)
            if value is None:
                continue
            ds = put(f, name, value)
            if name in _FIXED_UNITS:
                ds.attrs["unit"] = _FIXED_UNITS[name]
            elif name == "mag":
                ds.attrs["unit"] = rec.mag_unit
        g = f.create_group("extra")
        for key, value in rec.extra.items():
            put(g, key, value)


def _attr_str(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _attr_str(value[()])
    return str(value)


def is_gnomon_recording(h5file) -> bool:
    """Whether an open ``h5py.File`` carries ``format == "gnomon-recording"``."""
    return _attr_str(h5file.attrs.get("format", "")) == FORMAT_NAME


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a gnomon HDF5 recording (module docstring) into a :class:`Recording`.

    Raises :class:`InputError` naming the file (and the dataset or attribute)
    for a missing file, a file that is not HDF5 or is truncated, a file of
    another format, a newer ``format_version``, a missing ``t``/``gyro``, a
    wrong ``unit`` attribute, or data that fail the ``Recording`` checks.
    """
    h5py = _h5py()
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", file=str(path))
    try:
        with h5py.File(path, "r") as f:
            if not is_gnomon_recording(f):
                raise InputError(f"not a gnomon recording (root attribute 'format' is "
                                 f"{_attr_str(f.attrs.get('format', '<missing>'))!r}, "
                                 f"expected {FORMAT_NAME!r})", file=str(path), field="format")
            version = int(np.asarray(f.attrs.get("format_version", -1)))
            if version < 1 or version > FORMAT_VERSION:
                raise InputError(f"format_version {version} is not supported by this gnomon "
                                 f"(reads 1..{FORMAT_VERSION}); upgrade gnomon",
                                 file=str(path), field="format_version")
            data = {}
            for name in ("t", "gyro") + _OPTIONAL:
                if name not in f:
                    if name in ("t", "gyro"):
                        raise InputError("required dataset missing", file=str(path), field=name)
                    continue
                ds = f[name]
                if name in _FIXED_UNITS and "unit" in ds.attrs:
                    unit = _attr_str(ds.attrs["unit"])
                    if unit != _FIXED_UNITS[name]:
                        raise InputError(f"unit {unit!r}, expected {_FIXED_UNITS[name]!r}",
                                         file=str(path), field=name)
                data[name] = ds[()]
            mag_unit = _attr_str(f.attrs.get("mag_unit", "uT"))
            if "mag" in f and "unit" in f["mag"].attrs:
                mag_unit = _attr_str(f["mag"].attrs["unit"])
            try:
                frames = json.loads(_attr_str(f.attrs["frames"])) if "frames" in f.attrs else None
            except json.JSONDecodeError as err:
                raise InputError(f"not a JSON object: {err}", file=str(path),
                                 field="frames") from None
            if frames is not None and not isinstance(frames, dict):
                raise InputError("not a JSON object", file=str(path), field="frames")
            try:
                meta = json.loads(_attr_str(f.attrs["meta"])) if "meta" in f.attrs else {}
            except json.JSONDecodeError as err:
                raise InputError(f"not a JSON object: {err}", file=str(path),
                                 field="meta") from None
            if not isinstance(meta, dict):
                raise InputError("not a JSON object", file=str(path), field="meta")
            source = _attr_str(f.attrs.get("source", ""))
            extra = {}
            if "extra" in f:
                for key, ds in f["extra"].items():
                    if not isinstance(ds, h5py.Dataset):
                        raise InputError("expected a dataset, found a group", file=str(path),
                                         field=f"extra/{key}")
                    extra[key] = ds[()]
    except InputError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as err:
        # h5py: "file signature not found", "truncated file", unreadable chunks, ...
        raise InputError(f"cannot read as HDF5 ({err})", file=str(path)) from None
    if frames is not None:
        data["frames"] = frames
    return build(path, {}, mag_unit=mag_unit, source=source, extra=extra, meta=meta, **data)
