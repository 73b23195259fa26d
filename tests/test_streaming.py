"""Every causal filter per sample: ``update`` and ``update_many`` run the compiled kernel on
the filter's own state, so any split of a recording into such calls gives ``run``'s result
(to 1e-12), and the compiled per-sample path equals the readable twin
(``update_reference``) sample by sample."""

import dataclasses

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.rotation import quat_from_euler

CAUSAL = registry.names(offline=False)
#: filters whose per-sample path is compiled (the others keep the readable one)
COMPILED = [n for n in CAUSAL if hasattr(registry.get(n), "update_reference")]


def _angle(q1, q2):
    """Largest rotation angle between two (N, 4) quaternion series (rad), exact near 0."""
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return float(np.max(4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))))


@pytest.fixture(scope="module")
def recordings():
    """One IMU recording at one rate (a BROAD excerpt), one with each sensor at its own
    rate, and short simulations of every spacecraft preset."""
    from conftest import synthetic_imu

    from gnomon.datasets import bundled
    from gnomon.io import read
    from gnomon.scenarios import list_presets, load_scenario, simulate

    broad = read(sorted(bundled("broad").glob("*.hdf5"))[0]).slice(0, 3000)
    full = synthetic_imu(quat_from_euler([0.3, -0.2, 2.0]), [0.3, -0.4, 0.5], n=3000, fs=200.0,
                         gyro_bias=[0.01, -0.02, 0.005], noise=0.005, seed=4)
    multi = dataclasses.replace(full, accel=full.accel[::2], accel_t=full.t[::2],
                                mag=full.mag[1::4], mag_t=full.t[1::4])
    out = {"imu": [("broad", broad), ("multi-rate", multi)], "spacecraft": []}
    for name in list_presets():
        sc = load_scenario(name)
        if sc.kind == "spacecraft":
            rec = simulate(sc.replace({"duration_s": 400.0}), rng_seed=3)
            out["spacecraft"].append((name, rec))
    return out


def _cases(recordings, name):
    """The recordings filter ``name`` runs on (by its own input check)."""
    f = registry.create(name)
    cases = []
    for label, rec in recordings[f.kind]:
        try:
            f.check_inputs(rec)
        except InputError:
            continue
        cases.append((label, rec))
    assert cases, f"no test recording for {name}"
    return cases


def _feed(f, rec, cuts):
    """``rec`` through ``update`` (one sample) and ``update_many`` (a buffer) alternately,
    split at ``cuts``: the attitude of every row."""
    args, kwargs = f.buffer_inputs(rec)
    rows = list(f.sample_inputs(rec))
    q, bounds = [], [0, *cuts, len(rec)]
    for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        if j % 2:  # one sample at a time
            q.extend(f.update(*rows[k][0], **rows[k][1]) for k in range(a, b))
        elif b > a:
            est = f.update_many(*(x if x is None else x[a:b] for x in args),
                                **{k: v[a:b] for k, v in kwargs.items()})
            q.extend(est.q)
    return np.array(q)


@pytest.mark.slow(reason="12 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name", CAUSAL)
def test_any_split_into_update_and_update_many_equals_run(recordings, name):
    for label, rec in _cases(recordings, name):
        ref = registry.create(name).run(rec).q
        rng = np.random.default_rng(len(label))
        for cuts in ([], [1], sorted(rng.choice(np.arange(1, len(rec)), 6, replace=False))):
            f = registry.create(name)
            f.prepare(rec)
            q = _feed(f, rec, list(cuts))
            assert q.shape == ref.shape
            assert _angle(q, ref) < 1e-12, (label, cuts, _angle(q, ref))


@pytest.mark.slow(reason="18 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name", COMPILED)
def test_compiled_update_equals_the_readable_twin(recordings, name):
    for label, rec in _cases(recordings, name):
        fast, twin = registry.create(name), registry.create(name)
        fast.prepare(rec)
        twin.prepare(rec)
        rows = list(fast.sample_inputs(rec))[:1500]
        q_fast = np.array([fast.update(*a, **kw) for a, kw in rows])
        q_twin = np.array([twin.update_reference(*a, **kw) for a, kw in rows])
        assert _angle(q_fast, q_twin) < 1e-12, (label, _angle(q_fast, q_twin))
        assert fast.flags == twin.flags


@pytest.mark.parametrize("name", [n for n in COMPILED if registry.get(n).kind == "imu"])
def test_a_broken_sample_is_refused_or_skipped_never_absorbed(recordings, name):
    """A non-finite gyro sample raises and changes nothing; an accelerometer or
    magnetometer sample with a NaN is no sample (never NaN in the state)."""
    _, rec = recordings["imu"][0]
    f = registry.create(name)
    f.prepare(rec)
    rows = list(f.sample_inputs(rec))
    for a, kw in rows[:50]:
        f.update(*a, **kw)
    before = f.get_state()
    dt, g, acc, *mag = rows[50][0]  # mag: [] for a filter without a magnetometer (tilt-cf)
    with pytest.raises(InputError, match="gyro_rad_s"):
        f.update(dt, np.array([np.nan, 0.0, 0.0]), acc, *mag)
    after = f.get_state()
    for key, value in before.items():
        if isinstance(value, np.ndarray):  # bit for bit, field by field (a copy of an
            # aligned record leaves its padding bytes uninitialised)
            for name in value.dtype.names or (None,):
                x, y = (value, after[key]) if name is None else (value[name], after[key][name])
                assert x.tobytes() == y.tobytes(), (key, name)
    bad = np.array([1.0, np.nan, 2.0])
    q = f.update(dt, g, bad, *(None if m is None else bad for m in mag))
    assert np.all(np.isfinite(q))
    with pytest.raises(InputError, match="accel_m_s2"):
        f.update(dt, g, [1.0, 2.0])
