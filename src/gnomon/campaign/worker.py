"""What a worker does: one run, or a chunk of runs, of a campaign -> table rows.

Runs in whatever process the executor chose; needs only a :class:`CampaignSpec`
(picklable) and run indices. Never raises for a failing run: its row gets
``status = "failed"`` and the error, and the others go on.

A row holds, in this column order: ``index``, ``seed``, ``status`` ("ok" / "failed"),
``error`` (the exception and the file:line where it was raised, one line; "" if ok),
``param.KEY`` for each varied key, the task's metrics (numbers as floats),
``elapsed_s`` (wall, s) and ``cpu_s`` (CPU time of this process, s).
"""

from __future__ import annotations

import dataclasses
import time
import traceback
from collections.abc import Mapping
from typing import Any

import numpy as np

from gnomon.campaign.seeds import describe_run
from gnomon.campaign.task import Task, resolve_task

__all__ = ["CampaignSpec", "as_scenario", "execute_run", "execute_chunk"]


@dataclasses.dataclass(frozen=True)
class CampaignSpec:
    """Everything a worker needs to run any run of a campaign (picklable).

    ``scenario``: the validated scenario config (dict); ``dists``: ``{KEY: Distribution}``
    in ``--vary`` order; ``scenario_keys``: which of those are scenario keys (the others
    go to the task as ``params``); ``task``: a ``Task`` or its ``"module:attribute"``
    name; ``task_options``: keyword arguments of the task (JSON values).
    """

    scenario: Any
    dists: dict
    scenario_keys: tuple
    root_seed: int
    task: Task | str
    task_options: dict


def as_scenario(scenario):
    """A preset name, YAML path, config dict or ``Scenario`` -> ``Scenario`` (validated)."""
    from gnomon.scenarios import Scenario, load_scenario

    if isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, Mapping):
        return Scenario.from_dict(dict(scenario), "dict")
    return load_scenario(scenario)


def _new_row(spec: CampaignSpec, index: int):
    """The row of run ``index`` with its seed and drawn parameters, and the run itself."""
    run = describe_run(spec.root_seed, index, spec.dists)
    row = {"index": run.index, "seed": run.seed, "status": "ok", "error": ""}
    row.update({f"param.{k}": v for k, v in run.params.items()})
    return row, run


def _run_inputs(spec: CampaignSpec, run, base=None):
    """``(scenario, task_params, seed)`` of ``run``; ``base``: ``as_scenario(spec.scenario)``
    when the caller has it already (a chunk validates it once). Raises if a drawn
    scenario value is rejected by the schema."""
    sc_over = {k: v for k, v in run.params.items() if k in spec.scenario_keys}
    task_params = {k: v for k, v in run.params.items() if k not in spec.scenario_keys}
    scenario = as_scenario(spec.scenario) if base is None else base
    if sc_over:
        scenario = scenario.replace(sc_over)
    return scenario, task_params, run.seed


def _record(row: dict, metrics) -> None:
    """Metrics into ``row``; an exception instead of metrics marks the run failed."""
    if isinstance(metrics, BaseException):
        row["status"] = "failed"
        tb = traceback.extract_tb(metrics.__traceback__)
        where = f" ({tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno})" if tb else ""
        row["error"] = f"{type(metrics).__name__}: {metrics}{where}".replace("\n", " ")
        return
    for k, v in metrics.items():
        row[k] = float(v) if isinstance(v, int | float | np.floating | np.integer) else v


def execute_run(spec: CampaignSpec, index: int) -> dict:
    """Run ``index`` alone; returns its row (never raises for a failing run)."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    row, run = _new_row(spec, index)
    try:
        _record(row, resolve_task(spec.task).run(*_run_inputs(spec, run), **spec.task_options))
    except Exception as err:  # noqa: BLE001 - a failing run is recorded, the campaign goes on
        _record(row, err)
    row["elapsed_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    return row


def execute_chunk(spec: CampaignSpec, indices: list[int]) -> list[dict]:
    """The rows of the runs ``indices``, in order.

    A task with a batch form gets them all in one call (runs that share a filter share
    one batch-over-runs kernel there); if that call raises or returns the wrong number of
    results, every run is done alone, so a failure stays one row. ``elapsed_s``/``cpu_s``
    of a batched run are its share of the chunk's."""
    task = resolve_task(spec.task)
    if task.batch is None or len(indices) < 2:
        return [execute_run(spec, i) for i in indices]
    t0 = time.perf_counter()
    c0 = time.process_time()
    try:
        base = as_scenario(spec.scenario)
    except Exception:  # noqa: BLE001 - then each run fails with the error in its row
        return [execute_run(spec, i) for i in indices]
    rows, inputs = [], []
    for index in indices:
        row, run = _new_row(spec, index)
        try:
            inputs.append((row, *_run_inputs(spec, run, base)))
        except Exception as err:  # noqa: BLE001 - recorded in its row
            _record(row, err)
        rows.append(row)
    try:
        results = task.batch([x[1] for x in inputs], [x[2] for x in inputs],
                             [x[3] for x in inputs], **spec.task_options)
        if len(results) != len(inputs):
            raise ValueError(f"task.batch returned {len(results)} results for "
                             f"{len(inputs)} runs")
    except Exception:  # noqa: BLE001 - fall back to one run at a time
        return [execute_run(spec, i) for i in indices]
    for (row, *_), metrics in zip(inputs, results, strict=True):
        _record(row, metrics)
    share_s = (time.perf_counter() - t0) / len(rows)
    share_cpu = (time.process_time() - c0) / len(rows)
    for row in rows:
        row.update(elapsed_s=share_s, cpu_s=share_cpu)
    return rows
