"""Uncertainty injection for seed 001: inertia tensor, field model, sun sensor at a level L %.

The paper ("Accuracy of microsatellite attitude estimation by the Kalman method under
uncertainty and measurement noise") draws each uncertain quantity "from a normal
random-number generator plus a constant component" at 2 % and 10 % of the true value,
without saying how a percentage applies to a tensor, a field model or a direction. The
models below make that explicit; ``l = L / 100``, ``z ~ N(0, 1)`` drawn once per run from
the run's generator unless said otherwise.

Inertia (what the filter believes; the spacecraft keeps its true tensor ``J``):

* ``per_axis`` (default): ``J' = S J S``, ``S = diag(sqrt(1 + l (c_k + z_k / 2)))`` with
  the constant uneven component ``c = (+1, -1, +1/2)`` plus the normal draw. (A uniform
  scaling would change nothing in ``J⁻¹ (ω × J ω)``: the error must be uneven.)
* ``uniform``: ``J' = (1 + l) J`` (shows that a uniform error hardly matters).
* ``random``: ``S = diag(sqrt(1 + l z_k))`` (the normal draw only).

Field model (the on-board model the filter uses; the magnetometer measures the truth),
by the spacecraft world's error injection (:mod:`gnomon.environment.magnetic`):

* ``per_component`` (default): world ``component``: ``B'_k = (1 + l z_k) B_k`` in ECEF.
* ``direction``: world ``tilt``: the field turned by ``atan(l)`` about a random fixed axis.
* ``magnitude``: world ``scale``: ``B' = (1 + l) B`` (no effect on unit-vector filters).
* ``gauss``: world ``gauss``: every Gauss coefficient times ``(1 + l z_nm)``.

Sun sensor (the measured sun vectors, on top of the scenario's sensor noise):

* ``combined`` (default): a constant misalignment of angle ``atan(l) / 2`` about a random
  axis plus white noise of ``atan(l) / 2`` per axis across the line of sight.
* ``misalignment``: a constant misalignment of angle ``atan(l)`` (random axis).
* ``random``: white noise of ``atan(l)`` per axis across the line of sight.
"""

from __future__ import annotations

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_rotvec

__all__ = ["MODELS", "DEFAULT_MODEL", "SOURCES", "inertia_model", "perturb_sun",
           "field_overrides", "inject"]

MODELS = {
    "inertia": ("per_axis", "uniform", "random"),
    "field_model": ("per_component", "direction", "magnitude", "gauss"),
    "sun_sensor": ("combined", "misalignment", "random"),
}
DEFAULT_MODEL = {"inertia": "per_axis", "field_model": "per_component", "sun_sensor": "combined"}
SOURCES = ("none",) + tuple(MODELS)
_FIELD_KIND = {"per_component": "component", "direction": "tilt", "magnitude": "scale",
               "gauss": "gauss"}
_C_INERTIA = np.array([1.0, -1.0, 0.5])


def _check(source: str, model: str | None, level_pct: float) -> str:
    if source not in SOURCES:
        raise InputError(f"unknown uncertainty source {source!r}; use one of {list(SOURCES)}",
                         field="uncertainty.source")
    if not np.isfinite(level_pct) or level_pct < 0:
        raise InputError(f"must be a finite number >= 0, got {level_pct!r}",
                         field="uncertainty.level_pct")
    if source == "none":
        return "none"
    model = model or DEFAULT_MODEL[source]
    if model not in MODELS[source]:
        raise InputError(f"unknown model {model!r} for {source}; use one of "
                         f"{list(MODELS[source])}", field="uncertainty.model")
    return model


def inertia_model(J, model: str, level_pct: float, rng: np.random.Generator) -> np.ndarray:
    """The filter's inertia tensor (3, 3) kg m² from the true ``J`` (see the module docstring)."""
    J = np.asarray(J, float)
    ell = level_pct / 100.0
    if model == "uniform":
        return (1.0 + ell) * J
    z = rng.standard_normal(3)
    f = 1.0 + ell * ((_C_INERTIA + 0.5 * z) if model == "per_axis" else z)
    s = np.sqrt(np.maximum(f, 0.05))
    return s[:, None] * J * s[None, :]


def perturb_sun(sun_b, valid, model: str, level_pct: float, rng: np.random.Generator):
    """Sun vectors (N, 3) with the sensor error of ``model`` added (invalid rows untouched)."""
    s = np.array(sun_b, float)
    ell = np.arctan(level_pct / 100.0)
    mis, noise = {"combined": (ell / 2, ell / 2), "misalignment": (ell, 0.0),
                  "random": (0.0, ell)}[model]
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    e = rng.standard_normal(s.shape)
    v = np.asarray(valid, bool)
    if mis:
        R = dcm_from_quat(quat_from_rotvec(mis * axis))
        s[v] = s[v] @ R.T
    if noise:
        sv = s[v]
        ev = e[v] * noise
        ev -= np.sum(ev * sv, axis=1, keepdims=True) * sv
        sv = sv + ev
        s[v] = sv / np.linalg.norm(sv, axis=1, keepdims=True)
    return s


def field_overrides(model: str, level_pct: float) -> dict:
    """Scenario overrides that make the world's on-board field model wrong."""
    return {"environment.field_error.kind": _FIELD_KIND[model],
            "environment.field_error.level_pct": float(level_pct)}


def inject(scenario, source: str, model: str | None, level_pct: float, seed: int):
    """Simulate ``scenario`` (seed ``seed``) with one uncertainty source injected.

    Returns ``(recording, inertia_for_filter)``: the recording carries the field-model
    error (``extra['b_o_model_nT']``) and the sun-sensor error (``sun``); the inertia
    tensor (3, 3) is what the filter should believe (the truth unless ``source`` is
    "inertia"). The injection's draws come from ``SeedSequence(seed, spawn_key=(1001,))``,
    independent of the simulation's.
    """
    from gnomon.scenarios import simulate

    model = _check(source, model, float(level_pct))
    if source == "field_model" and level_pct > 0:
        scenario = scenario.replace(field_overrides(model, level_pct))
    rec = simulate(scenario, rng_seed=seed)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(1001,)))
    J = np.asarray(rec.extra["inertia_kg_m2"][0], float)
    if source == "inertia" and level_pct > 0:
        J = inertia_model(J, model, level_pct, rng)
    if source == "sun_sensor" and level_pct > 0:
        sun = perturb_sun(rec.sun, rec.sun_valid, model, level_pct, rng)
        rec = Recording(t=rec.t, gyro=rec.gyro, accel=rec.accel, mag=rec.mag,
                        mag_unit=rec.mag_unit, sun=sun, sun_valid=rec.sun_valid,
                        q_true=rec.q_true, mask=rec.mask, frames=rec.frames, source=rec.source,
                        extra=rec.extra)
    return rec, J
