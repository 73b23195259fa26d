"""Your IMU log to attitude: read a real BROAD excerpt, run two filters, score and plot.

    python examples/imu_log_to_attitude.py [OUT_DIR]
"""

import sys
from pathlib import Path

import gnomon
from gnomon.datasets import bundled

# a BROAD excerpt shipped with gnomon (CC BY 4.0, see gnomon/data/README.md)
trial = bundled("broad", "01_undisturbed_slow_rotation_A_excerpt.mat")
out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")
out.mkdir(parents=True, exist_ok=True)

rec = gnomon.read(trial)
print(f"{rec.source}: {len(rec)} samples at {rec.sample_rate_hz:.1f} Hz, mag in {rec.mag_unit}")
for name in ("mahony", "tilt-cf"):
    est = gnomon.make_filter(name).run(rec)
    s = gnomon.score(rec.q_true, est.q, rec.score_mask)
    print(f"{name:>10}: total {s['total_deg']:.2f} deg, heading {s['heading_deg']:.2f} deg, "
          f"inclination {s['inclination_deg']:.2f} deg")
    gnomon.plot_estimate(rec, est, out / f"{name}.png")
print(f"figures in {out}")
