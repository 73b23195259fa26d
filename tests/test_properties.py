"""Properties every registered filter must keep on arbitrary (valid) input.

Hypothesis draws short recordings with random rates, vectors of any size,
zero-norm vectors, saturated gyros, time gaps and sun dropouts; every filter in
the registry must return finite unit quaternions and finite signals, and a run
split in two with a saved state must equal the whole run. (Innovation signals may hold
NaN where no measurement was used; nothing else may.)
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gnomon.estimators import registry
from gnomon.recording import Recording


def make_recording(needs, seed, n, gap, zero_rows, gyro_scale, reference="ENU"):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.005, 0.02, n))
    if gap:
        t[n // 2:] += gap
    gyro = rng.normal(0, gyro_scale, (n, 3))
    acc = rng.normal(0, 1, (n, 3)) + [0, 0, 9.8]
    mag = rng.normal(0, 10, (n, 3)) + [0, 20, -40]
    for r in zero_rows:
        acc[r % n] = 0.0
        mag[(r * 7) % n] = 0.0
    kw = {"t": t, "gyro": gyro, "accel": acc, "mag": mag, "mag_unit": "uT"}
    if "sun" in needs:
        sun = rng.normal(0, 1, (n, 3))
        sun /= np.linalg.norm(sun, axis=1, keepdims=True)
        valid = rng.uniform(size=n) > 0.3
        sun[~valid] = np.nan
        kw.update(sun=sun, sun_valid=valid)
    extra = {}
    for need in needs:
        if need.startswith("extra."):
            v = rng.normal(0, 1, (n, 3))
            extra[need[6:]] = v / np.linalg.norm(v, axis=1, keepdims=True)
    if "extra.b_o_nT" in needs:
        extra["b_o_nT"] = extra["b_o_nT"] * 30000.0
    # in the frame the filter estimates against (a spacecraft filter refuses all but "o")
    return Recording(**kw, extra=extra, frames={"reference": reference, "body": "sensor"})


def _inputs(cls):
    """What to record for ``cls``: its ``needs``, and for a filter that takes any of several
    attitude sensors (``SENSOR_INPUTS``, the spacecraft ``mekf``) the magnetometer."""
    extra = getattr(cls, "SENSOR_INPUTS", {}).get("magnetometer", ())
    return tuple(cls.needs) + tuple(n for n in extra if n not in cls.needs)


def names():
    return registry.names()


@pytest.mark.parametrize("name", names())
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 300),
       gap=st.sampled_from([0.0, 0.5, 30.0]),
       zero_rows=st.lists(st.integers(0, 10_000), max_size=5),
       gyro_scale=st.sampled_from([0.0, 0.5, 35.0]))
def test_outputs_finite_unit_quaternions(name, seed, n, gap, zero_rows, gyro_scale):
    cls = registry.get(name)
    rec = make_recording(_inputs(cls), seed, n, gap, zero_rows, gyro_scale,
                         cls.reference_frame or "ENU")
    est = cls().run(rec)
    assert est.q.shape == (n, 4)
    assert np.all(np.isfinite(est.q))
    np.testing.assert_allclose(np.linalg.norm(est.q, axis=1), 1.0, atol=1e-9)
    for key, v in est.signals.items():
        v = np.asarray(v)
        if v.dtype.kind == "f":
            if key.startswith("innovation"):  # NaN marks "no measurement used here"
                assert not np.any(np.isinf(v)), key
            else:
                assert np.all(np.isfinite(v)), key


@pytest.mark.parametrize("name", registry.names(offline=False))  # offline: the whole log
def test_split_run_resumes_exactly(name):
    cls = registry.get(name)
    if not cls.state_fields:
        pytest.fail(f"{name} declares no state_fields: its state cannot be saved")
    rec = make_recording(_inputs(cls), 7, 400, 0.0, [], 0.5, cls.reference_frame or "ENU")
    whole = cls().run(rec).q
    first = cls()
    a = first.run(rec.slice(0, 157)).q
    second = cls()
    second.set_state(first.get_state())
    b = second.run(rec.slice(157, 400)).q
    np.testing.assert_allclose(np.vstack([a, b]), whole, rtol=0, atol=1e-12)


# ---------------------------------------------------------------- sensors at their own rates
def _multi_rate(rng, n=300):
    from gnomon.recording import Recording

    t = np.cumsum(rng.uniform(0.004, 0.006, n))
    mag_t = np.sort(rng.uniform(t[0] - 0.01, t[-1] + 0.01, n // 4))
    mag_t = mag_t[np.concatenate([[True], np.diff(mag_t) > 0])]
    return Recording(t=t, gyro=rng.normal(size=(n, 3)),
                     accel=rng.normal(size=(n, 3)), mag=rng.normal(size=(mag_t.size, 3)),
                     mag_t=mag_t)


def test_on_time_base_places_every_sample_once_and_invents_none():
    rng = np.random.default_rng(11)
    rec = _multi_rate(rng)
    base = rec.on_time_base("mag")
    arrivals = rec.arrivals("mag")
    new = np.isfinite(base).all(axis=1)
    assert np.array_equal(new, arrivals > 0)  # a row holds a value only if a sample arrived
    assert np.isnan(base[~new]).all()
    used = rec.mag_t <= rec.t[-1]
    assert arrivals.sum() == used.sum()
    for k in np.flatnonzero(new):  # each value is the mean of the samples of its interval
        lo = -np.inf if k == 0 else rec.t[k - 1]
        inside = (rec.mag_t > lo) & (rec.mag_t <= rec.t[k])
        np.testing.assert_allclose(base[k], rec.mag[inside].mean(axis=0), rtol=1e-14)
    assert rec.on_time_base("accel") is rec.accel  # a sensor on the time base: itself


def test_slice_keeps_each_sample_in_its_arrival_row():
    rng = np.random.default_rng(12)
    rec = _multi_rate(rng)
    whole = rec.on_time_base("mag")
    a, b = rec.slice(0, 120), rec.slice(120, len(rec))
    np.testing.assert_array_equal(np.concatenate([a.on_time_base("mag"),
                                                  b.on_time_base("mag")]), whole)
    assert a.mag.shape[0] + b.mag.shape[0] == rec.arrivals("mag").sum()


def test_multi_rate_validation_names_the_field():
    from gnomon.errors import InputError
    from gnomon.recording import Recording

    t = np.arange(10) * 0.01
    with pytest.raises(InputError, match="mag_t.*increase strictly") as e:
        Recording(t=t, gyro=np.zeros((10, 3)), mag=np.ones((3, 3)), mag_t=[0.0, 0.02, 0.02])
    assert e.value.row == 2
    with pytest.raises(InputError, match=r"expected shape \(3, 3\)"):
        Recording(t=t, gyro=np.zeros((10, 3)), mag=np.ones((4, 3)), mag_t=[0.0, 0.02, 0.04])
    with pytest.raises(InputError, match="given without 'accel'"):
        Recording(t=t, gyro=np.zeros((10, 3)), accel_t=t)
    same = Recording(t=t, gyro=np.zeros((10, 3)), accel=np.ones((10, 3)), accel_t=t.copy())
    assert same.single_rate and same.accel_t is None  # own stamps equal to t: single rate


def test_a_filter_without_multi_rate_support_refuses_such_a_recording():
    from gnomon.errors import InputError
    from gnomon.estimators.base import Estimator

    class Plain(Estimator):
        name = "plain"
        needs = ("gyro", "mag")

        def reset(self):
            pass

    rec = _multi_rate(np.random.default_rng(13))
    with pytest.raises(InputError, match="needs every sensor on the gyro's time stamps"):
        Plain().check_inputs(rec)
