"""The one spacecraft MEKF (``mekf``) and its presets: the kernel against its readable
twin, the presets against the two filters they replaced, the magnetometer bias, the gyro
scale factors and the star tracker on closed-form truths, bad input and the contract."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.estimators.ecf_spacecraft import vector_pairs
from gnomon.estimators.mekf import (
    FLAG_NAMES,
    MEKF,
    star_tracker_inputs,
)
from gnomon.metrics import error_angle_rad
from gnomon.recording import Recording
from gnomon.rotation import (
    quat_conj,
    quat_from_euler,
    quat_from_rotvec,
    quat_mul,
    quat_rotate,
    rotvec_from_quat,
)
from gnomon.scenarios import load_scenario, simulate

N_ORBIT = 2 * np.pi / 5800.0  # mean motion, rad/s
ARCSEC = np.radians(1.0 / 3600.0)
REFERENCE = Path(__file__).parent / "data" / "mekf_presets_before_merge.npz"


def _attitude(t, w_ob_b, swing_deg):
    """``q_ob(t) = q0 ⊗ exp(w_ob_b t) ⊗ exp(x φ1) ⊗ exp(y φ2) ⊗ exp(z φ3)``, ``φi = swing_deg[i]
    sin(2π t / (300 + 100 i))``, and its body rate ``ω_ob_b`` (closed form: each factor
    turns about a fixed axis of its own frame)."""
    q0 = quat_from_euler(np.radians([5.0, -3.0, 8.0]))
    w_ob_b = np.asarray(w_ob_b, float)
    amp = np.radians(np.asarray(swing_deg, float))
    per = 2 * np.pi / (300.0 + 100.0 * np.arange(3))
    phi = amp * np.sin(t[:, None] * per)
    dphi = amp * per * np.cos(t[:, None] * per)
    e = np.eye(3)
    f = [quat_from_rotvec(phi[:, i:i + 1] * e[i]) for i in range(3)]
    q = quat_mul(quat_mul(q0, quat_from_rotvec(t[:, None] * w_ob_b)),
                 quat_mul(f[0], quat_mul(f[1], f[2])))
    tail = quat_mul(f[1], f[2])
    w = (quat_rotate(quat_conj(quat_mul(f[0], tail)), w_ob_b)
         + quat_rotate(quat_conj(tail), dphi[:, 0:1] * e[0])
         + quat_rotate(quat_conj(f[2]), dphi[:, 1:2] * e[1]) + dphi[:, 2:3] * e[2])
    return q, w


def _q_io(t):
    """The orbital frame turning at ``[0, −n, 0]`` from the inertial one."""
    return quat_from_rotvec(t[:, None] * np.array([0.0, -N_ORBIT, 0.0]))


def spacecraft(n=3000, dt=1.0, w_ob_b=(0.001, -0.0005, 0.0008), swing_deg=(0, 0, 0),
               bias=(0, 0, 0), scale=(0, 0, 0), mag_bias=(0, 0, 0), mag_noise=0.0,
               st_noise_rad=0.0, st_every=0, st_latency=0.0, seed=0):
    """Closed-form truth (``_attitude``), the orbital frame turning at ``[0, −n, 0]``, the
    field turning at 2n in the orbit plane, the sun along the orbit normal. The gyro
    measures ``(I + diag(scale)) ω_ib + bias``; the magnetometer ``R_bo B_o + mag_bias +
    noise`` (nT); with ``st_every`` a star tracker every that many samples,
    ``q̂_ib(t − st_latency) ⊗ exp(noise)``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    q, w_ob = _attitude(t, w_ob_b, swing_deg)
    w_io_o = np.tile([0.0, -N_ORBIT, 0.0], (n, 1))
    q_bo = quat_conj(q)
    w_ib = w_ob + quat_rotate(q_bo, w_io_o)
    b_o = 3e4 * np.stack([np.cos(2 * N_ORBIT * t), 0.3 + 0 * t, np.sin(2 * N_ORBIT * t)], 1)
    s_o = np.tile([0.0, -1.0, 0.0], (n, 1))
    mag = quat_rotate(q_bo, b_o) + np.asarray(mag_bias, float) + rng.normal(0, mag_noise, (n, 3))
    gyro = (1.0 + np.asarray(scale, float)) * w_ib + np.asarray(bias, float)
    extra = {"b_o_nT": b_o, "s_o": s_o, "w_io_o": w_io_o, "q_io": _q_io(t)}
    if st_every:
        tl = t - st_latency
        st = quat_mul(quat_mul(_q_io(tl), _attitude(tl, w_ob_b, swing_deg)[0]),
                      quat_from_rotvec(rng.normal(0, st_noise_rad, (n, 3))))
        valid = (np.arange(n) % st_every == 0) & (tl >= 0)
        st[~valid] = np.nan
        extra.update(st_q_ib=st, st_valid=valid, st_boresight_b=np.tile([0.0, 0.0, 1.0], (n, 1)))
    return Recording(t=t, gyro=gyro, mag=mag, mag_unit="nT", sun=quat_rotate(q_bo, s_o),
                     sun_valid=np.ones(n, bool), q_true=q, frames={"reference": "o", "body": "b"},
                     source="synthetic", extra=extra)


def _messy(rec):
    """Sun gaps, a zero and a non-finite vector, a time gap."""
    valid = rec.sun_valid.copy()
    valid[200:260] = False
    sun, mag, t = rec.sun.copy(), rec.mag.copy(), rec.t.copy()
    sun[210] = np.nan
    sun[300] = 0.0
    mag[400] = 0.0
    t[500:] += 30.0  # a 31 s gap
    return dataclasses.replace(rec, t=t, sun=sun, sun_valid=valid, mag=mag)


def _twin(f, rec, q0):
    """The readable ``step`` of a fresh copy of ``f`` over the kernel's inputs (the second
    pairs of ``vector_pairs``), sample by sample:
    ``(q (N, 4), bias, mag bias, flags (N, 5), the twin)``."""
    p = f.params
    g = type(f)(p)
    g.reset(q0)
    pairs = vector_pairs(rec, p.sun_substitute, p.delay_samples, p.orbital_rate_rad_s)
    st = star_tracker_inputs(rec, p.use_star_tracker)
    n = len(rec)
    q, b, m, flags = np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 5), bool)
    m_ = p.delay_samples  # the delayed pair's swing: since the twin's estimate M samples ago
    for i in range(n):
        st_q = st["st_q"][i] if st["st_valid"][i] else None
        q[i] = g.step(pairs["dt"][i], pairs["gyro"][i], pairs["w_io_o"][i], pairs["mag_b"][i],
                      pairs["mag_o"][i], pairs["sec_b"][i], pairs["sec_o"][i],
                      pairs["sec_valid"][i] and p.use_sun, pairs["substituted"][i], st_q,
                      st["st_bore"][i], q_old=q[i - m_] if i >= m_ else None)
        b[i], m[i] = g.bias, g.mag_bias
        flags[i] = [g.flags[k] for k in FLAG_NAMES]
    return q, b, m, flags, g


@pytest.mark.parametrize("preset, params", [
    ("mekf", {}),
    ("mekf-delayed", {"delay_samples": 100}),
    ("mekf-spacecraft", {}),
    ("mekf", {"estimate_mag_bias": True, "estimate_gyro_scale": True, "relinearise": True,
              "transition": "first-order", "gyro_sample": "current"}),
    ("mekf", {"estimate_mag_bias": True, "st_latency_s": 2.0}),
])
def test_kernel_equals_readable_twin_sample_by_sample(preset, params):
    """Every output of ``run`` (the compiled kernel) against the numpy ``step`` after every
    sample, on messy input, in each form, with the optional states and the star tracker."""
    rec = _messy(spacecraft(n=700, bias=(1e-4, -2e-4, 5e-5), scale=(0.002, -0.001, 0.003),
                            mag_bias=(150.0, -100.0, 80.0), mag_noise=100.0,
                            st_noise_rad=20 * ARCSEC, st_every=5, st_latency=2.0))
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(np.radians([3.0, -2.0, 4.0])))
    f = registry.create(preset, params)
    est = f.run(rec, q0=q0)
    q, b, m, flags, g = _twin(f, rec, q0)
    np.testing.assert_allclose(est.q, q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(est.signals["bias_rad_s"], b, rtol=0, atol=1e-13)
    if f.params.estimate_mag_bias:
        np.testing.assert_allclose(est.signals["mag_bias_nT"], m, rtol=0, atol=1e-6)
    for i, name in enumerate(FLAG_NAMES):
        np.testing.assert_array_equal(est.signals[name], flags[:, i], err_msg=name)
    np.testing.assert_allclose(f.P, g.P, rtol=1e-7, atol=1e-20)
    assert np.all(np.isfinite(est.q))
    assert est.signals["gap"][500] and est.signals["coast"][500]
    assert est.signals["mag_unusable"][400]


@pytest.mark.parametrize("case, preset", [("seed000", "mekf-delayed"),
                                          ("seed001", "mekf-spacecraft")])
def test_presets_give_the_results_of_the_filters_they_replaced(case, preset):
    """``mekf-delayed`` and ``mekf-spacecraft`` against the outputs of the two MEKFs before
    the merge (``tests/data/make_mekf_presets_reference.py``), to rounding."""
    changes = {"seed000": {"duration_s": 4000.0},
               "seed001": {"duration_s": 2000.0, "environment.field_error.kind": "tilt",
                           "environment.field_error.level_pct": 10.0}}[case]
    ref = np.load(REFERENCE)
    est = registry.create(preset).run(simulate(load_scenario(case).replace(changes)))
    np.testing.assert_allclose(est.q[::4], ref[f"{case}_q"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(est.signals["bias_rad_s"][::4], ref[f"{case}_bias"], rtol=0,
                               atol=1e-15)


def test_former_parameter_names_of_mekf_spacecraft_name_the_new_ones():
    for old, new in (("sigma_mag", "sigma_mag_rad"), ("p0_att_rad", "sigma0_att_rad"),
                     ("gyro_rrw_rad_s_rt_s", "bias_rw_rad_s_rt_s")):
        with pytest.raises(InputError, match=new):
            registry.create("mekf-spacecraft", {old: 0.01})
    for name in ("gyro_sample", "transition", "correction", "sun_substitute"):
        with pytest.raises(InputError, match=name):
            MEKF(**{name: "nope"})
    assert registry.create("mekf", {"estimate_mag_bias": "true"}).params.estimate_mag_bias


def test_magnetometer_bias_is_estimated_and_the_attitude_kept():
    """A 400 nT bias: without its states the attitude errs by about the bias's angle
    (|b⊥| / |B| ≈ 0.7°); with them the bias is found to a few nT and the error is that of
    the bias-free case (noiseless: closed form, the truth known)."""
    bias = np.array([300.0, -200.0, 150.0])
    rec = spacecraft(n=6000, bias=np.radians([0.01, -0.01, 0.005]), mag_bias=bias)
    free = spacecraft(n=6000, bias=np.radians([0.01, -0.01, 0.005]))
    p = {"sigma_mag_rad": 0.01, "sigma_sun_rad": 0.005}
    late = slice(3000, None)
    e_free = np.degrees(error_angle_rad(free.q_true, MEKF(**p).run(free).q))[late]
    e_blind = np.degrees(error_angle_rad(rec.q_true, MEKF(**p).run(rec).q))[late]
    est = MEKF(estimate_mag_bias=True, **p).run(rec)
    e_est = np.degrees(error_angle_rad(rec.q_true, est.q))[late]
    assert e_blind.mean() > 0.2
    assert np.max(np.abs(est.signals["mag_bias_nT"][-1] - bias)) < 5.0
    assert np.sqrt(np.mean(e_est ** 2)) < 1.3 * np.sqrt(np.mean(e_free ** 2)) + 0.01


def test_gyro_scale_factors_are_estimated():
    """A satellite swinging by ±20° about each axis (rates up to ~0.4°/s) with 1 % scale
    errors: the scale states find them (they are told from a bias by the changing rate)."""
    scale = np.array([0.01, -0.008, 0.006])
    rec = spacecraft(n=4000, swing_deg=(20.0, 20.0, 20.0), scale=scale,
                     bias=np.radians([0.01, -0.01, 0.005]), st_every=1, st_noise_rad=10 * ARCSEC)
    est = MEKF(estimate_gyro_scale=True, sigma0_gyro_scale=0.02).run(rec)
    assert np.max(np.abs(est.signals["gyro_scale"][-1] - scale)) < 2e-4
    plain = MEKF().run(rec)
    e_s = np.degrees(error_angle_rad(rec.q_true, est.q))[2000:] * 3600
    e_p = np.degrees(error_angle_rad(rec.q_true, plain.q))[2000:] * 3600
    # the residual ~17″ is the held gyro sample over a swinging motion (not the scale)
    assert np.sqrt(np.mean(e_s ** 2)) < 0.95 * np.sqrt(np.mean(e_p ** 2))


def test_star_tracker_latency_is_carried_over_by_the_gyro():
    """A noiseless tracker 2 s late on a satellite turning at ~0.07°/s: the error is the
    motion over the latency (~500″) unless the filter knows the latency; then ~0."""
    rec = spacecraft(n=600, st_every=1, st_latency=2.0)
    late = slice(300, None)
    e0 = np.degrees(error_angle_rad(rec.q_true, MEKF().run(rec).q))[late] * 3600
    e2 = np.degrees(error_angle_rad(rec.q_true, MEKF(st_latency_s=2.0).run(rec).q))[late] * 3600
    assert e0.mean() > 200
    assert e2.max() < 2.0


def test_star_tracker_outlier_is_gated_and_flagged():
    """A tracker attitude 2° off (a wrong star match) is rejected (flag ``star_unused``)
    and leaves no mark on the estimate."""
    rec = spacecraft(n=400, st_every=2, st_noise_rad=10 * ARCSEC, seed=3)
    st = rec.extra["st_q_ib"].copy()
    st[300] = quat_mul(st[300], quat_from_rotvec(np.radians([2.0, 0.0, 0.0])))
    bad = dataclasses.replace(rec, extra={**rec.extra, "st_q_ib": st})
    a, b = MEKF().run(rec), MEKF().run(bad)
    assert b.signals["star_unused"][300] and not b.signals["star_unused"][302]
    assert np.degrees(error_angle_rad(rec.q_true, b.q))[300:].max() * 3600 < 60
    assert np.degrees(error_angle_rad(a.q, b.q))[301:].max() * 3600 < 20


def test_star_tracker_without_q_io_is_named():
    rec = spacecraft(n=20, st_every=1)
    bare = dataclasses.replace(rec, extra={k: v for k, v in rec.extra.items() if k != "q_io"})
    with pytest.raises(InputError, match="q_io"):
        MEKF().run(bare)
    assert not MEKF(use_star_tracker=False).run(bare).signals["star_unused"].any()


def test_covariance_signals_and_streaming():
    """``att_std_rad`` is the root of the attitude block of ``att_cov_rad2``; the streaming
    ``update`` (TRIAD at its first call) equals ``run`` on the same samples."""
    rec = spacecraft(n=300, bias=(1e-4, -2e-4, 5e-5), mag_noise=100.0)
    est = MEKF().run(rec)
    cov = est.signals["att_cov_rad2"]
    np.testing.assert_allclose(est.signals["att_std_rad"] ** 2,
                               np.diagonal(cov, axis1=1, axis2=2), rtol=1e-12)
    assert "att_cov_rad2" not in MEKF().run(rec, keep_covariance=False).signals
    f = MEKF()
    dt = np.diff(rec.t, prepend=rec.t[0])
    q = [f.update(dt[i], rec.gyro[i], mag_b=rec.mag[i], mag_ref_o=rec.extra["b_o_nT"][i],
                  sun_b=rec.sun[i], sun_ref_o=rec.extra["s_o"][i],
                  w_io_o_rad_s=rec.extra["w_io_o"][i]) for i in range(len(rec))]
    np.testing.assert_allclose(np.array(q), est.q, rtol=0, atol=1e-10)


def test_error_rotation_vector_convention():
    """The kernel's error convention: ``q_true = q̂ ⊗ exp(θ)`` with θ in body axes: a tracker
    that sees the truth pulls a fresh filter from ``q0 = q_true ⊗ exp(−θ)`` back by θ."""
    rec = spacecraft(n=3, w_ob_b=(0, 0, 0), st_every=1)
    rec = dataclasses.replace(rec, extra={**rec.extra, "w_io_o": np.zeros((3, 3)),
                                          "q_io": np.tile([1.0, 0, 0, 0], (3, 1)),
                                          "st_q_ib": rec.q_true.copy()},
                              gyro=np.zeros((3, 3)), mag=np.zeros((3, 3)))
    theta = np.radians([0.01, -0.02, 0.015])
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(-theta))
    est = MEKF(sigma0_att_rad=1.0, sigma_sun_rad=10.0).run(rec, q0=q0)
    left = rotvec_from_quat(quat_mul(quat_conj(est.q[1]), rec.q_true[1]))
    assert np.linalg.norm(left) < 1e-3 * np.linalg.norm(theta)


def test_contract_filters_list_and_campaign_vary(tmp_path, capsys):
    """Issue 22's contract: ``gnomon filters`` lists ``mekf`` with ``estimate_mag_bias``;
    ``gnomon campaign SCENARIO --filter mekf --vary filter.mekf.estimate_mag_bias=true``
    runs, its metrics named ``mekf.rms_deg``, ``mekf.eclipse_max_deg``,
    ``mekf.sunlit_rms_deg``."""
    import json

    from gnomon.cli import main

    assert main(["filters", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert "estimate_mag_bias" in {p["name"] for p in rows["mekf"]["params"]}
    assert main(["campaign", "seed001", "--runs", "2", "--out", str(tmp_path / "c"),
                 "--vary", "duration_s=300", "--filter", "mekf",
                 "--vary", "filter.mekf.estimate_mag_bias=true", "--executor", "serial",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["failed_total"] == 0
    assert {"mekf.rms_deg", "mekf.eclipse_max_deg", "mekf.sunlit_rms_deg"} <= set(
        summary["metrics"])
    assert summary["metrics"]["mekf.rms_deg"]["max"] < 1.0


def test_a_campaign_names_the_new_name_of_a_renamed_parameter():
    from gnomon.campaign.default_task import accepts_filter_key

    with pytest.raises(InputError, match="filter.mekf-spacecraft.sigma0_att_rad"):
        accepts_filter_key("filter.mekf-spacecraft.p0_att_rad")
    assert accepts_filter_key("filter.mekf.estimate_mag_bias")


def test_any_attitude_sensor_will_do_the_tracker_starts_the_filter():
    """Gyro and star tracker only (no magnetometer, no sun): ``mekf`` runs, starts from the
    tracker's first attitude (not the orbital frame, 10° away here) and holds it; with no
    attitude sensor at all the error names what each would need."""
    rec = spacecraft(n=600, st_every=1, st_noise_rad=10 * ARCSEC, seed=5)
    keep = {k: v for k, v in rec.extra.items() if k not in ("b_o_nT", "s_o")}
    bare = dataclasses.replace(rec, mag=None, sun=None, sun_valid=None, extra=keep)
    est = MEKF().run(bare)
    err = np.degrees(error_angle_rad(rec.q_true, est.q)) * 3600
    assert err[0] < 60 and np.sqrt(np.mean(err[100:] ** 2)) < 15 and err[100:].max() < 60
    assert est.signals["mag_unusable"][1:].all()  # row 0 starts the filter: no step
    assert registry.default_for(bare)[0] == "mekf"
    none = dataclasses.replace(bare, extra={k: v for k, v in keep.items()
                                            if not k.startswith("st_")})
    with pytest.raises(InputError, match="star tracker: extra.st_q_ib and extra.q_io"):
        MEKF().run(none)
    with pytest.raises(InputError, match="mag"):
        registry.create("mekf-spacecraft").run(bare)
