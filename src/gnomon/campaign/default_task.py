"""The default campaign task: simulate the scenario, run filters on it, score them.

:data:`simulate_and_score` (named ``"gnomon.campaign:simulate_and_score"``) is a
:class:`~gnomon.campaign.task.Task`: its run form simulates one run, its batch form
(:func:`simulate_and_score_batch`) a chunk, handing the runs that share a filter, its
parameters and their time stamps to the filter's ``Estimator.run_many`` in one call
(results equal the one-run ones to the kernels' 1e-12). Its own ``--vary`` keys are
``filter.NAME.PARAM`` (a filter's tuning value). Scores: :func:`gnomon.metrics.score_run`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from gnomon.campaign.task import Task
from gnomon.errors import InputError

__all__ = ["simulate_and_score", "simulate_and_score_batch", "accepts_filter_key",
           "DEFAULT_TASK"]

DEFAULT_TASK = "gnomon.campaign:simulate_and_score"


def accepts_filter_key(key: str) -> bool:
    """Whether ``key`` is ``filter.NAME.PARAM`` of a registered filter. Raises
    ``InputError`` for an unknown filter or an unknown (or renamed: the new name is
    given) parameter of a known one."""
    from gnomon.estimators import registry

    parts = key.split(".")
    if len(parts) != 3 or parts[0] != "filter":
        return False
    cls = registry.get(parts[1])
    names = {f.name for f in dataclasses.fields(cls.Params)}
    if parts[2] in cls.Params.renamed:
        raise InputError(f"renamed: use filter.{parts[1]}.{cls.Params.renamed[parts[2]]} "
                         f"(check its unit with `gnomon filters`)", field=key)
    if parts[2] not in names:
        raise InputError(f"unknown parameter of filter {parts[1]!r}; known: "
                         f"{', '.join(sorted(names))}", field=key)
    return True


def _simulate_and_score_one(scenario, params: dict, seed: int,
                            filters: Sequence[str] | None = None,
                            settle_s: float | None = None) -> dict:
    """The default task, one run: simulate ``scenario`` with ``seed``, run ``filters``,
    score them.

    ``params`` may hold ``filter.NAME.PARAM`` values. ``filters`` None: every registered
    filter whose inputs the recording has (sorted by name). Metrics per filter ``F``
    (:func:`gnomon.metrics.score_run`; degrees, samples after ``settle_s`` s; None: the
    scenario's ``settle_s``, else 300 s): ``F.rms_deg``, ``F.max_deg``, ``F.mean_deg``;
    with a sun sensor also ``F.sunlit_rms_deg``, ``F.eclipse_rms_deg``,
    ``F.eclipse_max_deg`` (NaN when there is no such sample) and ``eclipse_fraction`` of
    the recording; on a vertical reference axis ``F.heading_rms_deg``,
    ``F.inclination_rms_deg``. For a budget (:func:`gnomon.metrics.score_run_budget`), per
    body axis ``A`` (x, y, z): ``F.A_rms_deg``, ``F.A_p99_deg``, and ``F.p99_deg``; with a
    sun sensor the same prefixed ``sunlit_`` / ``eclipse_``. Raises what failed the run.
    """
    result = simulate_and_score_batch([scenario], [params], [seed], filters, settle_s)[0]
    if isinstance(result, BaseException):
        raise result
    return result


def _filters_for(rec, filters):
    from gnomon.estimators import registry

    if filters is not None:
        return list(filters)
    # causal filters by default (an offline one, --filter NAME-offline, sees the whole run)
    # whose inputs the recording has (their own check: sensors, rates, reference frame)
    names = []
    for name in registry.names(offline=False):
        try:
            registry.create(name).check_inputs(rec)
        except InputError:
            continue
        names.append(name)
    return names


def _filter_params(params: dict, name: str) -> dict:
    return {k.split(".", 2)[2]: v for k, v in params.items() if k.startswith(f"filter.{name}.")}


def _settle_s(scenario, settle_s):
    if settle_s is not None:
        return settle_s
    return float(getattr(scenario, "config", {}).get("settle_s", 300.0))


def simulate_and_score_batch(scenarios, params_list, seeds, filters=None,
                             settle_s: float | None = None) -> list:
    """The default task for the runs of a chunk, as one call (its batch form).

    ``scenarios``, ``params_list``, ``seeds``: one per run, as the run form takes them.
    The runs are simulated together (:func:`gnomon.scenarios.simulate_many`:
    the IMU runs of one scenario in one compiled call; each run as it would be alone).
    Filters with a batch-over-runs kernel (those that
    override ``Estimator.run_many``) get the runs that share the filter, its parameters
    and their time stamps together, in one call; the others run as each recording is
    simulated (each recording is dropped when no batch still needs it); a batch's runs are
    scored together (:func:`gnomon.campaign.scoring.score_runs`, the same numbers).
    Returns one metrics
    dict per run, or the exception that failed that run."""
    from gnomon.campaign.scoring import score_runs
    from gnomon.estimators import registry
    from gnomon.estimators.base import Estimator
    from gnomon.scenarios import simulate_many

    def batched(name):
        return registry.get(name).run_many.__func__ is not Estimator.run_many.__func__

    def score(k, name, q):
        if isinstance(results[k], BaseException):
            return
        if isinstance(q, BaseException):
            results[k] = q
            return
        settle = _settle_s(scenarios[k], settle_s)
        scores = score_runs([recs[k]], [q], settle)[0]
        results[k].update({f"{name}.{m}": v for m, v in scores.items()})

    def score_many(ks, name, qs):
        # the runs of a batch that share their settling time: scored together
        # (gnomon.campaign.scoring.score_runs: the same numbers as score(k, name, q))
        todo: dict = {}
        for k, q in zip(ks, qs, strict=True):
            if isinstance(results[k], BaseException) or isinstance(q, BaseException):
                score(k, name, q)
            else:
                todo.setdefault(_settle_s(scenarios[k], settle_s), []).append((k, q))
        for settle, items in todo.items():
            try:
                rows = score_runs([recs[k] for k, _ in items], [q for _, q in items], settle)
            except Exception:  # noqa: BLE001 - then one run at a time, to fail only the bad one
                for k, q in items:
                    try:
                        score(k, name, q)
                    except Exception as err:  # noqa: BLE001
                        results[k] = err
                continue
            for (k, _), scores in zip(items, rows, strict=True):
                results[k].update({f"{name}.{m}": v for m, v in scores.items()})

    results: list = []
    recs: dict = {}
    groups: dict = {}
    simulated = simulate_many(scenarios, seeds)
    for k in range(len(simulated)):
        results.append({})
        try:
            rec = simulated[k]
            simulated[k] = None
            if isinstance(rec, BaseException):
                raise rec
            recs[k] = rec
            if rec.sun_valid is not None:
                results[k]["eclipse_fraction"] = float(np.mean(~rec.sun_valid))
            for name in _filters_for(rec, filters):
                fp = _filter_params(params_list[k], name)
                if batched(name):
                    key = (name, repr(sorted(fp.items())), rec.t.size, rec.t[0], rec.t[-1])
                    groups.setdefault(key, (name, fp, []))[2].append(k)
                else:
                    score(k, name, registry.create(name, fp).run(rec).q)
        except Exception as err:  # noqa: BLE001 - this run fails, the others go on
            results[k] = err
        if not any(k in ks for _, _, ks in groups.values()):
            recs.pop(k, None)
    for name, fp, ks in groups.values():
        try:
            cls = registry.get(name)
            qs = cls.run_many([recs[k] for k in ks], cls.Params.from_dict(fp))
        except Exception:  # noqa: BLE001 - then one run at a time, to fail only the bad one
            qs = []
            for k in ks:
                try:
                    qs.append(registry.create(name, fp).run(recs[k]).q)
                except Exception as err:  # noqa: BLE001
                    qs.append(err)
        score_many(ks, name, qs)
    return results


#: The default task (``"gnomon.campaign:simulate_and_score"``); call it as the run form:
#: ``simulate_and_score(scenario, params, seed, filters=None, settle_s=None) -> dict``.
simulate_and_score = Task(_simulate_and_score_one, batch=simulate_and_score_batch,
                          accepts=accepts_filter_key, name=DEFAULT_TASK)
