"""Explicit complementary filter for a 9-axis IMU (gyro + accelerometer + magnetometer).

Mahony, Hamel, Pflimlin, "Nonlinear complementary filters on the special
orthogonal group", IEEE TAC 53(5), 2008, the "explicit complementary filter"
with bias estimation (their eq. 32), written with quaternions. It is the IMU
twin of the spacecraft filter of seed 000 (``shared/spec/000-*.md``).

Frames: navigation frame n = East-North-Up; the estimate is ``q_nb`` (ENU from
body). With ``v̂_i = R̂_nbᵀ v_i⁰`` the reference directions predicted in the body:

    e_acc = a × v̂_up,   e_mag = P(m × v̂_mag)        (body frame)

``a``, ``m`` are the normalised accelerometer and magnetometer readings;
``v_up = [0, 0, 1]``; the magnetic reference is built from the estimate,
``[0, |h_xy|, h_z]/|h|`` with ``h = R̂ m`` (Madgwick's trick: no local
inclination needed). ``P`` keeps only the component of the magnetic correction
about the vertical (``mag_heading_only``), so a disturbed field cannot tilt the
estimate. In gnomon's form the two proportional gains are separate,

    ω = ω_y - b + k_a e_acc + k_m e_mag,   ḃ = -k_I (e_acc + e_mag),

with ``kp_acc_rad_s``, ``kp_mag_rad_s`` (rad/s per unit error) and ``ki_rad_s2``
(rad/s² per unit error; formerly named ``ki_per_s``).

Samples with a zero-norm accelerometer or magnetometer vector skip that
correction and are flagged (``acc_skipped``, ``mag_skipped``). Intervals longer
than ``max_dt_s`` are treated as gaps: the filter only propagates the gyro
over them (``gap`` flag). Each step first propagates with the gyro sample over
``(t[k-1], t[k]]`` and then corrects with the vector measurements at ``t[k]``
(correcting the old state with new vectors would leave a lag error of ``|ω|·dt``).

The readable per-sample ``update`` is the reference; ``run`` uses the numba
kernel ``gnomon.kernels.mahony`` which the tests compare to it sample by sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import (
    CompiledIMUUpdate,
    Estimate,
    Estimator,
    Params,
    imu_buffer,
    param,
)
from gnomon.estimators.initial import attitude_from_acc_mag, initial_attitude
from gnomon.kernels.entry import record
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

__all__ = ["MahonyParams", "Mahony", "run_batch"]


@dataclass(frozen=True)
class MahonyParams(Params):
    renamed: ClassVar[dict[str, str]] = {"ki_per_s": "ki_rad_s2"}

    kp_acc_rad_s: float = param(0.6, "rad/s", "proportional gain of the accelerometer correction")
    kp_mag_rad_s: float = param(0.3, "rad/s", "proportional gain of the magnetometer correction")
    ki_rad_s2: float = param(0.005, "rad/s^2", "integral gain (gyro bias estimation)")
    mag_heading_only: bool = param(True, "", "magnetometer corrects heading only (not tilt)")
    init_samples: int = param(1, "samples", "samples averaged for the initial attitude")
    max_dt_s: float = param(1.0, "s", "longer sample intervals are gaps: gyro propagation only")

    def validate(self):
        self._require("kp_acc_rad_s", self.kp_acc_rad_s >= 0, "must be >= 0")
        self._require("kp_mag_rad_s", self.kp_mag_rad_s >= 0, "must be >= 0")
        self._require("ki_rad_s2", self.ki_rad_s2 >= 0, "must be >= 0")
        self._require("init_samples", self.init_samples >= 1, "must be >= 1")
        self._require("max_dt_s", self.max_dt_s > 0, "must be > 0")


def _new(v):
    """A sample, or None for none (None or NaN: no new sample of that sensor)."""
    return None if v is None or not np.all(np.isfinite(v)) else v


def _unit(v):
    if v is None:
        return None, False
    v = np.asarray(v, float)
    n = float(np.sqrt(v @ v))
    return (v / n, True) if n > 0.0 and np.isfinite(n) else (v, False)


class Mahony(CompiledIMUUpdate, Estimator):
    """Explicit complementary filter (Mahony et al. 2008), 9-axis, ENU; estimate ``q_nb``.

    State: ``state``, a one-element ``gnomon.kernels.mahony.STATE`` array (``q``, ``bias``;
    None until the first accelerometer/magnetometer pair initialises the attitude)."""

    name = "mahony"
    summary = "Explicit complementary filter (Mahony 2008), gyro+acc+mag, PI bias estimation"
    paper = "Mahony et al. 2008"
    kind = "imu"
    reference_frame = "ENU"
    Params = MahonyParams
    needs = ("gyro", "accel", "mag")
    multi_rate = True
    state_fields = ("state", "t_last")
    flag_bits = {"acc_skipped": 1, "mag_skipped": 2, "gap": 4}

    def reset(self) -> None:
        self.state = None  # kernels.mahony.STATE (1,), set from the first acc/mag sample
        self.t_last = None  # s, time of the last sample processed by ``run``
        self._reset_sample_path()

    @property
    def q(self) -> np.ndarray | None:
        """Current ``q_nb`` (4,), ENU from body (None before initialisation)."""
        return None if self.state is None else self.state["q"][0].copy()

    @q.setter
    def q(self, q_nb) -> None:
        from gnomon.kernels.mahony import new_state

        self.state = new_state(q_nb, self.bias)

    @property
    def bias(self) -> np.ndarray:
        """Current gyro-bias estimate (3,) rad/s."""
        return np.zeros(3) if self.state is None else self.state["bias"][0].copy()

    def initialise(self, acc, mag) -> None:
        """Set ``q`` from accelerometer and magnetometer samples (N, 3) (or (3,))."""
        self.q = initial_attitude(np.atleast_2d(acc), np.atleast_2d(mag),
                                  self.params.init_samples)

    def _start(self, accel_m_s2, mag_uT) -> None:
        """The first sample initialises the attitude (both vectors needed)."""
        if accel_m_s2 is None or mag_uT is None:
            raise InputError("the first sample needs accelerometer and magnetometer "
                             "readings (the initial attitude)", field="accel_m_s2, mag_uT")
        self.initialise(accel_m_s2, mag_uT)

    def _sample_kernel(self, dt_s, accel, mag):
        """``update``'s kernel (``CompiledIMUUpdate``): ``mahony_sample``; the first sample
        initialises the attitude."""
        from gnomon.kernels.mahony import coefficients, mahony_sample

        if self.state is None:
            self._start(accel, mag)
        return mahony_sample, record(coefficients(self.params))

    def update_many(self, dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None, *,
                    t_s=None) -> Estimate:
        """A buffer of N samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s (each since the previous sample), ``gyro_rad_s`` (N, 3),
        ``accel_m_s2``, ``mag_uT`` (N, 3) body frame with NaN rows where that sensor has no
        new sample (None: none at all). ``t_s`` (N,) the samples' times for the returned
        ``Estimate`` (default: the running sum of ``dt_s``)."""
        dt, gyro, acc, mag = imu_buffer(dt_s, gyro_rad_s, accel_m_s2, mag_uT)
        if self.state is None:
            self._start(*(None if np.isnan(x[0, 0]) else x[0] for x in (acc, mag)))
        # the multi-rate loop always: a buffer whose rows all hold samples may follow one
        # whose rows did not (a correction then covers the time since the previous sample)
        return self._batch(dt, gyro, acc, mag, np.cumsum(dt) if t_s is None else t_s, True)

    def _batch(self, dt, gyro, acc, mag, t_s, multi_rate: bool) -> Estimate:
        """``update_many`` on checked inputs (``run``'s come from a ``Recording``);
        ``multi_rate``: some ``acc``/``mag`` rows are NaN (no sample)."""
        from gnomon.kernels.mahony import coefficients, mahony_batch

        n = len(dt)
        q_out = np.empty((n, 4))
        b_out = np.empty((n, 3))
        flags = np.empty(n, np.uint8)
        mahony_batch(dt, np.ascontiguousarray(gyro), np.ascontiguousarray(acc),
                     np.ascontiguousarray(mag), self.state, coefficients(self.params), q_out, b_out,
                     flags, multi_rate)
        return Estimate(
            t=np.asarray(t_s, float), q=q_out,
            estimator=self.name, params=self.params.as_dict(),
            frames={"reference": "ENU", "body": "sensor"},
            signals={"bias_rad_s": b_out, "acc_skipped": (flags & 1) != 0,
                     "mag_skipped": (flags & 2) != 0, "gap": (flags & 4) != 0},
        )

    def update_reference(self, dt_s: float, gyro_rad_s, accel_m_s2=None,
                         mag_uT=None) -> np.ndarray:
        """The readable twin of ``update`` (numpy, one sample; the tests hold the compiled
        paths to it sample by sample). Same arguments and result."""
        p = self.params
        accel_m_s2, mag_uT = _new(accel_m_s2), _new(mag_uT)
        if self.state is None:
            self._start(accel_m_s2, mag_uT)
        s = self.state.view(np.recarray)[0]
        gyro = np.asarray(gyro_rad_s, float)
        self._flags = 0
        if dt_s <= 0.0:
            return self.q
        # prediction with the gyro over (t[k-1], t[k]], then correction with the vectors at t[k]
        q = quat_mul(s.q, quat_from_rotvec((gyro - s.bias) * dt_s))
        if dt_s > p.max_dt_s:
            self._flags = 4
            s.q[:] = q / np.linalg.norm(q)
            s.since_acc_s = s.since_mag_s = 0.0
            return self.q
        e_acc, ok_a = self._accel_error(q, accel_m_s2)
        e_mag, ok_m = self._mag_error(q, mag_uT)
        self._flags = (0 if ok_a else 1) | (0 if ok_m else 2)
        # each correction over the time since that sensor's previous sample (its own rate)
        s.since_acc_s += dt_s
        s.since_mag_s += dt_s
        e_acc = e_acc * (min(s.since_acc_s, p.max_dt_s) / dt_s)
        e_mag = e_mag * (min(s.since_mag_s, p.max_dt_s) / dt_s)
        if accel_m_s2 is not None:
            s.since_acc_s = 0.0
        if mag_uT is not None:
            s.since_mag_s = 0.0
        s.bias[:] = s.bias - p.ki_rad_s2 * (e_acc + e_mag) * dt_s
        correction = p.kp_acc_rad_s * e_acc + p.kp_mag_rad_s * e_mag
        q = quat_mul(q, quat_from_rotvec(correction * dt_s))
        s.q[:] = q / np.linalg.norm(q)
        return self.q

    @staticmethod
    def _accel_error(q_nb, accel):
        """``e_acc = a/|a| × R_nbᵀ up`` (body) and whether the sample was used."""
        a, ok = _unit(accel)
        if not ok:
            return np.zeros(3), False
        v_up = quat_rotate(quat_conj(q_nb), np.array([0.0, 0.0, 1.0]))
        return np.cross(a, v_up), True

    def _mag_error(self, q_nb, mag):
        """``e_mag = m/|m| × R_nbᵀ ref``, ``ref = [0, |h_xy|, h_z]`` with ``h = R_nb m``
        (Madgwick's reference from the estimate), only its vertical part when
        ``mag_heading_only``; and whether the sample was used."""
        m, ok = _unit(mag)
        if not ok:
            return np.zeros(3), False
        q_bn = quat_conj(q_nb)
        h = quat_rotate(q_nb, m)
        ref = np.array([0.0, np.hypot(h[0], h[1]), h[2]])
        e_mag = np.cross(m, quat_rotate(q_bn, ref))
        if self.params.mag_heading_only:
            v_up = quat_rotate(q_bn, np.array([0.0, 0.0, 1.0]))
            e_mag = (e_mag @ v_up) * v_up
        return e_mag, True

    @classmethod
    def run_many(cls, recs, params=None):
        """``Estimator.run_many`` through ``run_batch`` when the recordings share their time
        stamps (else one by one); each run starts from its own initial attitude, as ``run``."""
        p = params or MahonyParams()
        t = recs[0].t if recs else None
        if len(recs) < 2 or any(r.t.shape != t.shape or not np.array_equal(r.t, t)
                                or not r.single_rate for r in recs):
            return [cls(p).run(rec).q for rec in recs]
        q0 = []
        for rec in recs:
            f = cls(p)
            f.check_inputs(rec)
            f.initialise(rec.accel, rec.mag)
            q0.append(f.q)
        q = run_batch(t, np.stack([r.gyro for r in recs]), np.stack([r.accel for r in recs]),
                      np.stack([r.mag for r in recs]), p, q0=np.array(q0))
        return list(q)

    def prepare(self, rec: Recording) -> None:
        """The initial attitude from ``rec``'s first ``init_samples`` (``run`` does this)."""
        self.initialise(rec.accel, rec.mag)

    def run(self, rec: Recording) -> Estimate:
        """Whole recording through the compiled kernel (``update_many`` over its rows, each
        sensor at its own rate: rows without a new sample are NaN); ``rec.frames['reference']``
        must be ENU."""
        self.check_inputs(rec)
        if self.state is None:
            self.prepare(rec)
        dt = np.empty(len(rec))
        dt[0] = self.first_dt(rec)
        dt[1:] = np.diff(rec.t)
        est = self._batch(dt, rec.gyro, rec.on_time_base("accel"), rec.on_time_base("mag"), rec.t,
                          not rec.single_rate)
        self.t_last = float(rec.t[-1])
        est.frames = {"reference": rec.frames.get("reference", "ENU"), "body": "sensor"}
        return est


def run_batch(t, gyro, acc, mag, params: MahonyParams | None = None, q0=None,
              out=None) -> np.ndarray:
    """R independent Mahony filters in one compiled call (Monte Carlo runs, parameter sweeps).

    ``t`` (N,) s shared by the runs; ``gyro`` (R, N, 3) rad/s, ``acc``, ``mag`` (R, N, 3)
    body frame; ``q0`` (R, 4) initial ``q_nb`` (default: from each run's first samples).
    Returns ``q_nb`` (R, N, 4). The kernel loops over runs innermost: arrays whose
    memory is run-minor (an (N, 3, R) C array seen through ``.transpose(2, 0, 1)``)
    are used without a copy; others are copied into that layout once.
    ``out``: an earlier result of the same shape to write into (no new memory: a loop
    over chunks of runs reuses one buffer; fresh memory costs its page faults).
    """
    from gnomon.kernels.mahony import coefficients, mahony_batch_runs

    p = params or MahonyParams()
    t = np.asarray(t, dtype=float)
    arrays = []
    for name, x in (("gyro", gyro), ("acc", acc), ("mag", mag)):
        x = np.asarray(x, dtype=float)
        if x.ndim != 3 or x.shape[2] != 3 or x.shape[1] != t.size:
            raise InputError(f"expected shape (R, {t.size}, 3), got {x.shape}", field=name)
        arrays.append(np.ascontiguousarray(x.transpose(1, 2, 0)))
    g, a, m = arrays
    r = g.shape[2]
    if q0 is None:
        q0 = initial_attitude_batch(a[: p.init_samples], m[: p.init_samples])
    q = np.ascontiguousarray(np.asarray(q0, dtype=float).reshape(r, 4).T)
    b = np.zeros((3, r))
    dt = np.empty(t.size)
    dt[0] = 0.0
    dt[1:] = np.diff(t)
    if out is None:
        out = np.empty((t.size, 4, r))
    else:
        given = np.asarray(out)
        out = given.transpose(1, 2, 0) if given.ndim == 3 else given
        if out.shape != (t.size, 4, r) or out.dtype != np.float64 \
                or not out.flags.c_contiguous:
            raise InputError(f"expected an earlier result of shape ({r}, {t.size}, 4) "
                             f"(float64, run-minor memory), got {given.shape} "
                             f"{given.dtype}", field="out")
    mahony_batch_runs(dt, g, a, m, q, b, coefficients(p), out)
    return out.transpose(2, 0, 1)


def initial_attitude_batch(acc, mag) -> np.ndarray:
    """``q_nb`` (R, 4) from the mean over the first axis of run-minor ``acc``, ``mag`` (k, 3, R)."""
    return attitude_from_acc_mag(acc.mean(axis=0).T, mag.mean(axis=0).T)
