"""Error metrics between an estimated and a true attitude (same frames: ``q_rb``, r from body).

* ``error_angle_rad``: total attitude error ``2·atan2(|δq_xyz|, |δq_w|)``,
  ``δq = conj(q_true) ⊗ q_est``.
* ``axis_errors_rad``: Euler angles ``[roll, pitch, yaw]`` (z-y'-x'') of ``δq``,
  the small-angle per-axis errors of the papers' plots (error expressed in the body frame).
* ``broad_errors_rad``: the BROAD benchmark's total / heading / inclination errors,
  exactly as it defines them (Laidig et al., Data 6(7):72, 2021): ``q_err = q_est ⊗ conj(q_true)``
  (error in the reference frame, whose z axis is vertical), total ``2·acos(|w|)``,
  heading ``2·atan(|z/w|)``, inclination ``2·acos(sqrt(w² + z²))``.
* ``rms``: root mean square over a boolean mask, NaN-free.

All inputs have shape ``(N, 4)`` (or ``(..., 4)``); outputs are radians. A row
with a NaN in either input (e.g. truth lost by the motion capture) gives NaN
there; ``rms`` then needs a mask that excludes it.

Scores of a whole estimate (degrees), built on the above; each is the one place its
numbers are computed:

* ``score``: a summary over a mask (``gnomon estimate``): BROAD split, per-axis, max.
* ``score_run``: the metrics row of a Monte Carlo run (``gnomon campaign``): RMS, max
  and mean after a convergence window, sunlit/eclipse and BROAD's split when they apply.
* ``score_run_budget``: the per-body-axis RMS and 99th percentiles of a Monte Carlo run
  (sunlit / eclipse too), from which a campaign's attitude-knowledge budget is built.
* ``score_broad``: the BROAD benchmark's per-trial RMSE (``gnomon benchmark broad``).
* ``compare``: BROAD's metric between two estimates (gnomon's and the device's own,
  ``gnomon estimate --compare onboard``), with their constant heading offset removed.

The alignment of a measured reference to the sensor (``quat_at``, ``body_rate``,
``estimate_lag``, ``estimate_body_misalignment``, ``align_truth``) lives in
:mod:`gnomon.alignment`; the names stay importable from here.

``score_run`` takes the RMS of the error in degrees, ``score``/``score_broad`` convert
the RMS in radians to degrees (``rms_deg``); the two differ in the last digit only, and
each keeps the numbers it has always published.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from gnomon.alignment import (
    ALIGN_OPTIONS,
    align_truth,
    body_rate,
    estimate_body_misalignment,
    estimate_lag,
    quat_at,
)
from gnomon.errors import InputError
from gnomon.rotation import error_angle, euler_from_quat, quat_conj, quat_mul

if TYPE_CHECKING:
    from gnomon.recording import Recording

__all__ = ["error_angle_rad", "axis_errors_rad", "broad_errors_rad", "rms", "rms_deg", "score",
           "score_run", "score_broad", "heading_offset_rad", "compare", "compare_onboard",
           "quat_at", "body_rate", "estimate_lag", "estimate_body_misalignment", "align_truth",
           "ALIGN_OPTIONS"]

_BROAD_KEYS = ("total", "heading", "inclination")


def _pair(q_true, q_est):
    """Shape-checked copies with NaN rows replaced by identity, and the NaN-row mask."""
    qt = np.asarray(q_true, dtype=float)
    qe = np.asarray(q_est, dtype=float)
    for name, q in (("q_true", qt), ("q_est", qe)):
        if q.shape[-1:] != (4,):
            raise ValueError(f"{name}: expected shape (..., 4), got {q.shape}")
    qt, qe = np.broadcast_arrays(qt, qe)
    bad = ~(np.all(np.isfinite(qt), axis=-1) & np.all(np.isfinite(qe), axis=-1))
    one = np.array([1.0, 0.0, 0.0, 0.0])
    return np.where(bad[..., None], one, qt), np.where(bad[..., None], one, qe), bad


def _with_nan(x, bad):
    return np.where(bad[..., None] if x.ndim > bad.ndim else bad, np.nan, x)


def error_angle_rad(q_true, q_est) -> np.ndarray:
    """Total attitude error angle (rad, in [0, π]), sign-safe."""
    qt, qe, bad = _pair(q_true, q_est)
    return _with_nan(error_angle(qt, qe), bad)


def axis_errors_rad(q_true, q_est) -> np.ndarray:
    """Per-axis errors ``[roll, pitch, yaw]`` (rad): Euler angles of ``conj(q_true) ⊗ q_est``."""
    qt, qe, bad = _pair(q_true, q_est)
    return _with_nan(euler_from_quat(quat_mul(quat_conj(qt), qe)), bad)


def broad_errors_rad(q_true, q_est) -> dict[str, np.ndarray]:
    """BROAD's ``total``, ``heading`` and ``inclination`` errors (rad), shape (...,) each.

    The reference frame's z axis must be vertical (ENU or NWU, as in BROAD).
    """
    qt, qe, bad = _pair(q_true, q_est)
    e = quat_mul(qe, quat_conj(qt))
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    w, z = e[..., 0], e[..., 3]
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore"):
        heading = 2.0 * np.arctan(np.abs(z / w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return {"total": _with_nan(total, bad), "heading": _with_nan(heading, bad),
            "inclination": _with_nan(inclination, bad)}


def rms(x, mask=None) -> float:
    """Root mean square of ``x`` (N,) or (N, k) over the rows where ``mask`` is true.

    Rows with a NaN are an error unless masked out. An empty selection gives NaN.
    """
    x = np.asarray(x, dtype=float)
    if mask is not None:
        x = x[np.asarray(mask, dtype=bool)]
    if x.size == 0:
        return float("nan")
    if not np.all(np.isfinite(x)):
        raise ValueError("rms: non-finite values inside the mask")
    return float(np.sqrt(np.mean(x * x)))


def rms_deg(x_rad, mask=None) -> float:
    """``rms`` converted to degrees."""
    return float(np.degrees(rms(x_rad, mask)))


def score(q_true, q_est, mask=None) -> dict:
    """Summary of an estimate against the truth, in degrees, over ``mask`` and valid truth rows.

    Keys: ``total_deg``, ``heading_deg``, ``inclination_deg`` (BROAD definitions;
    meaningful when the reference frame's z axis is vertical), ``roll_deg``,
    ``pitch_deg``, ``yaw_deg`` (RMS of the per-axis errors), ``max_deg`` (largest
    total error) and ``samples`` (how many rows were scored).
    """
    q_true = np.asarray(q_true, dtype=float)
    valid = np.all(np.isfinite(q_true), axis=-1)
    m = valid if mask is None else valid & np.asarray(mask, dtype=bool)
    broad = broad_errors_rad(q_true[m], np.asarray(q_est, dtype=float)[m])
    axes = axis_errors_rad(q_true[m], np.asarray(q_est, dtype=float)[m])
    out = {f"{k}_deg": rms_deg(v) for k, v in broad.items()}
    out.update({f"{k}_deg": rms_deg(axes[:, i]) for i, k in enumerate(("roll", "pitch", "yaw"))})
    out["max_deg"] = float(np.degrees(broad["total"].max())) if broad["total"].size else np.nan
    out["samples"] = int(m.sum())
    return out


def score_run(rec: Recording, q_est, settle_s: float = 0.0) -> dict[str, float]:
    """The metrics of one campaign run: errors (deg) of ``q_est`` against ``rec.q_true``.

    ``rec``: a recording with ``t`` (N,) s and ``q_true`` (N, 4); ``q_est``: (N, 4), same
    frames. Samples count from ``settle_s`` (s) after ``rec.t[0]`` and where the error is
    finite. Keys (degrees; NaN when no sample qualifies):

    * ``rms_deg``, ``max_deg``, ``mean_deg``: of the total error angle;
    * with a vertical reference axis (``rec.frames["reference"]`` ENU or NWU) BROAD's split
      ``heading_rms_deg``, ``inclination_rms_deg`` (a tilt-only filter is judged by the
      latter; NaN if the split is undefined at a sample, an error of exactly 180°);
    * with a sun sensor (``rec.sun_valid`` (N,) bool): ``sunlit_rms_deg``,
      ``eclipse_rms_deg``, ``eclipse_max_deg``.

    The RMS is taken of the error in degrees (the published campaign columns).
    """
    err = np.degrees(error_angle_rad(rec.q_true, q_est))
    m = ((rec.t - rec.t[0]) >= settle_s) & np.isfinite(err)
    out = {"rms_deg": rms(err, m), "max_deg": _max(err[m]), "mean_deg": _mean(err[m])}
    if rec.frames.get("reference") in ("ENU", "NWU"):
        parts = broad_errors_rad(rec.q_true, q_est)
        out.update(heading_rms_deg=_rms_or_nan(np.degrees(parts["heading"]), m),
                   inclination_rms_deg=_rms_or_nan(np.degrees(parts["inclination"]), m))
    if rec.sun_valid is not None:
        sun = m & rec.sun_valid
        ecl = m & ~rec.sun_valid
        out.update(sunlit_rms_deg=rms(err, sun), eclipse_rms_deg=rms(err, ecl),
                   eclipse_max_deg=_max(err[ecl]))
    return out


#: the body axes of :func:`body_axis_errors_rad`, in column order
BODY_AXES = ("x", "y", "z")


def _error_rotvec(qt, qe) -> np.ndarray:
    """Rotation vector (rad) of ``conj(qt) ⊗ qe`` for finite (k, 4) inputs: angle
    ``2·atan2(|v|, |w|)`` along ``v`` (the short arc; scale-free, small-angle safe)."""
    d = quat_mul(quat_conj(qt), qe)
    w = d[:, 0]
    v = d[:, 1:] * np.where(w < 0.0, -1.0, 1.0)[:, None]
    w = np.abs(w)
    s = np.sqrt(np.einsum("ij,ij->i", v, v))
    small = s < 1e-9
    k = np.where(small, 2.0 / np.where(w > 0.0, w, 1.0),
                 2.0 * np.arctan2(s, w) / np.where(small, 1.0, s))
    return k[:, None] * v


def body_axis_errors_rad(q_true, q_est) -> np.ndarray:
    """Per-axis errors in the body axes (rad), shape (N, 3) for inputs (N, 4): the
    rotation vector of ``δq = conj(q_true) ⊗ q_est`` (components on the true body's x, y,
    z axes; exact at any angle, equal to the small-angle ``2·δq_xyz``; its norm is
    :func:`error_angle_rad`). NaN rows where an input has a NaN."""
    qt, qe, bad = _pair(np.atleast_2d(q_true), np.atleast_2d(q_est))
    out = np.full((qt.shape[0], 3), np.nan)
    out[~bad] = _error_rotvec(qt[~bad], qe[~bad])
    return out


def score_run_budget(rec: Recording, q_est, settle_s: float = 0.0) -> dict[str, float]:
    """The per-axis metrics of one campaign run, for an attitude-knowledge budget (degrees).

    Same samples as :func:`score_run` (from ``settle_s`` s after ``rec.t[0]``, finite
    error). Per-axis errors are :func:`body_axis_errors_rad`. Keys, for each body axis
    ``A`` in x, y, z: ``A_rms_deg`` (RMS of the axis error) and ``A_p99_deg`` (99th
    percentile of its absolute value, linear interpolation); ``p99_deg`` (99th percentile
    of the total error angle). With a sun sensor (``rec.sun_valid``) the same again over
    the sunlit and the eclipse samples, prefixed ``sunlit_`` / ``eclipse_`` (NaN when
    there is no such sample).
    """
    qt = np.asarray(rec.q_true, dtype=float)
    qe = np.asarray(q_est, dtype=float)
    if qe.shape != qt.shape:
        raise ValueError(f"q_est: expected shape {qt.shape}, got {qe.shape}")
    m = (((rec.t - rec.t[0]) >= settle_s) & np.isfinite(qt).all(axis=1)
         & np.isfinite(qe).all(axis=1))
    e = np.degrees(_error_rotvec(qt[m], qe[m]))
    # rows (contiguous, for the partitions): |e_x|, |e_y|, |e_z|, the total angle (the
    # rotation vector's norm)
    err = np.empty((4, e.shape[0]))
    np.abs(e.T, out=err[:3])
    err[3] = np.sqrt(np.einsum("ij,ij->i", e, e))
    phases = {"": None}
    if rec.sun_valid is not None:
        lit = np.asarray(rec.sun_valid, dtype=bool)[m]
        phases.update(sunlit_=lit, eclipse_=~lit)
    out = {}
    for prefix, sel in phases.items():
        x = err if sel is None else err[:, sel]
        if x.shape[1]:
            ms = np.sqrt(np.einsum("ij,ij->i", x[:3], x[:3]) / x.shape[1])
            p99 = np.quantile(x, 0.99, axis=1)
        else:
            ms = p99 = np.full(4, np.nan)
        for i, a in enumerate(BODY_AXES):
            out[f"{prefix}{a}_rms_deg"] = float(ms[i])
            out[f"{prefix}{a}_p99_deg"] = float(p99[i])
        out[f"{prefix}p99_deg"] = float(p99[3])
    return out


def score_broad(rec: Recording, q_est) -> dict[str, float]:
    """BROAD's RMSE (deg) of ``q_est`` (N, 4) on ``rec`` over ``rec.score_mask``.

    Keys ``total_deg``, ``heading_deg``, ``inclination_deg`` (``broad_errors_rad``; the
    reference frame's z axis vertical). Raises ``InputError`` if no sample is scored.
    """
    m = rec.score_mask
    if not m.any():
        raise InputError("no sample with movement and a valid truth to score",
                         file=rec.source or None, field="movement")
    e = broad_errors_rad(rec.q_true[m], np.asarray(q_est)[m])
    return {f"{k}_deg": rms_deg(e[k]) for k in _BROAD_KEYS}


def _rms_or_nan(x, mask) -> float:
    """``rms(x, mask)``, NaN instead of an error when a selected value is not finite."""
    sel = x[mask]
    return rms(sel) if np.all(np.isfinite(sel)) else float("nan")


def _max(x) -> float:
    return float(np.max(x)) if x.size else float("nan")


def _mean(x) -> float:
    return float(np.mean(x)) if x.size else float("nan")


def heading_offset_rad(q_ref, q_est, mask=None) -> float:
    """The constant rotation ``ψ`` (rad) about the reference frame's vertical that best
    turns ``q_ref`` onto ``q_est``: the circular mean over ``mask`` (and finite rows) of
    the heading part ``2·atan2(z, w)`` of ``q_est ⊗ conj(q_ref)``. Two estimates that
    refer heading to different norths (magnetic vs true, a declination) differ by it."""
    qr, qe, bad = _pair(q_ref, q_est)
    m = ~bad if mask is None else ~bad & np.asarray(mask, dtype=bool)
    if not m.any():
        return float("nan")
    e = quat_mul(qe[m], quat_conj(qr[m]))
    psi = 2.0 * np.arctan2(e[:, 3] * np.sign(e[:, 0] + (e[:, 0] == 0)), np.abs(e[:, 0]))
    return float(np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi))))


def compare(q_ref, q_est, mask=None, match_heading: bool = True) -> dict:
    """BROAD's RMS metric (deg) between two estimates, e.g. gnomon's and a device's own
    (``Recording.q_onboard``), over the rows where both exist (and ``mask``).

    With ``match_heading`` the constant heading offset between them (``heading_offset_rad``)
    is removed from ``q_ref`` first and reported (``heading_offset_deg``): an autopilot
    that refers heading to true north and a filter that refers it to magnetic north
    then compare by their attitude, not by the local declination. Keys: ``total_deg``,
    ``heading_deg``, ``inclination_deg``, ``samples``, ``heading_offset_deg``,
    ``heading_matched``.
    """
    from gnomon.rotation import quat_from_rotvec

    qr, qe, bad = _pair(q_ref, q_est)  # rows without both: identity, not scored
    m = ~bad if mask is None else ~bad & np.asarray(mask, dtype=bool)
    psi = heading_offset_rad(qr, qe, m) if match_heading else 0.0
    if match_heading and np.isfinite(psi):
        qr = quat_mul(quat_from_rotvec(np.array([0.0, 0.0, psi])), qr)
    e = broad_errors_rad(qr[m], qe[m])
    out = {f"{k}_deg": rms_deg(e[k]) for k in _BROAD_KEYS}
    out.update(samples=int(m.sum()), heading_offset_deg=float(np.degrees(psi)),
               heading_matched=bool(match_heading))
    return out


def compare_onboard(rec: Recording, q_est) -> tuple[dict, np.ndarray]:
    """``compare`` of ``q_est`` (N, 4) with the device's own estimate ``rec.q_onboard``,
    over the rows where both exist; returns the summary (``compare``'s keys plus
    ``heading_reference``, a sentence saying how the heading references were matched) and
    the device's estimate with the offset removed (N, 4; NaN where it has none).

    The two refer heading to different norths in general (PX4's EKF2 and ArduPilot with a
    declination to true north, a phone OS to magnetic or true north depending on the API,
    a filter on the magnetometer to magnetic north), so the constant heading offset
    between them is removed first. ``heading_reference`` names the device's north when
    the reader knew it (``rec.meta["onboard_heading_reference"]``)."""
    if rec.q_onboard is None:
        why = (rec.meta or {}).get("onboard_absent")
        raise InputError(why or "the recording holds no attitude estimate of the device's own",
                         field="q_onboard", file=rec.source or None)
    from gnomon.rotation import quat_from_rotvec

    out = compare(rec.q_onboard, q_est)
    if out["samples"] == 0:
        raise InputError("no sample where both estimates exist", field="q_onboard",
                         file=rec.source or None)
    psi = np.radians(out["heading_offset_deg"])
    north = (rec.meta or {}).get("onboard_heading_reference")
    its = f"its north: {north}" if north else "its north"
    out["heading_reference"] = (f"constant heading offset {out['heading_offset_deg']:+.2f} deg "
                                f"removed from the device's estimate ({its}; vs the "
                                f"filter's magnetic north)")
    matched = np.full_like(rec.q_onboard, np.nan)
    ok = np.all(np.isfinite(rec.q_onboard), axis=1)
    matched[ok] = quat_mul(quat_from_rotvec(np.array([0.0, 0.0, psi])), rec.q_onboard[ok])
    return out, matched
