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
    rec = make_recording(cls.needs, seed, n, gap, zero_rows, gyro_scale,
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


@pytest.mark.parametrize("name", names())
def test_split_run_resumes_exactly(name):
    cls = registry.get(name)
    if not cls.state_fields:
        pytest.fail(f"{name} declares no state_fields: its state cannot be saved")
    rec = make_recording(cls.needs, 7, 400, 0.0, [], 0.5, cls.reference_frame or "ENU")
    whole = cls().run(rec).q
    first = cls()
    a = first.run(rec.slice(0, 157)).q
    second = cls()
    second.set_state(first.get_state())
    b = second.run(rec.slice(157, 400)).q
    np.testing.assert_allclose(np.vstack([a, b]), whole, rtol=0, atol=1e-12)
