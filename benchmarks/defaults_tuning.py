"""How the 9-axis filters' defaults were chosen with the data sets held apart (BROAD and the
tyrex smartphones): tune on one, check on the other, both directions.

    python benchmarks/defaults_tuning.py [--broad DIR] [--tyrex DIR] [--out JSON]

The data sets are found like the tests find them (``gnomon.datasets``). Every recording
is read once; the tyrex truth is aligned once per trial (``gnomon.metrics.align_truth``,
body and lag, as ``gnomon benchmark tyrex`` does), BROAD's is not (its protocol). Scores
are BROAD's metric (mean over trials of the total RMSE, deg), VQF's in the same run for
scale.

For each filter a small grid over the parameters that set how fast the heading and the
gyro bias follow their measurements; for each direction (``broad->tyrex``,
``tyrex->broad``) the grid point with the lowest mean on the tuning set, and what it gives
on the other. ``joint`` is the point with the lowest sum of the two means relative to VQF
(the shipped default where it is not the same). Writes ``docs/figures/defaults_tuning.json``
(rendered into ``docs/estimators/realworld-ahrs.md`` by ``make_docs``).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GRIDS = {
    "robust-ahrs": {"tau_mag_s": [9.0, 15.0, 30.0, 45.0],
                    "heading_bias_ref_deg_s": [0.0, 0.02, 0.05, 0.1, 0.2],
                    "tau_acc_s": [2.5, 3.0], "mag_bias_gain_per_s": [0.0, 0.003]},
    "eskf-r3": {"bias_gate": [0.0, 2.0, 3.0], "accel_lowpass_follow": [0.0, 0.4, 1.0]},
}


def load(broad_dir, tyrex_dir) -> dict[str, list]:
    from gnomon.io import read
    from gnomon.io.broad import broad_trials
    from gnomon.io.phone import read_tyrex
    from gnomon.io.tyrex import tyrex_trials
    from gnomon.metrics import align_truth

    sets = {"broad": [read(p, format="broad") for p in broad_trials(broad_dir)], "tyrex": []}
    for p in tyrex_trials(tyrex_dir)[0]:
        rec = read_tyrex(p, mag="calibrated")
        q, _ = align_truth(rec, ("body", "lag"))
        sets["tyrex"].append(dataclasses.replace(rec, q_true=q))
    return sets


def scores(sets, run) -> dict[str, list[float]]:
    """Total RMSE (deg) of ``run(rec) -> q`` on every trial of every set."""
    from gnomon.benchmark import _score

    return {name: [_score(r, run(r))["total_deg"] for r in recs] for name, recs in sets.items()}


def tune(sets, name: str, grid: dict, vqf: dict) -> dict:
    from gnomon.estimators import registry

    points = []
    for vals in itertools.product(*grid.values()):
        p = dict(zip(grid, vals, strict=True))
        s = scores(sets, lambda r, p=p: registry.create(name, p).run(r).q)
        points.append({"params": p, **{k: float(np.mean(v)) for k, v in s.items()},
                       **{f"{k}_worst": float(np.max(v)) for k, v in s.items()}})
        print(name, p, {k: round(float(np.mean(v)), 3) for k, v in s.items()}, file=sys.stderr)
    out = {"grid": grid, "points": points, "directions": {}}
    for a, b in (("broad", "tyrex"), ("tyrex", "broad")):
        best = min(points, key=lambda pt: pt[a])
        out["directions"][f"{a}->{b}"] = {"params": best["params"], "tuned_deg": best[a],
                                          "checked_deg": best[b],
                                          "checked_worst_deg": best[f"{b}_worst"]}
    joint = min(points, key=lambda pt: pt["broad"] / vqf["broad"] + pt["tyrex"] / vqf["tyrex"])
    out["joint"] = joint
    return out


def main(argv=None) -> dict:
    from gnomon.anchors import run_anchor
    from gnomon.datasets import broad_dir, tyrex_dir
    from gnomon.estimators import registry

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--broad", default=None)
    ap.add_argument("--tyrex", default=None)
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "defaults_tuning.json"))
    args = ap.parse_args(argv)
    b, t = args.broad or broad_dir(), args.tyrex or tyrex_dir()
    if b is None or t is None:
        sys.exit("needs the full BROAD and tyrex data sets (--broad, --tyrex or "
                 "GNOMON_BROAD_DIR / GNOMON_TYREX_DIR)")
    sets = load(b, t)
    vqf = {k: float(np.mean(v)) for k, v in scores(sets, lambda r: run_anchor("vqf", r)).items()}
    report = {"trials": {k: len(v) for k, v in sets.items()}, "vqf_deg": vqf, "filters": {}}
    for name, grid in GRIDS.items():
        res = tune(sets, name, grid, vqf)
        d = registry.create(name).params.as_dict()
        res["default"] = {k: d[k] for k in grid}
        report["filters"][name] = res
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")
    return report


if __name__ == "__main__":
    main()
