"""Recording: the one validated in-memory form of sensor data (and, when known, the truth).

Every reader returns a ``Recording``, every simulator produces one, every
estimator's ``run`` takes one. Frames and units (see the conventions page):

=============  ========  ============  =====================================================
field          shape     unit          meaning
=============  ========  ============  =====================================================
``t``          (N,)      s             sample times, strictly increasing, finite
``gyro``       (N, 3)    rad/s         angular rate of the body b relative to inertial
                                       space, in b (``w_ib_b``)
``accel``      (N, 3)    m/s²          specific force in b (reads ``+g`` up at rest);
                                       optional
``mag``        (N, 3)    ``mag_unit``  magnetic field in b; optional
``sun``        (N, 3)    1             sun direction in b (unit vectors); optional, with
``sun_valid``  (N,)      bool          whether ``sun`` holds a measurement at that sample
``q_true``     (N, 4)    1             truth ``q_rb`` ``[w, x, y, z]``: reference frame r
                                       (``frames['reference']``) from body b; NaN rows
                                       where the truth is missing
``mask``       (N,)      bool          samples that count for scoring (default: all)
``extra``      dict      SI            further time series (N, ...) such as truth rate,
                                       reference vectors ``b_o``, ``s_o``, eclipse flags
=============  ========  ============  =====================================================

``frames`` names the frames (``{"reference": "ENU", "body": "sensor"}``) and
``source`` says where the data came from. Validation happens once, here:
shapes, finite values (NaN only in ``q_true`` rows and in ``sun`` rows that are
flagged invalid), increasing time. An error names the field and the first bad row.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError

__all__ = ["Recording", "MAG_UNITS_TO_TESLA"]

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


def _check_finite(name: str, a: np.ndarray, allowed_rows: np.ndarray | None = None) -> None:
    bad = ~np.isfinite(a)
    if allowed_rows is not None:
        bad &= ~allowed_rows.reshape((-1,) + (1,) * (a.ndim - 1))
    if bad.any():
        row = _first_bad_row(bad)
        raise InputError(f"non-finite value {a[row].tolist()}", field=name, row=row)


@dataclass(frozen=True, eq=False)
class Recording:
    """Sensor samples on one time base, validated on construction (see module docstring)."""

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
        for name in ("accel", "mag"):
            value = getattr(self, name)
            if value is not None:
                a = _vectors(name, value, n, 3)
                _check_finite(name, a)
                set_(self, name, a)
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
        if self.q_true is not None:
            q = _vectors("q_true", self.q_true, n, 4)
            missing = np.all(np.isnan(q), axis=1)
            _check_finite("q_true", q, allowed_rows=missing)
            norm = np.linalg.norm(q[~missing], axis=1)
            if norm.size and np.any(np.abs(norm - 1.0) > 1e-3):
                row = int(np.flatnonzero(~missing)[np.argmax(np.abs(norm - 1.0) > 1e-3)])
                raise InputError(f"not a unit quaternion (norm {np.linalg.norm(q[row]):.6g})",
                                 field="q_true", row=row)
            set_(self, "q_true", q)
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

    # ------------------------------------------------------------ derived views
    def __len__(self) -> int:
        return self.t.size

    @property
    def dt(self) -> np.ndarray:
        """Sample intervals (N-1,), s."""
        return np.diff(self.t)

    @property
    def sample_rate_hz(self) -> float:
        """Median sampling rate, Hz."""
        return float(1.0 / np.median(self.dt))

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
        """Samples ``start:stop`` as a new Recording."""
        s = np.s_[start:stop]

        def cut(a):
            return None if a is None else a[s]

        return Recording(
            t=self.t[s], gyro=self.gyro[s], accel=cut(self.accel), mag=cut(self.mag),
            mag_unit=self.mag_unit, sun=cut(self.sun), sun_valid=cut(self.sun_valid),
            q_true=cut(self.q_true), mask=cut(self.mask), frames=self.frames,
            source=self.source, extra={k: v[s] for k, v in self.extra.items()},
        )
