"""Figures for users' own data and for the benchmark (matplotlib, Agg backend, no display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _broken_at_wraps(deg: np.ndarray) -> np.ndarray:
    """Euler angles (N, 3) deg, in their principal ranges, with NaN where an angle jumps by
    more than 180 deg to the next sample (a wrap at ±180): drawn as lines, no vertical
    stroke across the plot. (Unwrapping instead drifts by 360 deg at each pass near
    pitch ±90 deg, where roll and yaw jump together, and parts from the truth.)"""
    out = np.array(deg, dtype=float)
    jump = np.abs(np.diff(out, axis=0)) > 180.0
    out[1:][jump] = np.nan
    return out


def plot_estimate(rec, est, path, compare=None) -> Path:
    """Attitude (Euler angles), errors vs truth (when present), bias estimate and flags.

    ``compare``: ``(label, q_ref)``, another estimate (N, 4) on ``rec.t`` (e.g. the device's
    own, its heading matched) drawn dashed beside the attitude, with BROAD's heading and
    inclination difference in a panel of their own."""
    from gnomon.metrics import axis_errors_rad, broad_errors_rad
    from gnomon.rotation import euler_from_quat, quat_conj, quat_mul

    plt = _plt()
    has_truth = rec.q_true is not None
    bias = est.signals.get("bias_rad_s")
    flags = {k: v for k, v in est.signals.items()
             if isinstance(v, np.ndarray) and v.dtype == bool and v.ndim == 1}
    std = est.signals.get("att_std_rad")  # offline estimators: per body axis, 1 sigma
    rows = (1 + has_truth + (compare is not None) + (bias is not None) + bool(flags)
            + (std is not None))
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.6 * rows), sharex=True, squeeze=False)
    axes = axes[:, 0]
    t = rec.t - rec.t[0]
    ax = axes[0]
    rpy = _broken_at_wraps(np.degrees(euler_from_quat(est.q)))
    for i, lab in enumerate(("roll", "pitch", "yaw")):
        ax.plot(t, rpy[:, i], lw=0.8, label=f"{lab} ({est.estimator})")
    if has_truth:
        ok = np.all(np.isfinite(rec.q_true), axis=1)
        rpy_t = np.full((len(rec), 3), np.nan)
        rpy_t[ok] = np.degrees(euler_from_quat(rec.q_true[ok]))
        rpy_t = _broken_at_wraps(rpy_t)
        for i in range(3):
            ax.plot(t, rpy_t[:, i], "k--", lw=0.6, label="truth" if i == 0 else None)
    if compare is not None:
        label, q_ref = compare
        ok = np.all(np.isfinite(q_ref), axis=1)
        rpy_c = np.full((len(rec), 3), np.nan)
        rpy_c[ok] = np.degrees(euler_from_quat(q_ref[ok]))
        rpy_c = _broken_at_wraps(rpy_c)
        for i in range(3):
            ax.plot(t, rpy_c[:, i], ":", color="0.3", lw=0.9, label=label if i == 0 else None)
    ax.set_ylabel("Euler angle (deg)")
    ax.set_title(f"{est.estimator} on {rec.source or 'recording'} "
                 f"(reference frame {est.frames.get('reference', '?')})")
    ax.legend(fontsize=7, ncol=4)
    k = 1
    if compare is not None:
        diff = broad_errors_rad(compare[1], est.q)
        ax = axes[k]
        for key in ("heading", "inclination"):
            ax.plot(t, np.degrees(diff[key]), lw=0.8, label=f"{key} difference")
        ax.set_ylabel(f"vs {compare[0]} (deg)")
        ax.legend(fontsize=7, ncol=2)
        k += 1
    if has_truth:
        err = np.degrees(axis_errors_rad(rec.q_true, est.q))
        ax = axes[k]
        for i, lab in enumerate(("roll", "pitch", "yaw")):
            ax.plot(t, err[:, i], lw=0.8, label=f"{lab} error")
        ax.set_ylabel("error (deg)")
        ax.legend(fontsize=7, ncol=3)
        k += 1
    if std is not None:
        # the estimate's own uncertainty: ±2 sigma per body axis, and where the truth is
        # known the error in the same axes (rotation vector of conj(q_true) ⊗ q_est)
        ax = axes[k]
        sd = np.degrees(np.asarray(std))
        colors = ("C0", "C1", "C2")
        if has_truth:
            ok = np.all(np.isfinite(rec.q_true), axis=1)
            d = quat_mul(quat_conj(rec.q_true[ok]), est.q[ok])
            d *= np.where(d[:, :1] < 0.0, -1.0, 1.0)
            e_body = np.full((len(rec), 3), np.nan)
            e_body[ok] = np.degrees(2.0 * d[:, 1:])
        for i, lab in enumerate(("x", "y", "z")):
            ax.fill_between(t, -2 * sd[:, i], 2 * sd[:, i], color=colors[i], alpha=0.15,
                            lw=0, label=f"±2σ {lab}")
            if has_truth:
                ax.plot(t, e_body[:, i], color=colors[i], lw=0.6, label=f"error {lab}")
        ax.set_ylabel("body-axis error,\n±2σ band (deg)")
        ax.legend(fontsize=7, ncol=6)
        k += 1
    if bias is not None:
        ax = axes[k]
        ax.plot(t, np.degrees(bias), lw=0.8)
        ax.set_ylabel("gyro bias (deg/s)")
        ax.legend(["x", "y", "z"], fontsize=7, ncol=3)
        k += 1
    if flags:
        ax = axes[k]
        for j, (name, v) in enumerate(flags.items()):
            ax.fill_between(t, j, j + 0.8 * v, step="mid", alpha=0.7, label=name)
        ax.set_yticks([j + 0.4 for j in range(len(flags))], list(flags), fontsize=7)
        ax.set_ylabel("flags")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_broad(res: dict, path) -> Path:
    """Per-trial bars of total RMSE for every method of a ``run_broad`` result."""
    plt = _plt()
    trials = sorted({r["trial"] for r in res["trials"]})
    methods = list(res["mean"])
    cell = {(r["trial"], r["method"]): r["total_deg"] for r in res["trials"]}
    x = np.arange(len(trials))
    w = 0.8 / max(len(methods), 1)
    fig, ax = plt.subplots(figsize=(max(8, 0.7 * len(trials) + 3), 4.5))
    for j, m in enumerate(methods):
        ax.bar(x + j * w - 0.4 + w / 2, [cell.get((t, m), np.nan) for t in trials], w,
               label=f"{m} (mean {res['mean'][m]['total_deg']:.2f} deg)")
    ax.set_xticks(x, [t.split("_", 1)[0] for t in trials])
    ax.set_xlabel("BROAD trial")
    ax.set_ylabel("total RMSE (deg)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title("BROAD benchmark: total orientation RMSE per trial")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
