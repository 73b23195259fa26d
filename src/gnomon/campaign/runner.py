"""Running a campaign: :func:`run_campaign` (all runs, resumable) and :func:`run_one`.

The runner checks the whole description before any run starts (every ``--vary`` key is
a scenario key or one the task accepts; the values a distribution can give are accepted
by the scenario schema; task options are JSON values), records it in ``campaign.json``
(:mod:`~gnomon.campaign.store`), cuts the pending runs into chunks, hands them to an
executor (:mod:`~gnomon.campaign.executors`) that runs them with
:func:`~gnomon.campaign.worker.execute_chunk`, writes each finished chunk as a part file
and consolidates the table at the end, also when interrupted.
"""

from __future__ import annotations

import functools
import json
import pathlib
import time
from collections.abc import Mapping, Sequence

import numpy as np

from gnomon.campaign import store
from gnomon.campaign.default_task import DEFAULT_TASK
from gnomon.campaign.distributions import parse_vary
from gnomon.campaign.executors import EXECUTORS, run_chunks
from gnomon.campaign.result import CampaignResult
from gnomon.campaign.task import resolve_task
from gnomon.campaign.worker import CampaignSpec, as_scenario, execute_chunk, execute_run
from gnomon.errors import InputError
from gnomon.progress import Progress

__all__ = ["run_campaign", "run_one"]

#: chunks: about this many per parallel worker (load balance) ...
_CHUNKS_PER_WORKER = 8
#: ... and at most this many runs each (what a crash can lose)
_MAX_CHUNK = 25


def _prepare(scenario, vary, root_seed, task, task_options):
    """``(Scenario, CampaignSpec)`` of a campaign; ``InputError`` for any bad input."""
    sc = as_scenario(scenario)
    dists = parse_vary(vary)
    resolved = resolve_task(task)
    # a task named by a string is resolved again in each worker (and recorded by that name)
    spec_task = task if isinstance(task, str) else resolved
    scenario_keys = []
    for key, dist in dists.items():
        try:
            sc.get(key)
            is_scenario = True
        except InputError:
            is_scenario = False
        if is_scenario:
            # check that the values the distribution gives are accepted by the schema
            # (normal: its mean; uniform: both ends; choice/const: every value)
            values = (dist.args[:1] if dist.kind == "normal" else dist.args)
            for v in values:
                try:
                    sc.replace({key: v})
                except InputError as err:
                    raise InputError(f"{dist.text or dist.kind}: value {v!r} rejected: "
                                     f"{err.message}", field=key) from None
            scenario_keys.append(key)
            continue
        if resolved.accepts(key):
            continue
        raise InputError("unknown key: not a scenario key nor a parameter of the task "
                         f"{_task_name(spec_task)}", field=key)
    try:
        json.dumps(task_options)
    except TypeError:
        raise InputError("task options must be JSON values", field="task_options") from None
    # a scenario loaded from a preset/file is passed as its validated config (picklable)
    spec = CampaignSpec(scenario=sc.to_dict(), dists=dists, scenario_keys=tuple(scenario_keys),
                        root_seed=int(root_seed), task=spec_task, task_options=dict(task_options))
    return sc, spec


def _task_name(task) -> str:
    """The name a task is recorded by: the string it was given as, else ``Task.name``."""
    return task if isinstance(task, str) else task.name


def _manifest(sc, spec: CampaignSpec, runs: int) -> dict:
    return {"scenario": spec.scenario, "scenario_source": sc.source, "runs": int(runs),
            "root_seed": spec.root_seed,
            "vary": {k: (d.text or f"{d.kind}{d.args}") for k, d in spec.dists.items()},
            "task": _task_name(spec.task), "task_options": spec.task_options}


def _chunks(pending: list[int], n_parallel: int, chunk_size: int | None) -> list[list[int]]:
    size = chunk_size or max(1, min(_MAX_CHUNK, len(pending) // (n_parallel * _CHUNKS_PER_WORKER)
                                    or 1))
    return [pending[i:i + size] for i in range(0, len(pending), size)]


def run_one(scenario, index: int, vary=None, root_seed: int = 0, task=DEFAULT_TASK,
            task_options: Mapping | None = None, filters: Sequence[str] | None = None) -> dict:
    """Run ``index`` of a campaign alone, in this process; returns its row (a dict).

    Arguments as :func:`run_campaign`'s; the row equals that run's row in the campaign's
    table (but for ``elapsed_s``/``cpu_s``)."""
    opts = dict(task_options or {})
    if filters is not None:
        opts["filters"] = list(filters)
    _, spec = _prepare(scenario, vary, root_seed, task, opts)
    return execute_run(spec, int(index))


def run_campaign(scenario, runs: int, out_dir: str | pathlib.Path | None, vary=None, *,
                 root_seed: int = 0, executor: str = "local", scheduler: str | None = None,
                 workers: int | None = None, resume: bool = False, only: int | None = None,
                 filters: Sequence[str] | None = None, task=DEFAULT_TASK,
                 task_options: Mapping | None = None, chunk_size: int | None = None,
                 progress: bool = True, dask_retries: int = 3) -> CampaignResult:
    """Run a Monte Carlo campaign (see :mod:`gnomon.campaign`); returns a
    :class:`~gnomon.campaign.result.CampaignResult`.

    ``scenario``: preset name, YAML path, dict or ``Scenario``. ``runs``: number of runs N.
    ``out_dir``: where ``results.parquet`` goes (required unless ``only``). ``vary``:
    ``{KEY: DIST}`` or ``["KEY=DIST"]``. ``executor``: "local" | "dask" | "serial".
    ``workers``: processes (local) or LocalCluster workers (dask); default: CPU count.
    ``resume``: continue a campaign in ``out_dir`` (only missing indices run); without it an
    existing table in ``out_dir`` is an error. ``only``: run that single index alone (in this
    process; written to ``out_dir/only-INDEX.parquet`` when ``out_dir`` is given).
    ``filters``: filter names for the default task. ``task``: a
    :class:`~gnomon.campaign.task.Task`, a function or ``"module:attribute"``;
    ``task_options``: its keyword arguments. ``chunk_size``: runs per chunk (default: about
    8 chunks per worker, at most 25 runs each). ``progress``: a progress bar on stderr
    (runs done, failed, rate, time left; only on a terminal and not in CI:
    :mod:`gnomon.progress`).
    Raises ``InputError`` for bad input before any run starts.
    """
    t_start = time.perf_counter()
    if not isinstance(runs, int | np.integer) or isinstance(runs, bool) or runs < 1:
        raise InputError(f"must be a positive integer, got {runs!r}", field="runs")
    if executor not in EXECUTORS:
        raise InputError(f"unknown executor {executor!r}; use local, dask or serial",
                         field="executor")
    if workers is not None and (int(workers) < 1):
        raise InputError(f"must be >= 1, got {workers!r}", field="workers")
    if scheduler is not None and executor != "dask":
        raise InputError("a scheduler address needs executor 'dask'", field="scheduler")
    opts = dict(task_options or {})
    if filters is not None:
        from gnomon.estimators import registry

        for f in filters:
            registry.get(f)
        opts["filters"] = list(filters)
    sc, spec = _prepare(scenario, vary, root_seed, task, opts)

    if only is not None:
        if not 0 <= int(only) < runs:
            raise InputError(f"must be in 0..{runs - 1}, got {only!r}", field="only")
        row = execute_run(spec, int(only))
        df = store.rows_to_frame([row])
        path = None if out_dir is None else store.write_only(pathlib.Path(out_dir), only, df)
        return CampaignResult(df, path, 1, int(row["status"] != "ok"),
                              time.perf_counter() - t_start, int(runs), int(only))
    if out_dir is None:
        raise InputError("an output directory is needed", field="out")
    out = pathlib.Path(out_dir)
    done = store.open_campaign_dir(out, _manifest(sc, spec, runs), resume)
    pending = [i for i in range(runs) if i not in done]
    ran = failed = 0
    bar = Progress(len(pending), f"campaign {sc.name}", unit="run", enabled=progress)

    def finished(rows):
        nonlocal ran, failed
        store.write_part(out, rows)
        ran += len(rows)
        failed += sum(r["status"] != "ok" for r in rows)
        bar.update(len(rows), failed=failed)

    try:
        if pending:
            run_chunks(executor, functools.partial(execute_chunk, spec),
                       lambda n_parallel: _chunks(pending, n_parallel, chunk_size), finished,
                       workers=workers, scheduler=scheduler, retries=dask_retries)
    finally:
        bar.close()
        df = store.consolidate(out)
    return CampaignResult(df, out / store.RESULTS, ran, failed, time.perf_counter() - t_start,
                          int(runs), None)
