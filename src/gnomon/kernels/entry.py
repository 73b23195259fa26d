"""Calling a compiled kernel once per sample from Python, at the cost of a C call.

A numba dispatcher called from Python first works out the numba type of every argument
(``typeof``) to pick the compiled version: for a kernel that takes a ``Coefficients``
named tuple and a state record that costs 1-2 µs per call, more than the step itself.
A live filter calls the same kernel with arguments of the same types at every sample, so
it looks the compiled version up once (:func:`entry_point`) and calls it directly: the
arguments are still converted (unboxed) from Python objects, but nothing is typed again.

The compiled version does not check the types it is given: a float32 array where it was
compiled for float64, or a (2,) array where it reads three values, would be read wrong.
Every caller therefore passes arguments of exactly the types it looked the entry point
up with — the filters' ``update`` validates each input with :func:`vec3` first. This is
numba's documented ``Dispatcher.overloads[signature].entry_point`` (a ``CompileResult``
attribute); measured on this project's 2-core machine: 0.44 µs for a 13-argument kernel
with a named tuple, against 1.7 µs through the dispatcher.
"""

from __future__ import annotations

import numpy as np

from gnomon.errors import InputError

__all__ = ["entry_point", "record", "vec3", "NO_SAMPLE", "BAD_GYRO"]

#: "No new sample of this sensor" for a kernel's sample path: a row of NaN (read only)
NO_SAMPLE = np.full(3, np.nan)
NO_SAMPLE.flags.writeable = False
#: The flag bit a sample path sets, doing nothing else, for a gyro sample that is not finite
#: (each kernel's other flag bits stay below it)
BAD_GYRO = 128
_F8 = np.dtype(np.float64)


def entry_point(kernel, *args):
    """The compiled function of the numba dispatcher ``kernel`` for the numba types of
    ``args`` (compiled, or loaded from the cache, now), callable without type dispatch.
    Falls back to ``kernel`` itself where numba does not expose it."""
    from numba import typeof, types

    # arrays in any layout: a strided (3,) view (a column of a (3, N) array) reads right
    sig = tuple(t.copy(layout="A") if isinstance(t, types.Array) else t
                for t in (typeof(a) for a in args))
    kernel.compile(sig)
    try:
        return kernel.overloads[sig].entry_point
    except (AttributeError, KeyError):  # pragma: no cover - other numba versions
        return kernel


def _dtype_of(value) -> np.dtype | str:
    """The numpy dtype of a named-tuple field value (recursively for nested tuples)."""
    if isinstance(value, bool | np.bool_):
        return "?"
    if isinstance(value, int | np.integer):
        return "i8"
    if isinstance(value, float | np.floating):
        return "f8"
    if isinstance(value, tuple) and hasattr(value, "_fields"):
        return np.dtype([(k, _dtype_of(v)) for k, v in zip(value._fields, value, strict=True)])
    if isinstance(value, tuple | np.ndarray):
        a = np.asarray(value)
        if a.dtype.kind in "fiub" and a.ndim >= 1:
            return np.dtype((_dtype_of(a.flat[0] if a.size else 0.0), a.shape))
    raise TypeError(f"no record field for {type(value).__name__} {value!r}")


def record(coefficients) -> np.ndarray:
    """A kernel's ``Coefficients`` named tuple as a one-element structured array with the
    same field names (nested named tuples as nested records, tuples of numbers as arrays):
    the kernel reads ``c = record[0]`` as it reads the tuple (``c.k_mag``, ``c.lp.b[1]``),
    and a per-sample call unboxes one array instead of every number of the tuple."""
    out = np.zeros(1, _dtype_of(coefficients))
    _fill(out[0], coefficients)
    return out


def _fill(rec, value) -> None:
    for k, v in zip(value._fields, value, strict=True):
        if isinstance(v, tuple) and hasattr(v, "_fields"):
            _fill(rec[k], v)
        else:
            rec[k] = v


def vec3(x, name: str, optional: bool = False):
    """``x`` as a C-contiguous float64 array of shape (3,) for a kernel's sample path (the
    array itself when it already is one; ``None`` stays ``None`` when ``optional``).
    Raises ``InputError`` naming ``name`` for another shape; values are not checked (a
    NaN in an accelerometer or magnetometer sample means "no sample")."""
    if type(x) is np.ndarray and x.dtype is _F8 and x.shape == (3,) and x.strides == (8,):
        return x
    if x is None:
        if optional:
            return None
        raise InputError("a sample is needed here", field=name)
    try:
        a = np.ascontiguousarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"expected 3 numbers, got {x!r}", field=name) from None
    if a.shape != (3,):
        raise InputError(f"expected shape (3,), got {a.shape}", field=name)
    return a
