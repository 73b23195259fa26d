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
  ``ki_single_rad_s2``): the magnetometer + gyro filter whose bias estimate
  comes from the turning field direction (observable over the orbit).

Gains switch to ``kp_single_rad_s`` / ``ki_single_rad_s2`` whenever only one
pair is usable (``K_I`` is in rad/s² per unit error: it integrates the error into
a rate; these were named ``ki_per_s`` / ``ki_single_per_s`` before).

Bad input: a zero or non-finite vector makes its pair unusable (flag), a sample
interval above ``max_dt_s`` or a non-finite interval is a gap (gyro-only
propagation, flag), an unusable gyro sample (None in ``update``) is skipped (flag
``coast``): the estimate never holds a NaN. ``update`` refuses a gyro sample with a
non-finite component (``InputError``, nothing done), as a ``Recording`` does.

The filter's compiled paths take raw samples and make the sun's substitute from the
filter's own tail of past samples (``ring``, ``delay_samples`` of them, part of the
state): ``update`` (one sample, the kernel ``gnomon.kernels.spacecraft_cf.ecf_sample``),
``update_many`` (a buffer, ``ecf_stream``) and ``run`` (a recording: ``prepare``, the
initial attitude, then the same ``ecf_stream``); any split of a recording into
``update``/``update_many`` calls gives ``run``'s result. Coefficients
``ecf_coefficients(params)``, state record ``STATE``. ``update_reference`` is the
readable twin of ``update`` (the substitute ``_second_pair``, then ``step``, the twin of
``ecf_step``, phase by phase: gyro prediction, vector pairs, PI correction), tested
against the kernel sample by sample.

Streaming arguments (shared by the seed-000 filters ``ecf-spacecraft``, ``qcf``,
``mekf-delayed``; ``None`` = no new sample of that input):

* ``dt_s`` (s) since the previous sample (0 at the first: no step);
* ``gyro_rad_s`` (3,) ``ω_ib_b`` rad/s (None: no propagation over this interval, flagged
  ``coast``; a non-finite component: refused);
* ``mag_b`` (3,) the measured field in b and ``mag_ref_o`` (3,) the field model in o (any
  one unit: only directions are used);
* ``sun_b`` (3,) the sun direction measured in b and ``sun_ref_o`` (3,) the sun model in o
  (any length; None or non-finite: no sun, e.g. eclipse);
* ``w_io_o_rad_s`` (3,) rate of the orbital frame (default ``[0, −n, 0]``,
  ``n = orbital_rate_rad_s``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.estimators.spacecraft_update import (
    NO_GYRO,
    CompiledSampleUpdate,
    buffer,
    gyro_sample,
    vec,
)
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

__all__ = ["SpacecraftCFParams", "ExplicitSpacecraftCF", "VectorPairFilter", "vector_pairs",
           "pairs_from_arrays", "initial_q_ob", "integrate_rates"]

SUN_SUBSTITUTES = ("delayed", "delayed-gyro", "none")
#: The integral gains' former names (their unit, rad/s², was not the one the name said).
KI_RENAMED = {"ki_per_s": "ki_rad_s2", "ki_single_per_s": "ki_single_rad_s2"}


@dataclass(frozen=True)
class SpacecraftCFParams(Params):
    renamed = KI_RENAMED

    kp_rad_s: float = param(0.03, "rad/s", "proportional gain K_P (both pairs usable; "
                             "tuned on seed000)")
    ki_rad_s2: float = param(3e-4, "rad/s^2", "integral gain K_I (gyro drift estimation)")
    kp_single_rad_s: float = param(0.005, "rad/s", "K_P when only one vector pair is usable")
    ki_single_rad_s2: float = param(2e-5, "rad/s^2", "K_I when only one vector pair is usable")
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
        for name in ("kp_rad_s", "ki_rad_s2", "kp_single_rad_s", "ki_single_rad_s2", "k_mag",
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
    if rec.sun is None:
        sun, valid = np.full((n, 3), np.nan), np.zeros(n, bool)
    else:
        sun = np.asarray(rec.sun, float)
        valid = np.ones(n, bool) if rec.sun_valid is None else np.asarray(rec.sun_valid, bool)
    s_o = rec.extra.get("s_o")
    s_o = np.full((n, 3), np.nan) if s_o is None else np.asarray(s_o, float)
    return pairs_from_arrays(dt, rec.gyro, _w_io_o(rec, orbital_rate_rad_s), rec.mag,
                             _field_reference(rec), sun, valid, s_o, sun_substitute,
                             delay_samples, history)


def pairs_from_arrays(dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_valid, sun_o,
                      sun_substitute: str = "delayed", delay_samples: int = 500,
                      history: dict | None = None) -> dict:
    """``vector_pairs`` of arrays (N rows; the streaming ``update`` passes one): ``dt`` (N,)
    s, ``gyro`` (N, 3) rad/s, ``w_io_o`` (N, 3) rad/s, the magnetic pair ``mag_b`` (b),
    ``mag_o`` (o), the sun pair ``sun_b`` (b), ``sun_o`` (o) and ``sun_valid`` (N,) bool
    (a non-finite sun row is invalid too)."""
    n = len(dt)
    mag_b = np.ascontiguousarray(mag_b, float)
    mag_o = np.ascontiguousarray(mag_o, float)
    gyro = np.ascontiguousarray(gyro, float)
    w_io = np.ascontiguousarray(w_io_o, float)
    sun = np.asarray(sun_b, float)
    valid = np.asarray(sun_valid, bool).copy()
    valid &= np.all(np.isfinite(sun), axis=1)
    s_o = np.asarray(sun_o, float)
    valid &= np.all(np.isfinite(s_o), axis=1)
    sec_b = np.where(valid[:, None], sun, 0.0)
    sec_o = np.where(valid[:, None], s_o, 0.0)
    sec_valid = valid.copy()
    substituted = np.zeros(n, bool)
    M = int(delay_samples)
    # the M samples before these (from an earlier piece) and these, end to end
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
            # body: v_b(n) = R_{b(n) b(n-M)} v_b(n-M); orbital likewise (a non-finite
            # vector stays so: its pair is unusable)
            sb, so = sb.copy(), so.copy()
            ok = np.all(np.isfinite(sb), axis=1) & np.all(np.isfinite(so), axis=1)
            n_, o_ = idx[ok] + h, old[ok]
            sb[ok] = quat_rotate(quat_mul(quat_conj(q_b[n_]), q_b[o_]), sb[ok])
            so[ok] = quat_rotate(quat_mul(quat_conj(q_o[n_]), q_o[o_]), so[ok])
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

    n = len(pairs["sec_valid"])
    stop = n if k is None else min(k, n)
    real = np.asarray(pairs["sec_valid"][:stop], bool)
    if pairs.get("substituted") is not None:
        real = real & ~np.asarray(pairs["substituted"][:stop], bool)
    for i in np.flatnonzero(real):
        res = triad(np.stack([pairs["sec_o"][i], pairs["mag_o"][i]]),
                    np.stack([pairs["sec_b"][i], pairs["mag_b"][i]]), np.array([1.0, 1.0]))
        if not res.degenerate:
            return res.q
    return np.array([1.0, 0.0, 0.0, 0.0])


def _unit(v):
    v = np.asarray(v, float)
    n = float(np.sqrt(v @ v)) if np.all(np.isfinite(v)) else 0.0
    return (v / n, True) if 0.0 < n < 1e300 else (np.zeros(3), False)


def _reference_vector(v, name: str) -> np.ndarray:
    """A streamed vector for the readable twins: None (no sample) as a NaN row."""
    return np.full(3, np.nan) if v is None else vec(v, name).copy()


def _turned(q, rv):
    """``q ⊗ exp(rv)`` normalised, or ``q`` for an absurd rotation (readable ``turn``)."""
    rv = np.asarray(rv, float)
    return _correct(q, rv) if float(rv @ rv) < 1e12 else q


# ---------------------------------------------------------------- readable phases
def _predict(s, dt, gyro, w_io_o) -> bool:
    """Gyro phase on the record ``s`` (readable twin of ``spacecraft_cf.predict``): ``q <-
    q ⊗ exp((ω_ib − R_bo ω_io − b̂) dt)``; False (no motion) if the gyro is unusable."""
    gyro = np.asarray(gyro, float)
    if not np.all(np.abs(gyro) < 1e6):
        return False
    w_ob = gyro - quat_rotate(quat_conj(s.q), np.asarray(w_io_o, float)) - s.bias
    s.q[:] = _correct(s.q, w_ob * dt)
    return True


def _correct(q, rv):
    """``normalise(q ⊗ exp(rv))`` (rotation vector rv in rad, body frame)."""
    rv = np.asarray(rv, float)
    q = quat_mul(q, quat_from_rotvec(rv))
    return q / np.linalg.norm(q)


def _vector_error(q, ub, uo):
    """``ub × (R_bo uo)``: Mahony's explicit correction of one unit pair (body frame)."""
    return np.cross(ub, quat_rotate(quat_conj(q), uo))


def _pi_correct(s, kp, ki, e, dt) -> None:
    """Correction phase: ``b̂ <- b̂ − K_I e dt``, ``q <- q ⊗ exp(K_P e dt)``."""
    s.bias[:] = s.bias - ki * e * dt
    s.q[:] = _correct(s.q, kp * e * dt)


class VectorPairFilter(CompiledSampleUpdate, Estimator):
    """What the seed-000 filters share: the kernel's state record (``q_ob``, gyro bias, the
    tail's position), the tail of past samples ``ring`` (the delayed substitute's pairs)
    and the last time; the kernel inputs of a recording's rows, the initial attitude
    (``prepare``), the substitute's readable twin and the batch outputs. Subclasses add
    ``step`` (the readable twin of the kernel's step), ``update``, ``update_reference``,
    ``update_many`` and ``run``."""

    kind = "spacecraft"
    reference_frame = "o"
    needs = ("gyro", "mag", "extra.b_o_nT")
    state_fields = ("state", "t_last", "ring")
    flag_bits = {"mag_unusable": 1, "sun_unusable": 2, "gap": 4, "coast": 8}

    def reset(self, q0_ob=None) -> None:
        """A fresh filter; ``q0_ob`` (4,): start from this attitude (default: ``run`` finds
        one by TRIAD, ``update`` starts from the identity, the orbital frame)."""
        self.state = None  # the kernel's STATE record (an array of one element) once started
        self.t_last = None  # s, last sample processed by ``run``
        self.ring = None  # the tail: the last delay_samples samples (kernels' RING records)
        # the orbital frame's rate when a sample gives none: [0, −n, 0] rad/s
        self._w_io0 = np.array([0.0, -getattr(self.params, "orbital_rate_rad_s", 0.0), 0.0])
        self._reset_sample_path()
        if q0_ob is not None:
            self._start(q0_ob)

    def _new_state(self) -> np.ndarray:
        """A fresh kernel state at the identity (subclasses with more fields override)."""
        from gnomon.kernels.spacecraft_cf import new_state

        return new_state([1.0, 0.0, 0.0, 0.0])

    @property
    def q(self):
        """``q_ob`` (4,) now (a copy), None before the first sample."""
        return None if self.state is None else self.state["q"][0].copy()

    @property
    def bias(self) -> np.ndarray:
        """Gyro-bias estimate (3,) rad/s now (a copy)."""
        return np.zeros(3) if self.state is None else self.state["bias"][0].copy()

    def record(self):
        """The state as a record with named fields (``s.q``, ``s.bias``, ...), writing through
        to ``self.state`` (created with an empty tail if there is none): what the readable
        phases work on."""
        if self.state is None:
            from gnomon.kernels.spacecraft_cf import new_ring

            self.state = self._new_state()
            self.ring = new_ring(self.params.delay_samples)
        return self.state.view(np.recarray)[0]

    # ---------------------------------------------------------------- a recording's rows
    def _rows(self, rec: Recording, first_dt: float = 0.0) -> dict:
        """The kernel inputs of ``rec``'s rows: ``dt`` (N,) s (``first_dt`` at row 0),
        ``gyro``, ``w_io_o``, ``mag_b``, ``mag_o`` (the field model), ``sun_b``, ``sun_o``
        (N, 3) (NaN where there is none) and ``sun_valid`` (N,) bool."""
        n = len(rec)
        dt = np.empty(n)
        dt[0] = first_dt
        dt[1:] = np.diff(rec.t)
        c = np.ascontiguousarray
        nan = np.full((n, 3), np.nan)
        sun_o = rec.extra.get("s_o")
        return {"dt": dt, "gyro": c(rec.gyro, float),
                "w_io_o": _w_io_o(rec, self.params.orbital_rate_rad_s),
                "mag_b": c(rec.mag, float), "mag_o": c(_field_reference(rec)),
                "sun_b": nan if rec.sun is None else c(rec.sun, float),
                "sun_o": nan if sun_o is None else c(sun_o, float),
                "sun_valid": (np.ones(n, bool) if rec.sun is None or rec.sun_valid is None
                              else c(rec.sun_valid, bool))}

    def _keywords(self, x: dict) -> dict:
        """The keyword inputs of ``update_many`` of the rows ``x`` (a sun row NaN where it is
        not valid)."""
        sun_b = np.where(x["sun_valid"][:, None], x["sun_b"], np.nan)
        return {"mag_b": x["mag_b"], "mag_ref_o": x["mag_o"], "sun_b": sun_b,
                "sun_ref_o": x["sun_o"], "w_io_o_rad_s": x["w_io_o"]}

    def buffer_inputs(self, rec: Recording):
        """``rec`` as ``update_many`` takes it: ``((dt, gyro), {mag_b, mag_ref_o, sun_b,
        sun_ref_o, w_io_o_rad_s})`` (``sun_b`` NaN where not valid)."""
        x = self._rows(rec)
        return (x["dt"], x["gyro"]), self._keywords(x)

    def sample_inputs(self, rec: Recording):
        """The rows of ``rec`` as ``update`` takes them (None where a NaN row says "none")."""
        args, kwargs = self.buffer_inputs(rec)
        for k in range(len(args[0])):
            kw = {}
            for key, v in kwargs.items():
                row = v[k]
                kw[key] = row if np.isfinite(row).all() else None
            yield (args[0][k], args[1][k]), kw

    def prepare(self, rec: Recording, q0=None) -> None:
        """What ``run(rec)`` does before its first sample: the attitude ``q0`` if given (the
        rest of the state kept), else for a fresh filter TRIAD of the first sample with the
        sun and a usable field (``initial_q_ob``; the identity without one)."""
        self._prepare(self._rows(rec), q0)

    def _prepare(self, x: dict, q0) -> None:
        if q0 is None and self.state is None:
            valid = (x["sun_valid"] & np.isfinite(x["sun_b"]).all(axis=1)
                     & np.isfinite(x["sun_o"]).all(axis=1))
            q0 = initial_q_ob({"sec_o": x["sun_o"], "mag_o": x["mag_o"], "sec_b": x["sun_b"],
                               "mag_b": x["mag_b"], "sec_valid": valid})
        self._start(q0)

    def _start(self, q0) -> None:
        """The attitude ``q0`` (the rest of the state kept; a fresh state if none); None: a
        fresh state at the identity if there is none."""
        s = self.record()
        if q0 is not None:
            s.q[:] = np.asarray(q0, float) / np.linalg.norm(q0)

    def pairs(self, rec: Recording) -> dict:
        """The kernel inputs of ``rec`` continuing this filter (its tail, its last time) with
        the second pair made (``sec_b``, ``sec_o``, ``sec_valid``, ``substituted``: what
        ``vector_pairs`` gives), the filter unchanged."""
        return self._pairs(self._rows(rec, self.first_dt(rec)))

    def _pairs(self, x: dict) -> dict:
        from gnomon.kernels.spacecraft_cf import new_ring, new_state, pairs_stream

        p = self.params
        if self.state is None:
            state, ring = new_state([1.0, 0.0, 0.0, 0.0]), new_ring(p.delay_samples)
        else:
            state, ring = self.state.copy(), self.ring.copy()
        n = len(x["dt"])
        out = {**x, "sec_b": np.empty((n, 3)), "sec_o": np.empty((n, 3)),
               "sec_valid": np.empty(n, bool), "substituted": np.empty(n, bool)}
        pairs_stream(self._coefficients(), state, ring, x["dt"], x["gyro"], x["w_io_o"],
                     x["mag_b"], x["mag_o"], x["sun_b"], x["sun_o"], x["sun_valid"],
                     out["sec_b"], out["sec_o"], out["sec_valid"], out["substituted"])
        return out

    def _buffer(self, dt_s, gyro_rad_s, w_io_o_rad_s, **arrays):
        """``update_many``'s inputs checked (``buffer``; ``arrays``: name -> (N, 3) or None,
        or ``(value, width)``), the orbital rate by default ``[0, −n, 0]``; the state
        started (the identity) if there is none."""
        spec = {k: (v if isinstance(v, tuple) else (v, 3)) + (None,) for k, v in arrays.items()}
        dt, gyro, x = buffer(dt_s, gyro_rad_s, w_io_o=(w_io_o_rad_s, 3, self._w_io0), **spec)
        self.record()
        return {"dt": dt, "gyro": gyro, **x}

    # ---------------------------------------------------------------- readable twins
    def _reference_row(self, gyro_rad_s, w_io_o_rad_s, mag_b, mag_ref_o, sun_b, sun_ref_o):
        """A streamed sample's inputs for the readable twins (numpy (3,); None: a NaN row,
        the sun pair as none unless both are given; the gyro None: ``NO_GYRO``). Raises
        ``InputError`` for a gyro sample with a non-finite component (nothing done)."""
        g = NO_GYRO.copy() if gyro_rad_s is None else vec(gyro_rad_s, "gyro_rad_s").copy()
        if not np.all(np.isfinite(g)):
            raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                             field="gyro_rad_s")
        w_io = (self._w_io0.copy() if w_io_o_rad_s is None
                else vec(w_io_o_rad_s, "w_io_o_rad_s").copy())
        sun = sun_b is not None and sun_ref_o is not None
        return (g, w_io, _reference_vector(mag_b, "mag_b"),
                _reference_vector(mag_ref_o, "mag_ref_o"),
                _reference_vector(sun_b if sun else None, "sun_b"),
                _reference_vector(sun_ref_o if sun else None, "sun_ref_o"))

    def _second_pair(self, s, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o):
        """Readable twin of ``spacecraft_cf.second_pair``: the second pair of a sample (the
        sun where finite, else the magnetic pair ``delay_samples`` ago, carried to now by
        the accumulated rotations for ``delayed-gyro``, once there is one), then the sample
        joins the tail. Returns ``(sec_b, sec_o, sec_valid, substituted, slot)``."""
        p = self.params
        m, k = p.delay_samples, int(s.n_seen)
        slot = k % m
        gyro_carried = p.sun_substitute == "delayed-gyro"
        if gyro_carried and k > 0:  # the body's and the orbital frame's turns since the start
            h = dt if np.isfinite(dt) else 0.0
            s.q_b0b[:] = _turned(s.q_b0b, np.where(np.abs(gyro) < 1e6, gyro, 0.0) * h)
            s.q_o0o[:] = _turned(s.q_o0o, np.where(np.abs(w_io_o) < 1e6, w_io_o, 0.0) * h)
        ring = self.ring
        sec_b, sec_o, ok, sub = np.zeros(3), np.zeros(3), False, False
        if np.all(np.isfinite(sun_b)) and np.all(np.isfinite(sun_o)):
            sec_b, sec_o, ok = sun_b, sun_o, True
        elif p.sun_substitute != "none" and k >= m:
            sec_b, sec_o = ring["mag_b"][slot].copy(), ring["mag_o"][slot].copy()
            ok = sub = True
            if gyro_carried and np.all(np.isfinite(sec_b)) and np.all(np.isfinite(sec_o)):
                sec_b = quat_rotate(quat_mul(quat_conj(s.q_b0b), ring["q_b0b"][slot]), sec_b)
                sec_o = quat_rotate(quat_mul(quat_conj(s.q_o0o), ring["q_o0o"][slot]), sec_o)
        if p.sun_substitute != "none":  # the tail is read only for a substitute
            ring["mag_b"][slot], ring["mag_o"][slot] = mag_b, mag_o
        if gyro_carried:
            ring["q_b0b"][slot], ring["q_o0o"][slot] = s.q_b0b, s.q_o0o
        s.n_seen = k + 1
        return sec_b, sec_o, ok, sub, slot

    def _predict_phase(self, s, dt_s, gyro, w_io_o, second: str):
        """First phase of every readable ``step``: reset the flags (``second``: the name of
        the second pair's flag), propagate with the gyro over ``dt_s``. Returns whether the
        gyro was usable, or None when the sample has no interval (no step)."""
        self.flags = {"mag_unusable": False, second: False, "gap": False, "coast": False}
        if not (0.0 < dt_s < 1e300):
            return None
        ok_g = _predict(s, dt_s, gyro, w_io_o)
        if not ok_g:
            self.flags["coast"] = True
        return ok_g

    def _gap(self, dt_s) -> bool:
        """Whether the interval is a gap (then flagged: no measurement is used)."""
        if dt_s > self.params.max_dt_s:
            self.flags.update(gap=True, coast=True)
            return True
        return False

    def _begin(self, s, dt_s, gyro, w_io_o, second: str) -> bool:
        """``_predict_phase`` and ``_gap``: True when the sample goes on to the measurements."""
        return (self._predict_phase(s, dt_s, gyro, w_io_o, second) is not None
                and not self._gap(dt_s))

    @staticmethod
    def _outputs(n: int):
        """``q_out`` (n, 4), ``b_out`` (n, 3), ``flags`` (n, 4) int8 for a batch kernel."""
        return np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 4), np.int8)

    def _estimate(self, t, q_out, b_out, flags, names, **signals) -> Estimate:
        """The outputs of a batch kernel (which has continued ``self.state`` in place) as an
        ``Estimate`` at the times ``t``; ``names``: the 4 flag columns' names."""
        flag_signals = {name: flags[:, i].astype(bool) for i, name in enumerate(names)}
        return Estimate(
            t=np.asarray(t, float), q=q_out, estimator=self.name,
            params=self.params.as_dict(), frames={"reference": "o", "body": "b"},
            signals={"bias_rad_s": b_out, **signals, **flag_signals})

    def _finish(self, rec: Recording, est: Estimate) -> Estimate:
        """``run``'s end: keep the last time; the frames of ``rec``."""
        self.t_last = float(rec.t[-1])
        est.frames = {"reference": rec.frames.get("reference", "o"), "body": "b"}
        return est


class ExplicitSpacecraftCF(VectorPairFilter):
    """Explicit complementary filter (Mahony 2008) on the magnetic and sun pairs; ``q_ob``.

    Streaming: ``update(dt_s, gyro_rad_s, *, mag_b, mag_ref_o, sun_b, sun_ref_o,
    w_io_o_rad_s)`` (see the module docstring); batch: ``run(rec)``."""

    name = "ecf-spacecraft"
    summary = ("Explicit complementary filter for spacecraft (seed 000 baseline): mag + sun + "
               "gyro, orbital frame, PI drift estimation, delayed-field sun substitute")
    paper = "seed 000 (baseline: Mahony, Hamel & Pflimlin 2008)"
    Params = SpacecraftCFParams

    def _coefficients(self):
        from gnomon.kernels.spacecraft_cf import ecf_coefficients

        return ecf_coefficients(self.params)

    def _sample_kernel(self):
        """``update``'s kernel (``CompiledSampleUpdate``): ``ecf_sample``."""
        from gnomon.kernels.entry import record
        from gnomon.kernels.spacecraft_cf import ecf_sample

        return ecf_sample, record(self._coefficients())

    def update(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None) -> np.ndarray:
        """One raw sample through the compiled kernel (the arithmetic of ``run``; arguments
        in the module docstring). Returns ``q_ob`` (4,); ``flags`` says what was used.
        ``update_reference`` is the readable twin."""
        if self.state is None:
            self.record()
        if sun_b is None or sun_ref_o is None:
            sun_b = sun_ref_o = None
        w_io = self._w_io0 if w_io_o_rad_s is None else vec(w_io_o_rad_s, "w_io_o_rad_s")
        return self._call(dt_s, gyro_sample(gyro_rad_s), w_io, vec(mag_b, "mag_b"),
                          vec(mag_ref_o, "mag_ref_o"), vec(sun_b, "sun_b"),
                          vec(sun_ref_o, "sun_ref_o"), self.state, self.ring)

    def update_many(self, dt_s, gyro_rad_s, *, mag_b=None, mag_ref_o=None, sun_b=None,
                    sun_ref_o=None, w_io_o_rad_s=None, t_s=None) -> Estimate:
        """A buffer of N raw samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s, ``gyro_rad_s`` (N, 3) and the keyword inputs (N, 3), NaN rows
        where there is no sample (None: none at all; ``w_io_o_rad_s`` None: ``[0, −n,
        0]``). ``t_s`` (N,) the samples' times for the ``Estimate`` (default: the running
        sum of ``dt_s``)."""
        x = self._buffer(dt_s, gyro_rad_s, w_io_o_rad_s, mag_b=mag_b, mag_o=mag_ref_o,
                         sun_b=sun_b, sun_o=sun_ref_o)
        x["sun_valid"] = np.ones(len(x["dt"]), bool)
        return self._batch(x, np.cumsum(x["dt"]) if t_s is None else t_s)

    def _batch(self, x: dict, t) -> Estimate:
        """The rows ``x`` (``_rows``) through ``ecf_stream``, continuing the state."""
        from gnomon.kernels.spacecraft_cf import ecf_stream

        n = len(x["dt"])
        q_out, b_out, flags = self._outputs(n)
        substituted = np.empty(n, bool)
        ecf_stream(self._coefficients(), self.state, self.ring, x["dt"], x["gyro"], x["w_io_o"],
                   x["mag_b"], x["mag_o"], x["sun_b"], x["sun_o"], x["sun_valid"], q_out,
                   b_out, flags, substituted)
        return self._estimate(t, q_out, b_out, flags,
                              ("mag_unusable", "sun_unusable", "gap", "coast"),
                              sun_substituted=substituted)

    def update_reference(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None,
                         sun_b=None, sun_ref_o=None, w_io_o_rad_s=None) -> np.ndarray:
        """The readable twin of ``update`` (numpy, one sample: the substitute from the tail,
        then ``step``; the tests hold the compiled paths to it). Same arguments and result."""
        g, w_io, m_b, m_o, s_b, s_o = self._reference_row(gyro_rad_s, w_io_o_rad_s, mag_b,
                                                          mag_ref_o, sun_b, sun_ref_o)
        s = self.record()
        sec_b, sec_o, ok, _, _ = self._second_pair(s, dt_s, g, w_io, m_b, m_o, s_b, s_o)
        return self.step(dt_s, g, w_io, m_b, m_o, sec_b, sec_o, ok)

    def step(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid) -> np.ndarray:
        """One sample given the kernel's inputs (the second pair already substituted): the
        readable twin of ``spacecraft_cf.ecf_step``. Returns ``q_ob`` (4,)."""
        p = self.params
        s = self.record()
        if not self._begin(s, dt_s, gyro, w_io_o, "sun_unusable"):
            return self.q
        # -- vector pairs: magnetometer, sun (or substitute) unless parallel to it
        ubm, ok_mb = _unit(mag_b)
        uom, ok_mo = _unit(mag_o)
        ok_m = ok_mb and ok_mo
        ubs, ok_sb = _unit(sec_b)
        uos, ok_so = _unit(sec_o)
        ok_s = bool(sec_valid) and ok_sb and ok_so
        if ok_m and ok_s and np.linalg.norm(np.cross(uom, uos)) < np.sin(
                np.radians(p.min_angle_deg)):
            ok_s = False
        self.flags.update(mag_unusable=not ok_m, sun_unusable=not ok_s)
        if not (ok_m or ok_s):
            self.flags["coast"] = True
            return self.q
        # -- PI correction
        e = np.zeros(3)
        if ok_m:
            e += p.k_mag * _vector_error(s.q, ubm, uom)
        if ok_s:
            e += p.k_sun * _vector_error(s.q, ubs, uos)
        if ok_m and ok_s:
            _pi_correct(s, p.kp_rad_s, p.ki_rad_s2, e, dt_s)
        else:
            _pi_correct(s, p.kp_single_rad_s, p.ki_single_rad_s2, e, dt_s)
        return self.q

    def run(self, rec: Recording, q0=None) -> Estimate:
        """Whole recording (compiled: ``prepare``, then the rows as ``update_many`` takes
        them). ``q0``: initial ``q_ob`` (default: TRIAD of the first sample with both pairs,
        else the current state, else identity)."""
        self.check_inputs(rec)
        x = self._rows(rec, self.first_dt(rec))
        self._prepare(x, q0)
        return self._finish(rec, self._batch(x, rec.t))
