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

The compiled paths take raw samples (the delayed pair from the filter's own tail of past
samples, ``ring``): ``update`` streams one (the kernel ``gnomon.kernels.mekf.mekf_sample``),
``update_many`` a buffer of them and ``run`` a recording (``prepare``: the initial
attitude; then the rows as ``update_many`` takes them), both through ``mekf_stream``: any
split of a recording into ``update``/``update_many`` calls gives ``run``'s result.
``update_reference`` is the readable twin in numpy (``gnomon.estimators.mekf_reference``:
``step``, the kernel's step phase by phase; tested sample by sample)::

    update(dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
           sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None, st_boresight_b=None)
           -> q_ob (4,)

``dt_s`` s since the previous sample (the first call starts the filter: from the star
tracker's attitude, else TRIAD of that sample's vectors; no step); ``gyro_rad_s`` (3,)
``ω_ib_b`` rad/s (None: none over this interval, coast; a non-finite component: refused,
``InputError``); ``mag_b`` (3,) the measured field in b (nT when the bias is estimated,
else any unit) and ``mag_ref_o`` (3,) the field model in o; ``sun_b``/``sun_ref_o`` (3,)
the sun direction in b and its model in o (None: none, e.g. eclipse); ``w_io_o_rad_s``
(3,) the orbital frame's rate (default ``[0, −n, 0]``); ``st_q_ob`` (4,) a star-tracker
attitude already in the orbital frame
(``q_oi ⊗ q̂_ib``) and ``st_boresight_b`` (3,) its boresight in b (needed with it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Params, param
from gnomon.estimators.ecf_spacecraft import VectorPairFilter, initial_q_ob
from gnomon.estimators.mekf_reference import FLAG_NAMES, ReadableMEKF
from gnomon.estimators.spacecraft_update import gyro_sample, vec
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_mul

__all__ = ["MEKFParams", "MEKF", "MEKFDelayedParams", "MEKFDelayed", "MEKFSpacecraftParams",
           "MEKFSpacecraft", "star_tracker_inputs", "FLAG_NAMES"]

ARCSEC = np.pi / 180.0 / 3600.0


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


class MEKF(ReadableMEKF, VectorPairFilter):
    """Multiplicative EKF on any of magnetometer, sun sensors, star tracker + gyro; q_ob.

    Streaming: ``update(dt_s, gyro_rad_s, *, mag_b, mag_ref_o, sun_b, sun_ref_o,
    w_io_o_rad_s, st_q_ob, st_boresight_b)`` (module docstring), ``update_many`` (a
    buffer); batch: ``run(rec)``; the readable twin: ``update_reference``."""

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

    flag_bits = dict(zip(FLAG_NAMES, (1, 2, 4, 8, 16), strict=True))

    def _new_state(self) -> np.ndarray:
        from gnomon.kernels.mekf import STATE
        from gnomon.kernels.spacecraft_cf import new_state

        p = self.params
        state = new_state([1.0, 0.0, 0.0, 0.0], STATE)
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
    def _sample_kernel(self):
        """``update``'s kernel (``CompiledSampleUpdate``): ``mekf_sample``."""
        from gnomon.kernels.entry import record
        from gnomon.kernels.mekf import coefficients, mekf_sample

        return mekf_sample, record(coefficients(self.params))

    def _start_from_sample(self, mag_b, mag_o, sun_b, sun_o, st_q) -> None:
        """A fresh filter's attitude from its first streamed sample: the star tracker's, else
        TRIAD of the sample's sun and field (the identity without both)."""
        p = self.params
        if p.use_star_tracker and np.all(np.isfinite(st_q)):
            self._start(st_q)
            return
        sun = p.use_sun and bool(np.all(np.isfinite(sun_b)) and np.all(np.isfinite(sun_o)))
        self._start(initial_q_ob({"sec_o": sun_o[None], "mag_o": mag_o[None],
                                  "sec_b": sun_b[None], "mag_b": mag_b[None],
                                  "sec_valid": np.array([sun])}))

    def update(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None,
               st_boresight_b=None) -> np.ndarray:
        """One raw sample through the compiled kernel (the arithmetic of ``run``; arguments
        in the module docstring). Returns ``q_ob`` (4,); ``flags`` says what was used.
        ``update_reference`` is the readable twin."""
        if sun_b is None or sun_ref_o is None:
            sun_b = sun_ref_o = None
        g, m_b, m_o = gyro_sample(gyro_rad_s), vec(mag_b, "mag_b"), vec(mag_ref_o, "mag_ref_o")
        s_b, s_o, st = vec(sun_b, "sun_b"), vec(sun_ref_o, "sun_ref_o"), vec(st_q_ob, "st_q_ob", 4)
        if not self.params.use_star_tracker:  # as ``run``: a tracker it does not use
            st = vec(None, "st_q_ob", 4)
        if self.state is None:  # start: the tracker's attitude, else TRIAD of this sample
            if not np.all(np.isfinite(g)):
                raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                                 field="gyro_rad_s")
            self._start_from_sample(m_b, m_o, s_b, s_o, st)
            dt_s = 0.0
        w_io = self._w_io0 if w_io_o_rad_s is None else vec(w_io_o_rad_s, "w_io_o_rad_s")
        return self._call(dt_s, g, w_io, m_b, m_o, s_b, s_o, st,
                          vec(st_boresight_b, "st_boresight_b"), self.state, self.ring)

    def update_many(self, dt_s, gyro_rad_s, *, mag_b=None, mag_ref_o=None, sun_b=None,
                    sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None, st_boresight_b=None,
                    t_s=None, keep_covariance: bool = True) -> Estimate:
        """A buffer of N raw samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s, ``gyro_rad_s`` (N, 3), the keyword inputs (N, 3) (``st_q_ob`` (N,
        4)), NaN rows where there is no sample (None: none at all; ``w_io_o_rad_s`` None:
        ``[0, −n, 0]``). ``t_s`` (N,) the samples' times for the ``Estimate`` (default: the
        running sum of ``dt_s``); ``keep_covariance`` as in ``run``."""
        x = self._buffer(dt_s, gyro_rad_s, w_io_o_rad_s, mag_b=mag_b, mag_o=mag_ref_o,
                         sun_b=sun_b, sun_o=sun_ref_o, st_q=(st_q_ob, 4), st_bore=st_boresight_b)
        x["sun_valid"] = np.ones(len(x["dt"]), bool)
        if not self.params.use_star_tracker:
            x["st_q"] = np.full_like(x["st_q"], np.nan)
        x["st_valid"] = np.isfinite(x["st_q"]).all(axis=1)
        if self.state is None and len(x["dt"]):  # start from the first row (no step)
            self._start_from_sample(x["mag_b"][0], x["mag_o"][0], x["sun_b"][0],
                                    x["sun_o"][0], x["st_q"][0])
            x["dt"] = x["dt"].copy()
            x["dt"][0] = 0.0
        return self._batch(x, np.cumsum(x["dt"]) if t_s is None else t_s, keep_covariance)

    # ---------------------------------------------------------------- a recording's rows
    def _rows(self, rec: Recording, first_dt: float = 0.0) -> dict:
        """The kernel inputs of ``rec``'s rows (``VectorPairFilter._rows``, the field in nT,
        zero without a magnetometer: every sample a dropout) and the star tracker's
        (``st_q``, ``st_valid``, ``st_bore``: ``star_tracker_inputs``)."""
        if "magnetometer" not in self._sensors(rec):  # no field: every sample a dropout
            zero = np.zeros((len(rec), 3))
            rec = dataclasses.replace(rec, mag=zero, mag_unit="nT",
                                      extra={**rec.extra, "b_o_nT": zero})
        elif rec.mag_unit != "nT":  # the bias, the magnitude row and mag_noise_nT are in nT
            rec = dataclasses.replace(rec, mag=rec.mag_tesla * 1e9, mag_unit="nT")
        x = super()._rows(rec, first_dt)
        st = star_tracker_inputs(rec, self.params.use_star_tracker)
        x.update(st_q=st["st_q"], st_valid=st["st_valid"], st_bore=st["st_bore"])
        return x

    def _keywords(self, x: dict) -> dict:
        kw = super()._keywords(x)
        if self.params.use_star_tracker and x["st_valid"].any():
            kw.update(st_q_ob=x["st_q"], st_boresight_b=x["st_bore"])
        return kw

    def _prepare(self, x: dict, q0) -> None:
        """The first tracker attitude for a fresh filter (if there is one), else TRIAD of the
        first sample with the sun (when it is used) and the field."""
        if q0 is None and self.state is None and x["st_valid"].any():
            q0 = x["st_q"][int(np.argmax(x["st_valid"]))]
        if not self.params.use_sun:
            x = {**x, "sun_valid": np.zeros(len(x["dt"]), bool)}
        super()._prepare(x, q0)

    # ---------------------------------------------------------------- batch
    def _batch(self, x: dict, t, keep_covariance: bool = True) -> Estimate:
        """The rows ``x`` (``_rows``) through ``mekf_stream``, continuing the state."""
        from gnomon.kernels.mekf import coefficients, mekf_stream

        p = self.params
        n, k = len(x["dt"]), self.n_states
        q_out, b_out, flags = np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 5), np.int8)
        m_out, s_out = np.empty((n, 3)), np.empty((n, 3))
        p_out = np.empty((n, k, k)) if keep_covariance else np.empty((n, 0, 0))
        innov, substituted = np.empty((n, 2)), np.zeros(n, bool)
        mekf_stream(coefficients(p), self.state, self.ring, x["dt"], x["gyro"], x["w_io_o"],
                    x["mag_b"], x["mag_o"], x["sun_b"], x["sun_o"], x["sun_valid"], substituted,
                    False, x["st_q"], x["st_valid"], x["st_bore"], q_out, b_out, m_out, s_out,
                    p_out, flags, innov)
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
            signals["sun_substituted"] = substituted
        return self._estimate(t, q_out, b_out, flags, FLAG_NAMES, **signals)

    def run(self, rec: Recording, q0=None, keep_covariance: bool = True) -> Estimate:
        """Whole recording (compiled: ``prepare``, then the rows as ``update_many`` takes
        them). ``q0``: initial ``q_ob`` (default: the first star-tracker attitude, else
        TRIAD of the first sample with the sun and the field, else the identity). A
        recording without a magnetometer runs on its other sensors (every sample flagged
        ``mag_unusable``). ``keep_covariance`` False: no ``att_std_rad``/``p_diag`` signals
        (saves ``8 n²`` bytes per sample while running)."""
        self.check_inputs(rec)
        x = self._rows(rec, self.first_dt(rec))
        self._prepare(x, q0)
        return self._finish(rec, self._batch(x, rec.t, keep_covariance))


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
