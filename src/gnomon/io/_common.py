"""What every log reader shares: frame constants, per-sensor series checks, the device's own
estimate resampled by slerp, optional imports with a one-line hint, and one error type.

Frames (``docs/conventions.md``): gnomon's IMU recordings are ``reference = ENU`` with the
accelerometer reading specific force (``+g`` up at rest). Flight controllers log body FRD
(x forward, y right, z down) and NED; a reader converts at the edge:

* vectors FRD → FLU: ``[x, -y, -z]`` (a 180° turn about x, ``q_FRD_FLU = [0, 1, 0, 0]``);
* attitude ``q_ENU_FLU = q_ENU_NED ⊗ q_NED_FRD ⊗ q_FRD_FLU`` with
  ``q_ENU_NED = [0, √½, √½, 0]`` (x↔y swapped, z flipped);
* NWU (x north, y west, z up, e.g. iOS's ``xTrueNorthZVertical``): ``q_ENU_NWU = [√½, 0, 0, √½]``.

No sensor value is ever repeated or interpolated: :func:`series` keeps each sensor's own
samples and time stamps; the only resampled series is the device's own attitude estimate
(:func:`onboard_on`), a comparison series a filter never sees, slerped onto the gyro time
stamps and NaN outside its span and across its gaps.

**Imperfect logs are kept.** A sample with a non-finite value (NaN, inf: a driver's
placeholder before the sensor is up, a lost message) is dropped from its own sensor only,
by :func:`build` through :func:`drop_nonfinite`: a gyro sample takes its row of the time
base with it (and that row of the truth, the own estimate, the mask, the sun sensors and
the ``extra`` series); an accelerometer or magnetometer sample is dropped from that sensor
alone, which then keeps its own time stamps (the multi-rate form of
:class:`~gnomon.recording.Recording`). The counts go to ``meta["dropped"]`` (``{"gyro": n,
"accel": n, "mag": n}``, sensors with drops only) and a sentence to ``meta["assumed"]``; a
sensor left with no sample (the gyro: fewer than 2) is an :class:`InputError` naming it.
Non-finite *time stamps* are still refused (a clock that fails is not a lost sample), and
NaN rows of ``q_true``/``q_onboard`` still mean missing truth or estimate. Reading
strictly (``gnomon.io.read(path, strict=True)``, ``--strict``, which :func:`series` and
:func:`build` see through :func:`strict_reading`) refuses a non-finite sample instead,
naming the field and the row, as before.

**No fake own estimate.** A device attitude (``q_onboard``) that is constant over the whole
log (a driver filling ``orientation`` with the identity), or that has no finite row, is no
estimate: :func:`build` sets ``q_onboard = None`` and says why in ``meta["onboard_absent"]``
(:func:`own_estimate_absent`); a reader that knows the estimate is marked absent (ROS
``orientation_covariance[0] = -1``) says so there itself.
"""

from __future__ import annotations

import contextlib
import contextvars
import importlib
import io
import math
import os
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import SENSORS, Recording
from gnomon.rotation import quat_mul

__all__ = ["Q_ENU_NED", "Q_FRD_FLU", "Q_ENU_NWU", "frd_to_flu", "ned_frd_to_enu_flu",
           "optional_import", "series", "onboard_on", "gaps", "build", "quiet", "quiet_fd2",
           "GAP_FACTOR", "LOGS_EXTRA", "cut_short", "drop_nonfinite", "own_estimate_absent",
           "strict_reading", "reading_strictly", "CONSTANT_ONBOARD_RAD"]

_S = math.sqrt(0.5)
#: ENU from NED: x↔y swapped, z flipped
Q_ENU_NED = np.array([0.0, _S, _S, 0.0])
#: FRD from FLU: 180° about x
Q_FRD_FLU = np.array([0.0, 1.0, 0.0, 0.0])
#: ENU from NWU: +90° about up
Q_ENU_NWU = np.array([_S, 0.0, 0.0, _S])
#: an interval longer than this many median intervals is a gap (inspect, onboard slerp)
GAP_FACTOR = 5.0
#: the optional extra that installs the log libraries
LOGS_EXTRA = "gnomon[logs]"
#: an own estimate whose every row is within this angle (rad) of its first is constant
CONSTANT_ONBOARD_RAD = 1e-6

_STRICT = contextvars.ContextVar("gnomon_strict_reading", default=False)


@contextlib.contextmanager
def strict_reading(strict: bool = True):
    """While inside, :func:`series` and :func:`build` refuse a non-finite sample instead of
    dropping it (``gnomon.io.read(path, strict=True)`` reads inside this)."""
    token = _STRICT.set(bool(strict))
    try:
        yield
    finally:
        _STRICT.reset(token)


def reading_strictly() -> bool:
    """Whether the current read refuses non-finite samples (:func:`strict_reading`)."""
    return _STRICT.get()


def frd_to_flu(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) from body FRD (forward, right, down) to FLU: ``[x, -y, -z]``."""
    return np.asarray(v, dtype=float) * np.array([1.0, -1.0, -1.0])


def ned_frd_to_enu_flu(q_ned_frd: np.ndarray) -> np.ndarray:
    """``q_NED_FRD`` (..., 4) to ``q_ENU_FLU = q_ENU_NED ⊗ q_NED_FRD ⊗ q_FRD_FLU``."""
    return quat_mul(quat_mul(Q_ENU_NED, np.asarray(q_ned_frd, dtype=float)), Q_FRD_FLU)


def optional_import(module: str, package: str, path, what: str):
    """Import ``module`` or raise one line naming the ``pip install`` that is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(f"reading {what} needs the package {package!r}, which is not "
                         f"installed: pip install '{package}' (or pip install "
                         f"'{LOGS_EXTRA}')", file=str(path)) from None


@contextlib.contextmanager
def quiet_fd2():
    """Send what C extensions write to file descriptor 2 to nowhere (pymavlink's fast
    indexer reports bad headers there); Python-level output is captured by :func:`quiet`."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@contextlib.contextmanager
def quiet():
    """Capture what a format library prints (pyulog and pymavlink print warnings); the text
    is available as the context value's ``getvalue()`` afterwards."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        yield buf


def series(path, field: str, t, values, *, width: int = 3, assumed: list | None = None,
           strict: bool | None = None):
    """One sensor's samples, checked: finite time stamps (s), time increasing; values that
    are not finite are kept (NaN rows) for :func:`build` to drop and count, or with
    ``strict`` (default: :func:`reading_strictly`) an :class:`InputError` naming ``field``
    and the row.

    Consecutive rows with the same time stamp *and* the same values are one sample logged
    twice (kept once; said in ``assumed``); the same time stamp with other values, or a time
    stamp going backward, is an :class:`InputError` naming ``field`` and the row (0-based
    message index). Returns ``(t, values)`` as float arrays.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v.reshape(-1, 1) if width == 1 else v
    if v.ndim != 2 or v.shape[1] != width or v.shape[0] != t.size:
        raise InputError(f"expected {t.size} rows of {width} values, got shape {v.shape}",
                         file=str(path), field=field)
    with np.errstate(over="ignore", invalid="ignore"):  # finite sums: all finite (cheap)
        unchecked = not (np.isfinite(np.sum(t)) and np.isfinite(np.sum(v)))
    if unchecked:
        bad_t = ~np.isfinite(t)
        if bad_t.any():
            i = int(np.argmax(bad_t))
            raise InputError(f"non-finite time stamp {float(t[i])!r}", file=str(path),
                             field=field, row=i)
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any() and (reading_strictly() if strict is None else strict):
            i = int(np.argmax(bad))
            raise InputError(f"non-finite value {v[i].tolist()}", file=str(path), field=field,
                             row=i)
    if t.size > 1:
        dt = np.diff(t)
        same = dt == 0
        if same.any():
            a, b = v[1:], v[:-1]
            equal = same & np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
            if np.any(same & ~equal):
                i = int(np.argmax(same & ~equal)) + 1
                raise InputError(f"time stamp {float(t[i])!r} repeats with another value",
                                 file=str(path), field=field, row=i)
            keep = np.concatenate([[True], ~equal])
            if assumed is not None:
                assumed.append(f"{field}: {int((~keep).sum())} rows repeating the time stamp "
                               "and the values of the row before were taken as one sample.")
            t, v, dt = t[keep], v[keep], np.diff(t[keep])
        if np.any(dt < 0):
            i = int(np.argmax(dt < 0)) + 1
            raise InputError(f"time stamp goes backward: {float(t[i])!r} after "
                             f"{float(t[i - 1])!r}", file=str(path), field=field, row=i)
    return t, v


def gaps(t: np.ndarray, factor: float = GAP_FACTOR) -> dict:
    """Intervals of ``t`` longer than ``factor`` median intervals: count and longest (s)."""
    t = np.asarray(t, dtype=float)
    if t.size < 3:
        return {"count": 0, "longest_s": 0.0}
    dt = np.diff(t)
    big = dt > factor * np.median(dt)
    return {"count": int(big.sum()), "longest_s": float(dt.max()) if big.any() else 0.0}


def onboard_on(path, field: str, t_src, q_src, t_dst, *, max_gap_s: float | None = None
               ) -> np.ndarray:
    """The device's own attitude ``q_src`` (M, 4) at ``t_src`` resampled onto ``t_dst`` by
    slerp: NaN rows outside ``[t_src[0], t_src[-1]]`` and inside intervals longer than
    ``max_gap_s`` (default ``GAP_FACTOR`` median intervals). Rows of ``q_src`` that are not
    finite or far from unit norm are dropped first (they open a gap). A comparison series,
    never a measurement."""
    t_src = np.asarray(t_src, dtype=float).reshape(-1)
    q = np.asarray(q_src, dtype=float)
    t_dst = np.asarray(t_dst, dtype=float).reshape(-1)
    if q.ndim != 2 or q.shape[1] != 4 or q.shape[0] != t_src.size:
        raise InputError(f"expected ({t_src.size}, 4) quaternions, got {q.shape}",
                         file=str(path), field=field)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(t_src) & np.isfinite(q).all(axis=1) & (np.abs(norm - 1.0) < 0.1)
    t_src, q = t_src[ok], q[ok] / norm[ok, None]
    if t_src.size < 2:
        return np.full((t_dst.size, 4), np.nan)
    if np.any(np.diff(t_src) < 0):
        i = int(np.argmax(np.diff(t_src) < 0)) + 1
        raise InputError(f"time stamp goes backward: {float(t_src[i])!r} after "
                         f"{float(t_src[i - 1])!r}",
                         file=str(path), field=field, row=i)
    dt = np.diff(t_src)
    if max_gap_s is None:
        max_gap_s = GAP_FACTOR * float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
    last = t_src.size - 2  # the last interval
    arc = _arc(q[:-1], q[1:])  # once per source interval, gathered per destination row
    out = np.empty((t_dst.size, 4))
    for lo in range(0, t_dst.size, _CHUNK):  # bounded temporaries on long logs
        td = t_dst[lo:lo + _CHUNK]
        i = np.searchsorted(t_src, td, side="right") - 1
        i[td == t_src[-1]] = last
        inside = (i >= 0) & (i <= last)
        np.clip(i, 0, last, out=i)
        span = dt[i]
        use = inside & (span > 0) & (span <= max_gap_s)
        whole = bool(use.all())
        r = slice(None) if whole else np.flatnonzero(use)
        i0 = i[r]
        f = np.clip((td[r] - t_src[i0]) / span[r], 0.0, 1.0)
        o = out[lo:lo + _CHUNK]
        blend = _blend(np.take(q, i0, axis=0), np.take(q, i0 + 1, axis=0), f,
                       [a[i0] for a in arc], out=o if whole else None)
        if not whole:
            o[r] = blend
            o[~use] = np.nan
            exact = inside & (span == 0)
            o[exact] = q[i[exact]]
    return out


_CHUNK = 16_384  # rows per slerp block (its temporaries stay in the cache)


def _arc(q0: np.ndarray, q1: np.ndarray) -> tuple:
    """The slerp's angle from unit quaternions q0 to q1 (K, 4) along the short arc: ``(θ,
    sin θ or 1 below 1e-6 rad, θ < 1e-6 rad, ±1)``."""
    d = np.einsum("ij,ij->i", q0, q1)
    sign = np.where(d < 0, -1.0, 1.0)  # the short arc
    theta = np.arccos(np.minimum(np.abs(d), 1.0))
    small = theta < 1e-6
    return theta, np.sin(np.where(small, 1.0, theta)), small, sign


def _blend(q0: np.ndarray, q1: np.ndarray, f: np.ndarray, arc, out=None) -> np.ndarray:
    """``(sin((1-f)θ) q0 + sin(fθ) q1) / sin θ`` with ``arc = _arc(q0, q1)``; a plain blend
    (then normalised) below 1e-6 rad, where the two agree to double precision. Into
    ``out`` (K, 4) when given."""
    theta, s, small, sign = arc
    a = np.where(small, 1.0 - f, np.sin((1.0 - f) * theta) / s)
    b = np.where(small, f, np.sin(f * theta) / s) * sign
    out = np.multiply(a[:, None], q0, out=out)
    out += b[:, None] * q1
    out /= np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
    return out


def _slerp(q0: np.ndarray, q1: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Slerp of unit quaternions (K, 4) along the short arc, ``f`` in [0, 1] (K,): the
    closed form ``(sin((1-f)θ) q0 + sin(fθ) q1) / sin θ``; a plain blend (then normalised)
    below 1e-6 rad, where the two agree to double precision. Equal to
    :func:`gnomon.rotation.quat_slerp` (tested) without its per-call validation."""
    return _blend(q0, q1, f, _arc(q0, q1))


def build(path, names: dict, *, strict: bool | None = None, **fields) -> Recording:
    """``Recording(**fields)`` of a log at ``path``, its InputError re-raised naming ``path``
    and the field as the log calls it (``names``: Recording field -> log field).

    First (module docstring) the non-finite samples are dropped from their own sensor
    (:func:`drop_nonfinite`; counts in ``meta["dropped"]``, a sentence in
    ``meta["assumed"]``) unless ``strict`` (default: :func:`reading_strictly`), when the
    Recording refuses them; and an own estimate that is none (:func:`own_estimate_absent`)
    is set to None with the reason in ``meta["onboard_absent"]``."""
    meta = dict(fields.get("meta") or {})
    try:
        if not (reading_strictly() if strict is None else strict):
            fields, dropped, first = drop_nonfinite(fields)
            if dropped:
                total = dict(meta.get("dropped") or {})
                for k, n in dropped.items():
                    total[k] = total.get(k, 0) + n
                meta["dropped"] = total
                meta["assumed"] = list(meta.get("assumed", [])) + [
                    _dropped_sentence(dropped, first, names)]
        why = own_estimate_absent(fields.get("q_onboard"),
                                  names.get("q_onboard") or meta.get("onboard") or
                                  "the device's own estimate (q_onboard)")
        if why is not None:
            fields = {**fields, "q_onboard": None}
            meta.update(onboard_absent=why, onboard=None, onboard_heading_reference=None)
            if "onboard_gravity_deg" in meta:
                meta["onboard_gravity_deg"] = None
        return Recording(**{**fields, "meta": meta})
    except InputError as err:
        raise InputError(err.message, file=str(path), field=names.get(err.field, err.field),
                         row=err.row) from None


#: per-row series of the time base that a dropped gyro sample takes with it
_PER_ROW = ("q_true", "q_onboard", "mask", "sun", "sun_valid")


def drop_nonfinite(fields: dict) -> tuple[dict, dict, dict]:
    """The samples of ``fields`` (``Recording`` keyword arguments) whose values are not all
    finite dropped, each from its own sensor (module docstring): ``(the new fields, {sensor:
    count dropped}, {sensor: time stamp (s) of its first dropped sample})``, sensors with
    drops only. A gyro sample takes its time-base row (``t``, the rows of ``q_true``,
    ``q_onboard``, ``mask``, ``sun``, ``sun_valid`` and each ``extra`` series) with it; a
    single-rate accelerometer or magnetometer then keeps all its samples at their own
    time stamps (the old rows of ``t``). An accelerometer or magnetometer sample is dropped
    alone (its own ``accel_t``/``mag_t`` are the kept time stamps). Fields of the wrong
    shape are left as they are for ``Recording`` to refuse. A sensor with every sample
    dropped (the gyro: fewer than 2 left) raises :class:`InputError` naming it."""
    out = dict(fields)
    try:
        t = np.asarray(fields.get("t"), dtype=float)
        gyro = np.asarray(fields.get("gyro"), dtype=float)
    except (TypeError, ValueError):
        return out, {}, {}
    if t.ndim != 1 or gyro.shape != (t.size, 3):
        return out, {}, {}
    counts, first = {}, {}
    bad = ~np.isfinite(gyro).all(axis=1)
    if bad.any():
        counts["gyro"], first["gyro"] = int(bad.sum()), float(t[bad][0])
        if t.size - counts["gyro"] < 2:
            raise InputError(f"{counts['gyro']} of {t.size} samples are not finite: fewer "
                             "than 2 left", field="gyro")
        keep = ~bad

        def rows(v):
            return np.asarray(v)[keep] if v is not None and np.shape(v)[:1] == (t.size,) \
                else v

        out.update(t=t[keep], gyro=gyro[keep], **{k: rows(fields.get(k)) for k in _PER_ROW})
        if fields.get("extra"):
            out["extra"] = {k: rows(v) for k, v in dict(fields["extra"]).items()}
    for name in SENSORS:
        if fields.get(name) is None:
            continue
        own = fields.get(f"{name}_t")
        try:
            v = np.asarray(fields[name], dtype=float)
            times = t if own is None else np.asarray(own, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            continue
        if v.ndim != 2 or v.shape[0] != times.size:
            continue
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():
            counts[name], first[name] = int(bad.sum()), float(times[bad][0])
            if bad.all():
                raise InputError(f"all {v.shape[0]} samples are not finite", field=name)
        if bad.any() or (own is None and "gyro" in counts):
            out[name], out[f"{name}_t"] = v[~bad], times[~bad]
    return out, counts, first


def _dropped_sentence(dropped: dict, first: dict, names: dict) -> str:
    parts = []
    for k in ("gyro", "accel", "mag"):
        if k in dropped:
            log = f" ({names[k]})" if names.get(k) not in (None, "", k) else ""
            parts.append(f"{k}{log} {dropped[k]} (the first at t = {first[k]:.6g} s)")
    tail = "; a gyro sample takes its row of the truth and the own estimate with it" \
        if "gyro" in dropped else ""
    return ("Samples with a non-finite value were dropped, each from its own sensor only: "
            f"{', '.join(parts)}{tail} (--strict refuses them).")


def own_estimate_absent(q_onboard, what: str) -> str | None:
    """Why the device's own attitude ``q_onboard`` (N, 4) is no estimate, or None when it is
    one (or there is none): no finite row, or every finite row within
    ``CONSTANT_ONBOARD_RAD`` of the first (a constant, e.g. a driver's identity
    placeholder). ``what`` names it in the sentence."""
    if q_onboard is None:
        return None
    try:
        q = np.asarray(q_onboard, dtype=float)
    except (TypeError, ValueError):
        return None
    if q.ndim != 2 or q.shape[1] != 4 or q.shape[0] == 0:
        return None
    q = q[np.isfinite(q).all(axis=1)]
    if q.shape[0] == 0:
        return f"{what}: no finite sample, so no estimate of the device's own"
    if q.shape[0] < 2:
        return None
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm == 0):
        return None  # not unit quaternions: the Recording refuses them
    u = q / norm[:, None]
    angle = 2.0 * np.arccos(np.minimum(np.abs(u @ u[0]), 1.0))
    if angle.max() > CONSTANT_ONBOARD_RAD:
        return None
    identity = abs(abs(u[0, 0]) - 1.0) < 1e-9
    q0 = u[0] if u[0, 0] >= 0 else -u[0]
    value = "the identity" if identity else f"[w, x, y, z] = {(np.round(q0, 6) + 0.0).tolist()}"
    return (f"{what}: constant ({value}) over all {q.shape[0]} samples: a placeholder, not "
            "an estimate")


def cut_short(start: int, size: int, present: int, t: np.ndarray, assumed: list) -> dict:
    """A log whose last message is cut off by the end of the file (a flight log cut at
    power-off): the sentence for ``assumed`` and ``meta["truncated"]``, ``{"at_byte":
    where the message starts, "message_bytes": its declared size, "bytes_present",
    "data_up_to_s": the last gyro time stamp (s)}`` (``gnomon inspect`` prints it)."""
    t_end = float(t[-1])
    assumed.append(f"The file ends inside a message at byte {start} ({present} of its {size} "
                   f"bytes present): the log is cut short; data up to t = {t_end:.3f} s "
                   f"({t_end - float(t[0]):.3f} s after the first gyro sample).")
    return {"at_byte": int(start), "message_bytes": int(size), "bytes_present": int(present),
            "data_up_to_s": t_end}


def as_path(path) -> Path:
    p = Path(path)
    if not p.exists():
        raise InputError("no such file", file=str(p))
    return p
