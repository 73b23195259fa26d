"""Speed of robust-ahrs vs VQF's C++ ``updateBatch`` in one process (interleaved, medians).

    PYTHONPATH=src python benchmarks/robust_ahrs_speed.py [BROAD_DIR]

Runs both on every BROAD trial (the same arrays), ``reps`` times in alternation, and
prints the median samples/s of each over the whole set.
"""

from __future__ import annotations

import sys
import time

import numpy as np


def main(data_dir: str = "../shared/data/broad", reps: int = 7) -> dict:
    import vqf

    from gnomon.estimators.robust_ahrs import RobustAHRS
    from gnomon.io import read
    from gnomon.io.broad import broad_trials

    recs = [read(p, format="broad") for p in broad_trials(data_dir)]
    arrays = [(np.ascontiguousarray(r.gyro), np.ascontiguousarray(r.accel),
               np.ascontiguousarray(r.mag)) for r in recs]
    n = sum(len(r) for r in recs)
    RobustAHRS().run(recs[0])  # compile / load the numba cache
    ours, theirs = [], []
    for _ in range(reps):
        t0 = time.perf_counter()
        for r in recs:
            RobustAHRS().run(r)
        ours.append(n / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for r, (g, a, m) in zip(recs, arrays, strict=True):
            vqf.VQF(1.0 / r.sample_rate_hz).updateBatch(g, a, m)
        theirs.append(n / (time.perf_counter() - t0))
    out = {"samples": n, "robust_ahrs_samples_per_s": float(np.median(ours)),
           "vqf_updateBatch_samples_per_s": float(np.median(theirs))}
    out["ratio"] = out["robust_ahrs_samples_per_s"] / out["vqf_updateBatch_samples_per_s"]
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(main(*sys.argv[1:2]), indent=1))
