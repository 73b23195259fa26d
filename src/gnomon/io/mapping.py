"""A map: how to read a table of unknown layout (CSV/TSV, ``.mat``, ``.npz``, Parquet) as a
``Recording``, proposed from the names and the data, saved as YAML, used for every file
of the same layout.

``propose_map(path)`` looks at the file (:func:`gnomon.io.table.load_table`) and finds:

* **time** — a column named like time (``t``, ``time``, ``Timestamp``, ``MATLABtime``,
  ``Time (s)``, ``stamp``, ...; else the first strictly increasing column), its unit from
  the spacing (:func:`gnomon.io.units.time_unit`); or, with no time, a sample-rate
  scalar (``fs``, ``rate``, ``sampling_rate``) of a ``.mat``/``.npz``;
* **gyro, accelerometer, magnetometer** — three columns sharing a stem and ending in an
  axis (``gyro_x``, ``gyr_x``, ``wx``, ``omega_x``, ``gyroX``, ``angular_velocity.x``,
  ``Gyroscope X (rad/s)``, ``acc_x``, ``ax``, ``mag_x``, ...) or one N×3/3×N array
  (``SENSgyro``, ``imu_acc``); a group whose name tells nothing is classified by its data
  (a norm that stays near 1 g is an accelerometer, near the Earth's field a
  magnetometer, else a gyro); units from the data (:mod:`gnomon.io.units`), a unit in
  the names breaking ties;
* **a reference quaternion** — four columns (``q_w..q_z``, ``cam_qx..cam_qw``,
  ``q1..q4``, ``orientation.w``) or an N×4/4×N array (``ABBquaternion``): its component
  order (wxyz or xyzw) **from the data** — the body rate each order gives, fitted to the
  gyro by one rotation (:func:`gnomon.io.units.quat_order`); the names decide only when
  the data cannot (rotation about one axis, no gyro);
* **a validity mask** for the reference (``isTracked``, ``valid``, ``tracking``: 0/1
  values), its 0 rows read as missing truth; and a **scoring mask** (``mask``,
  ``movement``: 0/1, BROAD's), the rows that count for the scores (``Recording.mask``);
* **the reference's frame**: ``ENU`` when gravity and, with a magnetometer, north seen
  through the reference point where gnomon's ENU has them (within 5°, the median tilt,
  and 10°, the circular mean heading), else ``unknown`` — a motion-capture world (y up,
  any heading), a marker not on the sensor's axes, a time lag: ``--align`` fits those,
  not the map.

The map (a dict, YAML on disk; ``write_map``/``load_map``, validated naming the key)::

    version: 1
    kind: csv                       # csv | mat | npz | parquet
    delimiter: ","                  # csv (informative; found again on reading)
    time: {column: Timestamp, unit: ms}       # or {rate_hz: 100}
    gyro: {columns: [gyro_x, gyro_y, gyro_z], unit: rad/s, axes: [x, y, z]}
    accel: {columns: [acc_x, acc_y, acc_z], unit: g, axes: [x, y, z]}
    mag: {array: SENSmag, unit: gauss, axes: [x, -y, -z]}      # optional
    truth: {columns: [cam_qx, cam_qy, cam_qz, cam_qw], order: xyzw, frame: unknown,
            valid: isTracked}                                  # optional
    mask: {column: movement}                                   # optional: rows scored
    evidence: {time: [...], gyro: [...], ...}                  # why; ignored on reading

Units: time ``s ms us ns datenum``; gyro ``rad/s deg/s``; accelerometer ``m/s^2 g mg``;
magnetometer ``uT nT mT T gauss mG`` (read into µT). ``axes`` remaps a sensor mounted
rotated: output axis i is the named input axis with its sign (a signed permutation,
``[x, -y, -z]``: turned 180° about x). ``order`` is the order the file stores the
components in, as listed. ``read_mapped(path, map)`` reads one file with it (each sensor through
``gnomon.io._common.build``, as every reader), ``frames = {"reference": "ENU", "body":
"sensor", "truth": <the map's truth frame>}``: the filters estimate against ENU, and
``frames["truth"] == "unknown"`` says the truth's world frame, its body (the marker) and
its clock are not known to be gnomon's (said in ``meta["assumed"]`` too).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io import units as U
from gnomon.io.table import TABLE_KINDS, Table, load_table, split_unit, table_kind

__all__ = ["propose_map", "read_mapped", "write_map", "load_map", "missing", "MAP_VERSION",
           "SENSOR_KEYS", "live_options"]

MAP_VERSION = 1
SENSOR_KEYS = ("gyro", "accel", "mag")
#: the suffixes of each kind (a folder benchmark with a map reads these)
KIND_SUFFIXES = {"csv": (".csv", ".tsv", ".txt", ".dat"), "mat": (".mat",), "npz": (".npz",),
                 "parquet": (".parquet", ".pq")}
UNITS = {"time": U.TIME_TO_S, "gyro": U.GYRO_TO_RAD_S, "accel": U.ACCEL_TO_M_S2,
         "mag": U.MAG_TO_UT}
_AXES = ("x", "y", "z")
_ORDERS = {"wxyz": (0, 1, 2, 3), "xyzw": (3, 0, 1, 2)}  # gnomon's w, x, y, z from the file's
_FRAMES = ("ENU", "unknown")

# name words (lower case tokens) of each quantity; a token containing a long word counts
_WORDS = {
    "gyro": ({"gyr", "gyro", "gyros", "gyroscope", "omega", "w", "g", "angvel", "angular",
              "rate", "rot"}, ("gyr", "omega", "angular")),
    "accel": ({"acc", "accel", "accelerometer", "acceleration", "a", "f", "linacc", "sf",
               "specific"}, ("acc",)),
    "mag": ({"mag", "magnetometer", "magnetic", "m", "b", "field", "h"}, ("mag",)),
    "truth": ({"q", "quat", "quaternion", "orientation", "ori", "att", "attitude", "rot",
               "rotation", "pose"}, ("quat", "orient")),
    "time": ({"t", "time", "timestamp", "timestamps", "stamp", "ts", "sec", "secs",
              "seconds", "epoch", "datenum", "utc"}, ("time", "stamp")),
    "valid": ({"valid", "tracked", "istracked", "tracking", "visible", "ok", "occluded"},
              ("track", "valid")),
    "mask": ({"mask", "movement", "moving", "score", "scored", "scoring"}, ()),
}
_NOT_SENSOR = ("bias", "cov", "std", "var", "err", "offset", "noise", "sigma", "est", "filt",
               "ref", "true")
_RATE_NAMES = ("fs", "rate", "sampling_rate", "sample_rate", "freq", "frequency", "hz")


# --------------------------------------------------------------------------- names
def _tokens(name: str) -> tuple[list[str], str | None]:
    """The lower-case words of a name (camelCase and ``SENSgyro`` split) and the unit in
    brackets at its end."""
    base, unit = split_unit(name)
    s = re.sub(r"([A-Z]{2,})([a-z])", r"\1_\2", base)
    s = re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", s)
    return [w for w in re.split(r"[^a-z0-9µ]+", s.lower()) if w], unit


def _is(quantity: str, tokens: list[str]) -> bool:
    exact, inside = _WORDS[quantity]
    return any(w in exact or any(x in w for x in inside) for w in tokens)


def _axis_split(name: str) -> tuple[str, str, str | None] | None:
    """(stem, axis, unit) of a column named like a vector component: a last word x/y/z/w or
    a digit, or a last word ending in x/y/z/w after a known stem (``wx``, ``gyrox``)."""
    tokens, unit = _tokens(name)
    if not tokens:
        return None
    last = tokens[-1]
    if last in ("x", "y", "z", "w") or last.isdigit() and len(last) == 1:
        return " ".join(tokens[:-1]), last, unit
    m = re.match(r"^([a-z]+?)_?([xyzw]|[0-4])$", last)
    if m and len(last) > 1:
        stem = " ".join(tokens[:-1] + [m.group(1)])
        if any(_is(q, [m.group(1)]) for q in ("gyro", "accel", "mag", "truth")):
            return stem, m.group(2), unit
    return None


def _groups(table: Table) -> list[dict]:
    """Columns grouped by stem into vectors (x, y, z; or 3 consecutive digits) and
    quaternions (w, x, y, z; or 4 consecutive digits), in the file's order."""
    by_stem: dict[str, dict] = {}
    for name in table.columns:
        hit = _axis_split(name)
        if hit is None:
            continue
        stem, axis, unit = hit
        g = by_stem.setdefault(stem, {"stem": stem, "axes": {}, "unit": unit})
        g["axes"].setdefault(axis, name)
    out = []
    for g in by_stem.values():
        axes = g["axes"]
        digits = sorted(a for a in axes if a.isdigit())
        if {"x", "y", "z"} <= set(axes):
            cols = [axes[a] for a in _AXES]
            if "w" in axes:  # listed in the file's order when that is wxyz or xyzw
                file_order = "".join(sorted("wxyz", key=lambda a: list(table.columns)
                                            .index(axes[a])))
                order = file_order if file_order in _ORDERS else "wxyz"
                out.append({**g, "width": 4, "columns": [axes[a] for a in order],
                            "names_order": order})
            else:
                out.append({**g, "width": 3, "columns": cols})
        elif len(digits) >= 3:
            ds = [int(d) for d in digits]
            for start in (0, 1):
                run = [d for d in range(start, start + 4) if d in ds]
                if len(run) == 4 and run == list(range(start, start + 4)):
                    out.append({**g, "width": 4, "columns": [axes[str(d)] for d in run],
                                "names_order": "wxyz" if start == 0 else None})
                    break
                if len(run) >= 3 and run[:3] == list(range(start, start + 3)) and len(ds) == 3:
                    out.append({**g, "width": 3, "columns": [axes[str(d)] for d in run[:3]]})
                    break
    return out


def _candidates(table: Table) -> list[dict]:
    """Every vector or quaternion the table offers: column groups and arrays, with the
    quantity its name suggests (``kind``: gyro/accel/mag/truth or None)."""
    cands = []
    for g in _groups(table):
        words = g["stem"].split()
        cands.append({**g, "source": "columns",
                      "what": f"columns {', '.join(g['columns'])}",
                      "data": np.column_stack([table.columns[c] for c in g["columns"]]),
                      "words": words})
    for name, a in table.arrays.items():
        words, unit = _tokens(name)
        cands.append({"source": "array", "array": name, "width": a.shape[1], "data": a,
                      "unit": unit, "words": words, "names_order": None,
                      "what": f"array {name} ({table.layout[name]})"})
    for c in cands:
        c["kind"] = None
        quantities = ("truth",) if c["width"] == 4 else SENSOR_KEYS
        for q in quantities:
            if _is(q, c["words"]):
                c["kind"] = q
                break
        c["secondary"] = any(x in w for w in c["words"] for x in _NOT_SENSOR)
    return cands


def _pick(cands: list[dict], kind: str) -> tuple[dict | None, list[str]]:
    """The first candidate named ``kind`` (primary before secondary: ``gyro_bias_x`` after
    ``gyro_x``), and the others as alternatives."""
    named = [c for c in cands if c["kind"] == kind]
    named.sort(key=lambda c: c["secondary"])
    if not named:
        return None, []
    return named[0], [c["what"] for c in named[1:]]


# --------------------------------------------------------------------------- propose
def _time(table: Table) -> tuple[dict | None, list[str], np.ndarray | None]:
    """The time entry of the map, its evidence and the raw stamps."""
    named, other = [], []
    for name, v in table.columns.items():
        words, unit = _tokens(name)
        ok = v[np.isfinite(v)]
        increasing = ok.size >= 2 and np.all(np.diff(ok) > 0)
        if _is("time", words) and increasing:
            named.append((name, unit))
        elif increasing and not any(w in ("frame", "index", "sample", "counter", "packet",
                                          "seq", "id") for w in words):
            other.append((name, unit))
    for how, found in (("its name", named), ("the first increasing column", other)):
        if found:
            name, unit = found[0]
            tunit, why = U.time_unit(table.columns[name], name, unit)
            ev = [f"{name}: {how}; {why}"]
            if len(found) > 1:
                ev.append(f"also increasing: {', '.join(n for n, _ in found[1:])}")
            return {"column": name, "unit": tunit}, ev, table.columns[name]
    for name, value in table.scalars.items():
        if name.lower() in _RATE_NAMES and value > 0:
            n = max((len(v) for v in table.columns.values()), default=0)
            n = max([n] + [a.shape[0] for a in table.arrays.values()])
            return ({"rate_hz": value}, [f"no time stamps; the scalar {name} = {value:g} "
                                         "read as the sample rate in Hz"],
                    np.arange(n) / value)
    return None, ["no column named like time and no increasing column"], None


def _in_unit(raw: np.ndarray, key: str, unit: str) -> np.ndarray:
    return np.asarray(raw, float) * UNITS[key][unit]


def propose_map(path: str | os.PathLike) -> dict:
    """A map for ``path`` (module docstring) with its ``evidence`` (a list of sentences
    per entry). Entries not found are left out; :func:`missing` says which of the
    required ones (time, gyro, accel)."""
    table = load_table(path)
    m: dict = {"version": MAP_VERSION, "kind": table.kind}
    if table.delimiter is not None:
        m["delimiter"] = table.delimiter
    ev: dict[str, list[str]] = {}
    time, ev["time"], t_raw = _time(table)
    if time is not None:
        m["time"] = time
    t_s = None
    if t_raw is not None:
        t_s = _seconds(t_raw, time)
    cands = _candidates(table)
    found: dict[str, dict] = {}
    for key in SENSOR_KEYS + ("truth",):
        c, alternatives = _pick(cands, key)
        if c is not None:
            found[key] = c
            ev[key] = [f"{c['what']}: named like {'a quaternion' if key == 'truth' else key}"]
            if alternatives:
                ev[key].append(f"also named like it: {'; '.join(alternatives)}")
    _by_data(cands, found, ev)
    raw = {k: c["data"] for k, c in found.items()}
    for key in SENSOR_KEYS:
        if key in found:
            m[key] = _entry(found[key])
    truth_fit = None
    if "truth" in found:
        c = found["truth"]
        valid, ev_valid = _valid(table)
        order, fits, why = U.quat_order(raw["truth"], t_s, raw.get("gyro"), valid) \
            if t_s is not None else (None, {}, "no time: the rate cannot be fitted")
        ev["truth"].append(why)
        if order is None:
            order = c.get("names_order") or "wxyz"
            ev["truth"].append(f"order {order} from "
                               + ("the names" if c.get("names_order") else
                                  "nothing: the default, check it"))
        elif c.get("names_order") and c["names_order"] != order:
            ev["truth"].append(f"the names suggest {c['names_order']}; the data decided")
        truth_fit = fits.get(order)
        m["truth"] = {**_entry(c, unit=False), "order": order}
        if valid is not None:
            m["truth"]["valid"] = ev_valid[0]
            ev["truth"].append(ev_valid[1])
        flag, ev_mask = _flag(table, "mask", exclude=m["truth"].get("valid"))
        if flag is not None:
            m["mask"] = {"column": ev_mask[0]}
            ev["mask"] = [f"{ev_mask[0]}: a 0/1 column named like a scoring mask, "
                          f"{int(flag.sum())} of {flag.size} rows scored"]
    if "gyro" in found:
        hint = found["gyro"].get("unit")
        unit, why = U.gyro_unit(raw["gyro"], hint,
                                None if truth_fit is None else truth_fit["scale"])
        m["gyro"]["unit"] = unit
        ev["gyro"].append(why)
    if "accel" in found:
        unit, why = U.accel_unit(raw["accel"], raw.get("gyro"), found["accel"].get("unit"))
        m["accel"]["unit"] = unit
        ev["accel"].append(why)
    if "mag" in found:
        unit, why = U.mag_unit(raw["mag"], found["mag"].get("unit"))
        m["mag"]["unit"] = unit
        ev["mag"].append(why)
    if "truth" in m:
        frame, why = _truth_frame(m, raw, truth_fit)
        m["truth"]["frame"] = frame
        ev["truth"].append(why)
    left = [c["what"] for c in cands if all(c is not f for f in found.values())]
    if left:
        ev["unused"] = [f"not mapped: {'; '.join(left)}"]
    if table.skipped:
        ev.setdefault("unused", []).append(f"not numeric or not N long: "
                                           f"{', '.join(table.skipped)}")
    m["evidence"] = {k: v for k, v in ev.items() if v}
    return m


def _seconds(raw: np.ndarray, time: dict) -> np.ndarray:
    if "rate_hz" in time:
        return np.asarray(raw, float)
    raw = np.asarray(raw, float)
    if time["unit"] == "datenum":
        return (raw - raw[np.isfinite(raw)][0]) * U.TIME_TO_S["datenum"]
    return raw * U.TIME_TO_S[time["unit"]]


def _entry(c: dict, unit: bool = True) -> dict:
    e = {"columns": list(c["columns"])} if c["source"] == "columns" else {"array": c["array"]}
    if unit:
        e["unit"] = None
        e["axes"] = list(_AXES)
    return e


def _by_data(cands: list[dict], found: dict, ev: dict) -> None:
    """Sensors not found by name, from the unnamed 3-wide candidates' data: a norm that
    stays within 30 % of 1 g (in m/s², g or mg) is an accelerometer, one within the Earth's
    field range in some unit a magnetometer, one that varies a gyro."""
    lo, hi = U.EARTH_FIELD_UT
    for c in cands:
        if c["width"] != 3 or c["kind"] is not None or any(c is f for f in found.values()):
            continue
        n = np.linalg.norm(c["data"], axis=1)
        n = n[np.isfinite(n)]
        if n.size < 3:
            continue
        med = float(np.median(n))
        spread = float(np.subtract(*np.percentile(n, [75, 25])) / med) if med > 0 else math.inf
        if "accel" not in found and spread < 0.3 and any(
                0.7 < med * f / 9.80665 < 1.3 for f in U.ACCEL_TO_M_S2.values()):
            key = "accel"
        elif "mag" not in found and spread < 0.3 and any(
                lo <= med * f <= hi for f in U.MAG_TO_UT.values()):
            key = "mag"
        elif "gyro" not in found and spread >= 0.3:
            key = "gyro"
        else:
            continue
        c["kind"] = key
        found[key] = c
        ev[key] = [f"{c['what']}: its name tells nothing; from the data (median norm "
                   f"{med:.4g}, relative spread {spread:.2f})"]


def _flag(table: Table, kind: str, exclude: str | None = None):
    """The first 0/1 column named like ``kind`` (``valid``, ``mask``): (rows 1, (its name,))
    or (None, None)."""
    for name, v in table.columns.items():
        ok = v[np.isfinite(v)]
        if name != exclude and ok.size and _is(kind, _tokens(name)[0]) and np.all(
                np.isin(ok, (0.0, 1.0))):
            return np.isfinite(v) & (v == 1.0), (name,)
    return None, None


def _valid(table: Table) -> tuple[np.ndarray | None, tuple[str, str] | None]:
    """A 0/1 column named like a validity flag: (rows valid, (its name, the evidence))."""
    for name, v in table.columns.items():
        words, _ = _tokens(name)
        ok = v[np.isfinite(v)]
        if ok.size and _is("valid", words) and np.all(np.isin(ok, (0.0, 1.0))):
            valid = np.isfinite(v) & (v == 1.0)
            if "occluded" in words:
                valid = np.isfinite(v) & (v == 0.0)
            return valid, (name, f"{name}: a validity flag (0/1), {int((~valid).sum())} of "
                                 f"{v.size} rows invalid: read as missing truth")
    return None, None


def _truth_frame(m: dict, raw: dict, fit: dict | None) -> tuple[str, str]:
    """``ENU`` when the reference turns the accelerometer's gravity to +z (5°, the median
    tilt) and the magnetometer's horizontal part to +y (10°, the circular mean heading),
    over the rows where both are finite; else ``unknown``."""
    if "accel" not in raw or m["accel"].get("unit") is None:
        return "unknown", "frame unknown: no accelerometer to check it"
    from gnomon.rotation import quat_rotate

    q = np.asarray(raw["truth"], float)[:, list(_ORDERS[m["truth"]["order"]])]
    n = np.linalg.norm(q, axis=1)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(n) & (np.abs(n - 1.0) < 0.1) & np.isfinite(raw["accel"]).all(axis=1)
    if ok.sum() < 3:
        return "unknown", "frame unknown: too few valid reference rows"
    q = q[ok] / n[ok, None]
    acc = _remap(_in_unit(raw["accel"][ok], "accel", m["accel"]["unit"]), m["accel"]["axes"])
    up = quat_rotate(q, acc)
    tilt = np.degrees(np.arccos(np.clip(up[:, 2] / np.linalg.norm(up, axis=1), -1, 1)))
    tilt_med = float(np.nanmedian(tilt))
    why = f"gravity through the reference {tilt_med:.1f} deg from +z (median)"
    if fit is not None:
        why += (f"; the reference's rate matches the gyro after a rotation of "
                f"{fit['angle_deg']:.1f} deg (marker to sensor) and a lag of "
                f"{1000 * fit['lag_s']:.0f} ms (to the fit's 50 ms windows)")
    if tilt_med > 5.0:
        return "unknown", f"frame unknown (not ENU, or the marker is not on the sensor's " \
                          f"axes): {why}; --align fits it"
    if "mag" not in raw or m["mag"].get("unit") is None:
        return "unknown", f"frame unknown: {why}, but no magnetometer to check the heading"
    fine = np.isfinite(raw["mag"][ok]).all(axis=1)
    if fine.sum() < 3:
        return "unknown", f"frame unknown: {why}, but too few magnetometer samples"
    mag = _remap(_in_unit(raw["mag"][ok][fine], "mag", m["mag"]["unit"]), m["mag"]["axes"])
    h = quat_rotate(q[fine], mag)
    heading = np.arctan2(h[:, 0], h[:, 1])  # of the field, from +y towards +x (rad)
    head_med = math.degrees(float(np.angle(np.mean(np.exp(1j * heading)))))
    why += f"; the field's horizontal part {head_med:+.1f} deg from +y (circular mean)"
    if abs(head_med) > 10.0:
        return "unknown", f"frame unknown (heading not ENU's): {why}; --align fits it"
    return "ENU", f"frame ENU: {why}"


def missing(m: dict) -> list[str]:
    """The required entries (time, gyro, accel) a map lacks."""
    return [k for k in ("time", "gyro", "accel") if k not in m]


# --------------------------------------------------------------------------- YAML
_HEADER = """\
# gnomon map: how to read files of this layout (gnomon inspect FILE --write-map MAP.yaml).
# Used by: gnomon estimate|calibrate|inspect FILE --map MAP.yaml, gnomon benchmark DIR --map.
# Units: time s|ms|us|ns|datenum, gyro rad/s|deg/s, accel m/s^2|g|mg,
#        mag uT|nT|mT|T|gauss|mG. axes: a signed permutation, e.g. [x, -y, -z].
# truth.order: the order the file stores the components in (wxyz or xyzw);
# truth.frame: ENU (gnomon's) or unknown (--align fits it); truth.valid: a 0/1 column
# (0: no truth); mask.column: a 0/1 column of the rows scored. evidence: why (not read).
"""


def write_map(path: str | os.PathLike, m: dict) -> Path:
    """Write map ``m`` as YAML (the header comment, the entries, then ``evidence``)."""
    import yaml

    m = load_map(m)  # validated before it is written
    body = {k: v for k, v in m.items() if k != "evidence"}
    text = _HEADER + yaml.safe_dump(body, sort_keys=False, default_flow_style=None,
                                    allow_unicode=True, width=100)
    if m.get("evidence"):
        text += yaml.safe_dump({"evidence": m["evidence"]}, sort_keys=False,
                               default_flow_style=False, allow_unicode=True, width=100)
    p = Path(path)
    p.write_text(text, encoding="utf-8")
    return p


_KEYS = {"version", "kind", "delimiter", "time", "gyro", "accel", "mag", "truth", "mask",
         "evidence"}
_ENTRY_KEYS = {"time": {"column", "unit", "rate_hz"},
               "sensor": {"columns", "array", "unit", "axes"},
               "truth": {"columns", "array", "order", "frame", "valid"}}


def load_map(source) -> dict:
    """A map from a YAML file (path) or a dict, validated: an :class:`InputError` names the
    key (``gyro.unit``) and the value."""
    where = None
    if isinstance(source, dict):
        m = dict(source)
    else:
        import yaml

        where = str(source)
        p = Path(source)
        if not p.is_file():
            raise InputError("no such file", file=where)
        try:
            m = yaml.safe_load(p.read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as err:
            raise InputError(f"not YAML ({' '.join(str(err).split())})", file=where) from None
        if not isinstance(m, dict):
            raise InputError("expected a mapping of keys (version, kind, time, gyro, ...)",
                             file=where)

    def bad(key: str, message: str):
        return InputError(message, file=where, field=key)

    unknown = sorted(set(map(str, m)) - _KEYS)
    if unknown:
        raise bad(unknown[0], f"unknown key; known: {', '.join(sorted(_KEYS))}")
    if m.get("version") != MAP_VERSION:
        raise bad("version", f"expected {MAP_VERSION}, got {m.get('version')!r}")
    if m.get("kind") not in TABLE_KINDS:
        raise bad("kind", f"expected one of {', '.join(TABLE_KINDS)}, got {m.get('kind')!r}")
    for key in ("time", "gyro", "accel"):
        if key not in m:
            raise bad(key, "missing (time, gyro and accel are required)")
    out = {"version": MAP_VERSION, "kind": m["kind"]}
    if "delimiter" in m:
        out["delimiter"] = m["delimiter"]
    out["time"] = _check_time(m["time"], bad)
    for key in SENSOR_KEYS:
        if m.get(key) is not None:
            out[key] = _check_sensor(key, m[key], bad)
    if m.get("truth") is not None:
        out["truth"] = _check_truth(m["truth"], bad)
    if m.get("mask") is not None:
        v = _mapping("mask", m["mask"], {"column"}, bad)
        if not isinstance(v.get("column"), str):
            raise bad("mask.column", f"expected a column name, got {v.get('column')!r}")
        out["mask"] = {"column": v["column"]}
    if m.get("evidence"):
        out["evidence"] = m["evidence"]
    return out


def _mapping(key: str, v, allowed: set, bad) -> dict:
    if not isinstance(v, dict):
        raise bad(key, f"expected a mapping, got {v!r}")
    unknown = sorted(set(map(str, v)) - allowed)
    if unknown:
        raise bad(f"{key}.{unknown[0]}", f"unknown key; known: {', '.join(sorted(allowed))}")
    return dict(v)


def _source(key: str, v: dict, width: int, bad) -> dict:
    if ("columns" in v) == ("array" in v):
        raise bad(key, "give either columns (a list of names) or array (one name)")
    if "columns" in v:
        cols = v["columns"]
        if not isinstance(cols, list) or len(cols) != width or not all(
                isinstance(c, str | int) for c in cols):
            raise bad(f"{key}.columns", f"expected {width} column names, got {cols!r}")
        return {"columns": [str(c) for c in cols]}
    if not isinstance(v["array"], str):
        raise bad(f"{key}.array", f"expected a variable name, got {v['array']!r}")
    return {"array": v["array"]}


def _check_time(v, bad) -> dict:
    v = _mapping("time", v, _ENTRY_KEYS["time"], bad)
    if "rate_hz" in v:
        rate = v["rate_hz"]
        if set(v) != {"rate_hz"} or not isinstance(rate, int | float) or not rate > 0:
            raise bad("time.rate_hz", f"expected a positive rate alone, got {v!r}")
        return {"rate_hz": float(rate)}
    if not isinstance(v.get("column"), str):
        raise bad("time.column", f"expected a column name, got {v.get('column')!r}")
    if v.get("unit") not in U.TIME_TO_S:
        raise bad("time.unit", f"expected one of {', '.join(U.TIME_TO_S)}, got "
                               f"{v.get('unit')!r}")
    return {"column": v["column"], "unit": v["unit"]}


def _check_sensor(key: str, v, bad) -> dict:
    v = _mapping(key, v, _ENTRY_KEYS["sensor"], bad)
    out = _source(key, v, 3, bad)
    if v.get("unit") not in UNITS[key]:
        raise bad(f"{key}.unit", f"expected one of {', '.join(UNITS[key])}, got "
                                 f"{v.get('unit')!r}")
    out["unit"] = v["unit"]
    axes = v.get("axes", list(_AXES))
    names = [str(a).strip().lower().lstrip("+") for a in axes] if isinstance(axes, list) \
        else None
    if names is None or len(names) != 3 or sorted(a.lstrip("-") for a in names) != list(_AXES):
        raise bad(f"{key}.axes", f"expected a signed permutation of x, y, z such as "
                                 f"[x, -y, -z], got {axes!r}")
    out["axes"] = names
    return out


def _check_truth(v, bad) -> dict:
    v = _mapping("truth", v, _ENTRY_KEYS["truth"], bad)
    out = _source("truth", v, 4, bad)
    order = v.get("order", "wxyz")
    if order not in _ORDERS:
        raise bad("truth.order", f"expected wxyz or xyzw, got {order!r}")
    frame = v.get("frame", "unknown")
    if frame not in _FRAMES:
        raise bad("truth.frame", f"expected {' or '.join(_FRAMES)}, got {frame!r}")
    out.update(order=order, frame=frame)
    if v.get("valid") is not None:
        if not isinstance(v["valid"], str):
            raise bad("truth.valid", f"expected a column name, got {v['valid']!r}")
        out["valid"] = v["valid"]
    return out


# --------------------------------------------------------------------------- read
def _remap(v: np.ndarray, axes: list[str]) -> np.ndarray:
    """Output axis i = the named input axis, with its sign (``[x, -y, -z]``)."""
    idx = [_AXES.index(a.lstrip("-")) for a in axes]
    sign = np.array([-1.0 if a.startswith("-") else 1.0 for a in axes])
    return np.asarray(v, float)[:, idx] * sign


def _get(table: Table, key: str, entry: dict, width: int) -> tuple[np.ndarray, str]:
    """The (N, width) values an entry names, and how the file names them."""
    if "columns" in entry:
        absent = [c for c in entry["columns"] if c not in table.columns]
        if absent:
            raise InputError(f"no column {absent[0]!r} ({key}); the file has: "
                             f"{', '.join(table.names())}", file=str(table.path),
                             field=f"{key}.columns")
        return (np.column_stack([table.columns[c] for c in entry["columns"]]),
                ",".join(entry["columns"]))
    name = entry["array"]
    if name not in table.arrays or table.arrays[name].shape[1] != width:
        raise InputError(f"no {width}xN or Nx{width} array {name!r} ({key}); the file has: "
                         f"{', '.join(table.names()) or 'nothing numeric'}",
                         file=str(table.path), field=f"{key}.array")
    return table.arrays[name], name


def read_mapped(path: str | os.PathLike, m, *, source: str | None = None,
                map_name: str | None = None):
    """Read ``path`` with map ``m`` (a dict or a YAML path; module docstring) into a
    :class:`~gnomon.recording.Recording` in SI units (gyro rad/s, accelerometer m/s²,
    magnetometer µT, truth ``[w, x, y, z]``), built by ``gnomon.io._common.build``;
    ``map_name`` says in ``meta["assumed"]`` which map (default: its file)."""
    from gnomon.io._common import build

    map_file = None if isinstance(m, dict) else str(m)
    map_name = map_name or map_file or "given as a dict"
    m = load_map(m)
    path = Path(path)
    kind = table_kind(path)
    if kind != m["kind"]:
        raise InputError(f"the map is for {m['kind']} files; this is a {kind} file",
                         file=str(path), field="kind")
    table = load_table(path, kind)
    names: dict[str, str] = {}
    assumed = [f"Read with a map ({map_name}): "
               + "; ".join(f"{k} from {_describe(m[k])}" for k in ("time",) + SENSOR_KEYS
                           + ("truth",) if k in m) + "."]
    time = m["time"]
    if "rate_hz" in time:
        n = max([len(v) for v in table.columns.values()] +
                [a.shape[0] for a in table.arrays.values()] + [0])
        t = np.arange(n) / time["rate_hz"]
        assumed.append(f"t = arange(N) / {time['rate_hz']:g} Hz (the map's rate).")
    else:
        if time["column"] not in table.columns:
            raise InputError(f"no column {time['column']!r} (time); the file has: "
                             f"{', '.join(table.names())}", file=str(path),
                             field="time.column")
        names["t"] = time["column"]
        t = _seconds(table.columns[time["column"]], time)
        if time["unit"] == "datenum":
            first = table.columns[time["column"]][np.isfinite(table.columns[time["column"]])]
            assumed.append(f"Time: MATLAB datenum days, t = 0 at {float(first[0])!r} days.")
    fields = {}
    for key in SENSOR_KEYS:
        if key not in m:
            fields[key] = None
            continue
        e = m[key]
        raw, names[key] = _get(table, key, e, 3)
        fields[key] = _remap(_in_unit(raw, key, e["unit"]), e["axes"])
        if e["axes"] != list(_AXES):
            assumed.append(f"{key} axes remapped: [{', '.join(e['axes'])}] of the file's.")
    q_true = None
    truth_frame = None
    if "truth" in m:
        e = m["truth"]
        raw, names["q_true"] = _get(table, "truth", e, 4)
        q_true = np.asarray(raw, float)[:, list(_ORDERS[e["order"]])]
        norm = np.linalg.norm(q_true, axis=1)
        with np.errstate(invalid="ignore"):
            bad = ~(np.abs(norm - 1.0) < 0.1)
        if e.get("valid"):
            if e["valid"] not in table.columns:
                raise InputError(f"no column {e['valid']!r} (truth.valid)", file=str(path),
                                 field="truth.valid")
            bad |= table.columns[e["valid"]] != 1.0
        q_true = q_true / np.where(bad, 1.0, norm)[:, None]
        q_true[bad] = np.nan
        if bad.any():
            assumed.append(f"Truth: {int(bad.sum())} of {bad.size} rows missing (invalid "
                           "flag, NaN or far from unit norm) read as NaN.")
        truth_frame = e["frame"]
        if truth_frame == "unknown":
            assumed.append("The truth's world frame, its body (a marker) and its clock are "
                           "not known to be gnomon's ENU, the sensor's axes and the gyro's "
                           "clock (frames['truth'] = 'unknown'): scores need --align.")
    mask = None
    if "mask" in m:
        col = m["mask"]["column"]
        if col not in table.columns:
            raise InputError(f"no column {col!r} (mask); the file has: "
                             f"{', '.join(table.names())}", file=str(path), field="mask.column")
        mask = table.columns[col] == 1.0
        names["mask"] = col
        assumed.append(f"Scored: the {int(mask.sum())} of {mask.size} rows where {col} is 1.")
    frames = {"reference": "ENU", "body": "sensor"}
    if truth_frame is not None:
        frames["truth"] = truth_frame
    return build(path, names, t=t, gyro=fields["gyro"], accel=fields["accel"],
                 mag=fields["mag"], mag_unit="uT", q_true=q_true, mask=mask, frames=frames,
                 source=path.stem if source is None else source,
                 meta={"format": "map", "kind": kind, "map": map_file, "assumed": assumed})


def _describe(e: dict) -> str:
    where = ("columns " + ", ".join(e["columns"]) if "columns" in e
             else f"array {e['array']}" if "array" in e
             else f"column {e['column']}" if "column" in e else f"{e['rate_hz']:g} Hz")
    extra = [e[k] for k in ("unit", "order") if k in e]
    return where + (f" ({', '.join(extra)})" if extra else "")


def live_options(m) -> dict:
    """A CSV map as ``gnomon.live.LineParser`` options (``columns`` by name and the units)
    for lines with the file's header; a map it cannot express (arrays, axis remaps,
    datenum or rate time, mg or mG) is an :class:`InputError` saying which key."""
    m = load_map(m)
    if m["kind"] != "csv":
        raise InputError("a live stream is read as CSV or JSON lines: the map must be for "
                         "csv files", field="kind")
    time = m["time"]
    if "column" not in time or time["unit"] == "datenum":
        raise InputError("live lines need a time column in s, ms, us or ns", field="time")
    cols = {"t": time["column"]}
    opts = {"time_unit": time["unit"]}
    names = {"gyro": ("gyr_x", "gyr_y", "gyr_z"), "accel": ("acc_x", "acc_y", "acc_z"),
             "mag": ("mag_x", "mag_y", "mag_z")}
    live_units = {"gyro": ("gyro_unit", ("rad/s", "deg/s")),
                  "accel": ("accel_unit", ("m/s^2", "g")),
                  "mag": ("mag_unit", ("uT", "nT", "mT", "T", "gauss"))}
    for key in SENSOR_KEYS:
        if key not in m:
            continue
        e = m[key]
        if "columns" not in e:
            raise InputError("live lines have columns, not arrays", field=f"{key}.array")
        if e["axes"] != list(_AXES):
            raise InputError("axis remaps are not applied to live lines", field=f"{key}.axes")
        option, allowed = live_units[key]
        if e["unit"] not in allowed:
            raise InputError(f"live lines take {', '.join(allowed)}", field=f"{key}.unit")
        opts[option] = e["unit"]
        cols.update(zip(names[key], e["columns"], strict=True))
    return {"columns": cols, **opts}
