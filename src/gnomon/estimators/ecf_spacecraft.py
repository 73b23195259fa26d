"""Explicit complementary filter for a spacecraft: magnetometer + sun sensor + gyros.

The baseline of seed 000 ("Estimating the attitude of a microsatellite with a
complementary filter", ``shared/spec/000-microsat-complementary.md``), i.e.
Mahony, Hamel & Pflimlin's explicit complementary filter (IEEE TAC 53(5),
2008) with the orbital frame as reference.

Frames and signals: the estimate is ``q_ob`` (orbital from body). The gyro
measures ``ω_ib_b`` (body relative to inertial), so the rate that moves
``q_ob`` is ``ω_ob_b = ω_ib_b − R_bo ω_io_o``, ``ω_io_o = [0, −n, 0]`` on a
circular orbit (taken from the recording's ``extra['w_io_o']`` when present,
otherwise from ``orbital_rate_rad_s``). Reference directions in o: the field
model ``B°`` (``extra['b_o_model_nT']``, else ``extra['b_o_nT']``) and the sun
``S°`` (``extra['s_o']``); measured in b: ``B^b`` (``mag``), ``S^b``
(``sun``, valid where ``sun_valid``). With unit vectors and ``v̂ = R̂_bo v°``

    e = k_mag B^b × B̂ + k_sun S^b × Ŝ                     (body frame)
    q̂ ← q̂ ⊗ exp((ω_ib − R̂_bo ω_io − b̂) dt)           (predict)
    b̂ ← b̂ − K_I e dt,   q̂ ← q̂ ⊗ exp(K_P e dt)          (correct)

the paper's ``d = K_P e + K_I ∫e`` with ``b̂ = −K_I ∫e``. For a small error
``θ`` (``q̂ = q ⊗ exp(θ)``) and orthogonal unit vectors ``b``, ``s``:
``e = −(2I − b bᵀ − s sᵀ) θ = −(I + c cᵀ) θ``, ``c = b × s``: the explicit
filter corrects with ``K_P`` about b and s and ``2 K_P`` about c (stable in
discrete time only for ``2 K_P dt < 2``).

Sun-sensor loss (``sun_substitute``), where ``sun_valid`` is false:

* ``"delayed"`` (the paper): ``S°[n] = B°[n−M]``, ``S^b[n] = B^b[n−M]``,
  ``M = delay_samples`` (500 at 1 s in the paper);
* ``"delayed-gyro"``: the same pair with the body vector carried to time n
  by the raw gyro rotation and the reference by the orbital frame's rotation
  (exact without gyro drift; drifts by the integrated bias, ~10° per axis
  after 500 s of a 0.02°/s drift);
* ``"none"``: the magnetometer pair alone (with ``kp_single_rad_s``,
  ``ki_single_per_s``): the magnetometer + gyro filter whose bias estimate
  comes from the turning field direction (observable over the orbit).

Gains switch to ``kp_single_rad_s`` / ``ki_single_per_s`` whenever only one
pair is usable. Bad input: a zero or non-finite vector makes its pair
unusable (flag), a sample interval above ``max_dt_s`` or a non-finite
interval is a gap (gyro-only propagation, flag), a non-finite gyro sample is
skipped (flag ``coast``): the estimate never holds a NaN.

``run`` uses the numba kernel ``gnomon.kernels.spacecraft_cf.ecf_batch``;
``update`` is the readable reference (tested against it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

__all__ = ["SpacecraftCFParams", "ExplicitSpacecraftCF", "vector_pairs", "initial_q_ob",
           "integrate_rates"]

SUN_SUBSTITUTES = ("delayed", "delayed-gyro", "none")


@dataclass(frozen=True)
class SpacecraftCFParams(Params):
    kp_rad_s: float = param(0.03, "rad/s", "proportional gain K_P (both pairs usable; "
                             "tuned on seed000)")
    ki_per_s: float = param(3e-4, "rad/s^2", "integral gain K_I (gyro drift estimation)")
    kp_single_rad_s: float = param(0.005, "rad/s", "K_P when only one vector pair is usable")
    ki_single_per_s: float = param(2e-5, "rad/s^2", "K_I when only one vector pair is usable")
    k_mag: float = param(1.0, "", "weight of the magnetometer pair")
    k_sun: float = param(1.0, "", "weight of the sun (or substitute) pair")
    sun_substitute: str = param("delayed", "", "when the sun is invalid: delayed | "
                                "delayed-gyro | none")
    delay_samples: int = param(500, "samples", "M of the delayed magnetometer pair")
    min_angle_deg: float = param(1.0, "deg", "pairs closer than this count as one")
    orbital_rate_rad_s: float = param(0.0, "rad/s", "mean motion n if the recording has no "
                                      "extra['w_io_o']")
    max_dt_s: float = param(10.0, "s", "longer sample intervals are gaps: gyro only")

    def validate(self):
        for name in ("kp_rad_s", "ki_per_s", "kp_single_rad_s", "ki_single_per_s", "k_mag",
                     "k_sun", "orbital_rate_rad_s"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")
        self._require("sun_substitute", self.sun_substitute in SUN_SUBSTITUTES,
                      f"must be one of {', '.join(SUN_SUBSTITUTES)}")
        self._require("delay_samples", self.delay_samples >= 1, "must be >= 1")
        self._require("min_angle_deg", 0 <= self.min_angle_deg < 90, "must be in [0, 90)")
        self._require("max_dt_s", self.max_dt_s > 0, "must be > 0")


# ---------------------------------------------------------------- preprocessing
def integrate_rates(dt, w):
    """Cumulative rotation ``q_0k`` (N, 4) of a frame turning at ``w`` (N, 3) rad/s (own axes).

    ``q[0] = 1``; ``q[k] = q[k-1] ⊗ exp(w[k] dt[k])`` (the rate sample at the end of
    the interval, as the filters use it). Non-finite rates or intervals count as zero.
    """
    from gnomon.kernels.spacecraft_cf import integrate_rates_batch

    dt = np.where(np.isfinite(dt), dt, 0.0)
    w = np.where(np.isfinite(w), w, 0.0)
    out = np.empty((len(dt), 4))
    integrate_rates_batch(np.ascontiguousarray(dt, float), np.ascontiguousarray(w, float), out)
    return out


def _field_reference(rec: Recording) -> np.ndarray:
    for key in ("b_o_model_nT", "b_o_nT"):
        if rec.extra.get(key) is not None:
            return np.asarray(rec.extra[key], float)
    raise InputError("the filter needs the reference field in the orbital frame; "
                     "the recording has none", field="extra.b_o_nT", file=rec.source or None)


def _w_io_o(rec: Recording, orbital_rate: float) -> np.ndarray:
    w = rec.extra.get("w_io_o")
    if w is not None:
        return np.ascontiguousarray(np.asarray(w, float).reshape(len(rec), 3))
    return np.tile([0.0, -orbital_rate, 0.0], (len(rec), 1))


def vector_pairs(rec: Recording, sun_substitute: str = "delayed", delay_samples: int = 500,
                 orbital_rate_rad_s: float = 0.0, history: dict | None = None) -> dict:
    """Arrays the spacecraft filters consume, with the sun substitution applied.

    Returns ``dt`` (N,) (``dt[0] = 0``), ``gyro``, ``w_io_o``, ``mag_b``, ``mag_o``,
    ``sec_b``, ``sec_o`` (N, 3) and ``sec_valid``, ``substituted`` (N,) bool. Where
    the sun is invalid the second pair is the substitute (see the module docstring)
    or unusable (``"none"``, or before M samples have passed). ``history``: the
    ``tail`` of the previous call's result (the last M samples before ``rec``), so a
    recording processed in pieces gets the same substitutes as in one piece; the
    result's ``tail`` is the same for the next piece.
    """
    n = len(rec)
    dt = np.zeros(n)
    dt[1:] = np.diff(rec.t)
    mag_b = np.ascontiguousarray(rec.mag, float)
    mag_o = np.ascontiguousarray(_field_reference(rec))
    w_io = _w_io_o(rec, orbital_rate_rad_s)
    gyro = np.ascontiguousarray(rec.gyro, float)
    if rec.sun is None:
        sun = np.full((n, 3), np.nan)
        valid = np.zeros(n, bool)
    else:
        sun = np.asarray(rec.sun, float)
        valid = (np.ones(n, bool) if rec.sun_valid is None
                 else np.asarray(rec.sun_valid, bool)).copy()
    valid &= np.all(np.isfinite(sun), axis=1)
    s_o = rec.extra.get("s_o")
    s_o = np.full((n, 3), np.nan) if s_o is None else np.asarray(s_o, float)
    valid &= np.all(np.isfinite(s_o), axis=1)
    sec_b = np.where(valid[:, None], sun, 0.0)
    sec_o = np.where(valid[:, None], s_o, 0.0)
    sec_valid = valid.copy()
    substituted = np.zeros(n, bool)
    M = int(delay_samples)
    # the M samples before this recording (from an earlier piece) and this one, end to end
    h = 0 if history is None else len(history["dt"])
    ext = {"dt": dt, "gyro": gyro, "w_io_o": w_io, "mag_b": mag_b, "mag_o": mag_o}
    if h:
        ext = {k: np.concatenate([history[k], v]) for k, v in ext.items()}
    if sun_substitute != "none":
        lost = ~valid
        lost[: max(0, M - h)] = False
        idx = np.flatnonzero(lost)
        old = idx + h - M  # index into the extended arrays
        sb = ext["mag_b"][old]
        so = ext["mag_o"][old]
        if sun_substitute == "delayed-gyro" and idx.size:
            q_b = integrate_rates(ext["dt"], ext["gyro"])  # q_{b(0) b(k)} from the raw gyro
            q_o = integrate_rates(ext["dt"], ext["w_io_o"])  # q_{o(0) o(k)}
            # body: v_b(n) = R_{b(n) b(n-M)} v_b(n-M); orbital likewise
            sb = quat_rotate(quat_mul(quat_conj(q_b[idx + h]), q_b[old]), sb)
            so = quat_rotate(quat_mul(quat_conj(q_o[idx + h]), q_o[old]), so)
        sec_b[idx] = sb
        sec_o[idx] = so
        sec_valid[idx] = True
        substituted[idx] = True
    tail = {k: v[max(0, len(v) - M):].copy() for k, v in ext.items()} if M > 0 else None
    return {"dt": dt, "gyro": gyro, "w_io_o": w_io,
            "mag_b": mag_b, "mag_o": mag_o, "sec_b": np.ascontiguousarray(sec_b),
            "sec_o": np.ascontiguousarray(sec_o), "sec_valid": sec_valid,
            "substituted": substituted, "tail": tail}


def initial_q_ob(pairs: dict, k: int | None = None) -> np.ndarray:
    """``q_ob`` from the first sample with a real (not substituted) sun pair and a usable,
    non-parallel magnetic pair (TRIAD, sun first), searched among the first ``k`` samples.

    Identity (the orbital frame) when there is none — the seed-000 satellite is
    stabilised close to it. The attitude of that sample initialises the filter at
    its first sample (the satellite turns slowly).
    """
    from gnomon.estimators.wahba import triad

    r = np.stack([pairs["sec_o"], pairs["mag_o"]], axis=1)
    b = np.stack([pairs["sec_b"], pairs["mag_b"]], axis=1)
    w = np.stack([pairs["sec_valid"].astype(float), np.ones(len(r))], axis=1)
    stop = len(r) if k is None else k
    real = pairs["sec_valid"] & ~pairs.get("substituted", np.zeros(len(r), bool))
    for i in range(min(stop, len(r))):
        if not real[i]:
            continue
        res = triad(r[i], b[i], w[i])
        if not res.degenerate:
            return res.q
    return np.array([1.0, 0.0, 0.0, 0.0])


def _unit(v):
    v = np.asarray(v, float)
    n = float(np.sqrt(v @ v)) if np.all(np.isfinite(v)) else 0.0
    return (v / n, True) if 0.0 < n < 1e300 else (np.zeros(3), False)


def _propagate(q, bias, dt, gyro, w_io_o):
    """The prediction step (readable twin of the kernel's); False if the gyro is unusable."""
    gyro = np.asarray(gyro, float)
    if not np.all(np.abs(gyro) < 1e6):
        return q, False
    w_ob = gyro - quat_rotate(quat_conj(q), np.asarray(w_io_o, float)) - bias
    q = quat_mul(q, quat_from_rotvec(w_ob * dt))
    return q / np.linalg.norm(q), True


def _correct(q, rv):
    rv = np.asarray(rv, float)
    q = quat_mul(q, quat_from_rotvec(rv))
    return q / np.linalg.norm(q)


class VectorPairFilter(Estimator):
    """What the seed-000 filters share: state (``q_ob``, gyro bias, last time, the tail of
    vector pairs for the delayed substitute), the pairs of a recording continuing that
    state, the initial attitude and the batch outputs. Subclasses add their update/run."""

    needs = ("gyro", "mag", "extra.b_o_nT")
    state_fields = ("q", "bias", "t_last", "tail")

    def reset(self) -> None:
        self.q = None
        self.bias = np.zeros(3)
        self.flags = {}
        self.t_last = None  # s, last sample processed by ``run``
        self.tail = None  # the last M samples' vector pairs (for the delayed substitute)

    def pairs(self, rec: Recording) -> dict:
        """``vector_pairs`` of ``rec`` continuing this filter's earlier runs."""
        p = self.params
        pairs = vector_pairs(rec, p.sun_substitute, p.delay_samples, p.orbital_rate_rad_s,
                             history=self.tail)
        pairs["dt"][0] = self.first_dt(rec)
        return pairs

    def _start(self, pairs: dict, q0) -> None:
        if q0 is not None:
            self.q = np.asarray(q0, float) / np.linalg.norm(q0)
        elif self.q is None:
            self.q = initial_q_ob(pairs)

    def _predict(self, dt_s, gyro, w_io_o, second: str):
        """First part of every readable ``update``: reset the flags (``second``: the name of
        the second pair's flag), then propagate with the gyro over ``dt_s``. Returns
        whether the gyro was usable, or None when the sample has no interval (no step)."""
        if self.q is None:
            self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.flags = {"mag_unusable": False, second: False, "gap": False, "coast": False}
        if not (0.0 < dt_s < 1e300):
            return None
        self.q, ok_g = _propagate(self.q, self.bias, dt_s, gyro, w_io_o)
        if not ok_g:
            self.flags["coast"] = True
        return ok_g

    @staticmethod
    def _outputs(n: int):
        """``q_out`` (n, 4), ``b_out`` (n, 3), ``flags`` (n, 4) int8 for a batch kernel."""
        return np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 4), np.int8)

    def _finish(self, rec: Recording, pairs: dict, q_out, b_out, flags, names,
                **signals) -> Estimate:
        """Keep the end state and wrap the outputs; ``names``: the 4 flag columns' names."""
        self.q, self.bias = q_out[-1].copy(), b_out[-1].copy()
        self.t_last, self.tail = float(rec.t[-1]), pairs["tail"]
        flag_signals = {name: flags[:, i].astype(bool) for i, name in enumerate(names)}
        return Estimate(
            t=rec.t, q=q_out, estimator=self.name, params=self.params.as_dict(),
            frames={"reference": rec.frames.get("reference", "o"), "body": "b"},
            signals={"bias_rad_s": b_out, **signals, **flag_signals})


class ExplicitSpacecraftCF(VectorPairFilter):
    """Explicit complementary filter (Mahony 2008) on the magnetic and sun pairs; ``q_ob``."""

    name = "ecf-spacecraft"
    summary = ("Explicit complementary filter for spacecraft (seed 000 baseline): mag + sun + "
               "gyro, orbital frame, PI drift estimation, delayed-field sun substitute")
    Params = SpacecraftCFParams

    def update(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid) -> np.ndarray:
        """One sample (readable reference of the kernel). Returns ``q_ob`` (4,)."""
        p = self.params
        if self._predict(dt_s, gyro, w_io_o, "sun_unusable") is None:
            return self.q
        if dt_s > p.max_dt_s:
            self.flags.update(gap=True, coast=True)
            return self.q
        ubm, ok_mb = _unit(mag_b)
        uom, ok_mo = _unit(mag_o)
        ok_m = ok_mb and ok_mo
        ubs, ok_sb = _unit(sec_b)
        uos, ok_so = _unit(sec_o)
        ok_s = bool(sec_valid) and ok_sb and ok_so
        if ok_m and ok_s and np.linalg.norm(np.cross(uom, uos)) < np.sin(
                np.radians(p.min_angle_deg)):
            ok_s = False
        self.flags["mag_unusable"] = not ok_m
        self.flags["sun_unusable"] = not ok_s
        q_bo = quat_conj(self.q)
        e = np.zeros(3)
        if ok_m:
            e += p.k_mag * np.cross(ubm, quat_rotate(q_bo, uom))
        if ok_s:
            e += p.k_sun * np.cross(ubs, quat_rotate(q_bo, uos))
        if ok_m and ok_s:
            kp, ki = p.kp_rad_s, p.ki_per_s
        elif ok_m or ok_s:
            kp, ki = p.kp_single_rad_s, p.ki_single_per_s
        else:
            self.flags["coast"] = True
            return self.q
        self.bias = self.bias - ki * e * dt_s
        self.q = _correct(self.q, kp * e * dt_s)
        return self.q

    def run(self, rec: Recording, q0=None) -> Estimate:
        """Whole recording (compiled). ``q0``: initial ``q_ob`` (default: TRIAD of the first
        sample with both pairs, else the current state, else identity)."""
        from gnomon.kernels.spacecraft_cf import ecf_batch

        self.check_inputs(rec)
        p = self.params
        pairs = self.pairs(rec)
        self._start(pairs, q0)
        q_out, b_out, flags = self._outputs(len(rec))
        state_q = np.array(self.q, float)
        state_b = np.array(self.bias, float)
        ecf_batch(pairs["dt"], pairs["gyro"], pairs["w_io_o"], pairs["mag_b"], pairs["mag_o"],
                  pairs["sec_b"], pairs["sec_o"], pairs["sec_valid"], state_q, state_b,
                  p.kp_rad_s, p.ki_per_s, p.kp_single_rad_s, p.ki_single_per_s, p.k_mag,
                  p.k_sun, p.max_dt_s, float(np.sin(np.radians(p.min_angle_deg))), q_out,
                  b_out, flags)
        return self._finish(rec, pairs, q_out, b_out, flags,
                            ("mag_unusable", "sun_unusable", "gap", "coast"),
                            sun_substituted=pairs["substituted"])
