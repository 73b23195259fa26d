"""A figure of an IMU noise analysis (``gnomon calibrate imu --plot``): the Allan deviation
of each gyro and accelerometer axis (log-log), the lines of the terms read off it
(white noise slope -1/2, bias instability flat, rate random walk slope +1/2) and the
points they are read at (N at τ = 1 s, K at τ = 3 s, B at the minimum). Needs matplotlib.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gnomon.calibration.allan import (
    BIAS_INSTABILITY_FACTOR,
    MIN_CLUSTERS,
    TAU_RANDOM_WALK_S,
    TAU_WHITE_S,
)
from gnomon.calibration.imu_noise import _KEYS

__all__ = ["plot_allan"]


def plot_allan(report: dict, curves: dict, path: str | os.PathLike, title: str = "") -> Path:
    """Write the figure of ``(report, curves)`` from
    :func:`gnomon.calibration.imu_noise.imu_noise` to ``path`` (PNG, SVG, PDF by its
    suffix): one panel per sensor, the curve of each axis (dotted beyond the cluster times
    read, fewer than ``MIN_CLUSTERS`` clusters), dashed lines N/√τ, 0.664 B and K√(τ/3)
    where the term was read, and its read-off point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sensors = [s for s in ("gyro", "accel") if s in curves]
    fig, axes = plt.subplots(1, len(sensors), figsize=(6.5 * len(sensors), 5.5), squeeze=False)
    fig.suptitle((title + "\n" if title else "") +
                 f"Allan deviation of a {report['duration_s']:.0f}-s static log "
                 f"(IEEE Std 952: N slope -1/2 read at {TAU_WHITE_S:g} s, B = flat / "
                 f"{BIAS_INSTABILITY_FACTOR:.3f}, K slope +1/2 read at {TAU_RANDOM_WALK_S:g} s)",
                 fontsize=10)
    for ax, sensor in zip(axes[0], sensors, strict=True):
        unit, kn, kb, kk = _KEYS[sensor]
        sec = report[sensor]
        tau, adev = curves[sensor]
        m = np.maximum(np.round(tau * sec["rate_hz"]), 1.0)
        read = sec["samples"] / m >= MIN_CLUSTERS
        for k, axis in enumerate("xyz"):
            color = f"C{k}"
            ax.loglog(tau[read], adev[read, k], color=color, lw=1.2, label=f"{axis}")
            ax.loglog(tau[~read], adev[~read, k], color=color, lw=0.8, ls=":")
            n, b, kw = sec[kn][k], sec[kb][k], sec[kk][k]
            if n is not None:
                ax.loglog(tau, n / np.sqrt(tau), color=color, lw=0.7, ls="--")
                ax.plot([TAU_WHITE_S], [n], "o", color=color, ms=5)
            if b is not None:
                ax.axhline(BIAS_INSTABILITY_FACTOR * b, color=color, lw=0.7, ls="-.")
                ax.plot([sec["read_at_tau_s"][kb][k]], [BIAS_INSTABILITY_FACTOR * b], "s",
                        color=color, ms=5)
            if kw is not None:
                ax.loglog(tau, kw * np.sqrt(tau / 3.0), color=color, lw=0.7, ls="--")
                ax.plot([TAU_RANDOM_WALK_S], [kw], "^", color=color, ms=6)
        marks = [v for key in (kn, kk) for v in sec[key] if v is not None]
        marks += [BIAS_INSTABILITY_FACTOR * v for v in sec[kb] if v is not None]
        lo = min([float(np.nanmin(adev[adev > 0]))] + marks) if np.any(adev > 0) else 1e-9
        hi = float(np.nanmax(adev))
        ax.set_ylim(lo / 3, hi * 3)
        ax.set_xlim(tau[0], tau[-1])
        ax.set_xlabel("cluster time tau (s)")
        ax.set_ylabel(f"Allan deviation ({unit})")
        ax.grid(True, which="both", lw=0.3, color="0.85")
        fmt = [f"{a}: N {_g(sec[kn][i])}, B {_g(sec[kb][i])}, K {_g(sec[kk][i])}"
               for i, a in enumerate("xyz")]
        k_unit = {"gyro": "rad/s^2/sqrt(Hz)", "accel": "m/s^3/sqrt(Hz)"}[sensor]
        ax.set_title(f"{sensor} (B {unit}; N {unit}/sqrt(Hz), K {k_unit})\n"
                     + "\n".join(fmt), fontsize=8)
        ax.plot([], [], "ko", ms=4, label="N (at 1 s)")
        ax.plot([], [], "ks", ms=4, label="0.664 B (minimum)")
        ax.plot([], [], "k^", ms=4, label="K (at 3 s)")
        ax.plot([], [], "k:", lw=0.8, label=f"< {MIN_CLUSTERS} clusters: not read")
        ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def _g(v) -> str:
    return "-" if v is None else f"{v:.3g}"
