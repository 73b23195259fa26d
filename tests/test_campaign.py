"""Campaign runner: distributions, seeds, crash + resume, failures, --only, Dask (incl. a killed
worker). Runs are tiny (a few hundred seconds of simulated flight)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd
import pytest

from gnomon.campaign import (
    CampaignResult,
    describe_run,
    draw_parameters,
    parse_distribution,
    read_manifest,
    read_results,
    run_campaign,
    run_one,
    run_seed,
    simulate_and_score,
)
from gnomon.campaign.store import rows_to_frame
from gnomon.campaign.task import resolve_task
from gnomon.errors import InputError

SRC = os.path.join(os.path.dirname(__file__), os.pardir, "src")
VARY = {"duration_s": "400", "sensors.magnetometer.noise_nT": "uniform(100, 500)",
        "spacecraft.inertia_error_pct": "uniform(0, 4)",
        "sensors.sun_sensor.noise_deg": "normal(0.3, 0.05)"}
FILTERS = ["mekf-spacecraft"]


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    timing = ("elapsed_s", "cpu_s")
    cols = [c for c in a.columns if c not in timing]
    assert sorted(cols) == sorted(c for c in b.columns if c not in timing)
    pd.testing.assert_frame_equal(a[cols].reset_index(drop=True), b[cols].reset_index(drop=True),
                                  check_exact=True)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted campaign in this process (serial executor): the table to match."""
    out = tmp_path_factory.mktemp("ref")
    res = run_campaign("seed001", 12, out, VARY, root_seed=7, executor="serial",
                       filters=FILTERS, progress=False)
    return res.table


def test_distributions_parse_and_reject():
    rng = np.random.default_rng(1)
    assert parse_distribution("normal(0,2)").kind == "normal"
    x = [parse_distribution("uniform(2, 3)").draw(rng) for _ in range(200)]
    assert 2.0 <= min(x) and max(x) <= 3.0
    assert parse_distribution("choice(tilt, scale)").draw(rng) in ("tilt", "scale")
    assert parse_distribution("4.5").draw(rng) == 4.5
    assert parse_distribution("[1, 2, 3.5]").draw(rng) == [1.0, 2.0, 3.5]
    for bad in ("normal(0,-1)", "uniform(3,1)", "normal(1)", "gamma(1,2)", "loguniform(0,1)",
                "choice()"):
        with pytest.raises(InputError, match="k"):
            parse_distribution(bad, key="k")


def test_bad_keys_and_values_fail_before_any_run(tmp_path):
    with pytest.raises(InputError, match="spacecraft.inertia_eror_pct"):
        run_campaign("seed001", 3, tmp_path, {"spacecraft.inertia_eror_pct": "normal(0,1)"},
                     progress=False)
    with pytest.raises(InputError, match="environment.field_error.kind"):
        run_campaign("seed001", 3, tmp_path, {"environment.field_error.kind": "choice(tilt,x)"},
                     progress=False)
    with pytest.raises(InputError, match="sigma_magg"):
        run_campaign("seed001", 3, tmp_path, {"filter.mekf-spacecraft.sigma_magg": "1"},
                     progress=False)
    assert not any(tmp_path.iterdir())          # nothing was written: no run started


def test_seeds_are_the_spawned_sequences():
    kids = np.random.SeedSequence(11).spawn(5)
    for i, k in enumerate(kids):
        assert run_seed(11, i) == int(k.generate_state(1, np.uint64)[0])
    d = {"a": parse_distribution("normal(0,1)"), "b": parse_distribution("uniform(0,1)")}
    assert draw_parameters(11, 3, d) == draw_parameters(11, 3, d)
    assert draw_parameters(11, 3, d) != draw_parameters(11, 4, d)
    run = describe_run(11, 3, d)
    assert (run.index, run.seed, run.params) == (3, run_seed(11, 3), draw_parameters(11, 3, d))


def _task_fn(scenario, params, seed):
    return {"x": 1.0}


def test_a_task_is_a_task_object_a_function_or_its_name():
    assert resolve_task("gnomon.campaign:simulate_and_score") is simulate_and_score
    assert simulate_and_score.name == "gnomon.campaign:simulate_and_score"
    assert simulate_and_score.batch is not None
    assert simulate_and_score.accepts("filter.mahony.kp_acc_rad_s")
    t = resolve_task(_task_fn)
    assert t.batch is None and not t.accepts("anything") and t.name.endswith(":_task_fn")
    assert resolve_task(t) is t
    for bad in ("nosuchmodule:task", "gnomon.campaign", 3):
        with pytest.raises(InputError, match="task"):
            resolve_task(bad)

    def old_style(scenario, params, seed):    # the former way: attributes on a function
        return {}

    old_style.batch = lambda *a, **k: []
    with pytest.raises(InputError, match="Task"):
        resolve_task(old_style)


@pytest.mark.slow(reason="29 s (2 cores): long runs or a first compilation")
def test_summary_is_the_json_contract(tmp_path, reference):
    res = CampaignResult(reference, tmp_path / "results.parquet", 12, 0, 2.0, 12)
    d = res.summary().to_dict()
    assert list(d) == ["runs", "ran", "failed_now", "rows", "failed_total", "elapsed_s",
                       "runs_per_s", "path", "metrics"]
    assert (d["runs"], d["rows"], d["runs_per_s"]) == (12, 12, 6.0)
    col = "mekf-spacecraft.rms_deg"
    assert d["metrics"][col] == {"mean": reference[col].mean(),
                                 "p95": reference[col].quantile(0.95),
                                 "max": reference[col].max()}
    assert not any(c.startswith("param.") or c in ("seed", "cpu_s") for c in d["metrics"])
    one = CampaignResult(reference.iloc[[4]], None, 1, 0, 0.0, 12, 4).summary().to_dict()
    assert one["row"]["index"] == 4 and one["path"] is None and one["runs_per_s"] is None


def test_run_one_and_the_manifest(tmp_path, reference):
    row = run_one("seed001", 5, VARY, root_seed=7, filters=FILTERS)
    _same(rows_to_frame([row]), reference[reference["index"] == 5])
    with pytest.raises(InputError, match="no campaign"):
        read_manifest(tmp_path)


@pytest.mark.slow(reason="21 s (2 cores): runs a Monte Carlo campaign")
def test_sigkill_then_resume_gives_the_uninterrupted_table(tmp_path, reference):
    out = tmp_path / "c"
    script = textwrap.dedent(f"""
        from gnomon.campaign import run_campaign
        run_campaign("seed001", 12, {str(out)!r}, {VARY!r}, root_seed=7, executor="local",
                     workers=2, chunk_size=1, filters={FILTERS!r}, progress=False)
    """)
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, start_new_session=True)
    parts = out / "parts"
    deadline = time.time() + 60
    while time.time() < deadline:
        n = len(list(parts.glob("part-*.parquet"))) if parts.is_dir() else 0
        if n >= 3 or proc.poll() is not None:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the campaign finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)          # the campaign and its worker processes
    proc.wait()
    partial = read_results(out)
    assert 3 <= len(partial) < 12
    with pytest.raises(InputError, match="resume"):
        run_campaign("seed001", 12, out, VARY, root_seed=7, filters=FILTERS, progress=False)
    res = run_campaign("seed001", 12, out, VARY, root_seed=7, executor="local", workers=2,
                       filters=FILTERS, resume=True, progress=False)
    assert res.ran == 12 - len(partial)
    table = pd.read_parquet(out / "results.parquet")
    assert table["index"].tolist() == list(range(12))      # every run exactly once
    _same(table, reference)
    # a resume of a complete campaign runs nothing; a different description is refused
    assert run_campaign("seed001", 12, out, VARY, root_seed=7, filters=FILTERS, resume=True,
                        progress=False).ran == 0
    with pytest.raises(InputError, match="root_seed"):
        run_campaign("seed001", 12, out, VARY, root_seed=8, filters=FILTERS, resume=True,
                     progress=False)
    m = read_manifest(out)
    assert (m["runs"], m["root_seed"], m["task"]) == (12, 7, "gnomon.campaign:simulate_and_score")
    assert m["vary"] == VARY and m["task_options"] == {"filters": FILTERS}


def test_failing_runs_are_recorded_and_the_rest_finish(tmp_path):
    vary = {"duration_s": "400", "filter.mekf-spacecraft.sigma0_att_rad": "choice(0.05, -1.0)"}
    res = run_campaign("seed001", 8, tmp_path, vary, root_seed=3, executor="local", workers=2,
                       filters=FILTERS, progress=False)
    t = res.table
    bad = t["param.filter.mekf-spacecraft.sigma0_att_rad"] < 0
    assert 0 < bad.sum() < 8
    assert (t.loc[bad, "status"] == "failed").all()
    assert t.loc[bad, "error"].str.contains("sigma0_att_rad").all()
    assert (t.loc[~bad, "status"] == "ok").all()
    assert t.loc[~bad, "mekf-spacecraft.rms_deg"].between(0.0, 2.0).all()
    assert res.failed == bad.sum()


def test_only_reproduces_one_run(tmp_path, reference):
    for i in (0, 9):
        res = run_campaign("seed001", 12, tmp_path, VARY, root_seed=7, only=i,
                           filters=FILTERS, progress=False)
        _same(res.table, reference[reference["index"] == i])


@pytest.mark.slow(reason="4 s (2 cores): runs a Monte Carlo campaign")
def test_dask_executor_with_a_worker_killed(tmp_path, reference):
    distributed = pytest.importorskip("distributed")
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        import threading

        box = {}
        out = tmp_path / "d"

        def go():
            box["res"] = run_campaign("seed001", 12, out, VARY, root_seed=7, executor="dask",
                                      scheduler=cluster.scheduler_address, chunk_size=1,
                                      filters=FILTERS, progress=False)

        th = threading.Thread(target=go)
        th.start()
        parts = out / "parts"
        deadline = time.time() + 60
        while time.time() < deadline and th.is_alive():
            if parts.is_dir() and len(list(parts.glob("part-*.parquet"))) >= 2:
                break
            time.sleep(0.01)
        killed = False
        if th.is_alive():
            pids = client.run(os.getpid)
            os.kill(next(iter(pids.values())), signal.SIGKILL)   # one worker dies mid-campaign
            killed = True
        th.join(120)
        assert not th.is_alive()
    assert killed, "the campaign finished before a worker could be killed"
    table = box["res"].table
    assert table["index"].tolist() == list(range(12))
    _same(table, reference)
    del distributed


def test_ctrl_c_keeps_finished_runs(tmp_path):
    out = tmp_path / "i"
    script = textwrap.dedent(f"""
        import signal
        signal.signal(signal.SIGINT, signal.default_int_handler)
        from gnomon.campaign import run_campaign
        run_campaign("seed001", 40, {str(out)!r}, {{"duration_s": "2000"}}, executor="local",
                     workers=2, chunk_size=1, filters={FILTERS!r}, progress=False)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], env={**os.environ, "PYTHONPATH": SRC},
                            stderr=subprocess.DEVNULL)
    parts = out / "parts"
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        if parts.is_dir() and len(list(parts.glob("part-*.parquet"))) >= 2:
            break
        time.sleep(0.02)
    assert proc.poll() is None
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(30) != 0
    table = pd.read_parquet(out / "results.parquet")       # consolidated on the way out
    assert 2 <= len(table) < 40 and table["index"].is_unique
    assert not list(parts.glob("part-*"))
