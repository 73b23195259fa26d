"""Scores of a benchmark: one trial's RMSE, the means over trials and groups, the speed,
the honesty of an uncertainty and the statistics of the truth's alignment.

The metric is BROAD's (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021): for every
scored sample ``q_err = q_est ⊗ conj(q_true)``; total ``2·acos(|w|)``, heading
``2·atan(|z/w|)``, inclination ``2·acos(sqrt(w²+z²))`` (``gnomon.metrics.broad_errors_rad``);
RMSE per trial in degrees; a method's score is the mean over trials.

**Uncertainty** (estimators that carry ``att_std_rad``, the offline ones): their rows and
means also have ``nees``, the mean normalised estimation error squared over the scored
samples (3 for an honest per-axis standard deviation; :func:`nees`).
"""

from __future__ import annotations

import numpy as np

from gnomon.errors import InputError
from gnomon.metrics import body_axis_errors_rad, broad_errors_rad, rms_deg
from gnomon.recording import Recording

__all__ = ["KEYS", "nees", "score_trial", "speed", "means", "group_means", "alignment_stats"]

#: the three error angles of every row and mean (``<key>_deg``)
KEYS = ("total", "heading", "inclination")


def nees(rec: Recording, q_est, std) -> float:
    """Mean normalised estimation error squared of an estimate that carries its per-axis
    1-sigma ``std`` (N, 3) rad (``att_std_rad``): ``Σ_i (ε_i / σ_i)²`` averaged over the
    scored samples, ``ε`` the body-axis error (``metrics.body_axis_errors_rad``). An honest
    uncertainty gives 3; larger means the band is too narrow for this data."""
    q = np.asarray(q_est, dtype=float)
    std = np.asarray(std, dtype=float)
    m = rec.score_mask & np.all(np.isfinite(q), axis=1) & np.all(std > 0, axis=1)
    if not m.any():
        return float("nan")
    eps = body_axis_errors_rad(rec.q_true[m], q[m])
    return float(np.mean(np.sum((eps / std[m]) ** 2, axis=1)))


def score_trial(rec: Recording, q_est) -> dict:
    """BROAD's RMSE (deg) over ``rec.score_mask`` and the rows where ``q_est`` exists (all
    rows for a filter; the device's own estimate may lack some): also ``samples``."""
    q = np.asarray(q_est, dtype=float)
    m = rec.score_mask & np.all(np.isfinite(q), axis=1)
    if not m.any():
        raise InputError("no sample with a valid truth and an estimate to score",
                         file=rec.source or None, field="q_true")
    e = broad_errors_rad(rec.q_true[m], q[m])
    return {**{f"{k}_deg": rms_deg(e[k]) for k in KEYS}, "samples": int(m.sum())}


def speed(timing: dict) -> dict:
    """Samples per second of each method: ``{method: [(samples, seconds), ...]}``."""
    return {m: sum(n for n, _ in v) / max(sum(s for _, s in v), 1e-12)
            for m, v in timing.items()}


def _mean_of(rows) -> dict:
    out = {**{f"{k}_deg": float(np.mean([r[f"{k}_deg"] for r in rows])) for k in KEYS},
           "trials": len(rows)}
    if all("nees" in r for r in rows):  # estimates with an uncertainty: its honesty
        out["nees"] = float(np.nanmean([r["nees"] for r in rows]))
    return out


def means(rows, methods) -> dict:
    """``{method: mean row}`` over the trials of each method (those with a row)."""
    return {m: _mean_of(sel) for m in methods if (sel := [r for r in rows if r["method"] == m])}


def group_means(rows, groups_of: dict, methods) -> dict:
    """``{method: {group: mean row}}``; ``groups_of``: trial -> its groups."""
    if not groups_of:
        return {}
    out = {}
    for m in methods:
        per_group: dict[str, list] = {}
        for r in rows:
            if r["method"] == m:
                for g in groups_of.get(r["trial"], []):
                    per_group.setdefault(g, []).append(r)
        if per_group:
            out[m] = {g: _mean_of(sel) for g, sel in sorted(per_group.items())}
    return out


def _stats(values) -> dict:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"min": None, "median": None, "max": None, "n": 0}
    return {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max()),
            "n": int(v.size)}


def alignment_stats(alignment: list, groups_of: dict) -> dict:
    """Lag (ms), misalignment (deg), gyro bias magnitude (deg/s) and the rate residuals
    over all trials and per phone."""
    sets = {"all": alignment}
    for a in alignment:
        for g in groups_of.get(a["trial"], []):
            if g.startswith("phone:"):
                sets.setdefault(g, []).append(a)
    return {k: {"lag_ms": _stats([1000.0 * a["lag_s"] for a in v]),
                "misalignment_deg": _stats([a["misalignment_deg"] for a in v]),
                "gyro_bias_deg_s": _stats([float(np.linalg.norm(a["gyro_bias_deg_s"]))
                                           for a in v]),
                "rate_rms_deg_s_before": _stats([a["rate_rms_deg_s_before"] for a in v]),
                "rate_rms_deg_s": _stats([a["rate_rms_deg_s"] for a in v])}
            for k, v in sets.items()}
