"""Monte Carlo campaigns: many runs of a scenario, on local processes or a Dask cluster.

A campaign is ``runs`` runs of one scenario. Run ``i`` is fully described by
``(index, seed, drawn parameters)``:

* ``seed``: the 64-bit integer drawn from ``numpy.random.SeedSequence(root_seed)
  .spawn(runs)[i]`` (computed directly as ``SeedSequence(root_seed, spawn_key=(i,))``,
  which is the same sequence); the simulation uses it as its seed.
* drawn parameters: for every ``--vary KEY=DIST``, a value drawn from ``DIST`` with a
  generator spawned from the same child sequence, in the order the keys were given.
  ``KEY`` is a dotted scenario key (``spacecraft.inertia_error_pct``) or a key the
  task accepts (the default task accepts ``filter.NAME.PARAM``).

So every run can be re-run alone (``only=INDEX``) with identical results, on any machine.

Distributions (``DIST``): ``normal(mu, sigma)``, ``uniform(a, b)``, ``choice(a, b, ...)``,
``loguniform(a, b)`` and constants (``3.5``, ``tilt``, ``const(x)``, a vector
``[0.5, -0.3, 0.4]``). Unknown keys and
invalid parameters raise ``InputError`` before any run starts.

Results: a Parquet table, one row per run: ``index``, ``seed``, ``status`` ("ok" or
"failed"), ``error`` (the exception, one line), ``elapsed_s`` (wall) and ``cpu_s`` (CPU
time of the worker process), ``param.KEY`` per varied key
and the task's metrics. Rows are written as runs finish — the parent writes one part file
``parts/part-<first index>-<n>.parquet`` per finished chunk (atomically: temporary name,
then rename), so a crash, SIGKILL or Ctrl-C loses only unfinished chunks; at the end the
parts are consolidated into ``results.parquet`` (sorted by index). ``resume=True`` runs only
the indices the table lacks. ``campaign.json`` beside the table records the campaign's
description; resuming with a different one is an error.

Executors: ``"local"`` (processes of this machine, ``concurrent.futures``), ``"serial"``
(in this process; for debugging), ``"dask"`` (``dask.distributed``: a ``LocalCluster``
started here when ``scheduler`` is None, else the cluster at ``scheduler``). Chunks lost
with a dead Dask worker are rescheduled by the scheduler; nothing finished is lost.

The task (what one run does) is a module-level function ``task(scenario, params, seed,
**options) -> dict[str, float]`` named ``"module:function"``; ``params`` holds the drawn
values of the keys that are not scenario keys. The default, :func:`simulate_and_score`,
simulates the scenario and scores filters against the truth.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import json
import math
import os
import pathlib
import re
import time
import traceback
import uuid
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from gnomon.errors import InputError
from gnomon.metrics import score_run

__all__ = ["Distribution", "parse_distribution", "parse_vary", "run_seed", "draw_parameters",
           "run_campaign", "run_one", "CampaignResult", "simulate_and_score",
           "simulate_and_score_batch", "read_results",
           "campaign_cli"]

DEFAULT_TASK = "gnomon.campaign:simulate_and_score"


# --------------------------------------------------------------------------- distributions
@dataclasses.dataclass(frozen=True)
class Distribution:
    """A parsed ``DIST``: ``kind`` in {normal, uniform, loguniform, choice, const}."""

    kind: str
    args: tuple
    text: str = ""

    def draw(self, rng: np.random.Generator):
        k, a = self.kind, self.args
        if k == "const":
            return a[0]
        if k == "normal":
            return float(rng.normal(a[0], a[1]))
        if k == "uniform":
            return float(rng.uniform(a[0], a[1]))
        if k == "loguniform":
            return float(math.exp(rng.uniform(math.log(a[0]), math.log(a[1]))))
        v = a[int(rng.integers(len(a)))]
        return v

    @property
    def numeric(self) -> bool:
        return all(isinstance(v, int | float) and not isinstance(v, bool) for v in self.args)


def _literal(tok: str):
    tok = tok.strip()
    if not tok:
        raise ValueError("empty value")
    try:
        v = ast.literal_eval(tok)
    except (ValueError, SyntaxError):
        return tok  # a bare word: a string
    if isinstance(v, bool | int | float | str):
        return v
    raise ValueError(f"unsupported value {tok!r}")


_DIST_RE = re.compile(r"^\s*([a-z_]+)\s*\((.*)\)\s*$", re.S)


def parse_distribution(text: str, key: str = "vary") -> Distribution:
    """Parse ``normal(0,2)``, ``uniform(a,b)``, ``loguniform(a,b)``, ``choice(a,b,c)``,
    ``const(x)`` or a bare constant. Invalid parameters raise ``InputError`` naming ``key``."""
    m = _DIST_RE.match(str(text))
    if not m:
        try:
            v = ast.literal_eval(str(text).strip())
        except (ValueError, SyntaxError):
            v = None
        if isinstance(v, list | tuple) and v and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            return Distribution("const", ([float(x) for x in v],), str(text))  # a vector
        try:
            return Distribution("const", (_literal(str(text)),), str(text))
        except ValueError as err:
            raise InputError(f"{err}", field=key) from None
    kind, body = m.group(1), m.group(2)
    try:
        args = tuple(_literal(t) for t in body.split(",")) if body.strip() else ()
    except ValueError as err:
        raise InputError(f"{text!r}: {err}", field=key) from None
    bad = lambda msg: InputError(f"{text!r}: {msg}", field=key)  # noqa: E731
    nums = all(isinstance(v, int | float) and not isinstance(v, bool) for v in args)
    if kind in ("normal", "uniform", "loguniform"):
        if len(args) != 2 or not nums:
            raise bad(f"{kind} takes two numbers")
        a, b = (float(x) for x in args)
        if not (math.isfinite(a) and math.isfinite(b)):
            raise bad("parameters must be finite")
        if kind == "normal" and b < 0:
            raise bad("the standard deviation must be >= 0")
        if kind in ("uniform", "loguniform") and b < a:
            raise bad("needs a <= b")
        if kind == "loguniform" and a <= 0:
            raise bad("needs 0 < a")
        return Distribution(kind, (a, b), text)
    if kind == "choice":
        if not args:
            raise bad("choice needs at least one value")
        return Distribution(kind, args, text)
    if kind == "const":
        if len(args) != 1:
            raise bad("const takes one value")
        return Distribution(kind, args, text)
    raise bad("unknown distribution; use normal, uniform, loguniform, choice, const or a value")


def parse_vary(vary: Mapping[str, str] | Sequence[str] | None) -> dict[str, Distribution]:
    """``{"KEY": "DIST"}`` or ``["KEY=DIST", ...]`` -> ``{KEY: Distribution}`` (order kept)."""
    if vary is None:
        return {}
    items = []
    if isinstance(vary, Mapping):
        items = list(vary.items())
    else:
        for s in vary:
            if "=" not in s:
                raise InputError(f"expected KEY=DIST, got {s!r}", field="vary")
            k, v = s.split("=", 1)
            items.append((k.strip(), v.strip()))
    out = {}
    for k, v in items:
        if not k:
            raise InputError(f"empty key in {k}={v}", field="vary")
        if k in out:
            raise InputError("given twice", field=k)
        out[k] = v if isinstance(v, Distribution) else parse_distribution(v, key=k)
    return out


# --------------------------------------------------------------------------- seeds and draws
def run_seed(root_seed: int, index: int) -> int:
    """The 64-bit seed of run ``index``: state of ``SeedSequence(root_seed).spawn(N)[index]``."""
    child = np.random.SeedSequence(int(root_seed), spawn_key=(int(index),))
    return int(child.generate_state(1, np.uint64)[0])


def draw_parameters(root_seed: int, index: int, dists: Mapping[str, Distribution]) -> dict:
    """The parameters of run ``index`` (one draw per key, in order)."""
    child = np.random.SeedSequence(int(root_seed), spawn_key=(int(index),))
    rng = np.random.default_rng(child.spawn(1)[0])
    return {k: d.draw(rng) for k, d in dists.items()}


# --------------------------------------------------------------------------- tasks
def _resolve_task(task) -> Callable:
    if callable(task):
        return task
    if not isinstance(task, str) or ":" not in task:
        raise InputError(f"expected 'module:function', got {task!r}", field="task")
    mod, name = task.split(":", 1)
    try:
        fn = getattr(importlib.import_module(mod), name)
    except (ImportError, AttributeError) as err:
        raise InputError(f"cannot load task {task!r}: {err}", field="task") from None
    return fn


def _task_name(task) -> str:
    if isinstance(task, str):
        return task
    return f"{task.__module__}:{task.__qualname__}"


def _load_scenario(scenario):
    from gnomon.scenarios import Scenario, load_scenario

    if isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, Mapping):
        return Scenario.from_dict(dict(scenario), "dict")
    return load_scenario(scenario)


def _accepts_filter_key(key: str) -> bool:
    from gnomon.estimators import registry

    parts = key.split(".")
    if len(parts) != 3 or parts[0] != "filter":
        return False
    cls = registry.get(parts[1])
    names = {f.name for f in dataclasses.fields(cls.Params)}
    if parts[2] not in names:
        raise InputError(f"unknown parameter of filter {parts[1]!r}; known: "
                         f"{', '.join(sorted(names))}", field=key)
    return True


def simulate_and_score(scenario, params: dict, seed: int, filters: Sequence[str] | None = None,
                       settle_s: float | None = None) -> dict:
    """The default task: simulate ``scenario`` with ``seed``, run ``filters`` and score them.

    ``params`` may hold ``filter.NAME.PARAM`` values. ``filters`` None: every registered
    filter whose inputs the recording has (sorted by name). Metrics per filter ``F``
    (degrees, samples after ``settle_s``; None: the scenario's ``settle_s``, else 300 s):
    ``F.rms_deg``, ``F.max_deg``, ``F.mean_deg``;
    with a sun sensor also ``F.sunlit_rms_deg``, ``F.eclipse_rms_deg``, ``F.eclipse_max_deg``
    (NaN when there is no such sample); ``eclipse_fraction`` of the recording.
    """
    result = simulate_and_score_batch([scenario], [params], [seed], filters, settle_s)[0]
    if isinstance(result, BaseException):
        raise result
    return result


def _filters_for(rec, filters):
    from gnomon.estimators import registry

    if filters is not None:
        return list(filters)
    return [name for name in registry.names()
            if all((rec.extra.get(k[6:]) is not None) if k.startswith("extra.")
                   else getattr(rec, k, None) is not None for k in registry.get(name).needs)]


def _filter_params(params: dict, name: str) -> dict:
    return {k.split(".", 2)[2]: v for k, v in params.items() if k.startswith(f"filter.{name}.")}


def _settle_s(scenario, settle_s):
    if settle_s is not None:
        return settle_s
    return float(getattr(scenario, "config", {}).get("settle_s", 300.0))


def simulate_and_score_batch(scenarios, params_list, seeds, filters=None,
                             settle_s: float | None = None) -> list:
    """``simulate_and_score`` for the runs of a chunk, as one call (its ``batch`` form).

    Each run is simulated alone. Filters with a batch-over-runs kernel (those that
    override ``Estimator.run_many``) get the runs that share the filter, its parameters
    and their time stamps together, in one call; the others run as each recording is
    made (which is then dropped unless a batch still needs it). Returns one metrics
    dict per run, or the exception that failed that run."""
    from gnomon.estimators import registry
    from gnomon.estimators.base import Estimator
    from gnomon.scenarios import simulate

    def batched(name):
        return registry.get(name).run_many.__func__ is not Estimator.run_many.__func__

    def score(k, name, q):
        if isinstance(results[k], BaseException):
            return
        if isinstance(q, BaseException):
            results[k] = q
            return
        scores = score_run(recs[k], q, _settle_s(scenarios[k], settle_s))
        results[k].update({f"{name}.{m}": v for m, v in scores.items()})

    results: list = []
    recs: dict = {}
    groups: dict = {}
    for k, (scenario, seed) in enumerate(zip(scenarios, seeds, strict=True)):
        results.append({})
        try:
            recs[k] = rec = simulate(scenario, rng_seed=seed)
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
        for k, q in zip(ks, qs, strict=True):
            score(k, name, q)
    return results


simulate_and_score.accepts = _accepts_filter_key  # type: ignore[attr-defined]
simulate_and_score.batch = simulate_and_score_batch  # type: ignore[attr-defined]


# --------------------------------------------------------------------------- one run / chunk
@dataclasses.dataclass(frozen=True)
class _Spec:
    """Everything a worker needs (picklable)."""

    scenario: Any
    dists: dict
    scenario_keys: tuple
    root_seed: int
    task: Any
    task_options: dict


_SCENARIO_CACHE: dict = {}


def _new_row(spec: _Spec, index: int) -> dict:
    return {"index": int(index), "seed": run_seed(spec.root_seed, index), "status": "ok",
            "error": ""}


def _prepare_run(spec: _Spec, index: int, row: dict):
    """``(scenario, task_params, seed)`` of run ``index``; the drawn values go into ``row``
    as they are drawn (a failed run's row still shows them). Raises on a bad draw."""
    seed = row["seed"]
    drawn = draw_parameters(spec.root_seed, index, spec.dists)
    for k, v in drawn.items():
        row[f"param.{k}"] = v
    sc_over = {k: v for k, v in drawn.items() if k in spec.scenario_keys}
    task_params = {k: v for k, v in drawn.items() if k not in spec.scenario_keys}
    scenario = _load_scenario(spec.scenario)
    if sc_over:
        scenario = scenario.replace(sc_over)
    return scenario, task_params, seed


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


def _execute(spec: _Spec, index: int) -> dict:
    """Run ``index``; never raises (a failure becomes a row with status 'failed')."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    row = _new_row(spec, index)
    try:
        scenario, task_params, seed = _prepare_run(spec, index, row)
        _record(row, _resolve_task(spec.task)(scenario, task_params, seed,
                                              **spec.task_options))
    except Exception as err:  # noqa: BLE001 - a failing run is recorded, the campaign goes on
        _record(row, err)
    row["elapsed_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    return row


def _execute_chunk(spec: _Spec, indices: list[int]) -> list[dict]:
    """The runs of a chunk. A task with a ``batch`` form (``task.batch(scenarios,
    params_list, seeds, **options) -> list`` of metrics or exceptions, one per run)
    gets them all in one call, where runs that share a filter share one batch-over-runs
    kernel (``Estimator.run_many``); if that call raises, every run is done alone, so
    a failure stays one row. ``elapsed_s``/``cpu_s`` of a batched run are its share of
    the chunk's."""
    batch = getattr(_resolve_task(spec.task), "batch", None)
    if batch is None or len(indices) < 2:
        return [_execute(spec, i) for i in indices]
    t0 = time.perf_counter()
    c0 = time.process_time()
    rows, inputs = [], []
    for index in indices:
        row = _new_row(spec, index)
        try:
            inputs.append((row, *_prepare_run(spec, index, row)))
        except Exception as err:  # noqa: BLE001 - recorded in its row
            _record(row, err)
        rows.append(row)
    try:
        results = batch([x[1] for x in inputs], [x[2] for x in inputs],
                        [x[3] for x in inputs], **spec.task_options)
        if len(results) != len(inputs):
            raise ValueError(f"task.batch returned {len(results)} results for "
                             f"{len(inputs)} runs")
    except Exception:  # noqa: BLE001 - fall back to one run at a time
        return [_execute(spec, i) for i in indices]
    for (row, *_), metrics in zip(inputs, results, strict=True):
        _record(row, metrics)
    share_s = (time.perf_counter() - t0) / len(rows)
    share_cpu = (time.process_time() - c0) / len(rows)
    for row in rows:
        row.update(elapsed_s=share_s, cpu_s=share_cpu)
    return rows


# --------------------------------------------------------------------------- storage
def _write_part(out_dir: pathlib.Path, rows: list[dict]) -> pathlib.Path:
    import pandas as pd

    parts = out_dir / "parts"
    parts.mkdir(parents=True, exist_ok=True)
    first = min(r["index"] for r in rows)
    name = f"part-{first:08d}-{len(rows)}-{uuid.uuid4().hex[:8]}.parquet"
    tmp = parts / (name + ".tmp")
    _frame(pd, rows).to_parquet(tmp, index=False)
    os.replace(tmp, parts / name)
    return parts / name


def _frame(pd, rows):
    df = pd.DataFrame(rows)
    if "seed" in df:
        df["seed"] = df["seed"].astype("uint64")
    return df


def read_results(out_dir: str | pathlib.Path):
    """All finished runs under ``out_dir`` (results.parquet + part files), one row per index,
    sorted by index (a pandas DataFrame; empty if none)."""
    import pandas as pd

    out_dir = pathlib.Path(out_dir)
    frames = []
    main = out_dir / "results.parquet"
    if main.is_file():
        frames.append(pd.read_parquet(main))
    parts = out_dir / "parts"
    if parts.is_dir():
        for p in sorted(parts.glob("part-*.parquet")):
            try:
                frames.append(pd.read_parquet(p))
            except Exception:  # noqa: BLE001 - a torn file (should not happen: atomic rename)
                continue
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(columns=["index", "seed", "status", "error", "elapsed_s"])
    df = pd.concat(frames, ignore_index=True, sort=False)
    df = df.drop_duplicates(subset="index", keep="first").sort_values("index")
    return df.reset_index(drop=True)


def _consolidate(out_dir: pathlib.Path):
    df = read_results(out_dir)
    tmp = out_dir / "results.parquet.tmp"
    df.to_parquet(tmp, index=False)
    os.replace(tmp, out_dir / "results.parquet")
    parts = out_dir / "parts"
    if parts.is_dir():
        for p in parts.glob("part-*"):
            p.unlink()
    return df


# --------------------------------------------------------------------------- the campaign
@dataclasses.dataclass
class CampaignResult:
    """What :func:`run_campaign` returns: the table and counts of this invocation."""

    table: Any                     # pandas DataFrame, one row per finished run
    path: pathlib.Path | None      # results.parquet (None for ``only``)
    ran: int                       # runs executed by this call
    failed: int                    # of which failed
    elapsed_s: float

    @property
    def runs_per_s(self) -> float:
        return self.ran / self.elapsed_s if self.elapsed_s > 0 else float("nan")


def _prepare(scenario, vary, root_seed, task, task_options):
    sc = _load_scenario(scenario)
    dists = parse_vary(vary)
    fn = _resolve_task(task)
    accepts = getattr(fn, "accepts", None)
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
        if accepts is not None and accepts(key):
            continue
        raise InputError("unknown key: not a scenario key nor a parameter of the task "
                         f"{_task_name(task)}", field=key)
    try:
        json.dumps(task_options)
    except TypeError:
        raise InputError("task options must be JSON values", field="task_options") from None
    # a scenario loaded from a preset/file is passed as its validated config (picklable)
    spec = _Spec(scenario=sc.to_dict(), dists=dists, scenario_keys=tuple(scenario_keys),
                 root_seed=int(root_seed), task=task if isinstance(task, str) else fn,
                 task_options=dict(task_options))
    return sc, spec


def _manifest(sc, spec: _Spec, runs: int) -> dict:
    return {"scenario": spec.scenario, "scenario_source": sc.source, "runs": int(runs),
            "root_seed": spec.root_seed,
            "vary": {k: (d.text or f"{d.kind}{d.args}") for k, d in spec.dists.items()},
            "task": _task_name(spec.task), "task_options": spec.task_options}


def run_one(scenario, index: int, vary=None, root_seed: int = 0, task=DEFAULT_TASK,
            task_options: Mapping | None = None, filters: Sequence[str] | None = None) -> dict:
    """Run ``index`` of a campaign alone, in this process; returns its row (a dict)."""
    opts = dict(task_options or {})
    if filters is not None:
        opts["filters"] = list(filters)
    _, spec = _prepare(scenario, vary, root_seed, task, opts)
    return _execute(spec, int(index))


def run_campaign(scenario, runs: int, out_dir: str | pathlib.Path | None, vary=None, *,
                 root_seed: int = 0, executor: str = "local", scheduler: str | None = None,
                 workers: int | None = None, resume: bool = False, only: int | None = None,
                 filters: Sequence[str] | None = None, task=DEFAULT_TASK,
                 task_options: Mapping | None = None, chunk_size: int | None = None,
                 progress: bool = True, dask_retries: int = 3) -> CampaignResult:
    """Run a Monte Carlo campaign (see the module docstring).

    ``scenario``: preset name, YAML path, dict or ``Scenario``. ``runs``: number of runs N.
    ``out_dir``: where ``results.parquet`` goes (required unless ``only``). ``vary``:
    ``{KEY: DIST}`` or ``["KEY=DIST"]``. ``executor``: "local" | "dask" | "serial".
    ``workers``: processes (local) or LocalCluster workers (dask); default: CPU count.
    ``resume``: continue a campaign in ``out_dir`` (only missing indices run); without it an
    existing table in ``out_dir`` is an error. ``only``: run that single index alone (in this
    process; written to ``out_dir/only-INDEX.parquet`` when ``out_dir`` is given).
    ``filters``: filter names for the default task. Raises ``InputError`` for bad input
    before any run starts.
    """
    t_start = time.perf_counter()
    if not isinstance(runs, int | np.integer) or isinstance(runs, bool) or runs < 1:
        raise InputError(f"must be a positive integer, got {runs!r}", field="runs")
    if executor not in ("local", "dask", "serial"):
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
    import pandas as pd

    if only is not None:
        if not 0 <= int(only) < runs:
            raise InputError(f"must be in 0..{runs - 1}, got {only!r}", field="only")
        row = _execute(spec, int(only))
        df = _frame(pd, [row])
        path = None
        if out_dir is not None:
            out = pathlib.Path(out_dir)
            out.mkdir(parents=True, exist_ok=True)
            path = out / f"only-{int(only)}.parquet"
            df.to_parquet(path, index=False)
        return CampaignResult(df, path, 1, int(row["status"] != "ok"),
                              time.perf_counter() - t_start)
    if out_dir is None:
        raise InputError("an output directory is needed", field="out")
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    manifest = _manifest(sc, spec, runs)
    mpath = out / "campaign.json"
    if mpath.is_file():
        old = json.loads(mpath.read_text())
        if not resume:
            raise InputError("holds a campaign already; use resume or another directory",
                             field="out", file=str(out))
        diff = [k for k in manifest if json.dumps(old.get(k), sort_keys=True, default=str)
                != json.dumps(manifest[k], sort_keys=True, default=str)]
        if diff:
            raise InputError(f"resume with a different campaign description ({', '.join(diff)})",
                             field="out", file=str(out))
    else:
        tmp = out / "campaign.json.tmp"
        tmp.write_text(json.dumps(manifest, indent=1, default=str))
        os.replace(tmp, mpath)
    done = set(read_results(out)["index"].astype(int).tolist())
    pending = [i for i in range(runs) if i not in done]
    n_workers = int(workers) if workers else (os.cpu_count() or 1)

    def make_chunks(n_parallel: int) -> list[list[int]]:
        # about 8 chunks per worker (load balance) and at most 25 runs per chunk (what a
        # crash can lose); ``chunk_size`` fixes it
        size = chunk_size or max(1, min(25, len(pending) // (n_parallel * 8) or 1))
        return [pending[i:i + size] for i in range(0, len(pending), size)]
    ran = failed = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(pending), unit="run", desc=f"campaign {sc.name}",
                   dynamic_ncols=True)

    def finished(rows):
        nonlocal ran, failed
        _write_part(out, rows)
        ran += len(rows)
        failed += sum(r["status"] != "ok" for r in rows)
        if bar is not None:
            bar.set_postfix(done=ran, failed=failed, refresh=False)
            bar.update(len(rows))

    try:
        if pending:
            if executor == "serial":
                for c in make_chunks(1):
                    finished(_execute_chunk(spec, c))
            elif executor == "local":
                _run_local(spec, make_chunks(n_workers), n_workers, finished)
            else:
                _run_dask(spec, make_chunks, workers, scheduler, finished, dask_retries)
    finally:
        if bar is not None:
            bar.close()
        df = _consolidate(out)
    return CampaignResult(df, out / "results.parquet", ran, failed,
                          time.perf_counter() - t_start)


def _run_local(spec, chunks, n_workers, finished):
    import concurrent.futures as cf
    import multiprocessing as mp

    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    pool = cf.ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx)
    try:
        futs = [pool.submit(_execute_chunk, spec, c) for c in chunks]
        for f in cf.as_completed(futs):
            finished(f.result())
    except BaseException:
        # Ctrl-C / error: keep what is written, do not wait for the running chunks
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _run_dask(spec, make_chunks, workers, scheduler, finished, retries):
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("the dask executor needs 'dask[distributed]' (pip install "
                         "'gnomon[dask]')", field="executor") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=int(workers) if workers else (os.cpu_count() or 1),
                               threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=30)
        except OSError as err:
            raise InputError(f"cannot reach the Dask scheduler: {err}",
                             field="scheduler") from None
    try:
        n_parallel = max(1, sum(client.nthreads().values()))
        futs = [client.submit(_execute_chunk, spec, c, pure=False, retries=retries)
                for c in make_chunks(n_parallel)]
        try:
            for f in as_completed(futs):
                finished(f.result())
        except BaseException:
            client.cancel(futs)
            raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def campaign_cli(scenario: str, runs: int, out: str | None, vary: Sequence[str] = (),
                 executor: str = "local", scheduler: str | None = None,
                 workers: int | None = None, resume: bool = False, only: int | None = None,
                 root_seed: int = 0, filters: Sequence[str] | None = None,
                 progress: bool = True) -> dict:
    """What ``gnomon campaign`` does; returns a JSON-able summary (also for ``--json``).

    Summary keys: ``runs``, ``ran`` (this call), ``failed_now``, ``rows`` (in the table),
    ``failed_total``, ``elapsed_s``, ``runs_per_s``, ``path`` (results.parquet),
    ``metrics`` ({column: {mean, p95, max}} over the successful rows) and, with ``only``,
    ``row`` (that run's full row). The progress bar goes to stderr.
    """
    res = run_campaign(scenario, runs, out, list(vary), root_seed=root_seed, executor=executor,
                       scheduler=scheduler, workers=workers, resume=resume, only=only,
                       filters=filters, progress=progress)
    df = res.table
    summary = {"runs": int(runs), "ran": res.ran, "failed_now": res.failed,
               "rows": int(len(df)), "failed_total": int((df["status"] != "ok").sum()),
               "elapsed_s": round(res.elapsed_s, 3), "runs_per_s": round(res.runs_per_s, 3),
               "path": str(res.path) if res.path else None}
    metric_cols = [c for c in df.columns if c not in ("index", "seed", "status", "error",
                                                       "elapsed_s", "cpu_s")
                   and not c.startswith("param.") and df[c].dtype.kind == "f"]
    ok = df[df["status"] == "ok"]

    def num(x):
        x = float(x)
        return x if math.isfinite(x) else None      # strict JSON: NaN -> null

    summary["metrics"] = {c: {"mean": num(ok[c].mean()), "p95": num(ok[c].quantile(0.95)),
                              "max": num(ok[c].max())} for c in metric_cols if len(ok)}
    if only is not None:
        row = {}
        for k, v in df.iloc[0].to_dict().items():
            v = v.item() if hasattr(v, "item") else v
            row[k] = None if isinstance(v, float) and not math.isfinite(v) else v
        summary["row"] = row
    return summary
