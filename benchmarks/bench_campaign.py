"""Campaign throughput: a 1,000-run seed-001 campaign (one orbit each) with the local
executor, Dask LocalCluster throughput with 1 vs 2 workers, and (``--imu-runs``) an
imu-handheld campaign against its batch filter alone.

    PYTHONPATH=src python benchmarks/bench_campaign.py [--runs 1000] [--dask-runs 120]
        [--workers 2] [--imu-runs 10000 [--repeat 3]] [--skip-local] [--skip-dask] [--out DIR]

``--imu-runs N``: ``gnomon campaign imu-handheld --runs N --filter mahony`` (local, the
same workers), then the filter alone over the same samples: the campaign's chunks
simulated again in as many processes and only the batched filter call
(``Mahony.run_many``, what the campaign calls) timed; ``ratio`` is the campaign's wall
time over the filter's (summed per process, the slowest process); ``--repeat N``: both
N times in turn, the best of each (``*_each``: every time).

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


def _filter_alone(chunks):
    """Seconds in ``Mahony.run_many`` over the runs of ``chunks`` (lists of seeds),
    each chunk simulated first (not timed), as the campaign's task does."""
    from gnomon.estimators.mahony import Mahony
    from gnomon.scenarios import load_scenario, simulate_many

    sc = load_scenario("imu-handheld")
    params = Mahony.Params()
    spent = samples = 0
    for seeds in chunks:
        recs = simulate_many([sc] * len(seeds), seeds)
        t0 = time.perf_counter()
        Mahony.run_many(recs, params)
        spent += time.perf_counter() - t0
        samples += sum(len(r) for r in recs)
    return spent, samples


def bench_imu(runs: int, workers: int, out: pathlib.Path, repeat: int = 1) -> dict:
    import concurrent.futures as cf
    import multiprocessing as mp

    import pandas as pd

    with tempfile.TemporaryDirectory() as d:     # compile / load the caches
        run_campaign("imu-handheld", 4, d, executor="serial", filters=["mahony"],
                     progress=False)
        _filter_alone([[1, 2]])
    walls, filters = [], []
    for rep in range(repeat):     # the campaign, then the filter alone, in turn
        t0 = time.perf_counter()
        res = run_campaign("imu-handheld", runs, out / f"imu{rep}", root_seed=2026,
                           executor="local", workers=workers, filters=["mahony"],
                           progress=True)
        walls.append(time.perf_counter() - t0)
        table = pd.read_parquet(out / f"imu{rep}" / "results.parquet").sort_values("index")
        seeds = [int(s) for s in table["seed"]]
        chunk = 25
        chunks = [seeds[i:i + chunk] for i in range(0, len(seeds), chunk)]
        per_worker = [chunks[w::workers] for w in range(workers)]
        ctx = mp.get_context("fork")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            done = list(pool.map(_filter_alone, per_worker))
        filters.append(max(sp for sp, _ in done))
        samples = sum(n for _, n in done)
    wall, filter_s = min(walls), min(filters)
    return {"runs": runs, "workers": workers, "samples": samples, "repeats": repeat,
            "campaign_wall_s": round(wall, 2), "filter_alone_s": round(filter_s, 2),
            "campaign_wall_s_each": [round(w, 2) for w in walls],
            "filter_alone_s_each": [round(f, 2) for f in filters],
            "ratio": round(wall / filter_s, 2), "failed": int(res.failed),
            "campaign_samples_per_s": round(samples / wall), "target_ratio": 3.0,
            "met": wall / filter_s <= 3.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--dask-runs", type=int, default=120)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--skip-local", action="store_true")
    ap.add_argument("--skip-dask", action="store_true")
    ap.add_argument("--imu-runs", type=int, default=0,
                    help="also an imu-handheld campaign of this many runs vs its filter")
    ap.add_argument("--repeat", type=int, default=1,
                    help="--imu-runs: campaign and filter alone this many times in turn; "
                         "the best of each (a machine whose speed moves)")
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
    if args.imu_runs:
        result["imu"] = bench_imu(args.imu_runs, args.workers, out, args.repeat)
    result["load_avg_end"] = os.getloadavg()
    print(json.dumps(result, indent=1))
    (out / "bench_campaign.json").write_text(json.dumps(result, indent=1))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
