"""Compile gnomon's kernels for this machine before their first use (``gnomon compile``).

numba compiles a kernel the first time a process runs it and keeps the machine code in
its cache (``NUMBA_CACHE_DIR``, else ``__pycache__`` beside the sources): every later
process loads it in milliseconds. The first use pays the compilation. Measured with an
empty cache, one target after the other in one process on a 2-core machine: ecf-spacecraft
81 s, qcf 76 s, mekf 87 s, ekf-spacecraft 32 s, eskf-offline 72 s, eskf-r3 48 s, mahony 35
s, robust-ahrs 15-16 s, scoring 13-14 s, the orbit simulator 18 s; every target 514 s, in
two processes 291 s. This module pays it ahead of time, once, where that suits: in a
container image or a CI cache, on each machine of a cluster before its workers start (each
worker process would otherwise compile the filters of its first run at the same time).

A target is what a user's command runs, on a short simulated input: a filter by its
registered name (its batch ``run``; a causal IMU filter also a few per-sample
``update`` calls, its live path; ``mahony`` also its batch over runs; a spacecraft filter
on two minutes of the first scenario preset with its sensors, which compiles the orbit
simulator too), ``simulation`` (the batched IMU simulator) and ``scoring`` (a campaign's
compiled scores). The targets are independent, so they compile in parallel processes,
each a fresh interpreter (``spawn``; numba compiles under one lock per process), the
longest first. A target that fails is reported with its error; the others go on. Other
argument types than these (a read-only array, another dtype) compile on first use as
before.

Compilation is machine code for this CPU: a cache made here is used by processes on the
same kind of machine (numba keys each entry by the CPU name and features).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import time

import numpy as np

__all__ = ["targets", "compile_target", "precompile"]

#: targets that are not filters
_OTHERS = ("simulation", "scoring")
#: compiled first: the longest (see above)
_SLOW = ("ecf-spacecraft", "qcf", "mekf", "eskf-offline", "eskf-r3", "mahony",
         "ekf-spacecraft")
#: causal IMU filters: these many per-sample ``update`` calls compile their live path
_LIVE_CALLS = 5


def targets() -> list[str]:
    """Every target's name: the registered filters, then ``simulation`` and ``scoring``."""
    from gnomon.estimators import registry

    return [*registry.names(), *_OTHERS]


def _imu_recording():
    """2 s of a simulated 9-axis IMU at 100 Hz (ENU reference, truth included)."""
    from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

    return simulate_ahrs(AhrsSimParams(duration_s=2.0, rate_hz=100.0, substeps=1),
                         np.random.default_rng(0))


def _spacecraft_recording(name: str):
    """A short simulated orbit of the first preset whose sensors filter ``name`` takes."""
    from gnomon.errors import InputError
    from gnomon.estimators import registry
    from gnomon.scenarios import load_scenario, simulate

    for preset in ("seed001", "smallsat-star-tracker", "seed000"):
        rec = simulate(load_scenario(preset).replace({"duration_s": 120.0}), rng_seed=1)
        try:
            registry.create(name).check_inputs(rec)
        except InputError:
            continue
        return rec
    raise InputError(f"no scenario preset has the sensors {name} needs", field="filter")


def _compile_filter(name: str) -> None:
    from gnomon.estimators import registry

    cls = registry.get(name)
    rec = _imu_recording() if cls.kind == "imu" else _spacecraft_recording(name)
    registry.create(name).run(rec)
    if cls.kind == "imu" and not getattr(cls, "offline", False):
        f = registry.create(name)
        dt = float(rec.t[1] - rec.t[0])
        with_mag = "mag" in cls.needs
        for k in range(_LIVE_CALLS):
            f.update(dt, rec.gyro[k], rec.accel[k], *([rec.mag[k]] if with_mag else []))
    if name == "mahony":
        cls.run_many([rec, rec])


def _compile_simulation() -> None:
    from gnomon.scenarios import load_scenario, simulate_many

    sc = load_scenario("imu-handheld").replace({"duration_s": 2.0})
    simulate_many([sc, sc], [1, 2])


def _compile_scoring() -> None:
    from gnomon.campaign.scoring import score_runs

    rec = _imu_recording()
    score_runs([rec, rec], [rec.q_true, rec.q_true], 0.5)


def compile_target(name: str) -> float:
    """Compile (or load from the cache) what target ``name`` runs; the seconds it took.
    Unknown names raise ``InputError`` naming the known ones."""
    from gnomon.errors import InputError

    known = targets()
    if name not in known:
        raise InputError(f"unknown target {name!r}; known: {', '.join(known)}", field="target")
    t0 = time.perf_counter()
    if name == "simulation":
        _compile_simulation()
    elif name == "scoring":
        _compile_scoring()
    else:
        _compile_filter(name)
    return time.perf_counter() - t0


def _compile_quietly(name: str) -> tuple[str, float | None, str]:
    """``(name, seconds, "")``, or ``(name, None, error)``: one target in a worker."""
    try:
        return name, compile_target(name), ""
    except Exception as err:  # noqa: BLE001 - reported in the result, the others go on
        return name, None, f"{type(err).__name__}: {err}"


def precompile(names=None, workers: int | None = None, progress=None) -> dict:
    """Compile the targets ``names`` (default: all, :func:`targets`) in ``workers``
    processes (None: the CPU count; 1: in this process).

    ``progress(name, seconds, error)``: called as each target ends. Returns ``{"targets":
    {name: {"seconds": float | None, "error": str}}, "workers": int, "wall_s": float}``,
    in the order of ``names``; a failed target has ``seconds`` None and its error."""
    from gnomon.errors import InputError

    known = targets()
    names = list(known if names is None else names)
    for n in names:
        if n not in known:
            raise InputError(f"unknown target {n!r}; known: {', '.join(known)}",
                             field="target")
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise InputError(f"expected at least 1 worker, got {workers}", field="workers")
    t0 = time.perf_counter()
    done: dict = {}

    def record(result):
        name, seconds, error = result
        done[name] = {"seconds": seconds, "error": error}
        if progress is not None:
            progress(name, seconds, error)

    if workers == 1 or len(names) < 2:
        for n in names:
            record(_compile_quietly(n))
    else:
        # the slowest first, so the pool does not end on one long compilation
        order = sorted(names, key=lambda n: n not in _SLOW)
        ctx = mp.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=min(workers, len(names)),
                                    mp_context=ctx) as pool:
            for fut in cf.as_completed([pool.submit(_compile_quietly, n) for n in order]):
                record(fut.result())
    return {"targets": {n: done[n] for n in names}, "workers": workers,
            "wall_s": time.perf_counter() - t0}


