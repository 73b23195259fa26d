"""Spacecraft filters of seed 000: kernels vs readable references, convergence, gain analysis,
bad input, and the reproduction's targets (quick mode)."""

import dataclasses

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.estimators.ecf_spacecraft import ExplicitSpacecraftCF, vector_pairs
from gnomon.estimators.mekf import MEKFDelayed
from gnomon.estimators.qcf import QuaternionCF
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

N_ORBIT = 2 * np.pi / 5800.0  # mean motion, rad/s


def spacecraft(n=3000, dt=1.0, w_ob_b=(0.001, -0.0005, 0.0008), bias=(0, 0, 0), mag_noise=0.0,
               q0=(5.0, -3.0, 8.0), seed=0):
    """Closed-form truth: q_ob(t) = q0 ⊗ exp(w_ob_b t); field turning at 2n in the orbit plane,
    sun along the orbit normal (s_o = [0, -1, 0])."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    q = quat_mul(quat_from_euler(np.radians(q0)), quat_from_rotvec(t[:, None] * np.asarray(
        w_ob_b)))
    w_io_o = np.tile([0.0, -N_ORBIT, 0.0], (n, 1))
    q_bo = quat_conj(q)
    w_ib = np.asarray(w_ob_b) + quat_rotate(q_bo, w_io_o)
    b_o = 3e4 * np.stack([np.cos(2 * N_ORBIT * t), 0.3 + 0 * t, np.sin(2 * N_ORBIT * t)], 1)
    s_o = np.tile([0.0, -1.0, 0.0], (n, 1))
    mag = quat_rotate(q_bo, b_o) + rng.normal(0, mag_noise, (n, 3))
    sun = quat_rotate(q_bo, s_o)
    return Recording(t=t, gyro=w_ib + np.asarray(bias, float), mag=mag, mag_unit="nT", sun=sun,
                     sun_valid=np.ones(n, bool), q_true=q, frames={"reference": "o", "body": "b"},
                     source="synthetic", extra={"b_o_nT": b_o, "s_o": s_o, "w_io_o": w_io_o})


def _messy(rec):
    """Sun gaps, a zero and a non-finite vector, a time gap."""
    n = len(rec)
    valid = np.ones(n, bool)
    valid[200:260] = False
    sun = rec.sun.copy()
    sun[210] = np.nan  # allowed where flagged invalid
    sun[300] = 0.0  # zero but flagged valid
    mag = rec.mag.copy()
    mag[400] = 0.0
    t = rec.t.copy()
    t[500:] += 30.0  # a 31 s gap
    b_o = rec.extra["b_o_nT"].copy()
    b_o[450] = np.nan
    return dataclasses.replace(rec, t=t, sun=sun, sun_valid=valid, mag=mag,
                               extra={**rec.extra, "b_o_nT": b_o})


def _reference_run(f, rec, pairs, q0, q_mes=None, ok=None):
    """The readable ``step`` of a fresh ``f`` over the kernel's inputs, sample by sample (the
    MEKF's delayed pair weighted by the swing since its own estimate M samples before)."""
    f.reset(q0)
    out = np.empty((len(rec), 4))
    m = f.params.delay_samples
    for i in range(len(rec)):
        common = (pairs["dt"][i], pairs["gyro"][i], pairs["w_io_o"][i])
        if isinstance(f, QuaternionCF):
            out[i] = f.step(*common, q_mes[i], ok[i], pairs["mag_b"][i], pairs["mag_o"][i])
        else:
            second = (pairs["mag_b"][i], pairs["mag_o"][i], pairs["sec_b"][i],
                      pairs["sec_o"][i], pairs["sec_valid"][i])
            if isinstance(f, MEKFDelayed):
                out[i] = f.step(*common, *second, pairs["substituted"][i],
                                q_old=out[i - m] if i >= m else None)
            else:
                out[i] = f.step(*common, *second)
    return out


def _streamed(f, rec, q0=None, q_mes=None, ok=None):
    """The streaming ``update`` of ``f`` (fresh if ``q0`` is given) over the raw samples of
    ``rec`` (None where the sun is invalid or a measured quaternion is unusable)."""
    if q0 is not None:
        f.reset(q0)
    dt = np.diff(rec.t, prepend=rec.t[0])
    out = np.empty((len(rec), 4))
    for i in range(len(rec)):
        kw = dict(mag_b=rec.mag[i], mag_ref_o=rec.extra["b_o_nT"][i],
                  w_io_o_rad_s=rec.extra["w_io_o"][i])
        if isinstance(f, QuaternionCF):
            kw["q_mes_ob"] = q_mes[i] if ok[i] else None
        elif rec.sun_valid[i]:
            kw.update(sun_b=rec.sun[i], sun_ref_o=rec.extra["s_o"][i])
        out[i] = f.update(dt[i], rec.gyro[i], **kw)
    return out


@pytest.mark.slow(reason="16 s (2 cores): builds and runs the C export")
@pytest.mark.parametrize("substitute", ["delayed", "delayed-gyro", "none"])
def test_kernels_match_readable_references(substitute):
    """Kernel (``run``) against the readable ``step`` on the kernel's inputs, sample by sample,
    and against the streaming ``update`` on the raw samples (which makes the sun substitute
    itself from the filter's tail)."""
    rec = _messy(spacecraft(n=700, bias=(1e-4, -2e-4, 5e-5), mag_noise=200.0))
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(np.radians([3.0, -2.0, 4.0])))
    pairs = vector_pairs(rec, substitute, delay_samples=100)
    # streamed, the substitute comes from the filter's own tail (the gyro's turns since
    # the start for delayed-gyro, as vector_pairs integrates them): the same arithmetic
    streamed_tol = 1e-12
    common = dict(sun_substitute=substitute, delay_samples=100, max_dt_s=10.0)
    ecf = ExplicitSpacecraftCF(kp_rad_s=0.2, ki_rad_s2=1e-3, kp_single_rad_s=0.05,
                               ki_single_rad_s2=1e-4, **common)
    est = ecf.run(rec, q0=q0)
    ref = _reference_run(ExplicitSpacecraftCF(ecf.params), rec, pairs, q0)
    assert np.max(np.abs(est.q - ref)) < 1e-12
    streamed = _streamed(ExplicitSpacecraftCF(ecf.params), rec, q0)
    assert np.max(np.abs(est.q - streamed)) < streamed_tol
    assert np.all(np.isfinite(est.q))
    assert est.signals["gap"][500] and est.signals["mag_unusable"][400]
    assert est.signals["mag_unusable"][450]
    qcf = QuaternionCF(kp_rad_s=0.3, ki_rad_s2=1e-3, kp_single_rad_s=0.05,
                       ki_single_rad_s2=1e-4, **common)
    est = qcf.run(rec, q0=q0)
    q_mes, ok = est.signals["q_mes"], est.signals["q_mes_ok"]
    ref = _reference_run(QuaternionCF(qcf.params), rec, pairs, q0, q_mes, ok)
    assert np.max(np.abs(est.q - ref)) < 1e-12
    streamed = _streamed(QuaternionCF(qcf.params), rec, q0, q_mes, ok)
    assert np.max(np.abs(est.q - streamed)) < 1e-12
    assert np.all(np.isfinite(est.q))
    if substitute == "none":
        assert est.signals["mes_unusable"][220] and est.signals["mes_unusable"][300]
    mekf_sub = "none" if substitute == "none" else "delayed"
    mekf = MEKFDelayed(sigma_mag_rad=0.01, sun_substitute=mekf_sub, delay_samples=100)
    est = mekf.run(rec, q0=q0)
    pairs_m = vector_pairs(rec, mekf_sub, 100)
    ref = _reference_run(MEKFDelayed(mekf.params), rec, pairs_m, q0)
    assert np.max(np.abs(est.q - ref)) < 1e-10
    assert np.max(np.abs(est.q - _streamed(MEKFDelayed(mekf.params), rec, q0))) < 1e-10
    assert np.all(np.isfinite(est.q))


def test_readable_step_equals_the_kernel_sample_by_sample_in_every_signal():
    """Attitude, bias and flags of the readable twins after every sample; the covariance."""
    rec = _messy(spacecraft(n=600, bias=(1e-4, -2e-4, 5e-5), mag_noise=200.0))
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(np.radians([3.0, -2.0, 4.0])))
    names = ("mag_unusable", "sun_unusable", "gap", "coast")
    for f in (ExplicitSpacecraftCF(delay_samples=50, kp_rad_s=0.2, ki_rad_s2=1e-3),
              MEKFDelayed(delay_samples=50, sigma_mag_rad=0.01)):
        est = f.run(rec, q0=q0)
        pairs = vector_pairs(rec, "delayed", delay_samples=50)
        g = type(f)(f.params)
        g.reset(q0)
        twin = []
        for i in range(len(rec)):
            row = [pairs[k][i] for k in ("dt", "gyro", "w_io_o", "mag_b", "mag_o", "sec_b",
                                         "sec_o", "sec_valid")]
            if isinstance(g, MEKFDelayed):  # the swing since its estimate 50 samples before
                row += [pairs["substituted"][i], None, None, twin[i - 50] if i >= 50 else None]
            q = g.step(*row)
            twin.append(q)
            assert np.max(np.abs(q - est.q[i])) < 1e-10, i
            assert np.max(np.abs(g.bias - est.signals["bias_rad_s"][i])) < 1e-12, i
            assert [g.flags[k] for k in names] == [bool(est.signals[k][i]) for k in names], i
        if isinstance(g, MEKFDelayed):
            np.testing.assert_allclose(g.P, f.P, rtol=1e-8, atol=1e-16)


def test_renamed_integral_gains_raise_naming_the_new_name():
    for name in ("ecf-spacecraft", "qcf"):
        cls = registry.get(name)
        for old, new in (("ki_per_s", "ki_rad_s2"), ("ki_single_per_s", "ki_single_rad_s2")):
            with pytest.raises(InputError, match=new):
                registry.create(name, {old: 1e-3})
            assert cls.Params.from_dict({new: 1e-3}).as_dict()[new] == 1e-3
            unit = {d["name"]: d["unit"] for d in cls.Params.describe()}[new]
            assert unit == "rad/s^2"


@pytest.mark.parametrize("name", ["ecf-spacecraft", "qcf", "mekf-delayed", "ekf-spacecraft",
                                  "mekf-spacecraft"])
def test_spacecraft_filters_say_kind_frame_and_paper(name):
    cls = registry.get(name)
    assert cls.kind == "spacecraft" and cls.reference_frame == "o"
    assert cls.paper.startswith("seed 00")
    rec = dataclasses.replace(spacecraft(n=20), frames={"reference": "ENU", "body": "b"})
    with pytest.raises(InputError, match="frames.reference"):
        registry.create(name).run(rec)


def test_a_run_continues_a_streamed_state():
    """``update`` and ``run`` share one state: streaming the first part, then running the
    rest, equals one run (the tail of the delayed substitute included)."""
    rec = _messy(spacecraft(n=700, bias=(1e-4, -2e-4, 5e-5), mag_noise=200.0))
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(np.radians([3.0, -2.0, 4.0])))
    for cls in (ExplicitSpacecraftCF, MEKFDelayed):
        f = cls(delay_samples=100)
        whole = f.run(rec, q0=q0).q
        g = cls(f.params)
        head = _streamed(g, rec.slice(0, 350), q0)
        g.t_last = float(rec.t[349])
        tail = g.run(rec.slice(350, len(rec))).q
        np.testing.assert_allclose(np.vstack([head, tail]), whole, rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", ["ecf-spacecraft", "qcf", "mekf-delayed"])
def test_noiseless_convergence_and_bias_estimation(name):
    bias = np.radians([0.02, -0.015, 0.01])
    rec = spacecraft(n=6000, bias=bias)
    params = {"ecf-spacecraft": {"kp_rad_s": 0.1, "ki_rad_s2": 1e-3},
              "qcf": {"kp_rad_s": 0.2, "ki_rad_s2": 2e-3},
              "mekf-delayed": {"sigma_mag_rad": 0.01, "bias_rw_rad_s_rt_s": 1e-6}}[name]
    f = registry.create(name, params)
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(np.radians([10.0, -8.0, 12.0])))
    est = f.run(rec, q0=q0)
    err = np.degrees(error_angle_rad(rec.q_true, est.q))
    assert err[0] > 10
    # the only residual is the sampling of the orbital-rate term: the gyro sample at t_k
    # contains R_bo(t_k) w_io while the filter subtracts R_bo(t_k-1) w_io, a rate
    # difference of |w_ob| n dt (1.5e-6 rad/s here) that the bias estimate absorbs
    sampling = np.linalg.norm([0.001, -0.0005, 0.0008]) * N_ORBIT * 1.0
    assert np.max(np.abs(est.signals["bias_rad_s"][-1] - bias)) < 1.2 * sampling
    assert np.max(err[-1000:]) < 0.005


def _one_correction(kind, theta, kp):
    """Error after one correction step from a small error theta (body frame), no motion."""
    rec = spacecraft(n=2, w_ob_b=(0, 0, 0))
    # orthonormal references at t=1: b = x_o-ish, s = -y_o; make b ⟂ s exactly
    b_o = np.tile([3e4, 0.0, 0.0], (2, 1))
    # no orbital rate: the attitude-dependent term -R_bo w_io would add O(|θ| n dt)
    rec = dataclasses.replace(rec, extra={**rec.extra, "b_o_nT": b_o,
                                          "w_io_o": np.zeros((2, 3))},
                              mag=quat_rotate(quat_conj(rec.q_true), b_o),
                              gyro=np.zeros((2, 3)))
    q0 = quat_mul(rec.q_true[0], quat_from_rotvec(theta))
    cls = {"ecf": ExplicitSpacecraftCF, "qcf": QuaternionCF}[kind]
    est = cls(kp_rad_s=kp, ki_rad_s2=0.0).run(rec, q0=q0)
    return rotvec_from_quat(quat_mul(quat_conj(rec.q_true[1]), est.q[1]))


def test_small_error_gain_ecf_is_kp_i_plus_cct_qcf_is_half_kp():
    """Linearised response: ECF θ+ = (I − Kp (I + c cᵀ)) θ, QCF θ+ = (1 − Kp/2) θ."""
    kp = 0.3
    q_bo = quat_conj(spacecraft(n=2, w_ob_b=(0, 0, 0)).q_true[1])
    b = quat_rotate(q_bo, [1.0, 0, 0])
    s = quat_rotate(q_bo, [0.0, -1.0, 0])
    c = np.cross(b, s)
    for axis, ecf_gain in ((b, kp), (s, kp), (c, 2 * kp)):
        theta = 1e-5 * axis
        out = _one_correction("ecf", theta, kp)
        assert np.allclose(out, (1 - ecf_gain) * theta, rtol=0, atol=1e-5 * 1e-4)
        out = _one_correction("qcf", theta, kp)
        assert np.allclose(out, (1 - kp / 2) * theta, rtol=0, atol=1e-5 * 1e-4)


def test_missing_extras_and_bad_params_raise():
    rec = spacecraft(n=10)
    bare = dataclasses.replace(rec, extra={})
    for name in ("ecf-spacecraft", "qcf", "mekf-delayed"):
        with pytest.raises(InputError, match="b_o_nT"):
            registry.create(name).run(bare)
    with pytest.raises(InputError, match="sun_substitute"):
        QuaternionCF(sun_substitute="guess")
    with pytest.raises(InputError, match="solver"):
        QuaternionCF(solver="nope")


def test_whole_outage_without_sun_never_nan_and_flags():
    rec = spacecraft(n=1500, bias=np.radians([0.02, 0.02, 0.02]), mag_noise=100.0)
    rec = dataclasses.replace(rec, sun=np.full((len(rec), 3), np.nan),
                              sun_valid=np.zeros(len(rec), bool))
    for f in (QuaternionCF(kp_single_rad_s=0.0, ki_single_rad_s2=0.0),
              ExplicitSpacecraftCF(sun_substitute="none"), MEKFDelayed()):
        est = f.run(rec)
        assert np.all(np.isfinite(est.q)) and np.all(np.isfinite(est.signals["bias_rad_s"]))
    # the paper's substitute starts after M samples; before, the QCF coasts and says so
    est = QuaternionCF(kp_single_rad_s=0.0, ki_single_rad_s2=0.0, delay_samples=500).run(rec)
    assert est.signals["coast"][1:500].all() and not est.signals["coast"][600:].any()
    assert est.signals["sun_substituted"][500:].all()


def test_p000_axis_errors_split_a_known_error_along_b_s_and_c():
    """The quick tier's look at the p000 reproduction: an estimate rotated from the truth
    by 0.01 rad about the true field direction (body) is an error on the b axis alone,
    one about b x s on the c axis alone (independent: the rotation is built here)."""
    from gnomon.reproduce import p000
    from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

    rec = p000.simulate_seed(3, duration_s=120.0)
    q_bo = quat_conj(rec.q_true)
    b = quat_rotate(q_bo, rec.extra["b_o_nT"])
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    s = quat_rotate(q_bo, rec.extra["s_o"])
    c = np.cross(b, s)
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    for axis, k in ((b, 0), (c, 2)):
        q_est = quat_mul(rec.q_true, quat_from_rotvec(0.01 * axis))
        e = p000.axis_errors_bsc_rad(rec, q_est)
        np.testing.assert_allclose(e[:, k], 0.01, atol=1e-9)
        np.testing.assert_allclose(np.delete(e, k, axis=1), 0.0, atol=1e-9)


@pytest.mark.slow(reason="12 s (2 cores): runs a paper's reproduction")
def test_reproduction_quick_meets_targets():
    from gnomon.reproduce import p000

    r = p000.run(quick=True)
    assert r["paper"] == "000"
    t = r["tuned"]
    for k in ("ecf", "qcf"):
        assert set(t[k]) >= {"kp", "ki", "mean_rms_deg", "p95_rms_deg"}
    # fair comparison (issue target >= 0.95): within a few percent of each other
    assert 0.95 <= t["ratio_ecf_over_qcf"] < 1.1
    # same gain: the paper's ratio reappears, and the c axis carries it
    sg = r["same_gain"]
    assert sg["ratio_ecf_over_qcf"] >= 2.0
    ax = sg["axis_rms_deg"]
    assert ax["ecf"]["c"] > 3 * ax["qcf"]["c"]
    # sun loss on the preset (a satellite swinging a few degrees): the paper's bound holds
    # on every seed, and the improved method beats the paper's substitute in RMS
    sl = r["sun_loss"]
    assert sl["paper"]["within_paper_bound_fraction"] == 1.0
    assert sl["improved"]["rms_deg"] < sl["paper"]["rms_deg"]
    assert set(sl["paper"]["max_abs_error_deg"]) == {"roll", "pitch", "yaw"}
    # for a small swing (motion_scale 0: about 3/2/6 deg) the paper's bound holds, and the
    # hybrid MEKF is about as good as the paper's substitute there
    small = sl["amplitude_sweep"][0]
    assert small["motion_scale"] == 0.0
    assert small["paper"]["within_paper_bound_fraction"] == 1.0
    assert small["improved"]["rms_deg"] < 1.2 * small["paper"]["rms_deg"]
    # all optimal Wahba solvers give the same q_mes
    s = r["solvers"]
    for name in ("quest", "davenport", "svd"):
        assert abs(s[name]["rms_error_deg"] - s["gauss-newton"]["rms_error_deg"]) < 1e-3


def test_initial_attitude_ignores_substituted_sun_pairs():
    from gnomon.estimators.ecf_spacecraft import initial_q_ob

    rec = spacecraft(n=800, w_ob_b=(0.002, 0.0, 0.0))
    valid = np.ones(len(rec), bool)
    valid[:600] = False  # sun lost at the start: the delayed pair exists from sample 100
    rec = dataclasses.replace(rec, sun_valid=valid)
    q0 = initial_q_ob(vector_pairs(rec, "delayed", delay_samples=100))
    assert np.degrees(error_angle_rad(rec.q_true[600], q0)) < 1e-6


def _split_feed(f, rec, cuts):
    """``rec`` through ``f.update`` and ``f.update_many`` alternately, split at ``cuts``."""
    args, kwargs = f.buffer_inputs(rec)
    rows = list(f.sample_inputs(rec))
    bounds, q = [0, *cuts, len(rec)], []
    for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        if j % 2:
            q.extend(f.update(*rows[k][0], **rows[k][1]) for k in range(a, b))
        else:
            q.extend(f.update_many(*(x[a:b] for x in args),
                                   **{k: v[a:b] for k, v in kwargs.items()}).q)
    return np.array(q)


@pytest.mark.slow(reason="3 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name, params", [
    ("ecf-spacecraft", {"sun_substitute": "delayed"}),
    ("ecf-spacecraft", {"sun_substitute": "delayed-gyro"}),
    ("qcf", {"sun_substitute": "delayed-gyro"}),
    ("mekf-delayed", {}),
    ("mekf", {"sun_substitute": "delayed", "estimate_mag_bias": True}),
    ("mekf", {"sun_substitute": "delayed", "use_sun": False}),
])
def test_streamed_with_the_substitute_from_the_tail_equals_run(name, params):
    """Messy input, the sun's substitute from the filter's tail (50 samples): any split into
    ``update``/``update_many`` gives ``run``'s result, and the compiled ``update`` equals
    the readable ``update_reference`` sample by sample, flags too."""
    rec = _messy(spacecraft(n=700, bias=(1e-4, -2e-4, 5e-5), mag_noise=200.0))
    params = {**params, "delay_samples": 50}
    ref = registry.create(name, params).run(rec)
    assert ref.signals["sun_substituted"].sum() == 60  # the sun's gap, 200..259
    for cuts in ([1], [3, 120, 201, 230, 260, 501, 690]):
        f = registry.create(name, params)
        f.prepare(rec)
        assert np.max(np.abs(_split_feed(f, rec, cuts) - ref.q)) < 1e-12, cuts
    fast, twin = registry.create(name, params), registry.create(name, params)
    fast.prepare(rec)
    twin.prepare(rec)
    for i, (a, kw) in enumerate(fast.sample_inputs(rec)):
        q_fast, q_twin = fast.update(*a, **kw), twin.update_reference(*a, **kw)
        assert np.max(np.abs(q_fast - q_twin)) < 1e-12, i
        assert fast.flags == twin.flags, i
        assert fast.flags["coast"] == ref.signals["coast"][i], i


@pytest.mark.parametrize("name", ["ecf-spacecraft", "qcf", "mekf-delayed"])
def test_a_broken_gyro_sample_is_refused_none_coasts(name):
    """A gyro sample with a non-finite component raises and changes nothing (state and tail
    bit for bit); None is "no gyro sample": the filter coasts over the interval (the
    MEKF preset with the current gyro sample; with the previous one, the next interval)."""
    rec = spacecraft(n=60)
    f = registry.create(name)
    f.prepare(rec)
    rows = list(f.sample_inputs(rec))
    for a, kw in rows[:30]:
        f.update(*a, **kw)
    before = f.get_state()
    (dt, _), kw = rows[30]
    for update in (f.update, f.update_reference):
        with pytest.raises(InputError, match="gyro_rad_s"):
            update(dt, np.array([0.0, np.nan, 0.0]), **kw)
        after = f.get_state()
        for key in ("state", "ring"):
            assert before[key].tobytes() == after[key].tobytes(), key
    q_before = f.q
    f.update(dt, None, **{k: v for k, v in kw.items() if k != "q_mes_ob"})
    assert f.flags["coast"] and not f.flags["gap"]
    assert np.all(np.isfinite(f.q)) and np.max(np.abs(f.q - q_before)) < 0.01
    with pytest.raises(InputError, match="mag_b"):
        f.update(dt, rows[31][0][1], mag_b=[1.0, 2.0], mag_ref_o=kw["mag_ref_o"])
