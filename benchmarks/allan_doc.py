"""The example of docs/calibration.md, 'IMU noise': a synthetic static log of a consumer
MEMS IMU with known noise terms, through ``gnomon calibrate imu`` (CSV written, read back
by the CLI), the figure ``docs/figures/allan_synthetic.png`` and the table of true
against recovered terms (markdown, printed).

    python benchmarks/allan_doc.py [--hours 4] [--rate-hz 100] [--out-dir DIR]

Terms (IEEE Std 952 definitions, per axis, the same on the three): gyro N = 0.005
deg/s/√Hz, B = 8 deg/h, K = 3e-6 rad/s²/√Hz; accelerometer N = 150 µg/√Hz, B = 40 µg,
K = 4e-5 m/s³/√Hz; a rest bias on each. White noise and random walk drawn in the time
domain, flicker (bias instability) shaped in the frequency domain (one-sided PSD
B²/(π f)); seed 1.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
D2R = math.pi / 180.0
UG = 9.80665e-6
TRUE = {"gyro": {"N": 0.005 * D2R, "B": 8.0 * D2R / 3600.0, "K": 3e-6,
                 "bias": [0.004, -0.011, 0.0025]},
        "accel": {"N": 150 * UG, "B": 40 * UG, "K": 4e-5, "bias": [0.0, 0.0, 0.06]}}


def series(rng, n, fs, N, B, K):
    """(n, 3): white (N), flicker (B) and random walk (K) noise."""
    white = N * math.sqrt(fs) * rng.standard_normal((n, 3))
    walk = np.cumsum(K / math.sqrt(fs) * rng.standard_normal((n, 3)), axis=0)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    s = np.zeros_like(f)
    s[1:] = B**2 / (math.pi * f[1:])
    c = np.sqrt(s * fs * n / 4.0)[:, None]
    z = c * (rng.standard_normal((f.size, 3)) + 1j * rng.standard_normal((f.size, 3)))
    return white + walk + np.fft.irfft(z, n, axis=0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--out-dir", default=str(ROOT / "docs" / "figures"))
    args = ap.parse_args()
    fs, n = args.rate_hz, int(args.hours * 3600 * args.rate_hz)
    rng = np.random.default_rng(1)
    t = np.arange(n) / fs
    g = TRUE["gyro"]
    a = TRUE["accel"]
    gyro = np.asarray(g["bias"]) + series(rng, n, fs, g["N"], g["B"], g["K"])
    accel = (np.array([0.0, 0.0, 9.80665]) + np.asarray(a["bias"])
             + series(rng, n, fs, a["N"], a["B"], a["K"]))
    out_dir = Path(args.out_dir)
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "static.csv"
        np.savetxt(csv, np.column_stack([t, gyro, accel]), delimiter=",", fmt="%.10g",
                   header="t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z", comments="")
        cmd = [sys.executable, "-m", "gnomon.cli", "calibrate", "imu", csv.name, "--json",
               "--plot", str((out_dir / "allan_synthetic.png").resolve())]
        report = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True,
                                           cwd=tmp).stdout)
    rows = [("gyro", "N", "noise_density_rad_s_sqrt_hz", "rad/s/√Hz"),
            ("gyro", "B", "bias_instability_rad_s", "rad/s"),
            ("gyro", "B (fitted model)", "bias_instability_fit_rad_s", "rad/s"),
            ("gyro", "K", "rate_random_walk_rad_s2_sqrt_hz", "rad/s²/√Hz"),
            ("gyro", "bias", "bias_rad_s", "rad/s"),
            ("accel", "N", "noise_density_m_s2_sqrt_hz", "m/s²/√Hz"),
            ("accel", "B", "bias_instability_m_s2", "m/s²"),
            ("accel", "B (fitted model)", "bias_instability_fit_m_s2", "m/s²"),
            ("accel", "K", "random_walk_m_s3_sqrt_hz", "m/s³/√Hz")]
    print(f"{args.hours:g} h at {fs:g} Hz ({n} samples), seed 1; "
          f"`gnomon calibrate imu` read {report['duration_s']:.0f} s")
    print()
    print("| sensor | term | unit | true | recovered x, y, z | worst error |")
    print("| --- | --- | --- | ---: | --- | ---: |")
    for sensor, term, key, unit in rows:
        true = TRUE[sensor][term.split()[0]]
        got = report[sensor][key]
        truth = true if isinstance(true, list) else [true] * 3
        errs = [abs(v / w - 1) for v, w in zip(got, truth, strict=True)
                if v is not None and w != 0]
        worst = f"{100 * max(errs):.0f} %" if errs else "-"
        shown = ", ".join("-" if v is None else f"{v:.3g}" for v in got)
        want = ", ".join(f"{v:.3g}" for v in truth) if isinstance(true, list) else f"{true:.3g}"
        print(f"| {sensor} | {term} | {unit} | {want} | {shown} | {worst} |")
    acc = report["accel"]
    print()
    print(f"accelerometer bias along gravity: {acc['bias_along_gravity_m_s2']:.4g} m/s² "
          f"(true {TRUE['accel']['bias'][2]:g}); notes: {report['notes']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
