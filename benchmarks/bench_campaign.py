"""Campaign throughput: a 1,000-run seed-001 campaign (one orbit each) with the local
executor, and Dask LocalCluster throughput with 1 vs 2 workers.

    PYTHONPATH=src python benchmarks/bench_campaign.py [--runs 1000] [--dask-runs 120]
        [--workers 2] [--out DIR] [--json]

Targets (issue 5): 1,000 runs in < 10 min on 2 cores (local); Dask 2 workers >= 1.6x the
throughput of 1 worker. Each run simulates one orbit (6,000 s at 1 s) and runs the EKF
and the MEKF. Numbers depend on what else shares the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import tempfile
import time

from gnomon.campaign import run_campaign

FILTERS = ["ekf-spacecraft", "mekf-spacecraft"]
VARY = {"spacecraft.inertia_error_pct": "uniform(0, 10)",
        "environment.field_error.kind": "choice(none, tilt, component)",
        "environment.field_error.level_pct": "uniform(0, 10)"}


def _warm():
    """Compile / load the numba caches once, outside the timings."""
    with tempfile.TemporaryDirectory() as d:
        run_campaign("seed001", 1, d, {"duration_s": "100"}, executor="serial",
                     filters=FILTERS, progress=False)


def bench_local(runs: int, workers: int, out: pathlib.Path) -> dict:
    t0 = time.perf_counter()
    res = run_campaign("seed001", runs, out / "local", VARY, root_seed=2026, executor="local",
                       workers=workers, filters=FILTERS, progress=True)
    dt = time.perf_counter() - t0
    cpu = float(res.table["cpu_s"].sum())
    return {"runs": runs, "workers": workers, "wall_s": round(dt, 2),
            "cpu_s_per_run": round(cpu / runs, 4), "cores_obtained": round(cpu / dt, 2),
            "runs_per_s": round(runs / dt, 3), "failed": int(res.failed),
            "target_wall_s": 600.0, "met": dt < 600.0}


def bench_dask(runs: int, out: pathlib.Path) -> dict:
    import pandas as pd
    from dask.distributed import Client, LocalCluster

    rates, detail = {}, {}
    for n in (1, 2):
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.run(_warm)                      # per-worker import + numba cache load
            t0 = time.perf_counter()
            run_campaign("seed001", runs, out / f"dask{n}", VARY, root_seed=2026,
                         executor="dask", scheduler=cluster.scheduler_address,
                         filters=FILTERS, progress=False)
            wall = time.perf_counter() - t0
            rates[n] = runs / wall
            t = pd.read_parquet(out / f"dask{n}" / "results.parquet")
            # cores the workers actually got from the (shared) machine
            detail[n] = {"wall_s": round(wall, 2),
                         "cpu_s_per_run": round(float(t["cpu_s"].mean()), 4),
                         "cores_obtained": round(float(t["cpu_s"].sum()) / wall, 2)}
    return {"runs": runs, "detail": detail, "runs_per_s_1_worker": round(rates[1], 3),
            "runs_per_s_2_workers": round(rates[2], 3),
            "speedup": round(rates[2] / rates[1], 3), "target_speedup": 1.6,
            "met": rates[2] / rates[1] >= 1.6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--dask-runs", type=int, default=120)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--skip-local", action="store_true")
    ap.add_argument("--skip-dask", action="store_true")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory() if args.out is None else None
    out = pathlib.Path(args.out or tmp.name)
    out.mkdir(parents=True, exist_ok=True)
    _warm()
    result = {"cpu_count": os.cpu_count(), "load_avg_start": os.getloadavg()}
    if not args.skip_local:
        result["local"] = bench_local(args.runs, args.workers, out)
    if not args.skip_dask:
        result["dask"] = bench_dask(args.dask_runs, out)
    result["load_avg_end"] = os.getloadavg()
    print(json.dumps(result, indent=1))
    (out / "bench_campaign.json").write_text(json.dumps(result, indent=1))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
