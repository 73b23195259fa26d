"""The spacecraft simulator's truth, computed once per orbit / spacecraft and shared by
the runs (gnomon.scenarios.simulator.truth_of), and the batched campaign simulation."""

from __future__ import annotations

import numpy as np

from gnomon.scenarios import load_scenario, simulate_many
from gnomon.scenarios import simulator as S


def _short(**over):
    return load_scenario("seed001").replace({"duration_s": 600.0, **over})


def test_samples_as_before_the_truth_was_shared():
    """Values of the simulator before the cache (commit 7e7a193), to the last digits."""
    S._TRUTHS.clear()
    sc = _short(**{"environment.field_error.kind": "tilt",
                   "environment.field_error.level_pct": 5.0})
    for _ in range(2):                       # computed, then from the cache
        r = S.simulate(sc, rng_seed=3)
        np.testing.assert_allclose(r.gyro[[10, 599]], [
            [2.2136933514858904e-03, -2.3574138269745319e-03, 2.2345901125651346e-03],
            [-3.8205733309649898e-06, -1.2049920583572474e-03, 5.9139098238232887e-05]],
            rtol=1e-13, atol=0)
        np.testing.assert_allclose(r.mag[300], [25774.421547720613, 2449.0967912883193,
                                                8325.075467597086], rtol=1e-13)
        np.testing.assert_allclose(r.q_true[600], [0.9999193510990729, 0.01134263056260232,
                                                   0.0052028048264979, -0.0023594176118073],
                                   rtol=1e-13)
        np.testing.assert_allclose(r.extra["b_o_model_nT"][450], [
            24068.965093085884, 3835.231980968225, 18009.334331997885], rtol=1e-13)
        np.testing.assert_allclose(r.sun[100], [-0.1775111396198879, 0.3282627049340301,
                                                -0.9277571836748247], rtol=1e-13)
    assert len(S._TRUTHS) == 1


def test_truth_shared_by_seeds_and_model_errors_not_by_dynamics():
    S._TRUTHS.clear()
    a = S.simulate(_short(), rng_seed=1)
    b = S.simulate(_short(**{"spacecraft.inertia_error_pct": 5.0,
                             "environment.field_error.kind": "scale",
                             "environment.field_error.level_pct": 2.0}), rng_seed=2)
    assert len(S._TRUTHS) == 1
    np.testing.assert_array_equal(a.q_true, b.q_true)
    assert not np.array_equal(a.gyro, b.gyro)
    assert not np.array_equal(a.extra["inertia_model_kg_m2"], b.extra["inertia_model_kg_m2"])
    c = S.simulate(_short(**{"initial.rate_ob_deg_s": [0.1, 0.0, 0.0]}), rng_seed=1)
    assert len(S._TRUTHS) == 2
    assert not np.array_equal(a.q_true, c.q_true)


def test_recordings_own_their_arrays():
    """A recording changed in place changes neither the cache nor the next recording."""
    S._TRUTHS.clear()
    sc = _short()
    a = S.simulate(sc, rng_seed=1)
    ref = {k: v.copy() for k, v in a.extra.items()}
    q = a.q_true.copy()
    for v in (*a.extra.values(), a.q_true, a.t):
        assert v.flags.writeable
        v[...] = 0
    b = S.simulate(sc, rng_seed=1)
    np.testing.assert_array_equal(b.q_true, q)
    for k, v in ref.items():
        np.testing.assert_array_equal(b.extra[k], v)
    for v in vars(S.truth_of(sc.config)).values():
        if isinstance(v, np.ndarray):
            assert not v.flags.writeable


def test_simulate_many_equals_simulate():
    """IMU runs of one scenario in one batch, spacecraft runs one by one: each the run
    ``simulate`` gives; a failing run is its exception, the others go on."""
    imu = load_scenario("imu-handheld").replace({"duration_s": 5.0})
    imu2 = imu.replace({"imu.gyro_noise_rad_s_rt_hz": 1e-3})
    sc = _short()
    scenarios = [imu, sc, imu2, imu, imu]
    seeds = [4, 5, 6, None, 2**63 + 7]
    out = simulate_many(scenarios, seeds)
    for k, (scn, seed) in enumerate(zip(scenarios, seeds, strict=True)):
        one = S.simulate(scn, rng_seed=seed)
        np.testing.assert_array_equal(out[k].gyro, one.gyro)
        np.testing.assert_array_equal(out[k].q_true, one.q_true)
        np.testing.assert_array_equal(out[k].mag, one.mag)
    bad = simulate_many([sc, "no-such-scenario"], [1, 2])
    assert isinstance(bad[1], Exception) and bad[0].gyro.shape == (601, 3)


def test_score_runs_equals_the_metrics():
    """Batched scoring = score_run + score_run_budget on IMU and spacecraft runs (with a
    sun sensor's sunlit / eclipse phases), the same keys and the same numbers to 1e-12
    (measured: 1.6e-15 of their size; the compiled sums run in another order than
    numpy's); recordings that do not fit (a NaN, other time stamps) go to the metrics
    functions themselves."""
    from gnomon.campaign.scoring import score_runs
    from gnomon.estimators.mahony import Mahony
    from gnomon.metrics import score_run, score_run_budget

    imu = load_scenario("imu-handheld").replace({"duration_s": 20.0})
    recs = simulate_many([imu] * 4, [1, 2, 3, 4])
    qs = Mahony.run_many(recs, Mahony.Params())
    qs[2] = -qs[2]                                  # the sign of q does not matter
    sc = S.simulate(_short(), rng_seed=1)
    cases = [(recs, qs, 3.0), (recs[:3], qs[:3], 0.0), (recs, qs, 25.0),
             ([recs[0], sc], [qs[0], sc.q_true], 1.0)]
    bad = qs[1].copy()
    bad[5] = np.nan
    cases.append((recs[:2], [qs[0], bad], 1.0))
    # a sun sensor: the sunlit and eclipse phases on the compiled path too (an orbit with
    # both, and a short sunlit one whose eclipse phase is empty: NaN), one run alone too
    from gnomon.rotation import quat_from_rotvec, quat_mul
    rng = np.random.default_rng(7)
    orbit = simulate_many([load_scenario("seed001").replace({"duration_s": 4000.0})] * 2,
                          [1, 2])
    assert orbit[0].sun_valid.any() and not orbit[0].sun_valid.all()
    off = [quat_mul(r.q_true, quat_from_rotvec(rng.normal(0, 0.01, (len(r), 3))))
           for r in orbit]
    cases += [(orbit, off, 300.0), ([orbit[1]], [off[1]], 0.0),
              ([sc], [quat_mul(sc.q_true, quat_from_rotvec(np.full((len(sc), 3), 0.02)))],
               10.0)]
    for rs, q, settle in cases:
        got = score_runs(rs, q, settle)
        for r, qq, row in zip(rs, q, got, strict=True):
            want = {**score_run(r, qq, settle), **score_run_budget(r, qq, settle)}
            assert list(row) == list(want)
            np.testing.assert_allclose(np.array(list(row.values())),
                                       np.array(list(want.values())), rtol=1e-12, atol=0)
