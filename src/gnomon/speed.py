"""Speed of gnomon's filters against the reference libraries, in one run (``gnomon bench``).

Not to be confused with ``gnomon.benchmark`` (accuracy on data sets with a reference).

``run_bench`` simulates one 9-axis IMU recording (``gnomon.simulation.ahrs``,
100 Hz, smooth random rotation, MEMS noise) and times, interleaved over
``repeats`` rounds in a random order each round (median per method, compilation
excluded by a warm-up call, freed memory kept for reuse by every method, see
``_freed_memory_kept``):

* every registered gnomon filter that runs on gyro + accelerometer + magnetometer
  (its batch ``run(recording)``, compiled kernels), the offline ones (``-offline``:
  forward and backward over the whole recording) included;
* ``gnomon-batch-mahony-R{runs}``: ``R`` independent Mahony filters in one call
  (``gnomon.estimators.mahony.run_batch``), one Monte Carlo run per filter;
* when installed: ``vqf-batch`` and ``basicvqf-batch`` (``updateBatch``, C++),
  ``vqf-offline`` (``offlineVQF``, C++: the reference of the ``-offline`` filters),
  ``imufusion`` (one ``update`` call per sample from Python, as users run it) and
  ``ahrs-madgwick`` (pure Python). Slow methods are timed on a prefix of the
  recording (``samples_timed`` says how many samples).

Per sample (``per_sample``): the same recording's first ``per_sample_samples`` rows fed
one call at a time from a Python loop, as a live program calls a filter: every causal
gnomon IMU filter's ``update(dt, gyro, accel, mag)`` (its compiled sample path), and when
installed VQF's ``update`` and ``BasicVQF``'s (C++ through its Python binding) and
imufusion's ``Ahrs.update`` (C); µs per call, median over interleaved rounds, with the
ratio to VQF's ``update``.

Simulation (``simulation``): simulated samples per second of the compiled, batched IMU
simulator (``gnomon.simulation.ahrs.simulate_ahrs_batch``, as a campaign chunk calls it:
``sim_runs`` runs of 120 s at 100 Hz with one 4th-order truth step per sample, each
run's random numbers drawn by its own generator, the ``kind: imu`` scenarios' SFC64 in
their ``"by-sample"`` order), median of ``repeats`` calls, compilation excluded.

Result (``gnomon bench --json``)::

    {"samples": int, "repeats": int,
     "results": {NAME: {"samples_per_s": float, "ratio_to_vqf_batch": float,
                        "samples_timed": int}},
     "per_sample": {NAME: {"us_per_update": float, "ratio_to_vqf_update": float,
                           "samples_timed": int}},
     "simulation": {"samples_per_s": float, "runs": int, "samples_timed": int},
     "machine": {"cpu_count": int, "python": str, "processor": str,
                 "freed_memory_reused": bool}}
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import importlib.util
import os
import platform
import time

import numpy as np

from gnomon.progress import Progress

__all__ = ["run_bench", "run_per_sample", "run_simulation", "markdown_table", "per_sample_table",
           "simulation_line"]

_IMU_NEEDS = {"gyro", "accel", "mag"}


def _recording(samples: int, seed: int = 0):
    from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

    p = AhrsSimParams(duration_s=(samples - 1) / 100.0, rate_hz=100.0, substeps=1)
    return simulate_ahrs(p, np.random.default_rng(seed))


def _methods(rec, runs: int):
    """name -> (callable, samples it processes)."""
    from gnomon.estimators import registry

    methods = {}
    for name in registry.names():
        cls = registry.get(name)
        if cls.kind == "imu" and set(cls.needs) <= _IMU_NEEDS:
            methods[name] = (lambda cls=cls: cls().run(rec), len(rec))

    # batch over runs: R filters, each fed the same motion with its own noise realisation
    from gnomon.estimators.mahony import Mahony, run_batch

    n_each = max(2, min(len(rec), 2_000_000 // runs))  # 2 million samples in all
    rng = np.random.default_rng(1)
    gyro = np.empty((n_each, 3, runs))
    gyro[:] = rec.gyro[:n_each, :, None]
    gyro += rng.normal(0.0, 0.003, gyro.shape)
    acc = np.empty_like(gyro)
    acc[:] = rec.accel[:n_each, :, None]
    mag = np.empty_like(gyro)
    mag[:] = rec.mag[:n_each, :, None]
    t = rec.t[:n_each]
    # (R, N, 3) views of run-minor arrays: run_batch uses them without a copy
    g_r, a_r, m_r = (x.transpose(2, 0, 1) for x in (gyro, acc, mag))
    params = Mahony.Params()
    methods[f"gnomon-batch-mahony-R{runs}"] = (
        lambda: run_batch(t, g_r, a_r, m_r, params), n_each * runs)

    gyr = np.ascontiguousarray(rec.gyro)
    accel = np.ascontiguousarray(rec.accel)
    magn = np.ascontiguousarray(rec.mag)
    ts = 1.0 / rec.sample_rate_hz
    if importlib.util.find_spec("vqf") is not None:
        import vqf

        methods["vqf-batch"] = (lambda: vqf.VQF(ts).updateBatch(gyr, accel, magn), len(rec))
        methods["basicvqf-batch"] = (
            lambda: vqf.BasicVQF(ts).updateBatch(gyr, accel, magn), len(rec))
        # the reference of the offline estimators (``-offline``): forward-backward
        methods["vqf-offline"] = (lambda: vqf.offlineVQF(gyr, accel, magn, ts), len(rec))
    from gnomon.recording import Recording

    def prefix(n):
        n = min(n, len(rec))
        return Recording(t=rec.t[:n], gyro=rec.gyro[:n], accel=rec.accel[:n], mag=rec.mag[:n])

    if importlib.util.find_spec("imufusion") is not None:
        from gnomon.anchors import run_imufusion

        short = prefix(200_000)
        methods["imufusion"] = (lambda: run_imufusion(short), len(short))
    if importlib.util.find_spec("ahrs") is not None:
        from gnomon.anchors import run_ahrs_madgwick

        tiny = prefix(20_000)
        methods["ahrs-madgwick"] = (lambda: run_ahrs_madgwick(tiny), len(tiny))
    return methods


def _per_sample_methods(rec, n: int):
    """name -> a function that feeds the first ``n`` rows of ``rec`` one call at a time."""
    from gnomon.estimators import registry

    n = min(n, len(rec))
    dt = np.diff(rec.t[:n], prepend=rec.t[0])
    rows = [(float(dt[k]), rec.gyro[k].copy(), rec.accel[k].copy(), rec.mag[k].copy())
            for k in range(n)]
    methods = {}
    for name in registry.names("imu", offline=False):
        cls = registry.get(name)
        if not set(cls.needs) <= _IMU_NEEDS or not hasattr(cls, "update_reference"):
            continue

        def feed(cls=cls):
            f = cls()
            f.prepare(rec)
            update = f.update
            if "mag" in cls.needs:
                for h, g, a, m in rows:
                    update(h, g, a, m)
            else:
                for h, g, a, _ in rows:
                    update(h, g, a)
        methods[name] = feed
    ts = 1.0 / rec.sample_rate_hz
    if importlib.util.find_spec("vqf") is not None:
        import vqf

        def feed_vqf(kind=vqf.VQF):
            f = kind(ts)
            update = f.update
            for _, g, a, m in rows:
                update(g, a, m)
        methods["vqf"] = feed_vqf
        methods["basicvqf"] = lambda: feed_vqf(vqf.BasicVQF)
    if importlib.util.find_spec("imufusion") is not None:
        import imufusion

        fusion_rows = [(np.degrees(g), a / 9.80665, m) for _, g, a, m in rows]

        def feed_fusion():
            ahrs = imufusion.Ahrs()
            ahrs.set_settings(imufusion.AhrsSettings(sample_rate=1.0 / ts))
            ahrs.set_sample_period(ts)
            update = ahrs.update
            for g, a, m in fusion_rows:
                update(g, a, m)
        methods["imufusion"] = feed_fusion
    return methods, n


def run_per_sample(rec, samples: int = 20_000, repeats: int = 5, seed: int = 0) -> dict:
    """µs per ``update`` call from Python for every per-sample method (module docstring):
    ``{name: {"us_per_update", "ratio_to_vqf_update", "samples_timed"}}``."""
    methods, n = _per_sample_methods(rec, samples)
    for fn in methods.values():  # warm-up: the compiled entry points are looked up
        fn()
    times = {name: [] for name in methods}
    names = list(methods)
    order = np.random.default_rng(seed)
    for _ in range(repeats):
        for name in [names[j] for j in order.permutation(len(names))]:
            t0 = time.perf_counter()
            methods[name]()
            times[name].append(time.perf_counter() - t0)
    us = {name: float(np.median(v)) / n * 1e6 for name, v in times.items()}
    ref = us.get("vqf")
    return {name: {"us_per_update": v, "ratio_to_vqf_update": v / ref if ref else None,
                   "samples_timed": n} for name, v in us.items()}


def run_simulation(runs: int = 25, duration_s: float = 120.0, repeats: int = 5,
                   seed: int = 0) -> dict:
    """Simulated samples per second of ``simulate_ahrs_batch`` (module docstring):
    ``{"samples_per_s", "runs", "samples_timed"}``."""
    from gnomon.scenarios.simulator import IMU_DRAW_ORDER, imu_rng
    from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs_batch

    p = AhrsSimParams(duration_s=duration_s)
    simulate_ahrs_batch(p, [imu_rng(seed)], IMU_DRAW_ORDER)   # warm-up: compilation, caches
    times, n = [], 0
    for _ in range(repeats):
        rngs = [imu_rng(seed + r) for r in range(runs)]
        t0 = time.perf_counter()
        recs = simulate_ahrs_batch(p, rngs, IMU_DRAW_ORDER)
        times.append(time.perf_counter() - t0)
        n = sum(len(r) for r in recs)
        del recs
    return {"samples_per_s": n / float(np.median(times)), "runs": runs, "samples_timed": n}


def run_bench(samples: int = 1_000_000, repeats: int = 5, runs: int = 1000,
              quick: bool = False, progress: bool = False, seed: int = 0,
              per_sample_samples: int = 20_000) -> dict:
    """Time every method (see module docstring); ``quick`` uses 200,000 samples, 3 repeats
    (and 5,000 per-sample calls).

    ``seed`` fixes the random order of the methods in each round. The simulation speed
    (``simulation``): 25 runs of 120 s (quick: 8 of 30 s).
    """
    if quick:
        samples, repeats = min(samples, 200_000), min(repeats, 3)
        per_sample_samples = min(per_sample_samples, 5_000)
    with _freed_memory_kept() as keeps_memory:
        rec = _recording(samples)
        methods = _methods(rec, runs)
        for fn, _ in methods.values():  # warm-up: compilation and caches
            fn()
        times: dict[str, list[float]] = {name: [] for name in methods}
        names = list(methods)
        order = np.random.default_rng(seed)
        bar = Progress(repeats * len(names), "bench", unit="timing", enabled=progress)
        for _ in range(repeats):
            # interleaved, in a new random order each round: no method always runs first or
            # always after the same neighbour (a call that follows one which freed a lot of
            # memory pays for fresh pages; the median should not inherit that from the order)
            for name in [names[j] for j in order.permutation(len(names))]:
                fn = methods[name][0]
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
                bar.update(1, last=f"{name} {methods[name][1] / times[name][-1] / 1e6:.2f} M/s")
        bar.close()
    rates = {name: methods[name][1] / float(np.median(v)) for name, v in times.items()}
    ref = rates.get("vqf-batch")
    results = {name: {"samples_per_s": rate,
                      "ratio_to_vqf_batch": (rate / ref) if ref else float("nan"),
                      "samples_timed": methods[name][1]}
               for name, rate in rates.items()}
    with _freed_memory_kept():
        per_sample = run_per_sample(rec, per_sample_samples, repeats, seed)
    with _freed_memory_kept():
        simulation = (run_simulation(8, 30.0, repeats, seed) if quick
                      else run_simulation(25, 120.0, repeats, seed))
    return {"samples": len(rec), "repeats": repeats, "results": results,
            "per_sample": per_sample, "simulation": simulation,
            "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version(),
                        "processor": platform.processor() or platform.machine(),
                        "freed_memory_reused": keeps_memory}}


@contextlib.contextmanager
def _freed_memory_kept():
    """Within: glibc serves large arrays from its heap and keeps freed memory (no ``mmap``,
    no trimming), so that every method, gnomon's and the references' alike, reuses pages
    the process already has. Otherwise each call's output arrays are fresh pages from
    the kernel, and on these machines touching 150 MB of them takes 5 ms or, now and
    then, 100-250 ms (compaction for transparent huge pages): noise that the median
    of a few rounds does not remove. Yields whether the setting took (glibc only);
    glibc's defaults are set again on exit."""
    m_trim_threshold, m_mmap_max = -1, -4
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        took = bool(libc.mallopt(m_mmap_max, 0)) and bool(
            libc.mallopt(m_trim_threshold, 2**31 - 1))
    except (OSError, AttributeError):
        libc, took = None, False
    try:
        yield took
    finally:
        if libc is not None:
            libc.mallopt(m_mmap_max, 65536)
            libc.mallopt(m_trim_threshold, 128 * 1024)
            libc.malloc_trim(0)


def markdown_table(res: dict) -> str:
    """The result as a Markdown table, fastest first (the README's table is made by this)."""
    rows = sorted(res["results"].items(), key=lambda kv: -kv[1]["samples_per_s"])
    lines = [f"Measured by `gnomon bench` ({res['samples']:,} samples, median of "
             f"{res['repeats']} rounds in random order, one thread, "
             f"{res['machine']['cpu_count']}-core machine, "
             f"Python {res['machine']['python']}):", "",
             "| method | million samples/s | ratio to VQF updateBatch |",
             "| --- | ---: | ---: |"]
    for name, r in rows:
        lines.append(f"| {name} | {r['samples_per_s'] / 1e6:.2f} | "
                     f"{r['ratio_to_vqf_batch']:.2f} |")
    return "\n".join(lines)


def simulation_line(res: dict) -> str:
    """The simulation speed as one sentence ("" when the result has none)."""
    sim = res.get("simulation")
    if not sim:
        return ""
    return (f"Simulation (`simulate_ahrs_batch`, {sim['runs']} runs, "
            f"{sim['samples_timed']:,} samples): "
            f"{sim['samples_per_s'] / 1e6:.2f} million simulated samples/s.")


def per_sample_table(res: dict) -> str:
    """The per-sample timings as a Markdown table, fastest first."""
    rows = sorted(res.get("per_sample", {}).items(), key=lambda kv: kv[1]["us_per_update"])
    if not rows:
        return ""
    n = rows[0][1]["samples_timed"]
    lines = [f"Per sample from Python (`update` in a loop over {n:,} samples, median of "
             f"{res['repeats']} rounds):", "",
             "| method | µs per update | ratio to VQF update |", "| --- | ---: | ---: |"]
    for name, r in rows:
        ratio = r["ratio_to_vqf_update"]
        lines.append(f"| {name} | {r['us_per_update']:.2f} | "
                     f"{'n/a' if ratio is None else f'{ratio:.2f}'} |")
    return "\n".join(lines)
