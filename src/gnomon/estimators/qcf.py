"""Complementary filter driven by a measured quaternion (the proposal of seed 000).

"Estimating the attitude of a microsatellite with a complementary filter"
(``shared/spec/000-microsat-complementary.md``): the two vector pairs
(magnetometer / field model, sun sensor / sun model) give a *measured*
attitude ``q_mes`` (= ``q_ob``, orbital from body) by a Wahba solver, and the
filter corrects its gyro propagation with the error quaternion

    e = conj(q̂) ⊗ q_mes        (sign chosen so that e_w >= 0)
    q̂ ← q̂ ⊗ exp((ω_ib − R̂_bo ω_io − b̂) dt)            (predict)
    b̂ ← b̂ − K_I vec(e) dt,   q̂ ← q̂ ⊗ exp(K_P vec(e) dt)  (correct)

(the paper's ``d = K_P vec(e) + K_I ∫vec(e)``). For a small error ``θ``,
``vec(e) ≈ −θ/2``: the correction acts with ``K_P/2`` on every axis (the
explicit filter acts with ``K_P (I + c cᵀ)``, ``c = b × s``: 2x on b, s and 4x on c
at the same ``K_P``, see ``ecf_spacecraft``).

``q_mes`` comes from the paper's Gauss-Newton iteration by default
(``solver="gauss-newton"``: ``gn_iterations`` steps per sample, each sample
starting from the previous solution — compiled in
``gnomon.kernels.spacecraft_cf.gn_sequence``), or from any solver of
``gnomon.estimators.wahba`` (``triad``, ``davenport``, ``quest``, ``svd``,
vectorised over the samples). Degenerate samples (a pair unusable, the two
directions closer than the quality threshold) give no measurement: the filter
then uses the magnetometer pair alone with ``kp_single_rad_s``,
``ki_single_rad_s2`` (the magnetometer + gyro filter) or, with both zero,
coasts on the gyro. Sun loss is handled by the same substitutes as the
explicit filter (``sun_substitute``: the paper's delayed magnetometer pair,
the gyro-propagated one, or none).

``run`` measures ``q_mes`` (``measure``: the sun's substitutes from the filter's tail,
``gnomon.kernels.spacecraft_cf.pairs_stream``) and runs the kernel
``gnomon.kernels.spacecraft_cf.qcf_stream`` (coefficients ``qcf_coefficients(params)``,
state record ``STATE``) as ``update_many`` does; ``update`` runs one sample of it
(``qcf_sample``): any split of a recording into ``update``/``update_many`` calls gives
``run``'s result. ``update_reference`` is the readable twin of ``update`` (``step``, the
twin of ``qcf_step`` phase by phase: gyro prediction, measured quaternion, magnetometer
fallback, PI correction). Streaming: ``update(dt_s, gyro_rad_s=None, *, q_mes_ob=None,
mag_b=None, mag_ref_o=None, w_io_o_rad_s=None)`` with ``q_mes_ob`` (4,) a measured
``q_ob`` (any solver; None: no measurement at this sample) and the other arguments as in
``gnomon.estimators.ecf_spacecraft`` (``None`` = no new sample); the magnetic pair joins
the tail a later ``run`` makes its substitutes from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.estimators.base import Estimate, Params, param
from gnomon.estimators.ecf_spacecraft import (
    KI_RENAMED,
    SUN_SUBSTITUTES,
    VectorPairFilter,
    _pi_correct,
    _unit,
    _vector_error,
    initial_q_ob,
)
from gnomon.estimators.spacecraft_update import gyro_sample, vec
from gnomon.estimators.wahba import DEFAULT_MIN_QUALITY, SOLVERS, solve
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_mul

__all__ = ["QuaternionCFParams", "QuaternionCF", "measured_quaternions",
           "gauss_newton_sequence_py"]


@dataclass(frozen=True)
class QuaternionCFParams(Params):
    renamed = KI_RENAMED

    kp_rad_s: float = param(0.06, "rad/s", "proportional gain K_P on vec(conj(q̂) ⊗ q_mes) "
                             "(tuned on seed000)")
    ki_rad_s2: float = param(6e-4, "rad/s^2", "integral gain K_I (gyro drift estimation)")
    kp_single_rad_s: float = param(0.005, "rad/s", "K_P of the magnetometer-only correction "
                                   "when there is no q_mes")
    ki_single_rad_s2: float = param(2e-5, "rad/s^2", "K_I of the magnetometer-only "
                                    "correction")
    solver: str = param("gauss-newton", "", "Wahba solver for q_mes: gauss-newton | quest | "
                        "davenport | svd | triad")
    gn_iterations: int = param(2, "", "Gauss-Newton steps per sample")
    k_mag: float = param(1.0, "", "weight of the magnetometer pair in Wahba's loss")
    k_sun: float = param(1.0, "", "weight of the sun (or substitute) pair")
    sun_substitute: str = param("delayed", "", "when the sun is invalid: delayed | "
                                "delayed-gyro | none")
    delay_samples: int = param(500, "samples", "M of the delayed magnetometer pair")
    min_quality: float = param(DEFAULT_MIN_QUALITY, "", "Wahba quality s2/s1 below which "
                               "q_mes is not used")
    orbital_rate_rad_s: float = param(0.0, "rad/s", "mean motion n if the recording has no "
                                      "extra['w_io_o']")
    max_dt_s: float = param(10.0, "s", "longer sample intervals are gaps: gyro only")

    def validate(self):
        for name in ("kp_rad_s", "ki_rad_s2", "kp_single_rad_s", "ki_single_rad_s2", "k_mag",
                     "k_sun", "orbital_rate_rad_s", "min_quality"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")
        self._require("solver", self.solver in SOLVERS, f"must be one of {', '.join(SOLVERS)}")
        self._require("gn_iterations", self.gn_iterations >= 1, "must be >= 1")
        self._require("sun_substitute", self.sun_substitute in SUN_SUBSTITUTES,
                      f"must be one of {', '.join(SUN_SUBSTITUTES)}")
        self._require("delay_samples", self.delay_samples >= 1, "must be >= 1")
        self._require("max_dt_s", self.max_dt_s > 0, "must be > 0")


def gauss_newton_sequence_py(pairs: dict, q0, iterations: int = 2, k_mag: float = 1.0,
                             k_sun: float = 1.0, min_quality: float = DEFAULT_MIN_QUALITY):
    """Readable twin of the compiled ``gn_sequence``: (q_mes (N, 4), ok (N,))."""
    from gnomon.estimators.wahba import gauss_newton

    n = len(pairs["dt"])
    q = np.asarray(q0, float) / np.linalg.norm(q0)
    out = np.empty((n, 4))
    ok = np.zeros(n, bool)
    for i in range(n):
        good = bool(pairs["sec_valid"][i])
        if good:
            r = np.stack([pairs["mag_o"][i], pairs["sec_o"][i]])
            b = np.stack([pairs["mag_b"][i], pairs["sec_b"][i]])
            res = gauss_newton(r, b, np.array([k_mag, k_sun]), min_quality=min_quality,
                               q0=q, iterations=0)
            good = not res.degenerate
            if good:
                q = gauss_newton(r, b, np.array([k_mag, k_sun]), q0=q, iterations=iterations).q
        ok[i] = good
        out[i] = q
    return out, ok


def measured_quaternions(pairs: dict, solver: str = "gauss-newton", q0=None,
                         gn_iterations: int = 2, k_mag: float = 1.0, k_sun: float = 1.0,
                         min_quality: float = DEFAULT_MIN_QUALITY):
    """``q_mes`` = ``q_ob`` (N, 4) from the vector pairs and its usability (N,) bool.

    ``pairs`` as returned by ``ecf_spacecraft.vector_pairs``. Gauss-Newton runs
    sequentially (compiled, warm-started); the other solvers are vectorised.
    """
    n = len(pairs["dt"])
    if solver == "gauss-newton":
        from gnomon.kernels.spacecraft_cf import GaussNewtonCoefficients, gn_sequence

        c = GaussNewtonCoefficients(float(k_mag), float(k_sun), int(gn_iterations),
                                    float(min_quality))
        q = np.array([1.0, 0.0, 0.0, 0.0] if q0 is None else q0, float)
        q_out = np.empty((n, 4))
        ok = np.zeros(n, np.bool_)
        gn_sequence(c, pairs["mag_o"], pairs["mag_b"], pairs["sec_o"], pairs["sec_b"],
                    pairs["sec_valid"], q, q_out, ok)
        return q_out, ok
    r = np.stack([pairs["mag_o"], pairs["sec_o"]], axis=1)
    b = np.stack([pairs["mag_b"], pairs["sec_b"]], axis=1)
    w = np.stack([np.full(n, float(k_mag)), np.where(pairs["sec_valid"], float(k_sun), 0.0)],
                 axis=1)
    if solver == "triad":  # TRIAD trusts its first vector: the noiseless sun
        r, b, w = r[:, ::-1], b[:, ::-1], w[:, ::-1]
    res = solve(solver, r, b, w, min_quality=min_quality)
    return res.q, ~res.degenerate & pairs["sec_valid"]


class QuaternionCF(VectorPairFilter):
    """Complementary filter on the measured quaternion (seed 000's proposal); ``q_ob``.

    Streaming: ``update(dt_s, gyro_rad_s, *, q_mes_ob, mag_b, mag_ref_o, w_io_o_rad_s)``
    (see the module docstring); batch: ``run(rec)`` (measures ``q_mes`` itself)."""

    name = "qcf"
    summary = ("Complementary filter driven by a measured quaternion (seed 000): Gauss-Newton "
               "(or QUEST/SVD/...) q_mes from mag + sun, PI on vec(conj(q) ⊗ q_mes)")
    paper = "seed 000"
    Params = QuaternionCFParams

    flag_bits = {"mag_unusable": 1, "mes_unusable": 2, "gap": 4, "coast": 8}

    def _coefficients(self):
        from gnomon.kernels.spacecraft_cf import qcf_coefficients

        return qcf_coefficients(self.params)

    def _sample_kernel(self):
        """``update``'s kernel (``CompiledSampleUpdate``): ``qcf_sample``."""
        from gnomon.kernels.entry import record
        from gnomon.kernels.spacecraft_cf import qcf_sample

        return qcf_sample, record(self._coefficients())

    def update(self, dt_s, gyro_rad_s=None, *, q_mes_ob=None, mag_b=None, mag_ref_o=None,
               w_io_o_rad_s=None) -> np.ndarray:
        """One raw sample through the compiled kernel (the arithmetic of ``run``). Returns
        ``q_ob`` (4,); ``flags`` says what was used. The magnetic pair and the gyro also join
        the tail a later ``run`` continues. ``update_reference`` is the readable twin."""
        if self.state is None:
            self.record()
        w_io = self._w_io0 if w_io_o_rad_s is None else vec(w_io_o_rad_s, "w_io_o_rad_s")
        return self._call(dt_s, gyro_sample(gyro_rad_s), w_io, vec(q_mes_ob, "q_mes_ob", 4),
                          vec(mag_b, "mag_b"), vec(mag_ref_o, "mag_ref_o"), self.state,
                          self.ring)

    def update_many(self, dt_s, gyro_rad_s, *, q_mes_ob=None, mag_b=None, mag_ref_o=None,
                    w_io_o_rad_s=None, t_s=None) -> Estimate:
        """A buffer of N raw samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s, ``gyro_rad_s`` (N, 3), ``q_mes_ob`` (N, 4) (NaN rows: no
        measurement), ``mag_b``, ``mag_ref_o``, ``w_io_o_rad_s`` (N, 3) (None: none at
        all; the orbital rate ``[0, −n, 0]``). ``t_s`` (N,) the samples' times (default:
        the running sum of ``dt_s``)."""
        x = self._buffer(dt_s, gyro_rad_s, w_io_o_rad_s, q_mes=(q_mes_ob, 4), mag_b=mag_b,
                         mag_o=mag_ref_o)
        ok = np.isfinite(x["q_mes"]).all(axis=1)
        return self._batch(x, x["q_mes"], ok, np.cumsum(x["dt"]) if t_s is None else t_s)

    def _batch(self, x: dict, q_mes, ok, t) -> Estimate:
        """The rows ``x`` with the measurements ``q_mes`` (usable where ``ok``) through
        ``qcf_stream``, continuing the state."""
        from gnomon.kernels.spacecraft_cf import qcf_stream

        q_out, b_out, flags = self._outputs(len(x["dt"]))
        qcf_stream(self._coefficients(), self.state, self.ring, x["dt"], x["gyro"], x["w_io_o"],
                   np.ascontiguousarray(q_mes, float), np.asarray(ok, np.bool_), x["mag_b"],
                   x["mag_o"], q_out, b_out, flags)
        return self._estimate(t, q_out, b_out, flags,
                              ("mag_unusable", "mes_unusable", "gap", "coast"))

    def update_reference(self, dt_s, gyro_rad_s=None, *, q_mes_ob=None, mag_b=None,
                         mag_ref_o=None, w_io_o_rad_s=None) -> np.ndarray:
        """The readable twin of ``update`` (numpy, one sample: the magnetic pair joins the
        tail, then ``step``). Same arguments and result."""
        g, w_io, m_b, m_o, s_b, s_o = self._reference_row(gyro_rad_s, w_io_o_rad_s, mag_b,
                                                          mag_ref_o, None, None)
        s = self.record()
        self._second_pair(s, dt_s, g, w_io, m_b, m_o, s_b, s_o)  # joins the tail (no sun)
        q_mes = np.full(4, np.nan) if q_mes_ob is None else vec(q_mes_ob, "q_mes_ob", 4)
        return self.step(dt_s, g, w_io, q_mes, q_mes_ob is not None, m_b, m_o)

    def step(self, dt_s, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o) -> np.ndarray:
        """One sample given the kernel's inputs: the readable twin of
        ``spacecraft_cf.qcf_step``. Returns ``q_ob`` (4,)."""
        p = self.params
        s = self.record()
        if not self._begin(s, dt_s, gyro, w_io_o, "mes_unusable"):
            return self.q
        # -- measured quaternion: e = conj(q̂) ⊗ q_mes, sign with e_w >= 0
        qm = np.asarray(q_mes, float)
        nm = float(np.linalg.norm(qm)) if np.all(np.isfinite(qm)) else 0.0
        ok_q = bool(mes_valid) and 0.5 < nm < 2.0
        # -- magnetometer (the fallback without q_mes)
        ubm, ok_mb = _unit(mag_b)
        uom, ok_mo = _unit(mag_o)
        ok_m = ok_mb and ok_mo
        self.flags.update(mag_unusable=not ok_m, mes_unusable=not ok_q)
        # -- PI correction
        if ok_q:
            e = quat_mul(quat_conj(s.q), qm / nm)
            _pi_correct(s, p.kp_rad_s, p.ki_rad_s2, e[1:] if e[0] >= 0 else -e[1:], dt_s)
        elif ok_m and (p.kp_single_rad_s > 0 or p.ki_single_rad_s2 > 0):
            _pi_correct(s, p.kp_single_rad_s, p.ki_single_rad_s2, _vector_error(s.q, ubm, uom),
                        dt_s)
        else:
            self.flags["coast"] = True
        return self.q

    def measure(self, rec: Recording, pairs: dict | None = None, q0=None):
        """(pairs, q_mes, ok) for ``rec`` with this filter's solver and substitution (the
        substitutes from its tail: ``pairs``; the filter unchanged)."""
        p = self.params
        if pairs is None:
            pairs = self.pairs(rec)
        if q0 is None:
            q0 = initial_q_ob(pairs)
        q_mes, ok = measured_quaternions(pairs, p.solver, q0, p.gn_iterations, p.k_mag,
                                         p.k_sun, p.min_quality)
        return pairs, q_mes, ok

    def buffer_inputs(self, rec: Recording):
        """``rec`` as ``update_many`` takes it: ``((dt, gyro), {q_mes_ob, mag_b, mag_ref_o,
        w_io_o_rad_s})``, ``q_mes_ob`` measured as ``run`` measures it (NaN where not
        usable)."""
        x = self._rows(rec)
        _, q_mes, ok = self.measure(rec, self._pairs(x))
        q_mes = np.where(np.asarray(ok, bool)[:, None], q_mes, np.nan)
        return (x["dt"], x["gyro"]), {"q_mes_ob": q_mes, "mag_b": x["mag_b"],
                                      "mag_ref_o": x["mag_o"], "w_io_o_rad_s": x["w_io_o"]}

    def run(self, rec: Recording, q0=None, measured=None) -> Estimate:
        """Whole recording (compiled). ``q0``: initial ``q_ob`` (default: TRIAD of the first
        sample with both pairs); ``measured``: a precomputed ``(pairs, q_mes, ok)``."""
        self.check_inputs(rec)
        x = self._rows(rec, self.first_dt(rec))
        pairs, q_mes, ok = measured if measured is not None else self.measure(rec, self._pairs(x))
        self._prepare(x, q0)
        est = self._batch(x, q_mes, ok, rec.t)
        est.signals.update(q_mes=q_mes, q_mes_ok=np.asarray(ok, bool),
                           sun_substituted=pairs["substituted"])
        return self._finish(rec, est)
