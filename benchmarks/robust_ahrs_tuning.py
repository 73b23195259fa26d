"""How robust-ahrs' defaults were chosen: a grid on the even BROAD trials, checked on the odd.

    PYTHONPATH=src python benchmarks/robust_ahrs_tuning.py [BROAD_DIR] [OUT_JSON]

Trials sorted by name, index 0, 2, 4, ... = tuning half, 1, 3, ... = held-out half.
Criterion: lowest mean total RMSE on the tuning half among the grid points with no
tuning trial worse than 1.2x VQF. The other direction (odd -> even) is reported too, and
leave-one-group-out (BROAD groups from trials.json) with the same criterion.
"""

from __future__ import annotations

import itertools
import json
import sys

import numpy as np

GRID = {"tau_mag_s": [12.0, 20.0, 30.0], "heading_rate_noise_s": [0.0, 0.3, 0.6],
        "tau_acc_s": [2.5, 3.0], "bias_sigma_motion_deg_s": [0.05, 0.1],
        "hard_iron_tau_s": [0.0, 3.0, 5.0, 10.0], "hard_iron_gate": [0.1, 0.2]}


def main(data_dir="../shared/data/broad", out=None) -> dict:
    from gnomon.anchors import run_anchor
    from gnomon.estimators.robust_ahrs import RobustAHRS
    from gnomon.io import read
    from gnomon.io.broad import broad_groups, broad_trials
    from gnomon.metrics import score_broad

    recs = [read(p, format="broad") for p in broad_trials(data_dir)]
    vqf = np.array([score_broad(r, run_anchor("vqf", r))["total_deg"] for r in recs])
    res = []
    for vals in itertools.product(*GRID.values()):
        p = dict(zip(GRID, vals, strict=True))
        res.append((p, np.array([score_broad(r, RobustAHRS(**p).run(r).q)["total_deg"]
                                 for r in recs])))
    idx = np.arange(len(recs))
    halves = {"even": idx[0::2], "odd": idx[1::2]}
    report = {"trials": [r.source for r in recs], "grid": GRID, "folds": {}}
    for tune, held in (("even", "odd"), ("odd", "even")):
        a, b = halves[tune], halves[held]
        ok = [(t[a].mean(), i) for i, (p, t) in enumerate(res) if (t[a] / vqf[a]).max() <= 1.2]
        p, t = res[min(ok)[1]]
        report["folds"][f"{tune}->{held}"] = {
            "params": p, "tuning_mean_deg": float(t[a].mean()),
            "tuning_vqf_deg": float(vqf[a].mean()), "held_out_mean_deg": float(t[b].mean()),
            "held_out_vqf_deg": float(vqf[b].mean()), "all_mean_deg": float(t.mean())}
    # leave one group out: choose on the other trials, score the group
    groups = broad_groups(data_dir)
    report["leave_one_group_out"] = {}
    for g in ("rotation", "translation", "tapping", "vibration", "stationary_magnet",
              "attached_magnet"):
        hold = np.array([i for i, r in enumerate(recs) if g in groups.get(r.source, [])])
        if hold.size == 0:
            continue
        rest = np.setdiff1d(idx, hold)
        ok = [(t[rest].mean(), i) for i, (p, t) in enumerate(res)
              if (t[rest] / vqf[rest]).max() <= 1.2]
        p, t = res[min(ok)[1]]
        report["leave_one_group_out"][g] = {
            "params": p, "held_out_mean_deg": float(t[hold].mean()),
            "held_out_vqf_deg": float(vqf[hold].mean()), "trials": int(hold.size)}
    if out:
        with open(out, "w") as f:
            json.dump(report, f, indent=1)
    return report


if __name__ == "__main__":
    print(json.dumps(main(*sys.argv[1:3]), indent=1))
