"""Reading and writing recordings: the only place that knows other people's formats.

``read(path)`` picks the reader from the file:

=====================  ==============================================================
file                   reader
=====================  ==============================================================
``.csv``, ``.txt``     :func:`read_csv` (generic IMU log; ``**csv_options`` apply)
``.mat``               :func:`read_broad` (BROAD trial, MATLAB v5)
``.h5``, ``.hdf5``     :func:`read_recording` if the root attribute ``format`` is
                       ``"gnomon-recording"``, else :func:`read_broad` if the file has
                       a dataset ``imu_gyr``, else an :class:`InputError`
=====================  ==============================================================

``write(path, rec)`` writes gnomon's HDF5 recording format (:mod:`gnomon.io.hdf5`).
Every failure on bad input is an :class:`~gnomon.errors.InputError` that names
the file (and, where it applies, the field and the row).
"""

from __future__ import annotations

import inspect
import os
from pathlib import Path

from gnomon.errors import InputError
from gnomon.io.broad import broad_groups, broad_trials, read_broad
from gnomon.io.csv import UnitWarning, read_csv
from gnomon.io.hdf5 import read_recording, write_recording
from gnomon.recording import Recording

__all__ = ["read", "write", "detect_format", "FORMATS", "read_broad", "broad_trials",
           "broad_groups", "read_csv", "UnitWarning", "read_recording", "write_recording"]

#: values of ``format`` accepted by :func:`read`
FORMATS = ("auto", "broad", "csv", "hdf5")

_CSV_SUFFIXES = (".csv", ".txt")
_HDF5_SUFFIXES = (".h5", ".hdf5")


def detect_format(path: str | os.PathLike) -> str:
    """The format of an existing file: ``"csv"``, ``"broad"`` or ``"hdf5"`` (gnomon's own).

    Raises :class:`InputError` for a missing file, an unknown suffix, an
    unreadable HDF5 file, or an HDF5 file that is neither a gnomon recording
    nor a BROAD trial.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", file=str(path))
    suffix = path.suffix.lower()
    if suffix in _CSV_SUFFIXES:
        return "csv"
    if suffix == ".mat":
        return "broad"
    if suffix in _HDF5_SUFFIXES:
        import h5py

        from gnomon.io.hdf5 import is_gnomon_recording

        try:
            with h5py.File(path, "r") as f:
                if is_gnomon_recording(f):
                    return "hdf5"
                if "imu_gyr" in f:
                    return "broad"
                keys = sorted(f.keys())
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"cannot read as HDF5 ({err})", file=str(path)) from None
        raise InputError(
            "HDF5 file is neither a gnomon recording (root attribute format="
            f"'gnomon-recording') nor a BROAD trial (dataset 'imu_gyr'); it has {keys[:10]}",
            file=str(path))
    raise InputError(f"cannot tell the format from the suffix {path.suffix!r}; use "
                     "format='csv', 'broad' or 'hdf5' (suffixes: .csv .txt .mat .h5 .hdf5)",
                     file=str(path))


def read(path: str | os.PathLike, format: str = "auto", **csv_options) -> Recording:
    """Read a recording from ``path``.

    Parameters
    ----------
    path : the file.
    format : ``"auto"`` (detect, see module docstring), ``"broad"``, ``"csv"`` or
        ``"hdf5"`` (gnomon's recording format).
    **csv_options : passed to :func:`read_csv` (``columns``, ``gyro_unit``,
        ``accel_unit``, ``mag_unit``, ``time_unit``, ``delimiter``, ...); given
        for another format they raise :class:`InputError`.
    """
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; use one of {', '.join(FORMATS)}",
                         field="format")
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", file=str(path))
    fmt = detect_format(path) if format == "auto" else format
    if csv_options and fmt != "csv":
        raise InputError(f"CSV options {sorted(csv_options)} given for a {fmt} file",
                         file=str(path), field=sorted(csv_options)[0])
    if fmt == "csv":
        known = set(inspect.signature(read_csv).parameters) - {"path"}
        unknown = sorted(set(csv_options) - known)
        if unknown:
            raise InputError(f"unknown CSV option(s) {unknown}; known: {', '.join(sorted(known))}",
                             field=unknown[0])
        return read_csv(path, **csv_options)
    if fmt == "broad":
        return read_broad(path)
    return read_recording(path)


def write(path: str | os.PathLike, rec: Recording) -> Path:
    """Write ``rec`` to ``path`` in gnomon's HDF5 recording format; returns the path."""
    return write_recording(path, rec)
