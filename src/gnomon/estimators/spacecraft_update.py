"""The compiled per-sample path the spacecraft filters share (``update``, ``update_many``).

A spacecraft filter's ``update(dt_s, gyro_rad_s, *, mag_b=..., sun_b=..., ...)`` takes its
inputs by keyword (the pairs of a measured vector in b and its model in o, the orbital
frame's rate, a star tracker's attitude, the wheels' momentum, ...). Each is checked
cheaply here (``vec``: a float64 array of the right shape passes as it is, anything else
is converted or refused naming the argument; None becomes ``NO_SAMPLE``, a NaN row the
kernel reads as "no sample"), then ``CompiledSampleUpdate._call`` runs the filter's
compiled sample kernel through its entry point (``gnomon.kernels.entry``: looked up once
after ``reset``, no type dispatch per call). ``buffer`` checks the arrays of
``update_many`` the same way.

A gyro sample given as None is "no gyro sample over this interval" (the filters coast:
no propagation, flagged ``coast``), passed to the kernels as ``NO_GYRO``, a finite value
beyond the 1e6 rad/s every spacecraft kernel treats as unusable; a gyro sample with a
non-finite component is refused (``InputError``, nothing done), as in a ``Recording``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from gnomon.errors import InputError
from gnomon.kernels.entry import BAD_GYRO

__all__ = ["CompiledSampleUpdate", "NO_GYRO", "NO_SAMPLE", "NO_SAMPLE4", "vec", "gyro_sample",
           "buffer"]

# The sentinels are writable arrays that nothing writes: numba types a read-only array
# apart from a writable one, and the first ``update`` after ``reset`` fixes the types of
# the entry point; a read-only sentinel there would compile the kernel once more.
#: "No new sample of this sensor" (3,): a row of NaN
NO_SAMPLE = np.full(3, np.nan)
#: "No new attitude (4,) of this sensor" (a star tracker's, a measured quaternion)
NO_SAMPLE4 = np.full(4, np.nan)
#: "No gyro sample over this interval": finite (not refused) and beyond the kernels'
#: 1e6 rad/s limit of a usable rate (the filter coasts)
NO_GYRO = np.full(3, 1e300)

_ND = np.ndarray
_F8 = np.dtype(np.float64)
_NONE = {3: NO_SAMPLE, 4: NO_SAMPLE4}


def vec(x, name: str, n: int = 3) -> np.ndarray:
    """``x`` as a float64 array (n,) for a sample kernel (itself when it already is one, in
    any strides); None as the NaN row ``NO_SAMPLE`` / ``NO_SAMPLE4`` (no sample). Raises
    ``InputError`` naming ``name`` for another shape; values are not checked (a NaN: no
    sample)."""
    if type(x) is _ND and x.dtype is _F8 and x.shape == (n,):
        return x
    if x is None:
        return _NONE[n]
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"expected {n} numbers, got {x!r}", field=name) from None
    if a.shape != (n,):
        raise InputError(f"expected shape ({n},), got {a.shape}", field=name)
    return a


def gyro_sample(x) -> np.ndarray:
    """The gyro sample (3,) rad/s for a sample kernel: None as ``NO_GYRO`` (coast); a
    non-finite one is left to the kernel, which refuses it (``BAD_GYRO``)."""
    return NO_GYRO if x is None else vec(x, "gyro_rad_s")


def buffer(dt_s, gyro_rad_s, **arrays) -> tuple[np.ndarray, np.ndarray, dict]:
    """The inputs of a spacecraft filter's ``update_many`` checked: ``dt_s`` (N,) s (finite,
    >= 0), ``gyro_rad_s`` (N, 3) finite (None: no gyro sample at all, ``NO_GYRO`` rows) and
    each keyword ``name=(value, width, default)``: ``value`` (N, width) or None (``default``
    in every row, a NaN row when None). Returns ``(dt, gyro, {name: array})``, C-contiguous
    float64 (the inputs themselves when they already are). Raises ``InputError`` naming
    the argument (and row)."""
    dt = np.ascontiguousarray(dt_s, dtype=float)
    if dt.ndim != 1:
        raise InputError(f"expected shape (N,), got {dt.shape}", field="dt_s")
    n = dt.shape[0]
    bad = np.flatnonzero(~(np.isfinite(dt) & (dt >= 0.0)))
    if bad.size:
        raise InputError(f"must be finite and >= 0, got {dt[bad[0]]!r}", field="dt_s",
                         row=int(bad[0]))
    if gyro_rad_s is None:
        gyro = np.tile(NO_GYRO, (n, 1))
    else:
        gyro = _rows(gyro_rad_s, n, 3, "gyro_rad_s")
        bad = np.flatnonzero(~np.isfinite(gyro).all(axis=1))
        if bad.size:
            raise InputError(f"non-finite value {gyro[bad[0]].tolist()}", field="gyro_rad_s",
                             row=int(bad[0]))
    out = {}
    for name, (value, width, default) in arrays.items():
        if value is None:
            row = np.full(width, np.nan) if default is None else np.asarray(default, float)
            out[name] = np.tile(row, (n, 1))
        else:
            out[name] = _rows(value, n, width, name)
    return dt, gyro, out


def _rows(x, n: int, width: int, name: str) -> np.ndarray:
    a = np.ascontiguousarray(x, dtype=float)
    if a.shape != (n, width):
        raise InputError(f"expected shape ({n}, {width}), got {a.shape}", field=name)
    return a


class CompiledSampleUpdate:
    """``update`` of a spacecraft filter through its compiled sample kernel (mixed into the
    filter's class before ``Estimator``).

    The filter provides ``_sample_kernel()``, called at the first ``update`` after
    ``reset`` (the state exists by then): ``(kernel, coefficients)``, a numba kernel
    ``kernel(dt_s, *inputs, coefficients, q_out) -> flags`` (``inputs`` the checked
    vectors, then the filter's state arrays; ``q_out`` (4,) written with the estimate;
    ``flags`` the kernel's bits, ``BAD_GYRO`` for a non-finite gyro sample that changed
    nothing) and its coefficients as a record (``gnomon.kernels.entry.record``).
    ``flag_bits`` names the bits for ``flags``; a readable twin sets ``flags`` to a dict.
    """

    #: flag name -> bit of the sample kernel's flags (``flags``)
    flag_bits: ClassVar[dict[str, int]] = {}

    def _sample_kernel(self):  # pragma: no cover - every filter overrides
        raise NotImplementedError

    def _reset_sample_path(self) -> None:
        """Called by the filter's ``reset``: the next ``update`` looks its kernel up again."""
        self._sample = None
        self._flags = {}

    @property
    def flags(self) -> dict[str, bool]:
        """What the last ``update`` (or ``update_reference``, ``step``) did, by name."""
        f = getattr(self, "_flags", {})
        if isinstance(f, dict):
            return f
        return {name: bool(f & bit) for name, bit in self.flag_bits.items()}

    @flags.setter
    def flags(self, value: dict) -> None:
        self._flags = value

    def _call(self, dt_s, *inputs) -> np.ndarray:
        """One sample through the compiled kernel: ``inputs`` as the kernel takes them after
        ``dt_s`` (the gyro first where there is one). Returns a copy of the estimate (4,)."""
        sample = self._sample
        if sample is None:
            from gnomon.kernels.entry import entry_point

            kernel, self._c_record = self._sample_kernel()
            self._q_now = np.zeros(4)
            sample = self._sample = entry_point(kernel, 0.0, *inputs, self._c_record,
                                                self._q_now)
        f = sample(dt_s, *inputs, self._c_record, self._q_now)
        self._flags = f
        if f & BAD_GYRO:
            raise InputError(f"non-finite value {inputs[0].tolist()} (the sample was not "
                             f"used)", field="gyro_rad_s")
        return self._q_now.copy()
