"""One spacecraft multiplicative EKF, ``mekf``, for any set of attitude sensors.

Lefferts, Markley & Shuster's MEKF ("Kalman filtering for spacecraft attitude
estimation", JGCD 5(5), 1982; Markley & Crassidis 2014, ch. 6). It estimates ``q_ob``
(orbital from body, the recordings' ``q_true``) from the gyro ``ω_ib_b`` and whatever
the recording holds of (at least one): the magnetometer (with the field model in o), the
sun sensors (coarse or fine: a unit vector with ``sun_valid``), the star tracker
(``extra.st_q_ib`` with ``st_valid`` and ``st_boresight_b``, turned into ``q̂_ob`` with
``extra.q_io``). Without a gyro: ``ekf-spacecraft`` (the dynamics model).

Error state (``q = q̂ ⊗ exp(θ)``, θ in body axes)::

    x = [θ (rad), δb (rad/s), δm (nT) if estimate_mag_bias, δs (1) if estimate_gyro_scale]

Prediction over ``dt`` with the gyro sample ``g = (I + diag(s)) ω_ib + b + noise``::

    ω̂_ib = (g − b̂) / (1 + ŝ),   q̂ ← q̂ ⊗ exp((ω̂_ib − R̂_bo ω_io_o) dt)
    Φ = I except the θ rows [exp(−[ω̂×] dt), −I dt, 0, −diag(ω̂) dt],   P ← Φ P Φᵀ + Q dt
    Q = diag(arw² I, bias_rw² I, mag_bias_rw² I, gyro_scale_rw² I)

Unit-vector measurements (body ``u``, reference ``v`` in o, noise ``σ`` rad per
direction): ``m̂ = R̂_bo v``, ``y = u − m̂``, ``H = [[m̂×], 0, ∂u/∂m, 0]``. The magnetometer's
``u = (B_b − m̂) / |B_b − m̂|`` has its bias removed when estimated, with
``∂u/∂δm = (I − u uᵀ) / |B_b − m̂|``: the bias is seen in the field direction as the
attitude turns the field through the body over the orbit; and the magnitude the unit
vector drops, ``|B_b − m̂| − |B_model| = uᵀ δm`` (noise ``sigma_mag_norm_nT``: TWOSTEP's
information, in the filter). The magnetometer's direction noise is ``sigma_mag_rad``, or
per sample ``sqrt(sigma_mag_rad² + (mag_noise_nT/|B|)²)`` (the field's strength varies
by 2.5× over a polar orbit). The star tracker's inertial
attitude measured ``L = st_latency_s`` before its stamp t, turned into o with ``q_io(t)``
and carried to t with the inertial rate: ``q_m = q_oi(t) ⊗ q̂_ib(t − L) ⊗ exp(ω̂_ib L)``; ``y =
rotvec(q̂⁻¹ ⊗ q_m)``, ``H = [I, 0]``, ``R = σ_c² (I − b bᵀ) + σ_a² b bᵀ`` with ``b`` the
unit boresight (the noise across and about it); the gyro noise over L is in the
prediction and in the carried measurement alike, so the gain is that of ``P − arw² L I``
(the measurement sees the error of t − L); gated at
``yᵀ S⁻¹ y > st_gate_chi2`` (a wrong star match). Each 3-row block is a Kalman update
``K = P Hᵀ S⁻¹``, ``P ← P − K H P``; the correction ``q̂ ← q̂ ⊗ exp(θ)``.

Options of the form (``gnomon.kernels.mekf``): ``gyro_sample`` (which sample
propagates over an interval), ``transition`` (exponential or first-order attitude
block of Φ), ``relinearise`` (each vector linearised about the attitude corrected by the
vectors before it in the same sample, or all about the prediction: the joint update),
``correction`` (``q̂ ⊗ exp(θ)`` or ``normalise(q̂ ⊗ [1, θ/2])``).
Paper 000's answer to the sun-sensor loss, the magnetometer pair ``delay_samples``
ago in place of the sun with the noise ``sqrt(σ_mag² + (swing_gain·Δ)²)`` (Δ the
estimated swing since then), is ``sun_substitute="delayed"``.

Presets (the two MEKFs gnomon had before, same results to rounding; a test holds them):

* ``mekf-delayed`` (seed 000's remedy): the delayed pair on, the current gyro sample,
  first-order Φ, relinearised vectors, ``arw_rad_rt_s=2e-5``, ``sigma0_att_rad=0.2``.
  Neither preset reads a star tracker (``use_star_tracker=false``): the filters they
  replace had none.
* ``mekf-spacecraft`` (seed 001's remedy: the gyro instead of the dynamics model of
  ``ekf-spacecraft``): the previous gyro sample, exponential Φ, the joint update, the
  first-order correction.
  Its former parameter names (``sigma_mag``, ``p0_att_rad``, ...) raise an error naming
  the new ones.

Bad input: unusable vectors (zero, non-finite) are skipped and flagged, intervals above
``max_dt_s`` propagate only (``gap``), a non-finite gyro sample does not move the
attitude (``coast``): the estimate never holds a NaN.

``run`` calls the kernel ``gnomon.kernels.mekf.mekf_batch``; ``step`` is its readable
twin in numpy (tested sample by sample); ``update`` streams one raw sample::

    update(dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
           sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None, st_boresight_b=None)
           -> q_ob (4,)

``dt_s`` s since the previous sample (the first call starts the filter: from the star
tracker's attitude, else TRIAD of that sample's vectors; no step); ``gyro_rad_s`` (3,)
``ω_ib_b`` rad/s; ``mag_b`` (3,) the measured field in b (nT when the bias is estimated,
else any unit) and ``mag_ref_o`` (3,) the field model in o; ``sun_b``/``sun_ref_o`` (3,)
the sun direction in b and its model in o (None: none, e.g. eclipse); ``w_io_o_rad_s``
(3,) the orbital frame's rate (default ``[0, −n, 0]``); ``st_q_ob`` (4,) a star-tracker
attitude already in the orbital frame
(``q_oi ⊗ q̂_ib``) and ``st_boresight_b`` (3,) its boresight in b.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Params, param
from gnomon.estimators.ecf_spacecraft import VectorPairFilter, _correct, _unit
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_conj, quat_from_rotvec, quat_mul, quat_rotate, skew

__all__ = ["MEKFParams", "MEKF", "MEKFDelayedParams", "MEKFDelayed", "MEKFSpacecraftParams",
           "MEKFSpacecraft", "star_tracker_inputs"]

ARCSEC = np.pi / 180.0 / 3600.0
FLAG_NAMES = ("mag_unusable", "sun_unusable", "gap", "coast", "star_unused")


@dataclass(frozen=True)
class MEKFParams(Params):
    """Tuning of :class:`MEKF` (SI; noise as 1-sigma)."""

    sigma_mag_rad: float = param(0.03, "rad", "direction noise of the magnetometer (noise/|B| "
                                 "plus field-model error)")
    mag_noise_nT: float = param(0.0, "nT", "magnetometer white noise: adds (mag_noise_nT/|B|)² "
                                "to the direction variance per sample (0: sigma_mag_rad only)")
    sigma_sun_rad: float = param(0.005, "rad", "direction noise of the sun sensor")
    arw_rad_rt_s: float = param(1e-4, "rad/sqrt(s)", "gyro angle random walk")
    bias_rw_rad_s_rt_s: float = param(1e-6, "rad/s/sqrt(s)", "gyro bias random walk")
    sigma0_att_rad: float = param(0.05, "rad", "initial attitude standard deviation")
    sigma0_bias_rad_s: float = param(0.002, "rad/s", "initial gyro bias standard deviation")
    estimate_mag_bias: bool = param(False, "", "estimate a magnetometer bias (3 states, nT)")
    sigma0_mag_bias_nT: float = param(1000.0, "nT", "initial magnetometer bias std")
    mag_bias_rw_nT_rt_s: float = param(0.0, "nT/sqrt(s)", "magnetometer bias random walk")
    sigma_mag_norm_nT: float = param(500.0, "nT", "with the bias estimated: noise of |B - bias| "
                                     "- |B_model| (sensor noise plus field-model error; 0: "
                                     "the field's direction only)")
    estimate_gyro_scale: bool = param(False, "", "estimate gyro scale factors (3 states)")
    sigma0_gyro_scale: float = param(0.01, "1", "initial gyro scale-factor std")
    gyro_scale_rw_rt_s: float = param(0.0, "1/sqrt(s)", "gyro scale-factor random walk")
    use_sun: bool = param(True, "", "use the sun sensor where it is valid")
    sun_substitute: str = param("none", "", "where the sun is invalid: none | delayed (paper "
                                "000's delayed magnetometer pair, weighted by the swing)")
    delay_samples: int = param(500, "samples", "M of the delayed magnetometer pair")
    swing_gain: float = param(8.0, "", "the delayed pair's noise grows by this times the "
                              "estimated attitude change over M samples (rad)")
    use_star_tracker: bool = param(True, "", "use the star tracker where the recording has "
                                   "one (extra.st_q_ib)")
    st_sigma_cross_rad: float = param(10 * ARCSEC, "rad", "star tracker noise about each "
                                      "axis across the boresight (10 arcsec)")
    st_sigma_about_rad: float = param(60 * ARCSEC, "rad", "star tracker noise about the "
                                      "boresight (60 arcsec)")
    st_latency_s: float = param(0.0, "s", "a star-tracker attitude stamped t is that of "
                                "t - latency (carried forward with the gyro)")
    st_gate_chi2: float = param(30.0, "", "reject a star-tracker attitude whose innovation "
                                "chi-square (3 dof) exceeds this (0: never)")
    gyro_sample: str = param("previous", "", "which gyro sample propagates over t[k-1]..t[k]: "
                             "previous (held) | current")
    transition: str = param("exponential", "", "attitude block of the transition matrix: "
                            "exponential | first-order (for turns up to 0.1 rad a sample)")
    relinearise: bool = param(False, "", "linearise each vector about the attitude already "
                              "corrected by the ones before it in the sample (false: the "
                              "joint update)")
    correction: str = param("exponential", "", "attitude correction: exponential (q ⊗ "
                            "exp(θ)) | first-order (normalise(q ⊗ [1, θ/2]))")
    orbital_rate_rad_s: float = param(0.0011, "rad/s", "mean motion n if the recording has no "
                                      "extra.w_io_o")
    max_dt_s: float = param(10.0, "s", "longer sample intervals are gaps: propagation only")

    def validate(self):
        for name in ("sigma_mag_rad", "sigma_sun_rad", "st_sigma_cross_rad",
                     "st_sigma_about_rad", "max_dt_s"):
            self._require(name, getattr(self, name) > 0, "must be > 0")
        for name in ("arw_rad_rt_s", "bias_rw_rad_s_rt_s", "sigma0_att_rad",
                     "sigma0_bias_rad_s", "sigma0_mag_bias_nT", "mag_bias_rw_nT_rt_s",
                     "mag_noise_nT", "sigma_mag_norm_nT",
                     "sigma0_gyro_scale", "gyro_scale_rw_rt_s", "st_latency_s",
                     "st_gate_chi2", "orbital_rate_rad_s", "swing_gain"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")
        self._require("sun_substitute", self.sun_substitute in ("none", "delayed"),
                      "must be none or delayed")
        self._require("delay_samples", self.delay_samples >= 1, "must be >= 1")
        self._require("gyro_sample", self.gyro_sample in ("previous", "current"),
                      "must be previous or current")
        for name in ("transition", "correction"):
            self._require(name, getattr(self, name) in ("exponential", "first-order"),
                          "must be exponential or first-order")


@dataclass(frozen=True)
class MEKFDelayedParams(MEKFParams):
    """``mekf-delayed``: seed 000's remedy for the sun-sensor loss (the delayed pair)."""

    arw_rad_rt_s: float = param(2e-5, "rad/sqrt(s)", "gyro angle random walk")
    sigma0_att_rad: float = param(0.2, "rad", "initial attitude standard deviation")
    sigma0_bias_rad_s: float = param(1e-3, "rad/s", "initial gyro bias standard deviation")
    sun_substitute: str = param("delayed", "", "where the sun is invalid: none | delayed "
                                "(paper 000's delayed magnetometer pair, weighted by the "
                                "swing)")
    gyro_sample: str = param("current", "", "which gyro sample propagates over "
                             "t[k-1]..t[k]: previous (held) | current")
    transition: str = param("first-order", "", "attitude block of the transition matrix: "
                            "exponential | first-order")
    relinearise: bool = param(True, "", "linearise each vector about the attitude already "
                              "corrected by the ones before it in the sample (false: the "
                              "joint update)")
    orbital_rate_rad_s: float = param(0.0, "rad/s", "mean motion n if the recording has no "
                                      "extra.w_io_o")
    use_star_tracker: bool = param(False, "", "use the star tracker where the recording has "
                                   "one (extra.st_q_ib; off: the seed-000 filter had none)")


@dataclass(frozen=True)
class MEKFSpacecraftParams(MEKFParams):
    """``mekf-spacecraft``: seed 001's remedy (the gyro instead of the dynamics model)."""

    renamed = {"sigma_mag": "sigma_mag_rad", "sigma_sun": "sigma_sun_rad",
               "gyro_arw_rad_rt_s": "arw_rad_rt_s", "gyro_rrw_rad_s_rt_s": "bias_rw_rad_s_rt_s",
               "p0_att_rad": "sigma0_att_rad", "p0_bias_rad_s": "sigma0_bias_rad_s",
               "orbit_rate_rad_s": "orbital_rate_rad_s"}

    correction: str = param("first-order", "", "attitude correction: exponential (q ⊗ "
                            "exp(θ)) | first-order (normalise(q ⊗ [1, θ/2]))")
    use_star_tracker: bool = param(False, "", "use the star tracker where the recording has "
                                   "one (extra.st_q_ib; off: the seed-001 filter had none)")


def star_tracker_inputs(rec: Recording, use: bool = True) -> dict:
    """``st_q`` (N, 4) the star tracker's ``q̂_ob = q_io⁻¹ ⊗ q̂_ib`` (NaN where none),
    ``st_valid`` (N,) bool and ``st_bore`` (N, 3) its boresight in b, from
    ``extra.st_q_ib``, ``st_valid``, ``st_boresight_b`` and ``q_io``; all invalid without
    a star tracker (or ``use`` False)."""
    n = len(rec)
    st = rec.extra.get("st_q_ib") if use else None
    if st is None:
        return {"st_q": np.full((n, 4), np.nan), "st_valid": np.zeros(n, bool),
                "st_bore": np.zeros((n, 3))}
    q_io = rec.extra.get("q_io")
    if q_io is None:
        raise InputError("a star tracker's inertial attitude needs the orbital frame's "
                         "attitude q_io to be used in the orbital frame",
                         field="extra.q_io", file=rec.source or None)
    st = np.asarray(st, float).reshape(n, 4)
    valid = np.all(np.isfinite(st), axis=1)
    if rec.extra.get("st_valid") is not None:
        valid &= np.asarray(rec.extra["st_valid"], bool).reshape(n)
    q = np.full((n, 4), np.nan)
    q[valid] = quat_mul(quat_conj(np.asarray(q_io, float).reshape(n, 4)[valid]), st[valid])
    bore = rec.extra.get("st_boresight_b")
    bore = np.tile([0.0, 0.0, 1.0], (n, 1)) if bore is None else np.asarray(bore, float)
    return {"st_q": np.ascontiguousarray(q), "st_valid": valid,
            "st_bore": np.ascontiguousarray(bore.reshape(n, 3))}


class MEKF(VectorPairFilter):
    """Multiplicative EKF on any of magnetometer, sun sensors, star tracker + gyro; q_ob.

    Streaming: ``update(dt_s, gyro_rad_s, *, mag_b, mag_ref_o, sun_b, sun_ref_o,
    w_io_o_rad_s, st_q_ob, st_boresight_b)`` (module docstring); batch: ``run(rec)``."""

    name = "mekf"
    summary = ("Multiplicative EKF (Lefferts-Markley-Shuster): gyro + any of magnetometer, "
               "sun sensors, star tracker; gyro bias, optional magnetometer bias and gyro "
               "scale factors")
    paper = "seeds 000, 001 (remedy: Lefferts, Markley & Shuster 1982)"
    #: the gyro, and at least one of the attitude sensors (``check_inputs``)
    needs = ("gyro",)
    Params = MEKFParams
    #: each attitude sensor and what it needs in the recording
    SENSOR_INPUTS = {"magnetometer": ("mag", "extra.b_o_nT"), "sun sensor": ("sun", "extra.s_o"),
                     "star tracker": ("extra.st_q_ib", "extra.q_io")}

    def check_inputs(self, rec: Recording) -> None:
        """Besides ``needs``: at least one attitude sensor with its reference, else an
        ``InputError`` naming what each would need."""
        super().check_inputs(rec)
        if not self._sensors(rec):
            need = "; ".join(f"{k}: {' and '.join(v)}" for k, v in self.SENSOR_INPUTS.items())
            raise InputError(f"filter '{self.name}' needs an attitude sensor besides the gyro "
                             f"({need}); the recording has none",
                             field="mag", file=rec.source or None)

    def _sensors(self, rec: Recording) -> list[str]:
        """The attitude sensors of ``rec`` this filter uses."""
        def has(name):
            return (rec.extra.get(name[6:]) is not None if name.startswith("extra.")
                    else getattr(rec, name) is not None)
        used = [k for k, v in self.SENSOR_INPUTS.items() if all(has(x) for x in v)]
        if not self.params.use_sun:
            used = [k for k in used if k != "sun sensor"]
        if not self.params.use_star_tracker:
            used = [k for k in used if k != "star tracker"]
        return used

    def reset(self, q0_ob=None) -> None:
        self.history = []  # past estimates (the delayed pair's weight, streaming)
        super().reset(q0_ob)

    def _new_state(self) -> np.ndarray:
        from gnomon.kernels.mekf import STATE

        p = self.params
        state = np.zeros(1, STATE)
        state["q"][0] = [1.0, 0.0, 0.0, 0.0]
        sd = [p.sigma0_att_rad] * 3 + [p.sigma0_bias_rad_s] * 3
        if p.estimate_mag_bias:
            sd += [p.sigma0_mag_bias_nT] * 3
        if p.estimate_gyro_scale:
            sd += [p.sigma0_gyro_scale] * 3
        n = len(sd)
        state["P"][0, :n, :n] = np.diag(np.square(sd))
        return state

    @property
    def n_states(self) -> int:
        """Size of the error state: 6, plus 3 for each of the magnetometer bias and the gyro
        scale factors when estimated."""
        p = self.params
        return 6 + 3 * bool(p.estimate_mag_bias) + 3 * bool(p.estimate_gyro_scale)

    @property
    def P(self):
        """Covariance (n, n) of the error state now (a copy), None before starting."""
        n = self.n_states
        return None if self.state is None else self.state["P"][0, :n, :n].copy()

    @property
    def mag_bias(self) -> np.ndarray:
        """Magnetometer-bias estimate (3,) nT now (a copy; zero unless estimated)."""
        return np.zeros(3) if self.state is None else self.state["mag_bias"][0].copy()

    @property
    def gyro_scale(self) -> np.ndarray:
        """Gyro scale-factor estimate (3,) now (a copy; zero unless estimated)."""
        return np.zeros(3) if self.state is None else self.state["scale"][0].copy()

    # ---------------------------------------------------------------- streaming
    def update(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None,
               st_boresight_b=None) -> np.ndarray:
        """One raw sample (streaming; arguments in the module docstring). Returns ``q_ob``
        (4,); ``self.flags`` says what was used."""
        fresh = self.state is None
        x = self.stream_pairs(dt_s, gyro_rad_s, mag_b, mag_ref_o, sun_b, sun_ref_o,
                              w_io_o_rad_s)
        valid = bool(x["sec_valid"]) and self.params.use_sun
        if fresh:  # start: the tracker's attitude, else TRIAD of this sample; no step
            one = {k: np.asarray(v)[None] for k, v in x.items()}
            one["sec_valid"] = np.array([valid])
            st_ok = (st_q_ob is not None and self.params.use_star_tracker
                     and bool(np.all(np.isfinite(st_q_ob))))
            self._start(one, np.asarray(st_q_ob, float) if st_ok else None)
            dt_s = 0.0
        return self.step(dt_s, x["gyro"], x["w_io_o"], x["mag_b"], x["mag_o"], x["sec_b"],
                         x["sec_o"], valid, x["substituted"], st_q_ob, st_boresight_b)

    # ---------------------------------------------------------------- readable twin
    def step(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
             substituted=False, st_q_ob=None, st_boresight_b=None) -> np.ndarray:
        """One sample given the kernel's inputs (readable twin of ``gnomon.kernels.mekf.step``
        and the batch loop's hold). Returns ``q_ob`` (4,)."""
        p = self.params
        s = self.record()
        self.flags = dict.fromkeys(FLAG_NAMES, False)
        if 0.0 < dt_s < 1e300:
            self._step(s, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, bool(sec_valid),
                       bool(substituted), st_q_ob, st_boresight_b)
        s.gyro_b[:] = gyro
        s.w_io_o[:] = w_io_o
        q = self.q
        self.history.append(q)
        if len(self.history) > p.delay_samples:
            self.history.pop(0)
        return q.copy()

    def _step(self, s, dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted,
              st_q, st_bore):
        p, n = self.params, self.n_states
        P = s.P[:n, :n]
        # -- gyro prediction: attitude, then covariance
        g, w_io = ((s.gyro_b.copy(), s.w_io_o.copy()) if p.gyro_sample == "previous"
                   else (np.asarray(gyro, float), np.asarray(w_io_o, float)))
        if np.all(np.abs(g) < 1e6):
            w = g - s.bias
            if p.estimate_gyro_scale:
                w = w / (1.0 + s.scale)
            w_ob = w - quat_rotate(quat_conj(s.q), w_io)
            s.q[:] = _correct(s.q, w_ob * dt)
        else:
            w = np.zeros(3)
            self.flags["coast"] = True
        Phi = self._transition(w, dt)
        P[:] = Phi @ P @ Phi.T + self._q_noise() * dt
        if dt > p.max_dt_s:
            self.flags.update(gap=True, coast=True)
            return
        # -- magnetometer, then the sun or the delayed magnetometer pair in its place
        dx = np.zeros(n)
        ok_m = self._magnetometer(s, P, dx, mag_b, mag_o)
        sigma = self._second_sigma(s.q, sec_valid, substituted)
        ok_s = sigma is not None and self._vector(s, P, dx, sec_b, sec_o, sigma)
        if not p.relinearise and (ok_m or ok_s):
            self._apply(s, dx)
        # -- star tracker
        ok_t = False
        if st_q is not None and np.all(np.isfinite(st_q)):
            ok_t = self._star(s, P, dx, np.asarray(st_q, float), st_bore, w)
            self.flags["star_unused"] = not ok_t
        self.flags.update(mag_unusable=not ok_m, sun_unusable=not ok_s,
                          coast=self.flags["coast"] or not (ok_m or ok_s or ok_t))

    def _transition(self, w, dt):
        p, n = self.params, self.n_states
        Phi = np.eye(n)
        if p.transition == "exponential" or np.dot(w, w) * dt * dt > 0.01:  # > 0.1 rad
            Phi[:3, :3] = dcm_from_quat(quat_from_rotvec(-w * dt))
        else:
            Phi[:3, :3] -= skew(w) * dt
        Phi[:3, 3:6] = -np.eye(3) * dt
        if p.estimate_gyro_scale:
            Phi[:3, n - 3:] = -np.diag(w) * dt
        return Phi

    def _q_noise(self):
        p = self.params
        q = [p.arw_rad_rt_s ** 2] * 3 + [p.bias_rw_rad_s_rt_s ** 2] * 3
        if p.estimate_mag_bias:
            q += [p.mag_bias_rw_nT_rt_s ** 2] * 3
        if p.estimate_gyro_scale:
            q += [p.gyro_scale_rw_rt_s ** 2] * 3
        return np.diag(q)

    def _second_sigma(self, q, sec_valid, substituted):
        """Noise (rad) of the second pair, None when it is not used (readable twin of
        ``second_sigma``)."""
        p = self.params
        if not sec_valid:
            return None
        if not substituted:
            return p.sigma_sun_rad
        if len(self.history) < p.delay_samples:
            return None
        old = self.history[-p.delay_samples]
        swing = 2.0 * np.arccos(min(1.0, abs(float(old @ q))))
        return np.sqrt(p.sigma_mag_rad ** 2 + (p.swing_gain * swing) ** 2)

    @staticmethod
    def _kalman(P, dx, H, y, R):
        """``dx += K (y − H dx)``, ``P ← P − K H P`` in place; the innovation's χ², None if
        ``S`` is singular."""
        S = H @ P @ H.T + R
        if not np.linalg.det(S) > 0:
            return None
        r = y - H @ dx
        K = P @ H.T @ np.linalg.inv(S)
        dx += K @ r
        P_new = P - K @ (H @ P)
        P[:] = 0.5 * (P_new + P_new.T)
        return float(r @ np.linalg.solve(S, r))

    def _apply(self, s, dx):
        """The correction: ``q ⊗ exp(θ)``, the biases (and scales) added; ``dx`` cleared."""
        p, n = self.params, self.n_states
        if p.correction == "exponential":
            s.q[:] = _correct(s.q, dx[:3])
        else:
            q = quat_mul(s.q, np.concatenate([[1.0], 0.5 * dx[:3]]))
            s.q[:] = q / np.linalg.norm(q)
        s.bias[:] = s.bias + dx[3:6]
        if p.estimate_mag_bias:
            s.mag_bias[:] = s.mag_bias + dx[6:9]
        if p.estimate_gyro_scale:
            s.scale[:] = s.scale + dx[n - 3:]
        dx[:] = 0.0

    def _magnetometer(self, s, P, dx, mag_b, mag_o) -> bool:
        """The magnetometer (readable twin of ``magnetometer``): a zero or non-finite field is
        a dropout; its bias removed when estimated, then the magnitude row."""
        p = self.params
        if not _unit(mag_b)[1]:
            return False
        v = np.asarray(mag_b, float) - s.mag_bias
        sigma = p.sigma_mag_rad
        if p.mag_noise_nT > 0 and _unit(v)[1]:
            sigma = np.sqrt(sigma ** 2 + (p.mag_noise_nT / np.linalg.norm(v)) ** 2)
        if not self._vector(s, P, dx, v, mag_o, sigma, mag_bias=p.estimate_mag_bias):
            return False
        if p.estimate_mag_bias and p.sigma_mag_norm_nT > 0:
            u = v / np.linalg.norm(v)
            H = np.zeros((1, self.n_states))
            H[0, 6:9] = u
            y = np.array([np.linalg.norm(v) - np.linalg.norm(mag_o)])
            if self._kalman(P, dx, H, y, np.array([[p.sigma_mag_norm_nT ** 2]])) is not None \
                    and p.relinearise:
                self._apply(s, dx)
        return True

    def _vector(self, s, P, dx, vb, vo, sigma, mag_bias=False) -> bool:
        """One unit-vector measurement (readable twin of ``vector_update``); False if either
        vector is unusable."""
        ub, ok_b = _unit(vb)
        uo, ok_o = _unit(vo)
        if not (ok_b and ok_o):
            return False
        m = quat_rotate(quat_conj(s.q), uo)
        H = np.zeros((3, self.n_states))
        H[:, :3] = skew(m)
        if mag_bias:
            H[:, 6:9] = (np.eye(3) - np.outer(ub, ub)) / np.linalg.norm(vb)
        if self._kalman(P, dx, H, ub - m, sigma ** 2 * np.eye(3)) is None:
            return False
        if self.params.relinearise:
            self._apply(s, dx)
        return True

    def _star(self, s, P, dx, st_q, bore, w_ib) -> bool:
        """The star tracker (readable twin of ``star_tracker``): ``st_q`` carried over the
        latency with the inertial rate ``w_ib``; False if gated out."""
        p = self.params
        b, ok = _unit(bore)
        if not ok:
            return False
        q_m = quat_mul(st_q, quat_from_rotvec(w_ib * p.st_latency_s))
        d = quat_mul(quat_conj(s.q), q_m)
        d = -d if d[0] < 0 else d
        v = np.linalg.norm(d[1:])
        y = d[1:] * (2.0 * np.arctan2(v, d[0]) / v if v > 1e-12 else 2.0)
        H = np.zeros((3, self.n_states))
        H[:, :3] = np.eye(3)
        R = (p.st_sigma_cross_rad ** 2 * (np.eye(3) - np.outer(b, b))
             + p.st_sigma_about_rad ** 2 * np.outer(b, b))
        saved = P.copy()
        lat = p.arw_rad_rt_s ** 2 * p.st_latency_s * np.diag([1.0] * 3 + [0.0] * (len(P) - 3))
        P -= lat  # the gain of P(t − L): the gyro noise since is in both
        chi2 = self._kalman(P, dx, H, y, R)
        P += lat
        if chi2 is None or (p.st_gate_chi2 > 0 and chi2 > p.st_gate_chi2):
            P[:] = saved
            dx[:] = 0.0
            return False
        self._apply(s, dx)
        return True

    # ---------------------------------------------------------------- batch
    def run(self, rec: Recording, q0=None, keep_covariance: bool = True) -> Estimate:
        """Whole recording (compiled). ``q0``: initial ``q_ob`` (default: the first star-tracker
        attitude, else TRIAD of the first sample with the sun and the field, else the
        identity). A recording without a magnetometer runs on its other sensors (every
        sample flagged ``mag_unusable``). ``keep_covariance`` False: no
        ``att_std_rad``/``p_diag`` signals (saves ``8 n²`` bytes per sample while running)."""
        from gnomon.kernels.mekf import coefficients, mekf_batch

        self.check_inputs(rec)
        p = self.params
        if "magnetometer" not in self._sensors(rec):  # no field: every sample a dropout
            zero = np.zeros((len(rec), 3))
            rec = dataclasses.replace(rec, mag=zero, mag_unit="nT",
                                      extra={**rec.extra, "b_o_nT": zero})
        elif rec.mag_unit != "nT":  # the bias, the magnitude row and mag_noise_nT are in nT
            rec = dataclasses.replace(rec, mag=rec.mag_tesla * 1e9, mag_unit="nT")
        pairs = self.pairs(rec)
        if not p.use_sun:
            pairs["sec_valid"] = np.zeros(len(rec), bool)
        st = star_tracker_inputs(rec, p.use_star_tracker)
        if q0 is None and self.state is None and st["st_valid"].any():
            q0 = st["st_q"][int(np.argmax(st["st_valid"]))]  # the first tracker attitude
        self._start(pairs, q0)
        n, k = len(rec), self.n_states
        q_out, b_out, flags = np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 5), np.int8)
        m_out, s_out = np.empty((n, 3)), np.empty((n, 3))
        p_out = np.empty((n, k, k)) if keep_covariance else np.empty((n, 0, 0))
        innov = np.empty((n, 2))
        mekf_batch(coefficients(p), self.state, pairs["dt"], pairs["gyro"], pairs["w_io_o"],
                   pairs["mag_b"], pairs["mag_o"], pairs["sec_b"], pairs["sec_o"],
                   pairs["sec_valid"], pairs["substituted"], st["st_q"], st["st_valid"],
                   st["st_bore"], q_out, b_out, m_out, s_out, p_out, flags, innov)
        signals = {"innovation_mag": innov[:, 0], "innovation_sun": innov[:, 1]}
        if keep_covariance:
            diag = np.diagonal(p_out, axis1=1, axis2=2)
            signals.update(p_diag=diag.copy(), att_std_rad=np.sqrt(diag[:, :3]),
                           att_cov_rad2=p_out[:, :3, :3].copy())
        if p.estimate_mag_bias:
            signals["mag_bias_nT"] = m_out
        if p.estimate_gyro_scale:
            signals["gyro_scale"] = s_out
        if p.sun_substitute != "none":
            signals["sun_substituted"] = pairs["substituted"]
        return self._finish(rec, pairs, q_out, b_out, flags, FLAG_NAMES, **signals)


class MEKFDelayed(MEKF):
    """Preset of :class:`MEKF`: seed 000's remedy (keeps attitude and drift through sun
    outages, the paper's delayed pair weighted by the swing)."""

    name = "mekf-delayed"
    summary = ("Preset of mekf for seed 000: mag (+ sun where valid, else the delayed pair "
               "weighted by the swing) + gyro with bias")
    paper = "seed 000 (remedy: Lefferts, Markley & Shuster 1982)"
    needs = ("gyro", "mag", "extra.b_o_nT")
    Params = MEKFDelayedParams


class MEKFSpacecraft(MEKF):
    """Preset of :class:`MEKF`: seed 001's remedy (the gyro instead of the dynamics model),
    the joint magnetometer + sun update."""

    name = "mekf-spacecraft"
    summary = "Preset of mekf for seed 001: gyro, magnetometer + sun sensor, joint update"
    paper = "seed 001 (remedy: Lefferts, Markley & Shuster 1982)"
    needs = ("gyro", "mag", "sun", "extra.b_o_nT", "extra.s_o")
    Params = MEKFSpacecraftParams
