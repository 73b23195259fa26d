"""Reader for generic CSV IMU logs.

One header line names the columns, then one line per sample. The default
header is::

    t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z

in s, rad/s, m/s² and µT. Optional columns ``q_w,q_x,q_y,q_z`` hold a truth
quaternion ``q_rb`` ``[w, x, y, z]`` (body to reference frame, default
``ENU``/``sensor``; empty or NaN cells mark a missing truth sample) and
``mask`` the samples that count for scoring (``1/0``, ``true/false``).
Blank lines and lines starting with ``#`` are skipped (before or after the header).

Other layouts: ``columns`` maps gnomon's column names (the names above) to
the names in the file, e.g. ``{"t": "time_ms", "gyr_x": "wx"}``; names not in
the map keep their default. Units (converted to SI on reading; the
magnetometer keeps its unit, recorded in ``Recording.mag_unit``):

==============  ===========================================  ======================
option          values                                       default
==============  ===========================================  ======================
``time_unit``   ``s``, ``ms``, ``us``, ``ns``                ``s``
``gyro_unit``   ``rad/s``, ``deg/s``                         ``rad/s``
``accel_unit``  ``m/s^2``, ``g`` (1 g = 9.80665 m/s²)        ``m/s^2``
``mag_unit``    ``uT``, ``nT``, ``mT``, ``T``, ``gauss``     ``uT``
==============  ===========================================  ======================

Required: time, the three gyro and the three accelerometer columns. The
magnetometer is optional (all three columns or none), so is the truth (all
four or none) and the mask.

Errors: bad input raises :class:`~gnomon.errors.InputError` naming the file,
the column (as written in the file's header) and the row. **Row convention:**
``row`` is the 1-based data row number, i.e. the first line after the header
is row 1 (blank and comment lines not counted); the message also gives the
line number in the file (1-based, header included), which is what an editor
shows. Caught: empty file, no data rows, missing column, a row with a wrong
number of cells, empty or non-numeric cell, NaN or infinity in the time column, a time
stamp that does not increase strictly, an unknown unit. A NaN or infinity in a sensor's
cells drops that sample of that sensor only (counted in ``meta["dropped"]``,
:mod:`gnomon.io._common`); read strictly (``gnomon.io.read(path, strict=True)``) it is an
error naming the column and the row.

A gyro log whose 99th-percentile rate exceeds 35 rad/s (2000 °/s — the
full-scale of most MEMS gyros) while read as rad/s raises a
:class:`UnitWarning` (probably deg/s); so does an accelerometer whose median
magnitude is near 1 while read as m/s² (probably g).
"""

from __future__ import annotations

import csv as _csv
import math
import os
import warnings
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import build, reading_strictly
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording

__all__ = ["read_csv", "write_csv", "sample_events", "UnitWarning", "DEFAULT_COLUMNS",
           "TIME_UNITS", "GYRO_UNITS", "ACCEL_UNITS", "STANDARD_GRAVITY_M_S2"]

STANDARD_GRAVITY_M_S2 = 9.80665  # m/s², exact by definition (CGPM 1901)

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # -> s
GYRO_UNITS = ("rad/s", "deg/s")
ACCEL_UNITS = {"m/s^2": 1.0, "g": STANDARD_GRAVITY_M_S2}  # -> m/s²

SENSOR_GROUPS = {
    "gyro": ("gyr_x", "gyr_y", "gyr_z"),
    "accel": ("acc_x", "acc_y", "acc_z"),
    "mag": ("mag_x", "mag_y", "mag_z"),
}
TRUTH_COLUMNS = ("q_w", "q_x", "q_y", "q_z")
#: gnomon column names, in the order of the default header (then truth and mask)
DEFAULT_COLUMNS = ("t",) + SENSOR_GROUPS["gyro"] + SENSOR_GROUPS["accel"] + \
    SENSOR_GROUPS["mag"] + TRUTH_COLUMNS + ("mask",)

#: gyro rates above this (99th percentile of |w|, rad/s) are implausible as rad/s
GYRO_RAD_S_PLAUSIBLE_MAX = 35.0

_MULTI_RATE = ("Multi-rate CSV: an empty cell means no sample of that sensor in that row; each "
               "sensor's time stamps are the times of the rows where its cells are filled.")
_TRUE = {"1", "true", "t", "yes", "y"}
_FALSE = {"0", "false", "f", "no", "n"}


class UnitWarning(UserWarning):
    """The data look as if they were in another unit than the one given."""


def _unit(option: str, value: str, allowed) -> None:
    if value not in allowed:
        raise InputError(f"unknown unit {value!r}; use one of {', '.join(allowed)}",
                         field=option)


class _Table:
    """Cells of a CSV file as strings, with the file line of every data row."""

    def __init__(self, path: Path, delimiter: str):
        self.path = path
        try:
            with open(path, newline="", encoding="utf-8-sig") as fh:
                reader = _csv.reader(fh, delimiter=delimiter)
                header, header_line = None, 0
                rows, lines = [], []
                self.comment_before_header = None
                for cells in reader:
                    if not cells or not "".join(cells).strip():
                        continue
                    if cells[0].lstrip().startswith("#"):
                        if header is None:
                            first = cells[0].lstrip()[1:]
                            self.comment_before_header = [c.strip() for c in [first] + cells[1:]]
                        continue
                    if header is None:
                        header, header_line = [c.strip() for c in cells], reader.line_num
                    else:
                        rows.append(cells)
                        lines.append(reader.line_num)
        except UnicodeDecodeError as err:
            raise InputError(f"not a UTF-8 text file ({err.reason} at byte {err.start})",
                             file=str(path)) from None
        except _csv.Error as err:
            raise InputError(f"malformed CSV ({err})", file=str(path)) from None
        if header is None:
            raise InputError("empty file: no header line", file=str(path))
        if not rows:
            raise InputError(f"no data rows after the header (line {header_line})",
                             file=str(path))
        self.header, self.header_line = header, header_line
        self.rows, self.lines = rows, np.asarray(lines)
        lengths = np.fromiter((len(r) for r in rows), int, len(rows))
        bad = np.flatnonzero(lengths != len(header))
        if bad.size:
            i = int(bad[0])
            short = lengths[i] < len(header)
            raise InputError(
                f"{lengths[i]} cells, header has {len(header)} (line {lines[i]})",
                file=str(path), field=header[lengths[i]] if short else None, row=i + 1)

    def error(self, message: str, column: str, i: int | None) -> InputError:
        """An InputError at data row index ``i`` (0-based) of ``column``."""
        if i is None:
            return InputError(message, file=str(self.path), field=column)
        return InputError(f"{message} (line {int(self.lines[i])})", file=str(self.path),
                          field=column, row=i + 1)

    def strings(self, column: str) -> np.ndarray:
        j = self.header.index(column)
        return np.array([r[j].strip() for r in self.rows], dtype=str)

    def numbers(self, column: str, *, allow_missing: bool = False, rows=slice(None),
                nonfinite: bool = False) -> np.ndarray:
        """Column as float (the data rows ``rows``); a bad cell raises naming column and
        row (``nan``/``inf`` too unless ``nonfinite`` or ``allow_missing``)."""
        index = np.arange(len(self.rows))[rows]
        s = self.strings(column)[rows]
        if allow_missing:
            s = np.where(s == "", "nan", s)
        try:
            values = s.astype(float)
        except ValueError:
            for i, cell in enumerate(s):
                try:
                    float(cell)
                except ValueError:
                    what = "empty cell" if cell == "" else f"not a number: {str(cell)!r}"
                    raise self.error(what, column, int(index[i])) from None
            raise  # pragma: no cover - astype and float disagree
        if not (allow_missing or nonfinite):
            bad = ~np.isfinite(values)
            if bad.any():
                i = int(np.argmax(bad))
                raise self.error(f"non-finite value {str(s[i])!r}", column, int(index[i]))
        return values


def read_csv(path: str | os.PathLike, columns: dict | None = None, gyro_unit: str = "rad/s",
             accel_unit: str = "m/s^2", mag_unit: str = "uT", time_unit: str = "s",
             delimiter: str = ",", *, frames: dict | None = None,
             source: str | None = None) -> Recording:
    """Read a CSV IMU log (module docstring for the layout, units and errors).

    Parameters
    ----------
    path : the CSV file.
    columns : gnomon column name -> column name in the file, for the columns
        whose names differ from the default header (``DEFAULT_COLUMNS``).
    gyro_unit, accel_unit, mag_unit, time_unit : units of the file's columns.
    delimiter : cell separator (one character, e.g. ``","``, ``";"``, ``"\\t"``).
    frames : frame names for the truth (default ``{"reference": "ENU", "body": "sensor"}``).
    source : description of the data; default the file name's stem.

    Returns a :class:`Recording` in SI units (``t`` s, ``gyro`` rad/s,
    ``accel`` m/s²; ``mag`` in ``mag_unit``).
    """
    columns, name = _options(columns, gyro_unit, accel_unit, mag_unit, time_unit, delimiter)
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", file=str(path))
    table = _Table(path, delimiter)
    has_mag, has_truth, has_mask = _present(table, name, columns)
    t = _time(table, name, time_unit)
    sensors = ("gyro", "accel", "mag") if has_mag else ("gyro", "accel")
    rows, multi_rate = _sensor_rows(table, name, sensors)
    meta = {"format": "csv", "multi_rate": True, "assumed": [_MULTI_RATE]} if multi_rate \
        else {}
    gyro = _group(table, name, "gyro", rows)
    if gyro_unit == "deg/s":
        gyro = np.deg2rad(gyro)
    accel = _group(table, name, "accel", rows) * ACCEL_UNITS[accel_unit]
    mag = _group(table, name, "mag", rows) if has_mag else None
    own_t = {}
    if multi_rate:
        t, own_t, mag = _own_times(table, name, t, rows, mag, meta["assumed"])
        _check_gyro_rows(table, name, rows["gyro"], has_truth, has_mask)
    q_true = _truth(table, name, rows["gyro"]) if has_truth else None
    mask = _mask(table, name, rows["gyro"], multi_rate) if has_mask else None
    _plausibility(path, gyro, gyro_unit, accel, accel_unit)
    try:
        return build(
            path, {}, t=t, gyro=gyro, accel=accel, mag=mag, mag_unit=mag_unit, q_true=q_true,
            mask=mask, meta=meta, **own_t,
            frames=frames if frames is not None else {"reference": "ENU", "body": "sensor"},
            source=path.stem if source is None else str(source),
        )
    except InputError as err:
        raise _named(table, name, rows, multi_rate, err) from None


def _options(columns: dict | None, gyro_unit: str, accel_unit: str, mag_unit: str,
             time_unit: str, delimiter: str) -> tuple[dict, dict]:
    """The options checked: ``(columns, gnomon column name -> the file's)``."""
    _unit("time_unit", time_unit, tuple(TIME_UNITS))
    _unit("gyro_unit", gyro_unit, GYRO_UNITS)
    _unit("accel_unit", accel_unit, tuple(ACCEL_UNITS))
    _unit("mag_unit", mag_unit, tuple(MAG_UNITS_TO_TESLA))
    if not isinstance(delimiter, str) or len(delimiter) != 1:
        raise InputError(f"expected one character, got {delimiter!r}", field="delimiter")
    columns = dict(columns or {})
    unknown = sorted(set(columns) - set(DEFAULT_COLUMNS))
    if unknown:
        raise InputError(f"unknown gnomon column name(s) {unknown}; known: "
                         f"{', '.join(DEFAULT_COLUMNS)}", field="columns")
    return columns, {k: str(columns.get(k, k)) for k in DEFAULT_COLUMNS}


def _require(table: _Table, name: dict, keys, why: str) -> None:
    """Raise naming the first of the columns ``keys`` missing from the header."""
    for k in keys:
        if name[k] not in table.header:
            hint = ""
            if name[k] in (table.comment_before_header or ()):
                hint = " (the column names seem to be in a '#' comment line; remove the '#')"
            raise InputError(
                f"missing column{why}; header (line {table.header_line}) has: "
                f"{', '.join(table.header)}{hint}", file=str(table.path), field=name[k])


def _present(table: _Table, name: dict, columns: dict) -> tuple[bool, bool, bool]:
    """Time, gyro and accelerometer required; whether the file has the magnetometer, the
    truth and the mask (each group all or none; required when named in ``columns``)."""

    def optional_group(keys):
        present = [name[k] in table.header for k in keys]
        if any(k in columns for k in keys):  # asked for explicitly
            _require(table, name, keys, " (given in 'columns')")
        elif any(present) and not all(present):
            _require(table, name, keys,
                     f" (the group {', '.join(name[k] for k in keys)} is incomplete)")
        return all(present)

    _require(table, name, ("t",) + SENSOR_GROUPS["gyro"] + SENSOR_GROUPS["accel"], "")
    return (optional_group(SENSOR_GROUPS["mag"]), optional_group(TRUTH_COLUMNS),
            optional_group(("mask",)))


def _time(table: _Table, name: dict, time_unit: str) -> np.ndarray:
    """The time column in s; it must increase strictly."""
    t_raw = table.numbers(name["t"])
    dt = np.diff(t_raw)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0)) + 1
        raise table.error(f"time stamps must increase strictly: {float(t_raw[i])!r} after "
                          f"{float(t_raw[i - 1])!r}", name["t"], i)
    return t_raw * TIME_UNITS[time_unit]


def _sensor_rows(table: _Table, name: dict, sensors: tuple) -> tuple[dict, bool]:
    """sensor -> the rows holding its samples (``slice(None)``: all), and whether the file
    is multi-rate (a sensor's three cells all empty in some row)."""
    empty = {k: np.column_stack([table.strings(name[c]) == "" for c in SENSOR_GROUPS[k]])
             for k in sensors}
    rows = {k: slice(None) for k in sensors}
    if not any(e.all(axis=1).any() for e in empty.values()):
        return rows, False
    # an empty group of cells means no sample of that sensor in this row
    for k in sensors:
        partial = empty[k].any(axis=1) & ~empty[k].all(axis=1)
        if partial.any():
            i = int(np.argmax(partial))
            col = name[SENSOR_GROUPS[k][int(np.argmax(empty[k][i]))]]
            raise table.error("empty cell (the other axes of this sensor have a value; "
                              "leave all three empty for no sample)", col, i)
        rows[k] = np.flatnonzero(~empty[k].all(axis=1))
    if rows["gyro"].size < 2:
        raise table.error(f"{rows['gyro'].size} row(s) with a gyro sample; at least 2 "
                          "needed", name["gyr_x"], None)
    return rows, True


def _group(table: _Table, name: dict, key: str, rows: dict) -> np.ndarray:
    """The three columns of sensor ``key`` in its rows, (N, 3) float (NaN/inf kept for
    ``build`` to drop, unless reading strictly)."""
    r = rows[key]
    keep = not reading_strictly()
    return np.column_stack([table.numbers(name[k], rows=r, nonfinite=keep)
                            for k in SENSOR_GROUPS[key]])


def _own_times(table: _Table, name: dict, t_rows: np.ndarray, rows: dict, mag, assumed: list
               ) -> tuple[np.ndarray, dict, np.ndarray | None]:
    """Multi-rate: ``(the gyro's time stamps, {"accel_t", "mag_t"}, mag)`` from the times
    of the rows holding each sensor's samples; no magnetometer when it has none."""
    t = t_rows[rows["gyro"]]
    own_t = {f"{k}_t": t_rows[rows[k]] for k in ("accel", "mag") if k in rows}
    if "mag" in rows and rows["mag"].size == 0:
        mag, own_t["mag_t"] = None, None
        assumed.append("The magnetometer columns are empty: no magnetometer.")
    if rows["accel"].size == 0:
        raise table.error("no row with an accelerometer sample", name["acc_x"], None)
    return t, own_t, mag


def _check_gyro_rows(table: _Table, name: dict, gyro_rows: np.ndarray, has_truth: bool,
                     has_mask: bool) -> None:
    """Multi-rate: truth and mask cells only in rows with a gyro sample."""
    others = np.setdiff1d(np.arange(len(table.rows)), gyro_rows)
    for key in (TRUTH_COLUMNS if has_truth else ()) + (("mask",) if has_mask else ()):
        filled = table.strings(name[key])[others] != ""
        if filled.any():
            i = int(others[np.argmax(filled)])
            raise table.error("a truth or mask value in a row without a gyro sample "
                              "(they belong to the gyro's time stamps)", name[key], i)


def _truth(table: _Table, name: dict, gyro_rows) -> np.ndarray:
    """``q_w..q_z`` on the gyro rows; a row with a missing cell is all NaN."""
    q_true = np.column_stack([table.numbers(name[k], allow_missing=True, rows=gyro_rows)
                              for k in TRUTH_COLUMNS])
    q_true[~np.isfinite(q_true).all(axis=1)] = np.nan  # missing sample: whole row NaN
    return q_true


def _mask(table: _Table, name: dict, gyro_rows, multi_rate: bool) -> np.ndarray:
    """The mask column on the gyro rows as bool (``1/0``, ``true/false``, ...)."""
    s = np.char.lower(table.strings(name["mask"])[gyro_rows])
    is_true, is_false = np.isin(s, list(_TRUE)), np.isin(s, list(_FALSE))
    if not np.all(is_true | is_false):
        j = int(np.argmax(~(is_true | is_false)))
        i = int(gyro_rows[j]) if multi_rate else j
        raise table.error(f"expected 1/0 or true/false, got {str(s[j])!r}", name["mask"], i)
    return is_true


def _named(table: _Table, name: dict, rows: dict, multi_rate: bool, err: InputError
           ) -> InputError:
    """The Recording's InputError named as the file calls it: column and table row."""
    field_to_column = {"t": name["t"], "gyro": ",".join(name[k] for k in SENSOR_GROUPS["gyro"]),
                       "accel": ",".join(name[k] for k in SENSOR_GROUPS["accel"]),
                       "mag": ",".join(name[k] for k in SENSOR_GROUPS["mag"]),
                       "q_true": ",".join(name[k] for k in TRUTH_COLUMNS),
                       "mask": name["mask"], "accel_t": name["t"], "mag_t": name["t"]}
    column = field_to_column.get(err.field, err.field)
    row = err.row
    if multi_rate and row is not None:  # the sensor's own index -> its table row
        sensor = str(err.field).removesuffix("_t")
        row = int(rows[sensor if sensor in rows else "gyro"][row])
    return table.error(err.message, column, row)


def _plausibility(path: Path, gyro: np.ndarray, gyro_unit: str, accel: np.ndarray,
                  accel_unit: str) -> None:
    """Warn (:class:`UnitWarning`) when the data look like another unit than declared."""
    rate = np.linalg.norm(gyro, axis=1)
    force = np.linalg.norm(accel, axis=1)
    rate, force = rate[np.isfinite(rate)], force[np.isfinite(force)]  # dropped later
    if gyro_unit == "rad/s" and rate.size:
        p99 = float(np.percentile(rate, 99))
        if p99 > GYRO_RAD_S_PLAUSIBLE_MAX:
            warnings.warn(
                f"{path}: gyro 99th-percentile rate {p99:.1f} rad/s "
                f"({math.degrees(p99):.0f} deg/s) is implausible; are the gyro columns "
                f"in deg/s? Then pass gyro_unit='deg/s'.", UnitWarning, stacklevel=3)
    if accel_unit == "m/s^2" and force.size:
        med = float(np.median(force))
        if 0.5 < med < 1.5:
            warnings.warn(
                f"{path}: median accelerometer magnitude {med:.3f} m/s^2 is near 1; are the "
                f"accelerometer columns in g? Then pass accel_unit='g'.", UnitWarning,
                stacklevel=3)


def sample_events(rec: Recording) -> dict:
    """Every sample of ``rec`` in time order, one row per time stamp: ``t`` (M,) s,
    ``gyro``, ``accel``, ``mag`` (M, 3) (µT) with NaN rows where that sensor has no sample,
    and ``gyro_row`` (M,) the index of the recording's gyro sample in that row (-1: none).
    A row holds at most one sample of each sensor; at equal stamps the accelerometer and
    the magnetometer come before (or with) the gyro, as ``Recording.on_time_base`` puts them
    in the gyro's row. A single-rate recording is its own rows (M = N)."""
    n = len(rec)
    to_uT = MAG_UNITS_TO_TESLA[rec.mag_unit] / MAG_UNITS_TO_TESLA["uT"]
    sensors = [("gyro", rec.gyro, rec.t, 2)]
    for rank, name in ((0, "accel"), (1, "mag")):
        v = getattr(rec, name)
        if v is not None:
            sensors.append((name, v * (to_uT if name == "mag" else 1.0), rec.times(name), rank))
    if rec.single_rate:
        out = {"t": rec.t, "gyro_row": np.arange(n)}
        for name in ("gyro", "accel", "mag"):
            v = dict((s[0], s[1]) for s in sensors).get(name)
            out[name] = np.full((n, 3), np.nan) if v is None else np.asarray(v, float)
        return out
    times = np.concatenate([s[2] for s in sensors])
    ranks = np.concatenate([np.full(len(s[2]), s[3]) for s in sensors])
    index = np.concatenate([np.arange(len(s[2])) for s in sensors])
    order = np.lexsort((ranks, times))
    row = np.empty(len(order), np.int64)  # the event's output row
    r, last_t, used = -1, None, set()
    for j, e in enumerate(order):
        te, rk = times[e], ranks[e]
        if te != last_t or rk in used or 2 in used:
            r, last_t, used = r + 1, te, set()
        used.add(rk)
        row[j] = r
    m = r + 1
    out = {"t": np.empty(m), "gyro_row": np.full(m, -1, np.int64)}
    for name in ("gyro", "accel", "mag"):
        out[name] = np.full((m, 3), np.nan)
    out["t"][row] = times[order]
    for name, v, _, rank in sensors:
        pick = ranks[order] == rank
        out[name][row[pick]] = np.asarray(v, float)[index[order][pick]]
        if name == "gyro":
            out["gyro_row"][row[pick]] = index[order][pick]
    return out


def write_csv(path: str | os.PathLike, rec: Recording) -> Path:
    """Write ``rec`` as a gnomon CSV, the input of an exported filter's ``gnomon_run``
    (and, for an IMU recording, of :func:`read_csv`, which reads it back sample for
    sample; the other columns it ignores): ``t,gyr_x..z[,acc_x..z][,mag_x..z]`` in s, rad/s,
    m/s² and µT, one row per time stamp (:func:`sample_events`: a single-rate recording's
    rows; each sensor at its own rate in the rows of its own stamps, empty cells where it
    has no sample); then, in the gyro's rows, the truth ``q_w..q_z`` and ``mask`` when
    present, the sun sensors' ``sun_x..z`` (b) and ``sun_valid`` when present, and every
    ``extra`` series of one value or one vector per gyro sample (``NAME`` or ``NAME_x,
    NAME_y, NAME_z``, ``NAME_0 ..`` for other widths; booleans as 0/1, NaN as an empty
    cell). Numbers with 17 significant digits: a write and a read give back the same
    floats. A spacecraft recording has no accelerometer: its CSV is for ``gnomon_run``
    (``read_csv`` needs one)."""
    path = Path(path)
    n = len(rec)
    ev = sample_events(rec)
    at_gyro = ev["gyro_row"]
    has_gyro = at_gyro >= 0

    def on_rows(v):  # a per-gyro-sample series in the event rows (NaN elsewhere)
        v = np.asarray(v, float)
        out = np.full((len(at_gyro), *v.shape[1:]), np.nan)
        out[has_gyro] = v[at_gyro[has_gyro]]
        return out

    cols: dict[str, np.ndarray] = {"t": ev["t"]}
    for sensor, names in SENSOR_GROUPS.items():
        if getattr(rec, sensor) is None:
            continue
        for j, name in enumerate(names):
            cols[name] = ev[sensor][:, j]
    if rec.q_true is not None:
        q = on_rows(rec.q_true)
        for j, name in enumerate(TRUTH_COLUMNS):
            cols[name] = q[:, j]
    if rec.mask is not None:
        cols["mask"] = on_rows(rec.mask)
    if rec.sun is not None:  # the sun sensors' direction (b) and validity
        sun = on_rows(rec.sun)
        for j, name in enumerate(("sun_x", "sun_y", "sun_z")):
            cols[name] = sun[:, j]
        if rec.sun_valid is not None:
            cols["sun_valid"] = on_rows(np.asarray(rec.sun_valid, bool))
    flags = {"mask", "sun_valid"}  # written as 0/1
    for name, v in sorted(rec.extra.items()):
        v = np.asarray(v)
        if v.shape[:1] != (n,) or v.dtype.kind not in "fiub" or v.ndim > 2:
            continue
        if v.dtype.kind == "b" and v.ndim == 1:
            flags.add(name)
        v = on_rows(v)
        if v.ndim == 1:
            cols[name] = v
        else:
            labels = "xyz" if v.shape[1] == 3 else [str(i) for i in range(v.shape[1])]
            for j, lab in enumerate(labels):
                cols[f"{name}_{lab}"] = v[:, j]
    cells = [[("" if x != x else str(int(x))) for x in v] if name in flags
             else [("" if x != x else repr(float(x))) for x in v] for name, v in cols.items()]
    with open(path, "w", newline="") as fh:
        fh.write(",".join(cols) + "\n")
        for row in zip(*cells, strict=True):
            fh.write(",".join(row) + "\n")
    return path
