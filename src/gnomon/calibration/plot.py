"""A figure of a magnetometer calibration (``gnomon calibrate mag --plot``): raw samples
and the fitted ellipsoid, corrected samples and the sphere of radius B (µT, sensor axes),
the magnitudes along the recording, the coverage cells visited. Needs matplotlib."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gnomon.calibration.coverage import COVERAGE_CELLS, _cell_index, coverage_cells
from gnomon.calibration.result import MagCalibration
from gnomon.calibration.samples import _as_mag

__all__ = ["plot_mag_calibration"]


def plot_mag_calibration(mag_uT, cal: MagCalibration, path: str | os.PathLike,
                         title: str = "") -> Path:
    """A figure of a calibration (``gnomon calibrate mag --plot``): the raw samples (µT)
    with the fitted ellipsoid, the corrected samples with the sphere of radius B, the
    magnitudes before and after along the samples, and the coverage cells the corrected
    directions visit (longitude/latitude of ``h/|h|``, sensor axes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = _as_mag(mag_uT)
    h = cal.correct(m)
    step = max(1, len(m) // 3000)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 37), np.linspace(0, np.pi, 19))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
    fig = plt.figure(figsize=(12, 9))
    status = "ok" if cal.ok else f"REFUSED: {cal.reason}"
    fig.suptitle((title + "\n" if title else "") +
                 f"{cal.model} model, coverage {cal.coverage:.2f}, residual "
                 f"{cal.residual_uT:.2f} uT (raw spread {cal.raw_residual_uT:.2f} uT), "
                 f"condition {cal.condition:.3g}; {status}", fontsize=10)
    ell = (cal.field_uT * sphere) @ np.linalg.inv(cal.soft_iron).T + cal.offset_uT
    for k, (pts, surf, name) in enumerate(((m, ell, "raw m (uT) and the fitted ellipsoid"),
                                           (h, cal.field_uT * sphere,
                                            f"corrected h = S (m - o) (uT), sphere |h| = "
                                            f"{cal.field_uT:.1f} uT"))):
        ax = fig.add_subplot(2, 2, k + 1, projection="3d")
        ax.plot_wireframe(surf[..., 0], surf[..., 1], surf[..., 2], color="0.75",
                          linewidth=0.4)
        ax.scatter(*pts[::step].T, s=2, c=np.arange(len(pts))[::step], cmap="viridis")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        lo, hi = pts.min(0), pts.max(0)
        mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, cal.field_uT)
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, strict=True):
            setter(c - half, c + half)
        ax.set_box_aspect((1, 1, 1))
    ax = fig.add_subplot(2, 2, 3)
    raw_norm = np.linalg.norm(m, axis=1)
    ax.plot(raw_norm - np.median(raw_norm) + cal.field_uT, lw=0.6, color="0.5",
            label="|m| raw, shifted to B at its median")
    ax.plot(np.linalg.norm(h, axis=1), lw=0.6, color="C0", label="|h| corrected")
    ax.axhline(cal.field_uT, color="k", lw=0.8, ls="--", label=f"B = {cal.field_uT:.1f} uT")
    ax.set_xlabel("sample")
    ax.set_ylabel("field magnitude (uT)")
    ax.legend(fontsize=8)
    ax.set_title("magnitude along the recording: flat = a good calibration in a clean "
                 "field", fontsize=9)
    ax = fig.add_subplot(2, 2, 4)
    d = h / np.linalg.norm(h, axis=1)[:, None]
    cells = np.unique(_cell_index(d))
    edges, counts = coverage_cells()
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for zone, (k, s0) in enumerate(zip(counts, start, strict=True)):
        lat_hi, lat_lo = 90 - np.degrees(edges[zone]), 90 - np.degrees(edges[zone + 1])
        for j in range(k):
            lon0, lon1 = 360.0 * j / k, 360.0 * (j + 1) / k
            ax.add_patch(plt.Rectangle((lon0, lat_lo), lon1 - lon0, lat_hi - lat_lo,
                                       facecolor="C2" if s0 + j in cells else "white",
                                       edgecolor="0.8", alpha=0.5, lw=0.5))
    lon = np.degrees(np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi))
    ax.scatter(lon[::step], np.degrees(np.arcsin(np.clip(d[::step, 2], -1, 1))), s=1,
               color="C0")
    ax.set_xlim(0, 360)
    ax.set_ylim(-90, 90)
    ax.set_xlabel("longitude of h/|h| (deg, from +x towards +y)")
    ax.set_ylabel("latitude of h/|h| (deg, +z up)")
    ax.set_title(f"coverage: {len(cells)} of {COVERAGE_CELLS} equal-area cells visited",
                 fontsize=9)
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p
