"""Reading and writing recordings: the only place that knows other people's formats.

``read(path, **options)`` picks the reader from the file's content (magic bytes, header,
folder layout), the suffix only when the content does not tell:

================  ===============================================  ====================
format            recognised by                                    reader
================  ===============================================  ====================
``ulog``          ``ULog`` magic bytes (PX4 ``.ulg``)              :func:`read_ulog`
``dataflash``     ``0xA3 0x95`` + FMT message (ArduPilot ``.BIN``)  :func:`read_dataflash`
``rosbag``        ``#ROSBAG V2.0`` (ROS 1), a folder with          :func:`read_rosbag`
                  ``metadata.yaml`` (ROS 2), an ``.mcap`` or
                  ``.db3`` file
``tyrex``         a folder with ``accelerometer.txt`` and          :func:`read_tyrex`
                  ``rotation-vector.txt`` (Android) or
                  ``attitude.txt`` (iOS)
``sensorlogger``  zip/folder with ``Gyroscope.csv`` headed         :func:`read_sensorlogger`
                  ``time,seconds_elapsed``
``phyphox``       zip/folder with CSVs headed ``Time (s)``, ...    :func:`read_phyphox`
``xsens``         text with ``//`` lines and ``PacketCounter`` /   :func:`read_xsens`
                  ``SampleTimeFine`` columns (MT Manager export)
``mat``           v5: version 0x0100 and endian ``IM``/``MI`` at   :func:`read_mat` (a v5
                  bytes 124-127 (the MAT-file spec; any header     file with BROAD's
                  text); v7.3: ``MATLAB 7.3`` header               fields: ``broad``)
``broad``         HDF5 with ``imu_gyr`` or a ``.mat`` BROAD trial  :func:`read_broad`
``hdf5``          HDF5 with root attribute ``format =              :func:`read_recording`
                  "gnomon-recording"``
``csv``           any other text (``.csv``, ``.txt``)              :func:`read_csv`
================  ===============================================  ====================

A table of any other layout (CSV/TSV, ``.mat``, ``.npz``, Parquet) is read with a map:
``read(path, map="map.yaml")`` (:mod:`gnomon.io.mapping`; ``propose_map(path)`` proposes
one from the names and the data).

``**options`` go to that reader (``topic``, ``instance``, ``mag_topic``, ``columns``,
``gyro_unit``, ...); an option the reader does not take is an :class:`InputError`
naming it. ``inspect(path)`` says what is inside (sensors, rates, gaps, units, the
device's own estimate, the topics/instances available, the samples dropped),
``write(path, rec)`` writes gnomon's HDF5 recording format (:mod:`gnomon.io.hdf5`). Every
failure on bad input is an :class:`~gnomon.errors.InputError` that names the file (and the
field and row). A sample with a non-finite value is dropped from its sensor and counted
(``meta["dropped"]``), or refused with ``read(path, strict=True)``.

The log libraries (``pyulog``, ``pymavlink``, ``rosbags``: ``pip install
'gnomon[logs]'``) are imported only when such a file is read.
"""

from __future__ import annotations

import inspect as _inspect
import os
from pathlib import Path

from gnomon.errors import InputError
from gnomon.io.broad import broad_groups, broad_trials, read_broad
from gnomon.io.csv import UnitWarning, read_csv
from gnomon.io.hdf5 import read_recording, write_recording
from gnomon.recording import Recording

__all__ = ["read", "write", "inspect", "detect_format", "FORMATS", "read_broad",
           "broad_trials", "broad_groups", "read_csv", "UnitWarning", "read_recording",
           "write_recording", "read_ulog", "read_dataflash", "read_rosbag", "read_tyrex",
           "read_sensorlogger", "read_phyphox", "read_xsens", "read_mat", "reader_for",
           "propose_map", "read_mapped"]

#: values of ``format`` accepted by :func:`read`
FORMATS = ("auto", "broad", "csv", "hdf5", "ulog", "dataflash", "rosbag", "tyrex",
           "sensorlogger", "phyphox", "xsens", "mat")

_CSV_SUFFIXES = (".csv", ".txt")
_HDF5_SUFFIXES = (".h5", ".hdf5")
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_BY_SUFFIX = {".ulg": "ulog", ".bin": "dataflash", ".bag": "rosbag", ".mcap": "rosbag",
              ".db3": "rosbag", ".mat": "broad"}


def read_ulog(path, **options) -> Recording:
    """PX4 ULog (:func:`gnomon.io.ulog.read_ulog`)."""
    from gnomon.io.ulog import read_ulog as f

    return f(path, **options)


def read_dataflash(path, **options) -> Recording:
    """ArduPilot DataFlash (:func:`gnomon.io.dataflash.read_dataflash`)."""
    from gnomon.io.dataflash import read_dataflash as f

    return f(path, **options)


def read_rosbag(path, **options) -> Recording:
    """ROS 1/2 bag (:func:`gnomon.io.rosbag.read_rosbag`)."""
    from gnomon.io.rosbag import read_rosbag as f

    return f(path, **options)


def read_tyrex(path, **options) -> Recording:
    """tyrex phone trial folder (:func:`gnomon.io.phone.read_tyrex`)."""
    from gnomon.io.phone import read_tyrex as f

    return f(path, **options)


def read_sensorlogger(path, **options) -> Recording:
    """Sensor Logger export (:func:`gnomon.io.phone.read_sensorlogger`)."""
    from gnomon.io.phone import read_sensorlogger as f

    return f(path, **options)


def read_phyphox(path, **options) -> Recording:
    """phyphox export (:func:`gnomon.io.phone.read_phyphox`)."""
    from gnomon.io.phone import read_phyphox as f

    return f(path, **options)


def read_xsens(path, **options) -> Recording:
    """Xsens MT Manager text export (:func:`gnomon.io.xsens.read_xsens`)."""
    from gnomon.io.xsens import read_xsens as f

    return f(path, **options)


def read_mat(path, **options) -> Recording:
    """MATLAB .mat v5/v7.3 (:func:`gnomon.io.matlab.read_mat`)."""
    from gnomon.io.matlab import read_mat as f

    return f(path, **options)


def propose_map(path) -> dict:
    """A map for a table of unknown layout (:func:`gnomon.io.mapping.propose_map`)."""
    from gnomon.io.mapping import propose_map as f

    return f(path)


def read_mapped(path, map) -> Recording:
    """A table read with a map (:func:`gnomon.io.mapping.read_mapped`)."""
    from gnomon.io.mapping import read_mapped as f

    return f(path, map)


def reader_for(fmt: str):
    """The function that reads format ``fmt`` (its own, with its documented options)."""
    if fmt == "csv":
        return read_csv
    if fmt == "broad":
        return read_broad
    if fmt == "hdf5":
        return read_recording
    module, name = {"ulog": ("ulog", "read_ulog"), "dataflash": ("dataflash", "read_dataflash"),
                    "rosbag": ("rosbag", "read_rosbag"), "tyrex": ("phone", "read_tyrex"),
                    "sensorlogger": ("phone", "read_sensorlogger"),
                    "phyphox": ("phone", "read_phyphox"), "xsens": ("xsens", "read_xsens"),
                    "mat": ("matlab", "read_mat")}[fmt]
    import importlib

    return getattr(importlib.import_module(f"gnomon.io.{module}"), name)


def _hdf5_kind(path: Path) -> str:
    import h5py

    from gnomon.io.hdf5 import is_gnomon_recording

    try:
        with h5py.File(path, "r") as f:
            if is_gnomon_recording(f):
                return "hdf5"
            if "imu_gyr" in f:
                return "broad"
            keys = sorted(f.keys())
    except (OSError, KeyError, ValueError, RuntimeError) as err:  # RuntimeError: h5py on damage
        raise InputError(f"cannot read as HDF5 ({err})", file=str(path)) from None
    raise InputError(
        "HDF5 file is neither a gnomon recording (root attribute format="
        f"'gnomon-recording') nor a BROAD trial (dataset 'imu_gyr'); it has {keys[:10]}",
        file=str(path))


def _detect_dir(path: Path) -> str:
    from gnomon.io.phone import is_phyphox, is_sensorlogger, tyrex_platform
    from gnomon.io.rosbag import is_ros2_bag_dir

    if is_ros2_bag_dir(path):
        return "rosbag"
    if tyrex_platform(path):
        return "tyrex"
    if is_sensorlogger(path):
        return "sensorlogger"
    if is_phyphox(path):
        return "phyphox"
    raise InputError("a folder, but not a ROS 2 bag (metadata.yaml), a tyrex trial "
                     "(accelerometer.txt, rotation-vector.txt/attitude.txt), a Sensor Logger "
                     "export (Gyroscope.csv) or a phyphox export (CSV with 'Time (s)')",
                     file=str(path))


def detect_format(path: str | os.PathLike) -> str:
    """The format of an existing file or folder (one of ``FORMATS`` but ``"auto"``), from
    its content; the suffix decides only when the content does not tell.

    Raises :class:`InputError` for a missing path, an unknown suffix with unknown content,
    an unreadable HDF5 file, or an HDF5 file that is neither a gnomon recording nor a
    BROAD trial.
    """
    path = Path(path)
    if path.is_dir():
        return _detect_dir(path)
    if not path.is_file():
        raise InputError("no such file", file=str(path))
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as err:
        raise InputError(f"cannot read ({err})", file=str(path)) from None
    from gnomon.io.matlab import mat_version

    suffix = path.suffix.lower()
    if head.startswith(b"ULog\x01\x12\x35"):
        return "ulog"
    if head[:3] == b"\xa3\x95\x80":  # DataFlash header, then the FMT message type (128)
        return "dataflash"
    if head.startswith(b"#ROSBAG V2.0") or head.startswith(b"\x89MCAP"):
        return "rosbag"
    if head.startswith(b"SQLite format 3\x00") and suffix == ".db3":
        return "rosbag"
    version = mat_version(head[:128])
    if version == "5":
        try:
            import scipy.io

            names = [v[0] for v in scipy.io.whosmat(path)]
        except Exception:  # noqa: BLE001 - scipy's failures on a broken file vary
            names = []
        return "broad" if "imu_gyr" in names else "mat"
    if version == "7.3":
        return "mat"
    if head.startswith(_HDF5_MAGIC) or (suffix in _HDF5_SUFFIXES):
        return _hdf5_kind(path)
    if head.startswith(b"PK\x03\x04"):
        from gnomon.io.phone import is_phyphox, is_sensorlogger

        if is_sensorlogger(path):
            return "sensorlogger"
        if is_phyphox(path):
            return "phyphox"
        raise InputError("a zip file, but not a Sensor Logger or phyphox export",
                         file=str(path))
    if suffix in _CSV_SUFFIXES or suffix not in _BY_SUFFIX:
        try:
            text = head.decode("utf-8-sig", errors="strict") if b"\x00" not in head else ""
        except UnicodeDecodeError:
            text = ""
        from gnomon.io.xsens import is_xsens_text

        if text and is_xsens_text(text):
            return "xsens"
        if suffix in _CSV_SUFFIXES:
            return "csv"
    if suffix in _BY_SUFFIX:
        return _BY_SUFFIX[suffix]
    raise InputError(f"cannot tell the format from the content or the suffix "
                     f"{path.suffix!r}; use format= one of {', '.join(FORMATS[1:])}",
                     file=str(path))


def read(path: str | os.PathLike, format: str = "auto", map=None, *, strict: bool = False,
         **options) -> Recording:
    """Read a recording from ``path`` (a file, or a folder for ROS 2 bags and phone exports).

    Parameters
    ----------
    path : the file or folder.
    format : ``"auto"`` (detect, see the module docstring) or one of ``FORMATS``.
    strict : refuse a sample with a non-finite value (an :class:`InputError` naming the
        field and the row) instead of dropping it from its sensor and counting it in
        ``meta["dropped"]`` (:mod:`gnomon.io._common`: imperfect logs are kept).
    **options : passed to the format's reader (e.g. ``topic``, ``instance`` for logs;
        ``columns``, ``gyro_unit``, ... for CSV); an option that reader does not take
        raises :class:`InputError` naming it.
    map : a map (a YAML path or a dict, :mod:`gnomon.io.mapping`): read a table of any
        layout (CSV/TSV, .mat, .npz, Parquet) with it; no format or options then.
    """
    if map is not None:
        from gnomon.io.mapping import read_mapped

        if format != "auto" or options:
            raise InputError(f"a map names the layout; option(s) {sorted(options) or [format]} "
                             "do not apply", file=str(path), field="map")
        from gnomon.io._common import strict_reading

        with strict_reading(strict):
            return read_mapped(path, map)
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; use one of {', '.join(FORMATS)}",
                         field="format")
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", file=str(path))
    fmt = detect_format(path) if format == "auto" else format
    reader = reader_for(fmt)
    known = [p.name for p in _inspect.signature(reader).parameters.values()
             if p.name != "path" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InputError(f"option(s) {unknown} do not apply to {fmt} files; its options: "
                         f"{', '.join(known) or 'none'}", file=str(path), field=unknown[0])
    from gnomon.io._common import strict_reading

    with strict_reading(strict):
        return reader(path, **options)


def inspect(path: str | os.PathLike, format: str = "auto", **options) -> dict:
    """What a log holds (:func:`gnomon.io.summary.summarise`): sensors with ``rate_hz``,
    ``samples``, ``unit``, gaps, duration, the device's own estimate (or why there is
    none), what else the file offers (topics, instances), the samples dropped and what the
    reader assumed. JSON-able; ``options`` as for :func:`read` (``strict`` too)."""
    from gnomon.io.summary import summarise

    fmt = detect_format(path) if format == "auto" else format
    return summarise(read(path, format=fmt, **options), str(Path(path)), fmt)


def write(path: str | os.PathLike, rec: Recording) -> Path:
    """Write ``rec`` to ``path``: gnomon's HDF5 recording format, or for a ``.csv`` path a
    gnomon CSV (``gnomon.io.csv.write_csv``: one row per gyro sample, the other sensors
    in their arrival rows, the truth and the extra series as columns); returns the path."""
    if Path(path).suffix.lower() == ".csv":
        from gnomon.io.csv import write_csv

        return write_csv(path, rec)
    return write_recording(path, rec)
