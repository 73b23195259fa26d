"""Recording: the one validated in-memory form of sensor data (and, when known, the truth).

Every reader returns a ``Recording``, every simulator produces one, every
estimator's ``run`` takes one. Frames and units (see the conventions page):

=============  ========  ============  =====================================================
field          shape     unit          meaning
=============  ========  ============  =====================================================
``t``          (N,)      s             gyro sample times, strictly increasing, finite: the
                                       recording's time base
``gyro``       (N, 3)    rad/s         angular rate of the body b relative to inertial
                                       space, in b (``w_ib_b``)
``accel``      (Na, 3)   m/s²          specific force in b (reads ``+g`` up at rest);
                                       optional
``accel_t``    (Na,)     s             its own sample times (None: the same as ``t``)
``mag``        (Nm, 3)   ``mag_unit``  magnetic field in b; optional
``mag_t``      (Nm,)     s             its own sample times (None: the same as ``t``)
``sun``        (N, 3)    1             sun direction in b (unit vectors); optional, with
``sun_valid``  (N,)      bool          whether ``sun`` holds a measurement at that sample
``q_true``     (N, 4)    1             truth ``q_rb`` ``[w, x, y, z]``: reference frame r
                                       (``frames['reference']``) from body b; NaN rows
                                       where the truth is missing
``q_onboard``  (N, 4)    1             the device's own attitude estimate (autopilot, phone
                                       OS) ``q_rb`` as a comparison series; NaN rows where
                                       it has none; optional
``mask``       (N,)      bool          samples that count for scoring (default: all)
``extra``      dict      SI            further time series (N, ...) such as truth rate,
                                       reference vectors ``b_o``, ``s_o``, eclipse flags
=============  ========  ============  =====================================================

**Every sensor at its own rate.** The accelerometer and the magnetometer keep their
own samples and time stamps (``accel_t``, ``mag_t``): nothing is resampled, repeated or
interpolated. Filters run on the gyro's time base and take each other sample once, at
the first gyro sample at or after its time stamp (``on_time_base``: the sample's row,
NaN rows where no new sample arrived; two samples in one gyro interval are averaged and
counted in ``arrivals``). A recording whose sensors share the time base (the single-rate
form, ``accel_t = mag_t = None``) is built exactly as before.

``frames`` names the frames (``{"reference": "ENU", "body": "sensor"}``),
``source`` says where the data came from and ``meta`` (a JSON-able dict) what a
reader assumed (``meta["assumed"]``: a list of sentences) and what it read (device,
topics, instances). Validation happens once, here: shapes, finite values (NaN only
in ``q_true``/``q_onboard`` rows and in ``sun`` rows that are flagged invalid),
increasing time. An error names the field and the first bad row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError

__all__ = ["Recording", "MAG_UNITS_TO_TESLA", "SENSORS"]

#: sensors that may have their own time stamps
SENSORS = ("accel", "mag")

MAG_UNITS_TO_TESLA = {"T": 1.0, "mT": 1e-3, "uT": 1e-6, "nT": 1e-9, "gauss": 1e-4}


def _first_bad_row(bad: np.ndarray) -> int:
    rows = np.flatnonzero(bad.reshape(bad.shape[0], -1).any(axis=1))
    return int(rows[0])


def _vectors(name: str, x, n: int | None, width: int) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 2 or a.shape[1] != width or (n is not None and a.shape[0] != n):
        want = f"({n if n is not None else 'N'}, {width})"
        raise InputError(f"expected shape {want}, got {a.shape}", field=name)
    return a


def _times(name: str, x) -> np.ndarray:
    t = np.asarray(x, dtype=float)
    if t.ndim != 1 or t.size < 1:
        raise InputError(f"expected shape (N,) with N >= 1, got {t.shape}", field=name)
    _check_finite(name, t)
    dt = np.diff(t)
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise InputError(
            f"time stamps must increase strictly: {name}[{row}] = {t[row]!r} after "
            f"{name}[{row - 1}] = {t[row - 1]!r}", field=name, row=row)
    return t


def _quats(name: str, x, n: int) -> np.ndarray:
    q = _vectors(name, x, n, 4)
    if np.isfinite(q).all():                  # the usual case: no row missing
        present, norm = None, np.sqrt(np.einsum("ij,ij->i", q, q))
    else:
        missing = np.all(np.isnan(q), axis=1)
        _check_finite(name, q, allowed_rows=missing)
        present = np.flatnonzero(~missing)
        norm = np.linalg.norm(q[present], axis=1)
    off = np.abs(norm - 1.0) > 1e-3
    if off.any():
        first = int(np.argmax(off))
        row = first if present is None else int(present[first])
        raise InputError(f"not a unit quaternion (norm {np.linalg.norm(q[row]):.6g})",
                         field=name, row=row)
    return q


def _check_finite(name: str, a: np.ndarray, allowed_rows: np.ndarray | None = None) -> None:
    if allowed_rows is None and np.isfinite(a).all():
        return
    bad = ~np.isfinite(a)
    if allowed_rows is not None:
        bad &= ~allowed_rows.reshape((-1,) + (1,) * (a.ndim - 1))
    if bad.any():
        row = _first_bad_row(bad)
        raise InputError(f"non-finite value {a[row].tolist()}", field=name, row=row)


@dataclass(frozen=True, eq=False)
class Recording:
    """Sensor samples (each sensor at its own rate), validated on construction (see the
    module docstring)."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray | None = None
    mag: np.ndarray | None = None
    mag_unit: str = "uT"
    sun: np.ndarray | None = None
    sun_valid: np.ndarray | None = None
    q_true: np.ndarray | None = None
    mask: np.ndarray | None = None
    frames: dict = field(default_factory=lambda: {"reference": "ENU", "body": "sensor"})
    source: str = ""
    extra: dict = field(default_factory=dict)
    accel_t: np.ndarray | None = None
    mag_t: np.ndarray | None = None
    q_onboard: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        set_ = object.__setattr__
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise InputError(f"expected shape (N,) with N >= 2, got {t.shape}", field="t")
        _check_finite("t", t)
        dt = np.diff(t)
        if np.any(dt <= 0):
            row = int(np.flatnonzero(dt <= 0)[0]) + 1
            raise InputError(
                f"time stamps must increase strictly: t[{row}] = {t[row]!r} after "
                f"t[{row - 1}] = {t[row - 1]!r}",
                field="t",
                row=row,
            )
        set_(self, "t", t)
        n = t.size
        gyro = _vectors("gyro", self.gyro, n, 3)
        _check_finite("gyro", gyro)
        set_(self, "gyro", gyro)
        for name in SENSORS:
            value, times = getattr(self, name), getattr(self, f"{name}_t")
            if value is None:
                if times is not None:
                    raise InputError(f"given without '{name}'", field=f"{name}_t")
                continue
            if times is not None:
                times = _times(f"{name}_t", times)
                if times.shape == t.shape and np.array_equal(times, t):
                    times = None  # on the time base: the single-rate form
            a = _vectors(name, value, n if times is None else times.size, 3)
            _check_finite(name, a)
            set_(self, name, a)
            set_(self, f"{name}_t", times)
        if self.mag_unit not in MAG_UNITS_TO_TESLA:
            raise InputError(
                f"unknown unit {self.mag_unit!r}; use one of {sorted(MAG_UNITS_TO_TESLA)}",
                field="mag_unit",
            )
        if self.sun is not None:
            sun = _vectors("sun", self.sun, n, 3)
            valid = (np.all(np.isfinite(sun), axis=1) if self.sun_valid is None
                     else np.asarray(self.sun_valid, dtype=bool).reshape(-1))
            if valid.shape != (n,):
                raise InputError(f"expected shape ({n},), got {valid.shape}", field="sun_valid")
            _check_finite("sun", sun, allowed_rows=~valid)
            set_(self, "sun", sun)
            set_(self, "sun_valid", valid)
        elif self.sun_valid is not None:
            raise InputError("given without 'sun'", field="sun_valid")
        for name in ("q_true", "q_onboard"):
            if getattr(self, name) is not None:
                set_(self, name, _quats(name, getattr(self, name), n))
        if self.mask is not None:
            m = np.asarray(self.mask).reshape(-1)
            if m.shape != (n,):
                raise InputError(f"expected shape ({n},), got {m.shape}", field="mask")
            set_(self, "mask", m.astype(bool))
        extra = {}
        for key, value in dict(self.extra).items():
            a = np.asarray(value)
            if a.shape[:1] != (n,):
                raise InputError(f"expected leading dimension {n}, got {a.shape}",
                                 field=f"extra.{key}")
            extra[key] = a
        set_(self, "extra", extra)
        set_(self, "frames", dict(self.frames))
        set_(self, "meta", dict(self.meta))

    # ------------------------------------------------------------ derived views
    def __len__(self) -> int:
        return self.t.size

    @property
    def dt(self) -> np.ndarray:
        """Sample intervals (N-1,), s."""
        return np.diff(self.t)

    @property
    def sample_rate_hz(self) -> float:
        """Median sampling rate of the gyro (the time base), Hz."""
        return float(1.0 / np.median(self.dt))

    @property
    def single_rate(self) -> bool:
        """Whether every sensor is sampled at the time base ``t``."""
        return all(getattr(self, f"{name}_t") is None for name in SENSORS)

    def times(self, name: str) -> np.ndarray:
        """Sample times (s) of ``"gyro"``, ``"accel"`` or ``"mag"``."""
        if name == "gyro":
            return self.t
        if name not in SENSORS:
            raise InputError(f"expected gyro, accel or mag, got {name!r}", field="sensor")
        if getattr(self, name) is None:
            raise InputError("the recording has none", field=name)
        own = getattr(self, f"{name}_t")
        return self.t if own is None else own

    def rate_hz(self, name: str) -> float:
        """Median sampling rate (Hz) of a sensor (``"gyro"``, ``"accel"``, ``"mag"``)."""
        t = self.times(name)
        return float(1.0 / np.median(np.diff(t))) if t.size > 1 else math.nan

    def nominal_dt_s(self, name: str, max_dt_s: float = math.inf, first: int = 100,
                     default: float = math.nan) -> float:
        """A sensor's nominal sample interval (s): the median of its first ``first``
        intervals that are positive and at most ``max_dt_s`` (longer ones are gaps);
        ``default`` when there is none."""
        dt = np.diff(self.times(name))
        dt = dt[(dt > 0) & (dt <= max_dt_s)][:first]
        return float(np.median(dt)) if dt.size else float(default)

    def arrivals(self, name: str) -> np.ndarray:
        """For each row of the time base, how many samples of sensor ``name`` arrive there
        (N,) int: those with ``t[k-1] < time <= t[k]`` (row 0: ``time <= t[0]``); samples
        after ``t[-1]`` arrive nowhere (``arrivals(name).sum()`` tells how many are used)."""
        own = getattr(self, f"{name}_t")
        if own is None:
            return np.ones(len(self), dtype=np.int64)
        rows = np.searchsorted(self.t, own, side="left")
        return np.bincount(rows[rows < len(self)], minlength=len(self))

    def on_time_base(self, name: str) -> np.ndarray | None:
        """Sensor ``name`` (``"accel"``/``"mag"``) on the gyro's time base, (N, 3): row ``k``
        holds the sample that arrived in ``(t[k-1], t[k]]`` (the mean when several did)
        and NaN when none did. No value is repeated or interpolated: a filter uses a row
        only when it is not NaN. The single-rate form returns the array itself."""
        values = getattr(self, name)
        own = getattr(self, f"{name}_t")
        if values is None or own is None:
            return values
        rows = np.searchsorted(self.t, own, side="left")
        keep = rows < len(self)
        rows, vals = rows[keep], values[keep]
        count = np.bincount(rows, minlength=len(self)).astype(float)
        out = np.zeros((len(self), 3))
        np.add.at(out, rows, vals)
        with np.errstate(invalid="ignore", divide="ignore"):
            out /= count[:, None]
        out[count == 0] = np.nan
        return out

    @property
    def mag_tesla(self) -> np.ndarray | None:
        """Magnetometer in tesla (N, 3), or None."""
        return None if self.mag is None else self.mag * MAG_UNITS_TO_TESLA[self.mag_unit]

    @property
    def score_mask(self) -> np.ndarray:
        """Samples to score: ``mask`` (default all) and a valid truth where truth exists."""
        m = np.ones(len(self), bool) if self.mask is None else self.mask.copy()
        if self.q_true is not None:
            m &= np.all(np.isfinite(self.q_true), axis=1)
        return m

    def slice(self, start: int, stop: int) -> Recording:
        """Samples ``start:stop`` of the time base as a new Recording; a sensor with its own
        time stamps keeps the samples that arrive in those rows (see ``arrivals``)."""
        s = np.s_[start:stop]
        start, stop, _ = s.indices(len(self))

        def cut(a):
            return None if a is None else a[s]

        own = {}
        for name in SENSORS:
            times = getattr(self, f"{name}_t")
            if times is None:
                own[name], own[f"{name}_t"] = cut(getattr(self, name)), None
                continue
            lo = -np.inf if start == 0 else self.t[start - 1]
            keep = (times > lo) & (times <= self.t[max(stop - 1, 0)])
            own[name], own[f"{name}_t"] = getattr(self, name)[keep], times[keep]
        return Recording(
            t=self.t[s], gyro=self.gyro[s], mag_unit=self.mag_unit, sun=cut(self.sun),
            sun_valid=cut(self.sun_valid), q_true=cut(self.q_true), mask=cut(self.mask),
            frames=self.frames, source=self.source,
            extra={k: v[s] for k, v in self.extra.items()}, q_onboard=cut(self.q_onboard),
            meta=self.meta, **own,
        )
