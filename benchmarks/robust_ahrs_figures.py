"""Figures and tables of docs/estimators/realworld-ahrs.md (robust-ahrs on real BROAD trials).

    PYTHONPATH=src python benchmarks/robust_ahrs_figures.py [BROAD_DIR] [OUT_DIR]

Writes PNGs and ``robust_ahrs_ablation.json`` (mean BROAD errors with each mechanism
switched off) into OUT_DIR (default docs/figures). Every number is computed here.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def _load(data_dir):
    from gnomon.io import read
    from gnomon.io.broad import broad_trials

    return {Path(p).stem: read(p, format="broad") for p in broad_trials(data_dir)}


def _err(rec, est, key):
    from gnomon.metrics import broad_errors_rad

    e = np.degrees(broad_errors_rad(rec.q_true, est.q)[key])
    e[~rec.score_mask] = np.nan  # no truth / not scored
    return e


def _shade(ax, t, flag, color, label):
    ax.fill_between(t, 0, 1, where=flag, transform=ax.get_xaxis_transform(), color=color,
                    alpha=0.15, lw=0, label=label)


def main(data_dir="../shared/data/broad", out_dir="docs/figures") -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gnomon.estimators.robust_ahrs import RobustAHRS
    from gnomon.metrics import score_broad

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    recs = _load(data_dir)

    # 1. magnetic disturbance rejection on the attached-magnet trial
    rec = recs["32_disturbed_attached_magnet_1cm"]
    t = rec.t - rec.t[0]
    on, off = RobustAHRS().run(rec), RobustAHRS(mag_rejection=False, hard_iron_tau_s=0.0).run(rec)
    rej = RobustAHRS(hard_iron_tau_s=0.0).run(rec)
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    _shade(ax[0], t, rej.signals["mag_disturbed"], "C3", "flagged disturbed (no hard iron)")
    ax[0].plot(t, _err(rec, off, "heading"), "C1", lw=0.8, label="rejection off, hard iron off")
    ax[0].plot(t, _err(rec, rej, "heading"), "C2", lw=0.8, label="rejection on, hard iron off")
    ax[0].plot(t, _err(rec, on, "heading"), "C0", lw=0.8,
               label="rejection + hard-iron offset (default)")
    ax[0].set_ylabel("heading error (deg)")
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].plot(t, np.linalg.norm(rec.mag, axis=1), "k", lw=0.5, label="|m|")
    ax[1].set_ylabel("|m| (uT)")
    ax[1].plot(t, np.linalg.norm(rec.mag - on.signals["hard_iron"], axis=1), "C0", lw=0.5,
               label="|m - hard-iron offset|")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[1].set_xlabel("time (s)")
    ax[0].set_title("BROAD 32 (magnet attached 1 cm): rejection and online hard-iron offset")
    fig.tight_layout()
    fig.savefig(out / "robust_ahrs_mag_rejection.png", dpi=110)
    plt.close(fig)

    # 2. heading Kalman gain: recovery after the rejected stretch (hard iron off to show it)
    kf_off = RobustAHRS(heading_kf=False, hard_iron_tau_s=0.0).run(rec)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    _shade(ax, t, rej.signals["mag_disturbed"], "C3", "flagged disturbed")
    ax.plot(t, _err(rec, kf_off, "heading"), "C1", lw=0.8, label="fixed gain (tau_mag)")
    ax.plot(t, _err(rec, rej, "heading"), "C0", lw=0.8, label="heading KF (default)")
    ax.set_ylabel("heading error (deg)")
    ax.set_xlabel("time (s)")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("BROAD 32 (hard iron off): recovery after rejection, heading KF vs fixed gain")
    fig.tight_layout()
    fig.savefig(out / "robust_ahrs_heading_kf.png", dpi=110)
    plt.close(fig)

    # 3. rest detection and bias estimation on a trial with breaks
    rec = recs["04_undisturbed_slow_rotation_with_breaks_A"]
    t = rec.t - rec.t[0]
    on, off = RobustAHRS().run(rec), RobustAHRS(rest_bias=False, motion_bias=False).run(rec)
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    _shade(ax[0], t, on.signals["rest"], "C2", "rest detected")
    ax[0].plot(t, np.degrees(on.signals["bias_rad_s"]), lw=0.9)
    ax[0].set_ylabel("bias estimate (deg/s)")
    ax[0].legend(["rest detected", "x", "y", "z"], fontsize=8, ncol=4)
    _shade(ax[1], t, on.signals["rest"], "C2", "rest")
    ax[1].plot(t, _err(rec, off, "total"), "C1", lw=0.8, label="bias estimation off")
    ax[1].plot(t, _err(rec, on, "total"), "C0", lw=0.8, label="rest + motion bias (default)")
    ax[1].set_ylabel("total error (deg)")
    ax[1].set_xlabel("time (s)")
    ax[1].legend(loc="upper left", fontsize=8)
    ax[0].set_title("BROAD 04 (slow rotation with breaks): rest detection and gyro bias")
    fig.tight_layout()
    fig.savefig(out / "robust_ahrs_rest_bias.png", dpi=110)
    plt.close(fig)

    # 4. linear acceleration: inertial-frame low-pass vs a short one on fast translation
    rec = recs["15_undisturbed_fast_translation_A"]
    t = rec.t - rec.t[0]
    on, short = RobustAHRS().run(rec), RobustAHRS(tau_acc_s=0.3).run(rec)
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    ax[0].plot(t, _err(rec, short, "inclination"), "C1", lw=0.7, label="tau_acc = 0.3 s")
    ax[0].plot(t, _err(rec, on, "inclination"), "C0", lw=0.8, label="tau_acc = 2.5 s (default)")
    ax[0].set_ylabel("inclination error (deg)")
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].plot(t, np.linalg.norm(rec.accel, axis=1) - 9.81, "k", lw=0.4)
    ax[1].set_ylabel("|a| - g (m/s²)")
    ax[1].set_xlabel("time (s)")
    ax[0].set_title("BROAD 15 (fast translation): accelerometer filtered in the inertial frame")
    fig.tight_layout()
    fig.savefig(out / "robust_ahrs_linear_acc.png", dpi=110)
    plt.close(fig)

    # ablation: each mechanism off, mean over the 15 trials
    variants = {"default": {}, "hard_iron off": {"hard_iron_tau_s": 0.0},
                "mag_rejection off": {"mag_rejection": False},
                "mag_rejection and hard_iron off": {"mag_rejection": False,
                                                    "hard_iron_tau_s": 0.0},
                "heading_kf off": {"heading_kf": False},
                "heading_rate_noise_s 0": {"heading_rate_noise_s": 0.0},
                "heading_bias_ref_deg_s 0 (heading noise not raised by the bias "
                "uncertainty)": {"heading_bias_ref_deg_s": 0.0},
                "rest_bias off": {"rest_bias": False}, "motion_bias off": {"motion_bias": False},
                "tau_acc 0.3 s": {"tau_acc_s": 0.3},
                "tau_acc 0.3 s, bias estimation off": {"tau_acc_s": 0.3, "rest_bias": False,
                                                       "motion_bias": False},
                "every sample (mag_every = bias_every = 1)": {"mag_every": 1, "bias_every": 1},
                "as VQF (tau_acc 3, tau_mag 9, no heading KF, no hard iron)":
                    {"tau_acc_s": 3.0, "tau_mag_s": 9.0, "heading_kf": False,
                     "heading_bias_ref_deg_s": 0.0, "bias_clip_deg_s": 2.0,
                     "heading_rate_noise_s": 0.0, "mag_every": 1, "bias_every": 1,
                     "hard_iron_tau_s": 0.0}}
    abl = {}
    for name, over in variants.items():
        rows = [score_broad(r, RobustAHRS(**over).run(r).q) for r in recs.values()]
        abl[name] = {k: float(np.mean([r[k] for r in rows]))
                     for k in ("total_deg", "heading_deg", "inclination_deg")}
    (out / "robust_ahrs_ablation.json").write_text(json.dumps(abl, indent=1))
    return abl


if __name__ == "__main__":
    print(json.dumps(main(*sys.argv[1:3]), indent=1))
