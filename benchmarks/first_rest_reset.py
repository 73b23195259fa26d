"""robust-ahrs' first-rest reset (``rest_reset``) on and off, against VQF.

    python benchmarks/first_rest_reset.py [--broad DIR] [--tyrex DIR]

On short, clean trials that begin at rest (``sim-tstick`` of ``defaults_loo.py``: 40 s,
the first 5 s at rest) most of robust-ahrs' error used to be made in the first seconds:
the gyro bias is unknown until the first rest is confirmed (``rest_min_s``), the
attitude drifts meanwhile, and the start-up's running means (the accelerometer in frame
I, the heading) keep that drift for seconds (the heading for about ``tau_mag_s``). With
``rest_reset`` (the default) the first rest of the start-up restarts the accelerometer
low-pass settled at the rest's force and sets the heading from the rest's field
(``gnomon.kernels.robust_ahrs.first_rest_reset``). This script scores robust-ahrs with
the reset and without it (``rest_reset=False``, the filter before the reset existed) and
VQF, as mean total RMSE (BROAD's metric, ``gnomon.benchmark``) over the development and
held-out halves as ``defaults_loo.py`` splits them: ``sim-tstick`` alone, with
``--broad`` BROAD too, with both folders every set of ``defaults_loo.py`` (the tyrex
truth aligned per trial as ``gnomon benchmark tyrex`` aligns it; the sets without a
rest, tyrex, sim-room and sim-raw-mag, cannot move).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from defaults_loo import halves, load, mean_total, sim_sets

    from gnomon.anchors import run_anchor
    from gnomon.estimators import registry

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--broad", default=None, help="the BROAD trials' folder")
    ap.add_argument("--tyrex", default=None, help="the tyrex trials' folder (with --broad)")
    args = ap.parse_args()
    if args.tyrex and not args.broad:
        ap.error("--tyrex needs --broad")
    sets = (load(args.broad, args.tyrex) if args.tyrex
            else {"sim-tstick": sim_sets()["sim-tstick"]})
    if args.broad and not args.tyrex:
        from gnomon.io import read
        from gnomon.io.broad import broad_trials

        sets["broad"] = [read(p, format="broad") for p in broad_trials(args.broad)]
    print("set, half (trials): mean total RMSE (deg), and its ratio to VQF's")
    for name, recs in sets.items():
        for half, rs in zip(("development", "held out"), halves(recs), strict=True):
            row = {label: mean_total(rs, lambda r, p=params: registry.create(
                       "robust-ahrs", p).run(r).q)
                   for label, params in (("rest_reset=False", {"rest_reset": False}),
                                         ("with the reset", {}))}
            v = mean_total(rs, lambda r: run_anchor("vqf", r))
            print(f"{name}, {half} ({len(rs)}): " + "; ".join(
                f"{k} {x:.3f} ({x / v:.3f}x)" for k, x in row.items()) + f"; VQF {v:.3f}")


if __name__ == "__main__":
    main()
