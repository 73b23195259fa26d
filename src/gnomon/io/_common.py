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
"""

from __future__ import annotations

import contextlib
import importlib
import io
import math
import os
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import Recording
from gnomon.rotation import quat_mul

__all__ = ["Q_ENU_NED", "Q_FRD_FLU", "Q_ENU_NWU", "frd_to_flu", "ned_frd_to_enu_flu",
           "optional_import", "series", "onboard_on", "gaps", "build", "quiet", "quiet_fd2",
           "GAP_FACTOR", "LOGS_EXTRA", "cut_short"]

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


def series(path, field: str, t, values, *, width: int = 3, assumed: list | None = None):
    """One sensor's samples, checked: finite time stamps (s) and values, time increasing.

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
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"non-finite value {v[i].tolist()}", file=str(path), field=field,
                             row=i)
    if t.size > 1:
        dt = np.diff(t)
        same = dt == 0
        if same.any():
            equal = same & np.all(v[1:] == v[:-1], axis=1)
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


def build(path, names: dict, **fields) -> Recording:
    """``Recording(**fields)``; its InputError re-raised naming ``path`` and the field as the
    log calls it (``names``: Recording field -> log field)."""
    try:
        return Recording(**fields)
    except InputError as err:
        raise InputError(err.message, file=str(path), field=names.get(err.field, err.field),
                         row=err.row) from None


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
