"""Alignment of a measured reference (motion capture, a robot arm) to the sensor it
scores: the one place it is done (``gnomon estimate --align``, ``gnomon benchmark
--align``). Everything is fitted from the sensor's own data against the reference, never
from an estimate being scored.

A reference ``q_wm`` (N, 4) gives the attitude of its marker body m in its own world w
(a motion-capture room: any up axis, any heading), often late or early by a clock
offset. The truth gnomon scores against is ``q_rs`` (reference r = ENU, body s = the
sensor):

    q_rs(t) = q_rw ⊗ q_wm(t + lag) ⊗ q_ms

three constants, each fitted in its own step:

* ``lag`` (:func:`estimate_lag`): the time offset, by cross-correlating the magnitude
  of the reference's body rate with the gyro's (neither rotation changes a magnitude);
  sub-sample by a parabola through the best three lags.
* ``body`` (:func:`estimate_body_misalignment`): ``q_ms``, the constant rotation from
  the sensor to the marker body, least squares on the rate vectors ``w_m ≈ R_ms (w_s -
  bias)`` (closed-form SVD, Kabsch; a gyro bias removed by centring). Needs rotation
  about at least two axes: ``excitation`` (the second largest over the largest singular
  value of the rate cross-covariance) below ``MIN_EXCITATION`` refuses it. A reference
  that gives the world-to-marker rotation instead (``q_mw``) is recognised here: its
  body rate does not follow the gyro by any constant rotation, its conjugate does
  (``reference_inverted``).
* ``world`` (:func:`estimate_world`): ``q_rw``, the reference's world turned onto ENU.
  Up from gravity: the mean specific force measured by the accelerometer, turned into
  the world by the aligned reference, is the world's up (linear accelerations average
  out over a recording that starts and ends at rest or moves back and forth). North
  from the magnetometer's mean horizontal field in the world (magnetic north, as a
  magnetometer-aided filter refers its heading); without a magnetometer the world's
  heading is kept (the heading errors are then relative to it).

``align_truth(rec, align)`` applies them in that order; ``align="auto"`` fits all three
and applies those the motion determines, reporting why it left the others out; it keeps
the world of a truth its reader gives in ENU (BROAD, tyrex, a gnomon recording; the
frame ``frames["truth"]``, else ``frames["reference"]``) when the accelerometer's up
agrees with its +z within ``MAX_ENU_TILT_DEG``: there the fitted up (tilted 0.1-0.4 deg
by the accelerometer's own errors on BROAD) and magnetic north (up to 2 deg from
BROAD's) would only add error. A named
component the motion does not determine is an :class:`~gnomon.errors.InputError` that
says why. :func:`save_alignment` / :func:`load_alignment` keep a fit for reuse
(``--save-alignment``, ``--align FILE.json``).

The lag, body and world fits are written here rather than taken from a library: they
are a few lines of numpy each (a correlation search, an SVD, a mean), and no maintained
package fits a motion-capture reference to an IMU's own axes and clock (the
hand-eye-calibration packages solve a pose problem from paired poses, not from a gyro).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gnomon.errors import InputError
from gnomon.rotation import quat_conj, quat_mul, quat_rotate

if TYPE_CHECKING:
    from gnomon.recording import Recording

__all__ = ["ALIGN_OPTIONS", "quat_at", "body_rate", "estimate_lag",
           "estimate_body_misalignment", "estimate_world", "align_truth", "parse_align",
           "apply_alignment", "save_alignment", "load_alignment", "fit_for", "align_names",
           "MIN_EXCITATION", "MAX_ENU_TILT_DEG", "WIDE_LAG_S",
           "MIN_LAG_CORRELATION"]

#: what ``align_truth`` can correct (``--align``), in the order it applies them
ALIGN_OPTIONS = ("lag", "body", "world")
#: the smallest ``excitation`` (second over largest singular value of the rate
#: cross-covariance) with which the body rotation counts as determined
MIN_EXCITATION = 0.05
#: the smallest rate-magnitude correlation with which a lag counts as determined
MIN_LAG_CORRELATION = 0.5
#: ``auto`` searches the lag within ±``max_lag_s`` (0.25 s), then, when the best lies on
#: that edge or correlates below ``MIN_LAG_CORRELATION``, within ±this (s; at most a
#: quarter of the recording)
WIDE_LAG_S = 5.0
#: ``auto`` keeps the world of a truth its reader gives in ENU unless the accelerometer's
#: up is further than this from its +z (deg): then the truth is in some other world
MAX_ENU_TILT_DEG = 5.0
#: the gravity magnitude used to pick the quasi-static samples of the gravity residual
_G = 9.80665
_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def quat_at(t, q, t_new) -> np.ndarray:
    """The series ``q`` (N, 4) at times ``t`` (N,) s, increasing, slerped at ``t_new`` (M,):
    NaN outside ``[t[0], t[-1]]`` and where either neighbouring row is NaN."""
    from gnomon.rotation import quat_slerp

    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    t_new = np.asarray(t_new, dtype=float)
    out = np.full((t_new.size, 4), np.nan)
    if t.size < 2:
        return out
    i = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, t.size - 2)
    frac = (t_new - t[i]) / (t[i + 1] - t[i])
    ok = (t_new >= t[0]) & (t_new <= t[-1])
    ok &= np.all(np.isfinite(q[i]), axis=1) & np.all(np.isfinite(q[i + 1]), axis=1)
    if ok.any():
        out[ok] = quat_slerp(q[i[ok]], q[i[ok] + 1], np.clip(frac[ok], 0.0, 1.0))
    return out


def body_rate(t, q) -> tuple[np.ndarray, np.ndarray]:
    """Body angular rate of the series ``q_rb`` (N, 4) at ``t`` (N,) s: ``(t_mid (N-1,),
    w_b (N-1, 3) rad/s)``, ``w = log(conj(q_k) ⊗ q_k+1) / dt`` at the interval midpoints
    (NaN where a row is NaN)."""
    from gnomon.rotation import rotvec_from_quat

    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    bad = ~np.all(np.isfinite(q), axis=1)
    qs = np.where(bad[:, None], _IDENTITY, q)
    d = quat_mul(quat_conj(qs[:-1]), qs[1:])
    w = rotvec_from_quat(d) / np.diff(t)[:, None]
    w[bad[:-1] | bad[1:]] = np.nan
    return 0.5 * (t[:-1] + t[1:]), w


def _gyro_integral(t, gyro):
    """Cumulative trapezoid integral of the gyro (N, 3) and the gyro's gaps (intervals
    longer than 5 median intervals) as (start, end) arrays."""
    dt = np.diff(t)
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (gyro[1:] + gyro[:-1]) *
                                                       dt[:, None], axis=0)])
    long = dt > 5.0 * np.median(dt)
    return cum, t[:-1][long], t[1:][long]


def _gyro_mean(t, cum, gaps, a, b) -> np.ndarray:
    """Mean gyro (K, 3) over the intervals ``[a, b]`` (K,) from the cumulative integral;
    NaN outside the gyro's span or across a gap."""
    out = np.stack([(np.interp(b, t, cum[:, k]) - np.interp(a, t, cum[:, k])) / (b - a)
                    for k in range(3)], axis=1)
    bad = (a < t[0]) | (b > t[-1])
    for g0, g1 in zip(*gaps, strict=True):
        bad |= (a < g1) & (b > g0)
    out[bad] = np.nan
    return out


def _grid_rates(t, gyro, q_true, step_s):
    """The truth's body rate on a uniform grid (its midpoints ``tm``, intervals of
    ``step_s``) and what is needed to average the gyro over the same intervals."""
    ok = np.all(np.isfinite(q_true), axis=1)
    if ok.sum() < 3:
        raise InputError("too few samples with a truth to align it", field="q_true")
    lo, hi = t[ok][0], t[ok][-1]
    grid = np.arange(lo, hi, step_s)
    tm, w_ref = body_rate(grid, quat_at(t, q_true, grid))
    cum, g0, g1 = _gyro_integral(t, gyro)
    return tm, w_ref, (cum, (g0, g1))


def _corr(x, y) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 10:
        return float("nan")
    x, y = x[ok] - x[ok].mean(), y[ok] - y[ok].mean()
    den = np.sqrt((x * x).sum() * (y * y).sum())
    return float((x * y).sum() / den) if den > 0 else float("nan")


def estimate_lag(t, gyro, q_true, max_lag_s: float = 0.25, step_s: float = 0.01) -> dict:
    """The time offset of a reference ``q_true`` (N, 4; NaN rows) against the gyro (N, 3)
    at ``t`` (N,): the lag ``L`` (s) such that the truth at gyro time ``t`` is
    ``q_true(t + L)``. Found by maximising the correlation of the reference's rate
    magnitude (on a grid of ``step_s``) with the gyro's mean rate magnitude over the same
    intervals shifted by ``-L`` (gyro bias and body misalignment leave it unchanged to
    first order): ``|L| <= max_lag_s`` in 5 ms steps, then 0.5 ms steps around the best,
    refined by a parabola through the best three. Returns ``{"lag_s", "correlation",
    "correlation_at_zero", "on_search_edge"}``."""
    t = np.asarray(t, dtype=float)
    grid = _grid_rates(t, np.asarray(gyro, dtype=float), np.asarray(q_true, dtype=float),
                       step_s)
    return _lag_on_grid(t, grid, max_lag_s, step_s)


def _lag_on_grid(t, grid, max_lag_s, step_s) -> dict:
    tm, w_ref, (cum, gaps) = grid
    r = np.linalg.norm(w_ref, axis=1)
    a, b = tm - 0.5 * step_s, tm + 0.5 * step_s

    def corr(L):
        return _corr(r, np.linalg.norm(_gyro_mean(t, cum, gaps, a - L, b - L), axis=1))

    step = max(0.005, max_lag_s / 50.0)  # a wide search: coarse first, then 5 ms steps
    coarse = np.arange(-max_lag_s, max_lag_s + 1e-9, step)
    c = np.array([corr(L) for L in coarse])
    if not np.isfinite(c).any():
        raise InputError("no overlap of the gyro with a valid truth to find the lag",
                         field="q_true")
    k = int(np.nanargmax(c))
    edge = k in (0, coarse.size - 1)
    best = float(coarse[k])
    if step > 0.005:
        mid = best + np.arange(-step, step + 1e-9, 0.005)
        mid = mid[np.abs(mid) <= max_lag_s + 1e-12]
        best = float(mid[int(np.nanargmax([corr(L) for L in mid]))])
    fine = best + np.arange(-0.006, 0.006 + 1e-9, 0.0005)
    fine = fine[np.abs(fine) <= max_lag_s + 1e-12]
    cf = np.array([corr(L) for L in fine])
    j = int(np.nanargmax(cf))
    lag = float(fine[j])
    if 0 < j < fine.size - 1 and np.all(np.isfinite(cf[j - 1:j + 2])):
        den = cf[j - 1] - 2.0 * cf[j] + cf[j + 1]
        if den < 0:
            lag += float(0.5 * (cf[j - 1] - cf[j + 1]) / den * 0.0005)
    return {"lag_s": lag, "correlation": float(cf[j]), "correlation_at_zero": corr(0.0),
            "on_search_edge": bool(edge)}


def estimate_body_misalignment(t, gyro, q_true, lag_s: float = 0.0, step_s: float = 0.01
                               ) -> dict:
    """The constant rotation ``q_bs`` from the sensor frame s (the gyro's) to the body
    frame b of a reference ``q_true = q_rb`` (N, 4), with the truth at gyro time ``t`` taken
    at ``t + lag_s``: least squares ``w_ref ≈ R_bs (w_gyro - bias)`` over the reference's
    rate on a grid of ``step_s`` and the gyro's mean over the same intervals (centred:
    a constant gyro bias is removed, closed-form SVD (Kabsch); one pass drops the
    intervals whose residual exceeds 4 times the median, e.g. differentiated capture
    glitches). The aligned truth is ``q_rs = q_rb ⊗ q_bs``.

    Returns ``{"q_bs", "misalignment_deg", "rotvec_deg" (of q_bs), "gyro_bias_deg_s",
    "rate_rms_deg_s" (residual), "rate_correlation" (of the centred rate components,
    reference against the turned gyro), "intervals", "excitation"}``. ``excitation``: the
    second largest over the largest singular value of the rate cross-covariance; near 0
    the reference turned about one axis only and the rotation about that axis is not
    determined (``MIN_EXCITATION``)."""
    t = np.asarray(t, dtype=float)
    grid = _grid_rates(t, np.asarray(gyro, dtype=float), np.asarray(q_true, dtype=float),
                       step_s)
    return _misalignment_on_grid(t, grid, lag_s, step_s)


def _misalignment_on_grid(t, grid, lag_s, step_s) -> dict:
    from gnomon.rotation import quat_from_dcm, rotvec_from_quat

    tm, w_ref, (cum, gaps) = grid
    g = _gyro_mean(t, cum, gaps, tm - 0.5 * step_s - lag_s, tm + 0.5 * step_s - lag_s)
    ok = np.all(np.isfinite(w_ref), axis=1) & np.all(np.isfinite(g), axis=1)
    if ok.sum() < 10:
        raise InputError("too few intervals with both a truth and a gyro to align the body",
                         field="q_true")
    A, B = w_ref[ok], g[ok]

    def solve(A, B):
        a0, b0 = A.mean(axis=0), B.mean(axis=0)
        H = (B - b0).T @ (A - a0)
        U, S, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
        return R, a0, b0, S

    R, a0, b0, S = solve(A, B)
    res = np.linalg.norm((A - a0) - (B - b0) @ R.T, axis=1)
    keep = res <= 4.0 * np.median(res)
    if keep.sum() >= 10 and not keep.all():
        A, B = A[keep], B[keep]
        R, a0, b0, S = solve(A, B)
        res = np.linalg.norm((A - a0) - (B - b0) @ R.T, axis=1)
    q_bs = quat_from_dcm(R)
    rv = rotvec_from_quat(q_bs)
    bias = b0 - R.T @ a0
    return {"q_bs": q_bs, "misalignment_deg": float(np.degrees(np.linalg.norm(rv))),
            "rotvec_deg": np.degrees(rv).tolist(), "gyro_bias_deg_s": np.degrees(bias).tolist(),
            "rate_rms_deg_s": float(np.degrees(np.sqrt(np.mean(res * res)))),
            "rate_correlation": _corr((A - a0).ravel(), ((B - b0) @ R.T).ravel()),
            "intervals": int(A.shape[0]),
            "excitation": float(S[1] / S[0]) if S[0] > 0 else 0.0}


def estimate_world(rec: Recording, q_ws) -> dict:
    """The rotation ``q_rw`` from a reference's world w to ENU, given the reference
    already turned onto the sensor ``q_ws`` (N, 4 on ``rec.t``; NaN rows): up is the mean
    over the accelerometer's samples of the specific force in w (``q_ws ⊗ f_s``), north
    the mean magnetic field in w, made horizontal (magnetic north); without a
    magnetometer (or with a vertical mean field) the shortest rotation that takes up to
    ``+z`` (the world's heading kept).

    Returns ``{"q_rw" (4,), "rotvec_deg", "up_in_world" (unit (3,)), "heading_from"
    ("magnetometer" or "kept"), "magnetic_dip_deg" (None without), "gravity_residual_deg"
    (RMS angle of the quasi-static specific force, |f| within 0.3 m/s² of g and the gyro
    below 0.2 rad/s, from +z once turned into ENU), "mean_specific_force_m_s2"}``.
    Raises ``InputError`` without an accelerometer, or when the mean specific force is no
    gravity (below g/2)."""
    from gnomon.rotation import quat_from_dcm, rotvec_from_quat

    if rec.accel is None:
        raise InputError("no accelerometer: the world's up is not determined", field="accel")
    t_acc = rec.accel_t if rec.accel_t is not None else rec.t
    f_w, f_s, kept = _in_world(rec.t, q_ws, t_acc, rec.accel)
    if f_w.shape[0] < 10:
        raise InputError("too few accelerometer samples with a truth to find the world's up",
                         field="accel")
    mean = f_w.mean(axis=0)
    g = float(np.linalg.norm(mean))
    if g < 0.5 * _G:
        raise InputError(f"the mean specific force in the reference's world is "
                         f"{g:.2f} m/s² (< g/2): no gravity to find the world's up from "
                         f"(accelerometer not in m/s², or not the reference's body?)",
                         field="accel")
    up = mean / g
    north, dip = None, None
    if rec.mag is not None:
        m_w, _, _ = _in_world(rec.t, q_ws, rec.mag_t if rec.mag_t is not None else rec.t,
                           rec.mag)
        if m_w.shape[0] >= 10:
            m = m_w.mean(axis=0)
            h = m - (m @ up) * up
            if np.linalg.norm(h) > 0.05 * np.linalg.norm(m):
                north = h / np.linalg.norm(h)
                dip = float(np.degrees(np.arctan2(-(m @ up), np.linalg.norm(h))))
    if north is None:  # the shortest arc from up to +z keeps the world's heading
        R = _shortest_arc(up, np.array([0.0, 0.0, 1.0]))
    else:
        R = np.stack([np.cross(north, up), north, up])
    q_rw = quat_from_dcm(R)
    f_r = f_w @ R.T
    n = np.linalg.norm(f_r, axis=1)
    rate = np.interp(t_acc, rec.t, np.linalg.norm(rec.gyro, axis=1))[kept]
    still = (np.abs(n - _G) < 0.3) & (rate < 0.2)
    tilt = np.arccos(np.clip(f_r[still, 2] / n[still], -1.0, 1.0))
    return {"q_rw": q_rw, "rotvec_deg": np.degrees(rotvec_from_quat(q_rw)).tolist(),
            "up_in_world": up.tolist(), "heading_from": "kept" if north is None
            else "magnetometer", "magnetic_dip_deg": dip,
            "gravity_residual_deg": float(np.degrees(np.sqrt(np.mean(tilt ** 2))))
            if tilt.size else None, "mean_specific_force_m_s2": g,
            "samples": int(f_s.shape[0])}


def _in_world(t, q_ws, t_s, v_s):
    """Sensor vectors ``v_s`` (M, 3) at ``t_s`` turned into the world by ``q_ws`` (N, 4
    at ``t``, slerped): ``(v_w (K, 3), v_s (K, 3), rows (M,) bool)`` over the K samples
    with a truth."""
    q = quat_at(t, q_ws, t_s)
    ok = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(v_s), axis=1)
    return quat_rotate(q[ok], v_s[ok]), v_s[ok], ok


def _angle_from_z_deg(up) -> float:
    return float(np.degrees(np.arccos(np.clip(up[2] / np.linalg.norm(up), -1.0, 1.0))))


def _shortest_arc(a, b) -> np.ndarray:
    """The rotation matrix of the smallest rotation taking unit ``a`` to unit ``b``."""
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def parse_align(text) -> tuple[str, ...] | str | dict:
    """``--align``: ``"auto"``, ``"body,lag"`` (any of ``ALIGN_OPTIONS``), ``"none"`` /
    ``""`` / None (nothing), a sequence of options, or a ``.json`` file of
    :func:`save_alignment` (its fit, applied as it is, returned as a dict)."""
    if text is None:
        return ()
    if isinstance(text, dict):
        return text
    if isinstance(text, str) and text.strip() == "auto":
        return "auto"
    if isinstance(text, str | os.PathLike) and str(text).lower().endswith(".json"):
        return load_alignment(text)
    items = text.split(",") if isinstance(text, str) else list(text)
    items = [s.strip() for s in items if s.strip() and s.strip() != "none"]
    bad = [s for s in items if s not in ALIGN_OPTIONS]
    if bad:
        raise InputError(f"unknown alignment {', '.join(bad)}; use auto, a comma-separated "
                         f"list of {', '.join(ALIGN_OPTIONS)}, none or a saved FILE.json",
                         field="align")
    return tuple(dict.fromkeys(items))


def align_names(align) -> list[str]:
    """What a parsed ``align`` asks for, as a JSON list: ``["auto"]``, ``["saved"]`` (a
    fit from a file) or the components."""
    if isinstance(align, dict):
        return ["saved"]
    return ["auto"] if align == "auto" else list(align)


def align_truth(rec: Recording, align=ALIGN_OPTIONS, max_lag_s: float = 0.25,
                step_s: float = 0.01) -> tuple[np.ndarray, dict]:
    """``rec.q_true`` aligned to the sensor, as every method is then scored against it
    (the module docstring): ``"lag"`` shifts it in time (the truth at gyro time ``t``
    becomes ``q_true(t + lag_s)``), ``"body"`` turns it onto the sensor's axes
    (``q_true ⊗ q_bs``, after taking its conjugate when the reference proves inverted),
    ``"world"`` turns its world onto ENU (``q_rw ⊗ q_true``), in that order.
    ``align="auto"``: all three fitted (the lag searched within ``±WIDE_LAG_S`` when the
    best within ``±max_lag_s`` lies on its edge or correlates poorly), those the motion
    determines applied, the others listed in ``refused`` with the reason; a component
    named in ``align`` that the motion does not determine raises ``InputError`` with the
    reason. Empty ``align``: the truth unchanged, the lag and body fit still reported. A
    dict (a saved fit,
    :func:`load_alignment`): applied as it is (:func:`apply_alignment`), nothing fitted.

    Returns ``(q_true (N, 4), info)``; ``info`` (JSON-able): ``align`` (what was asked),
    ``applied``, ``refused`` (component -> reason), ``lag_s``, ``lag_correlation``,
    ``lag_on_search_edge``, ``body_q`` (``q_bs`` [w, x, y, z]: sensor to the reference's
    body), ``misalignment_deg``, ``misalignment_rotvec_deg``, ``reference_inverted``,
    ``gyro_bias_deg_s``, ``rate_rms_deg_s_before`` (gyro vs reference rate, nothing
    corrected), ``rate_rms_deg_s`` (the residual after the fit), ``rate_correlation``,
    ``intervals``, ``excitation``; with ``world`` fitted also ``world_q`` (``q_rw``: the
    reference's world to ENU) and the rest of :func:`estimate_world`'s fit
    (``world_*``). Raises ``InputError`` when ``rec`` has no truth or too little
    overlap."""
    if rec.q_true is None:
        raise InputError("no truth to align", field="q_true", file=rec.source or None)
    align = parse_align(align) if isinstance(align, str) else align
    if isinstance(align, dict):
        return apply_alignment(rec, align), {**align, "from_file": True}
    auto = align == "auto"
    wanted = ALIGN_OPTIONS if auto else tuple(align)
    unknown = [a for a in wanted if a not in ALIGN_OPTIONS]
    if unknown:
        raise InputError(f"unknown alignment {unknown}; use auto or {', '.join(ALIGN_OPTIONS)}",
                         field="align")
    t, gyro, q = rec.t, rec.gyro, rec.q_true
    grid = _grid_rates(t, gyro, q, step_s)
    lag = _lag_on_grid(t, grid, max_lag_s, step_s)
    wide = min(WIDE_LAG_S, 0.25 * float(t[-1] - t[0]))
    if auto and wide > max_lag_s and (lag["on_search_edge"] or  # clocks further apart
                                      not lag["correlation"] >= MIN_LAG_CORRELATION):
        max_lag_s = wide
        lag = _lag_on_grid(t, grid, max_lag_s, step_s)
    refused: dict = {}
    if "lag" in wanted:
        if lag["on_search_edge"]:
            refused["lag"] = (f"the best lag lies at the edge of the search (±{max_lag_s:g} "
                              f"s): the clocks differ by more, or the rates do not match")
        elif not lag["correlation"] >= MIN_LAG_CORRELATION:
            refused["lag"] = (f"the rate magnitudes correlate only {lag['correlation']:.2f} "
                              f"(< {MIN_LAG_CORRELATION}) at the best lag: the motion does "
                              f"not determine the lag")
    lag_s = lag["lag_s"] if "lag" in wanted and "lag" not in refused else 0.0
    body = _misalignment_on_grid(t, grid, lag_s, step_s)
    inverted = False
    if "body" in wanted:  # a world-to-marker reference: its conjugate follows the gyro
        q_conj = q * _CONJ  # NaN rows stay NaN
        other = _misalignment_on_grid(t, _grid_rates(t, gyro, q_conj, step_s), lag_s, step_s)
        if other["rate_rms_deg_s"] < 0.5 * body["rate_rms_deg_s"]:
            body, q, inverted = other, q_conj, True
        if body["excitation"] < MIN_EXCITATION:
            refused["body"] = (f"the reference turns about one axis only (excitation "
                               f"{body['excitation']:.3f} < {MIN_EXCITATION}): the rotation "
                               f"about that axis between sensor and marker is not determined")
        elif not body["rate_correlation"] >= MIN_LAG_CORRELATION:
            refused["body"] = (f"the gyro does not follow the reference's rate (correlation "
                               f"{body['rate_correlation']:.2f} after the best rotation)")
    tm, w_ref, (cum, gaps) = grid
    g0 = _gyro_mean(t, cum, gaps, tm - 0.5 * step_s, tm + 0.5 * step_s)
    before = np.linalg.norm(w_ref - g0, axis=1)
    before = before[np.isfinite(before)]
    applied = [a for a in ("lag", "body") if a in wanted and a not in refused]
    out = quat_at(t, q, t + lag_s) if "lag" in applied else q.copy()
    ok = np.all(np.isfinite(out), axis=1)
    if "body" in applied:
        out[ok] = quat_mul(out[ok], body["q_bs"])
    info = {"align": "auto" if auto else list(wanted), "lag_s": lag["lag_s"],
            "lag_correlation": lag["correlation"], "lag_on_search_edge": lag["on_search_edge"],
            "body_q": body["q_bs"].tolist(), "misalignment_deg": body["misalignment_deg"],
            "misalignment_rotvec_deg": body["rotvec_deg"], "reference_inverted": inverted,
            "gyro_bias_deg_s": body["gyro_bias_deg_s"],
            "rate_rms_deg_s_before": float(np.degrees(np.sqrt(np.mean(before ** 2))))
            if before.size else float("nan"),
            "rate_rms_deg_s": body["rate_rms_deg_s"],
            "rate_correlation": body["rate_correlation"], "intervals": body["intervals"],
            "excitation": body["excitation"]}
    if "world" in wanted:
        world = None
        if auto and "body" in refused:
            refused["world"] = "needs the body rotation, which the motion does not determine"
        else:
            try:
                world = estimate_world(rec, out)
            except InputError as err:
                refused["world"] = err.message
        tilt = None if world is None else _angle_from_z_deg(world["up_in_world"])
        truth_frame = rec.frames.get("truth", rec.frames.get("reference"))
        if world is not None and auto and truth_frame == "ENU" and tilt < MAX_ENU_TILT_DEG:
            refused["world"] = (f"the truth is in ENU already (the reader's frame; its up "
                                f"{tilt:.2f} deg from the accelerometer's): kept")
            world = None
        if world is not None:
            out[ok] = quat_mul(world["q_rw"], out[ok])
            applied.append("world")
            info.update({"world_q": world.pop("q_rw").tolist(),
                         **{f"world_{k}": v for k, v in world.items()}})
    if refused and not auto:
        name = next(iter(refused))
        raise InputError(f"--align {name}: {refused[name]}", field="align",
                         file=rec.source or None)
    info.update(applied=applied, refused=refused)
    return out, info


def apply_alignment(rec: Recording, fit: dict) -> np.ndarray:
    """``rec.q_true`` aligned by a fit of :func:`align_truth` (its ``applied``, ``lag_s``,
    ``reference_inverted``, ``body_q``, ``world_q``), fitting nothing: the same rig's
    alignment reused on another recording."""
    if rec.q_true is None:
        raise InputError("no truth to align", field="q_true", file=rec.source or None)
    for key in ("applied", "lag_s", "body_q"):
        if key not in fit:
            raise InputError(f"not an alignment: no {key!r}", field="align")
    applied = list(fit["applied"])
    q = rec.q_true * _CONJ if fit.get("reference_inverted") else rec.q_true
    out = quat_at(rec.t, q, rec.t + float(fit["lag_s"])) if "lag" in applied else q.copy()
    ok = np.all(np.isfinite(out), axis=1)
    if "body" in applied:
        out[ok] = quat_mul(out[ok], np.asarray(fit["body_q"], dtype=float))
    if "world" in applied:
        if "world_q" not in fit:
            raise InputError("the alignment applies 'world' but holds no 'world_q'",
                             field="align")
        out[ok] = quat_mul(np.asarray(fit["world_q"], dtype=float), out[ok])
    return out


def save_alignment(path: str | os.PathLike, fit: dict) -> Path:
    """Write a fit of :func:`align_truth` (or ``{trial: fit}`` of a benchmark) as JSON
    (``{"gnomon_alignment": 1, ...}``) for ``--align FILE.json``."""
    p = Path(path)
    p.write_text(json.dumps({"gnomon_alignment": 1, **fit}, indent=2, default=_plain) + "\n",
                 encoding="utf-8")
    return p


def load_alignment(path: str | os.PathLike) -> dict:
    """A file of :func:`save_alignment`: one fit, or ``{"trials": {name: fit}}``."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such alignment file", file=str(p), field="align")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise InputError(f"not JSON: {err}", file=str(p), field="align") from None
    if not isinstance(d, dict) or d.pop("gnomon_alignment", None) != 1:
        raise InputError("not a gnomon alignment (no \"gnomon_alignment\": 1; write one with "
                         "--save-alignment)", file=str(p), field="align")
    return d


def fit_for(fits: dict, trial: str) -> dict:
    """The fit of ``trial`` in a loaded alignment file: its entry in ``trials``, or the
    file's one fit (the same rig for every recording; so is a file of one trial)."""
    if "trials" not in fits:
        return fits
    if trial not in fits["trials"] and len(fits["trials"]) == 1:
        return next(iter(fits["trials"].values()))
    if trial not in fits["trials"]:
        raise InputError(f"the alignment file has no fit for {trial!r} (it has "
                         f"{', '.join(sorted(fits['trials']))})", field="align")
    return fits["trials"][trial]


def _plain(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")
