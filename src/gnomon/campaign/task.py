"""The campaign task: what one run does, which ``--vary`` keys it takes, how a chunk batches.

A :class:`Task` is three functions and a name:

* ``run(scenario, params, seed, **options) -> {metric: value}``: one run. ``scenario``
  is a :class:`gnomon.scenarios.Scenario` with the run's scenario keys already set;
  ``params`` the drawn values of the other keys (the task's own, e.g.
  ``filter.NAME.PARAM``); ``seed`` the run's 64-bit seed; ``options`` the campaign's
  ``task_options`` (the default task: ``filters``, ``settle_s``). Returns the metrics
  row (numbers become float columns); raising fails this run only.
* ``batch(scenarios, params_list, seeds, **options) -> [row or exception, ...]``
  (optional): the runs of a chunk in one call, one result per run in order, an exception
  in place of the row of a run that failed. Runs that share a filter, its parameters and
  their time stamps go through the filter's batch form (``Estimator.run_many``) there.
  If the call itself raises, the chunk is run one run at a time.
* ``accepts(key) -> bool`` (optional): whether a ``--vary`` key that is not a scenario
  key is a parameter of the task; it may raise ``InputError`` for a near miss (a
  misspelled filter parameter).
* ``name``: ``"module:attribute"``, recorded in ``campaign.json``; default: the run
  function's.

A campaign names its task by the object, by a plain function (a task with neither batch
form nor keys of its own) or by ``"module:attribute"`` (resolved in each worker; the
attribute is a ``Task`` or a function). The default is
:data:`gnomon.campaign.simulate_and_score` (:mod:`gnomon.campaign.default_task`).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

from gnomon.errors import InputError

__all__ = ["Task", "RunFn", "BatchFn", "resolve_task"]


class RunFn(Protocol):
    """One run: ``(scenario, params, seed, **options) -> {metric: value}``."""

    def __call__(self, scenario: Any, params: dict[str, Any], seed: int,
                 **options: Any) -> Mapping[str, Any]: ...


class BatchFn(Protocol):
    """A chunk of runs: one metrics row or exception per run, in order."""

    def __call__(self, scenarios: Sequence[Any], params_list: Sequence[dict[str, Any]],
                 seeds: Sequence[int], **options: Any
                 ) -> list[Mapping[str, Any] | BaseException]: ...


def _no_keys(key: str) -> bool:
    return False


@dataclasses.dataclass(frozen=True)
class Task:
    """What one run of a campaign does (see the module docstring). Picklable when its
    functions are module-level, as the local and Dask executors need."""

    run: RunFn
    batch: BatchFn | None = None
    accepts: Callable[[str], bool] = _no_keys
    name: str = ""

    def __post_init__(self):
        if not callable(self.run):
            raise TypeError(f"Task.run must be callable, got {self.run!r}")
        if not self.name:
            object.__setattr__(self, "name", f"{self.run.__module__}:{self.run.__qualname__}")

    def __call__(self, scenario, params: dict, seed: int, **options) -> Mapping[str, Any]:
        """``self.run(scenario, params, seed, **options)``."""
        return self.run(scenario, params, seed, **options)


def resolve_task(task: Task | RunFn | str) -> Task:
    """``task`` as a :class:`Task`: itself, a plain function wrapped, or the ``Task`` or
    function a ``"module:attribute"`` name points to. Raises ``InputError`` (field ``task``)
    when it cannot be loaded."""
    obj = task
    if isinstance(task, str):
        if ":" not in task:
            raise InputError(f"expected 'module:function', got {task!r}", field="task")
        mod, name = task.split(":", 1)
        try:
            obj = getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError) as err:
            raise InputError(f"cannot load task {task!r}: {err}", field="task") from None
    if isinstance(obj, Task):
        return obj
    if not callable(obj):
        raise InputError(f"expected a Task, a function or 'module:function', got {task!r}",
                         field="task")
    old = [a for a in ("batch", "accepts") if hasattr(obj, a)]
    if old:   # the former way (attributes set on the function) would be silently ignored
        raise InputError(f"{task!r} has attribute(s) {', '.join(old)}: give "
                         "gnomon.campaign.Task(run, batch=..., accepts=...) instead",
                         field="task")
    return Task(obj)
