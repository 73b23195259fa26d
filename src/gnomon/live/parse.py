"""Lines of a live stream (UDP datagrams, serial lines) into sensor samples.

Two line formats, told apart by their first character:

* **CSV** with gnomon's column names (``t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,
  mag_z``, as ``gnomon estimate`` reads files) in a header line, sent first (and again at
  any time: a new header replaces the old one); without a header, the default order, or
  ``columns`` (gnomon name -> the sender's column name, or its 0-based position). An
  empty cell is no sample of that sensor (all three cells of a sensor empty), as in a
  multi-rate CSV file.
* **JSON** objects, one per line, with the same names as keys (``{"t": 0.01, "gyr_x":
  ...}``) or with vectors (``{"t": 0.01, "gyro": [..], "accel": [..], "mag": [..]}``); a
  missing sensor is no sample.

Units as ``gnomon estimate``'s options (``time_unit``, ``gyro_unit``, ``accel_unit``,
``mag_unit``; converted to s, rad/s, m/s², µT). A line without a time column is stamped
on arrival. Anything else is malformed: :meth:`LineParser.parse` raises
:class:`Malformed` (the caller counts it and goes on); it never raises anything else.
"""

from __future__ import annotations

import json
import math

import numpy as np

from gnomon.errors import InputError
from gnomon.io.csv import ACCEL_UNITS, GYRO_UNITS, SENSOR_GROUPS, TIME_UNITS
from gnomon.recording import MAG_UNITS_TO_TESLA

__all__ = ["LineParser", "Malformed", "LIVE_COLUMNS"]

#: the columns a live line may hold, in the default order
LIVE_COLUMNS = ("t",) + SENSOR_GROUPS["gyro"] + SENSOR_GROUPS["accel"] + SENSOR_GROUPS["mag"]
#: the order samples of one line are returned in: the gyro last, so that a row can run
#: on its gyro sample with the others of the same line already in
_ORDER = ("accel", "mag", "gyro")
_VECTOR_KEYS = {"gyro": ("gyro", "gyr"), "accel": ("accel", "acc"), "mag": ("mag",)}


class Malformed(ValueError):
    """A line that is not a sample; ``reason`` says why in a few words."""


class LineParser:
    """Turns lines into ``[(sensor, t_s, value (3,))]`` in SI units (module docstring).

    ``columns``: gnomon column name -> the sender's name (str) or position (int); units as
    ``gnomon estimate``'s options. Bad options raise ``InputError`` here, at construction.
    """

    def __init__(self, columns: dict | None = None, *, time_unit: str = "s",
                 gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", mag_unit: str = "uT"):
        for option, value, allowed in (("time_unit", time_unit, TIME_UNITS),
                                       ("gyro_unit", gyro_unit, GYRO_UNITS),
                                       ("accel_unit", accel_unit, ACCEL_UNITS),
                                       ("mag_unit", mag_unit, MAG_UNITS_TO_TESLA)):
            if value not in allowed:
                raise InputError(f"unknown unit {value!r}; use one of {', '.join(allowed)}",
                                 field=option)
        columns = dict(columns or {})
        unknown = sorted(set(columns) - set(LIVE_COLUMNS))
        if unknown:
            raise InputError(f"unknown gnomon column name(s) {unknown}; known: "
                             f"{', '.join(LIVE_COLUMNS)}", field="columns")
        self.columns = columns
        self.scale = {"t": TIME_UNITS[time_unit],
                      "gyro": math.pi / 180.0 if gyro_unit == "deg/s" else 1.0,
                      "accel": ACCEL_UNITS[accel_unit],
                      "mag": MAG_UNITS_TO_TESLA[mag_unit] / MAG_UNITS_TO_TESLA["uT"]}
        positional = {k: v for k, v in columns.items() if isinstance(v, int)}
        if positional and len(positional) != len(columns):
            raise InputError("give every column by name or every column by position",
                             field="columns")
        # gnomon name -> position in a CSV line (None until a header names them)
        self._index = ({k: int(v) for k, v in positional.items()} if positional
                       else self._from_header(LIVE_COLUMNS) if not columns else None)
        self._default = not columns  # the default order until a header comes
        self._positional = bool(positional)  # lines may hold more cells than those named
        self._cells = 1 + max(self._index.values()) if self._index else 0  # per line
        self.headers = 0

    # ------------------------------------------------------------------ CSV
    def _from_header(self, names) -> dict:
        """gnomon name -> position, from a header's column names."""
        names = [n.strip() for n in names]
        index = {}
        for key in LIVE_COLUMNS:
            want = str(self.columns.get(key, key))
            if want in names:
                index[key] = names.index(want)
        return index

    def _is_header(self, cells) -> bool:
        def number(c):
            try:
                float(c)
            except ValueError:
                return c.strip() == ""
            return True

        return not all(number(c) for c in cells)

    def parse(self, line: bytes | str) -> list[tuple[str, float, np.ndarray]]:
        """The samples in one line (``[]`` for a header or a blank/comment line); raises
        :class:`Malformed`."""
        if isinstance(line, bytes | bytearray):
            try:
                line = line.decode("utf-8")
            except UnicodeDecodeError:
                raise Malformed("not UTF-8 text") from None
        text = line.strip().lstrip("\ufeff")
        if not text or text.startswith("#"):
            return []
        if text[0] == "{":
            return self._json(text)
        cells = text.split(",")
        if self._is_header(cells):
            index = self._from_header(cells)
            if "gyr_x" not in index and not any(k in index for k in SENSOR_GROUPS["gyro"]):
                raise Malformed("not a number, nor a header naming the gyro columns")
            self._index = index
            self._default = self._positional = False
            self._cells = len(cells)
            self.headers += 1
            return []
        if self._index is None:
            raise Malformed("a data line before the header that --columns names")
        return self._csv(cells)

    def _csv(self, cells) -> list:
        index = self._index
        if self._default and len(cells) == 7:  # no header: t, gyro, accel without a mag
            index = {k: v for k, v in index.items() if v < 7}
        elif len(cells) != self._cells and not (self._positional and len(cells) > self._cells):
            raise Malformed(f"{len(cells)} cells, expected {self._cells}")

        def cell(key):
            j = index.get(key)
            if j is None:
                return None
            c = cells[j].strip()
            return None if c == "" else c

        try:
            t = cell("t")
            t = math.nan if t is None else _stamp(float(t) * self.scale["t"])
            out = []
            for sensor in _ORDER:
                raw = [cell(k) for k in SENSOR_GROUPS[sensor]]
                if all(c is None for c in raw):
                    continue
                if any(c is None for c in raw):
                    raise Malformed(f"{sensor}: one or two of its cells empty")
                out.append((sensor, t, np.array([float(c) for c in raw]) * self.scale[sensor]))
        except Malformed:
            raise
        except ValueError:
            raise Malformed("a cell is not a number") from None
        return self._checked(out)

    # ------------------------------------------------------------------ JSON
    def _json(self, text: str) -> list:
        try:
            obj = json.loads(text)
        except (ValueError, RecursionError):
            raise Malformed("not a JSON object") from None
        if not isinstance(obj, dict):
            raise Malformed("not a JSON object")

        def key(name):
            return self.columns.get(name, name) if isinstance(self.columns.get(name, name),
                                                               str) else name

        try:
            t = obj.get(key("t"))
            t = math.nan if t is None else _stamp(float(t) * self.scale["t"])
            out = []
            for sensor in _ORDER:
                vec = next((obj[k] for k in _VECTOR_KEYS[sensor] if k in obj), None)
                if vec is None:
                    parts = [obj.get(key(k)) for k in SENSOR_GROUPS[sensor]]
                    if all(p is None for p in parts):
                        continue
                    vec = parts
                if not isinstance(vec, list | tuple) or len(vec) != 3 \
                        or any(isinstance(x, bool) or x is None for x in vec):
                    raise Malformed(f"{sensor}: not three numbers")
                out.append((sensor, t, np.array([float(x) for x in vec]) * self.scale[sensor]))
        except Malformed:
            raise
        except (TypeError, ValueError, OverflowError):
            raise Malformed("a value is not a number") from None
        return self._checked(out)

    @staticmethod
    def _checked(out: list) -> list:
        if not out:
            raise Malformed("no sensor values")
        for sensor, _, v in out:
            if not np.all(np.isfinite(v)):
                raise Malformed(f"{sensor}: non-finite value")
        return out


def _stamp(t: float) -> float:
    """A time stamp that is there must be a number (a missing one means "on arrival")."""
    if not math.isfinite(t):
        raise Malformed("non-finite time stamp")
    return t
