"""Runs that share a filter share one batch-over-runs kernel call (campaign chunks)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import synthetic_imu

import gnomon.estimators.mahony as mahony_mod
import gnomon.scenarios as scenarios_mod
from gnomon.campaign import Task, run_campaign, simulate_and_score, simulate_and_score_batch
from gnomon.estimators.mahony import Mahony, MahonyParams
from gnomon.rotation import quat_from_euler


def _imu_run(seed):
    """An IMU recording whose noise and motion depend on the seed (shared time stamps)."""
    rng = np.random.default_rng(seed)
    return synthetic_imu(quat_from_euler(rng.uniform(-1, 1, 3)), rng.uniform(-0.5, 0.5, 3),
                         n=1500, noise=0.01, seed=seed)


@pytest.fixture
def batch_calls(monkeypatch):
    calls = []
    real = mahony_mod.run_batch

    def spy(t, gyro, *args, **kwargs):
        calls.append(gyro.shape[0])
        return real(t, gyro, *args, **kwargs)

    monkeypatch.setattr(mahony_mod, "run_batch", spy)
    return calls


@pytest.mark.slow(reason="11 s (2 cores): long runs or a first compilation")
def test_run_many_equals_runs_one_by_one(batch_calls):
    recs = [_imu_run(s) for s in range(5)]
    p = MahonyParams(kp_acc_rad_s=0.9, ki_rad_s2=0.02)
    qs = Mahony.run_many(recs, p)
    assert batch_calls == [5]
    for rec, q in zip(recs, qs, strict=True):
        np.testing.assert_allclose(q, Mahony(p).run(rec).q, atol=1e-12)


def test_simulate_and_score_batch_groups_runs_by_filter_parameters(monkeypatch, batch_calls):
    def fake_simulate(scenario, rng_seed=None):
        if rng_seed == 13:
            raise RuntimeError("simulation failed for this seed")
        return _imu_run(rng_seed)

    monkeypatch.setattr(scenarios_mod, "simulate", fake_simulate)
    seeds = [1, 2, 13, 4, 5]
    params = [{}, {}, {}, {"filter.mahony.kp_acc_rad_s": 2.0}, {}]
    res = simulate_and_score_batch([None] * 5, params, seeds, filters=["mahony"], settle_s=1.0)
    assert batch_calls == [3]  # runs 1, 2, 5 share the default parameters; 4 runs alone
    assert isinstance(res[2], RuntimeError)
    for k in (0, 1, 3, 4):
        alone = simulate_and_score(None, params[k], seeds[k], filters=["mahony"], settle_s=1.0)
        assert res[k].keys() == alone.keys()
        for key, value in alone.items():
            assert res[k][key] == pytest.approx(value, rel=1e-9, abs=1e-12)
    with pytest.raises(RuntimeError, match="this seed"):
        simulate_and_score(None, {}, 13, filters=["mahony"])


def _imu_task(scenario, params, seed, settle_s=1.0):
    q = Mahony().run(_imu_run(seed)).q
    return {"q_end_w": float(q[-1, 0])}


def _imu_task_batch(scenarios, params_list, seeds, settle_s=1.0):
    qs = Mahony.run_many([_imu_run(s) for s in seeds])
    return [{"q_end_w": float(q[-1, 0])} for q in qs]


def _broken_batch(scenarios, params_list, seeds, settle_s=1.0):
    raise RuntimeError("batch form broken")


def test_campaign_chunks_use_the_batch_form_and_fall_back(tmp_path, batch_calls):
    res = run_campaign("seed001", 6, tmp_path / "a", root_seed=2, executor="serial",
                       task=Task(_imu_task, batch=_imu_task_batch), chunk_size=3,
                       progress=False)
    assert batch_calls == [3, 3]
    t = res.table.sort_values("index")
    assert (t["status"] == "ok").all()
    alone = [_imu_task(None, {}, s)["q_end_w"] for s in t["seed"]]
    np.testing.assert_allclose(t["q_end_w"], alone, atol=1e-12)
    # a batch form that raises: each run alone
    res = run_campaign("seed001", 6, tmp_path / "b", root_seed=2, executor="serial",
                       task=Task(_imu_task, batch=_broken_batch), chunk_size=3,
                       progress=False)
    assert (res.table["status"] == "ok").all()
    np.testing.assert_allclose(res.table.sort_values("index")["q_end_w"], alone, atol=1e-12)


def test_imu_campaign_runs_share_the_batch_kernel(tmp_path, batch_calls):
    """``gnomon campaign imu-handheld --filter mahony``: chunks of runs in one kernel call,
    each run scored as it would be alone."""
    vary = {"duration_s": "20", "imu.gyro_bias_std_rad_s": "uniform(0.0, 0.02)"}
    res = run_campaign("imu-handheld", 6, tmp_path, vary, root_seed=5, executor="serial",
                       filters=["mahony"], chunk_size=3, progress=False)
    assert batch_calls == [3, 3]
    t = res.table.sort_values("index").reset_index(drop=True)
    assert (t["status"] == "ok").all()
    # a sanity bound: with a gyro bias of up to 0.02 rad/s (1.1 deg/s) per axis, Mahony's
    # default integral gain leaves a few degrees over 20 s (about 5 at 0.018 rad/s)
    assert t["mahony.rms_deg"].between(0.0, 10.0).all()
    # heading and inclination parts of the same error (BROAD's split): each below the total
    assert (t["mahony.inclination_rms_deg"] <= t["mahony.rms_deg"] + 1e-9).all()
    assert (t["mahony.heading_rms_deg"] <= t["mahony.rms_deg"] + 1e-9).all()
    for i in (0, 4):
        alone = run_campaign("imu-handheld", 6, None, vary, root_seed=5, only=i,
                             filters=["mahony"], progress=False).table
        assert alone["mahony.rms_deg"].iloc[0] == pytest.approx(t["mahony.rms_deg"][i],
                                                                rel=1e-9)


@pytest.mark.slow(reason="3 s (2 cores): runs a Monte Carlo campaign")
def test_tilt_only_filters_are_judged_by_inclination(tmp_path):
    res = run_campaign("imu-handheld", 2, tmp_path, {"duration_s": "30"}, root_seed=1,
                       executor="serial", filters=["tilt-cf", "mahony"], progress=False)
    t = res.table
    assert (t["tilt-cf.rms_deg"] > 30.0).all()  # its heading is free
    # the heading's drift dominates its total; the inclination is held by gravity
    assert (t["tilt-cf.inclination_rms_deg"] < 0.5 * t["tilt-cf.rms_deg"]).all()
    assert (t["tilt-cf.inclination_rms_deg"] < 10.0).all()
