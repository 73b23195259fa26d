"""The magnetometer's samples as the calibration takes them: raw readings (N, 3) in µT,
in the sensor's axes, validated (finite, no zero rows, at least ``MIN_SAMPLES``); a
``Recording``'s magnetometer converted to µT from any ``mag_unit``."""

from __future__ import annotations

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording

__all__ = ["mag_uT_of", "MIN_SAMPLES"]

#: fewest samples accepted (the full model has 9 parameters)
MIN_SAMPLES = 30


def _as_mag(mag_uT) -> np.ndarray:
    """Raw readings ``mag_uT`` as a validated (N, 3) float array, µT; InputError naming
    the first bad row."""
    try:
        m = np.asarray(mag_uT, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"not numbers: {exc}", field="mag") from None
    if m.ndim != 2 or m.shape[1] != 3:
        raise InputError(f"expected shape (N, 3), got {m.shape}", field="mag")
    bad = ~np.isfinite(m).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InputError(f"non-finite value {m[row].tolist()}", field="mag", row=row)
    zero = ~np.any(m != 0, axis=1)
    if zero.any():
        row = int(np.flatnonzero(zero)[0])
        raise InputError(f"zero vector {m[row].tolist()} (a missing reading? "
                         f"{int(zero.sum())} such rows)", field="mag", row=row)
    if m.shape[0] < MIN_SAMPLES:
        raise InputError(f"too few samples: {m.shape[0]} (at least {MIN_SAMPLES})",
                         field="mag")
    return m



def mag_uT_of(rec: Recording) -> np.ndarray:
    """The recording's magnetometer samples in µT (N, 3); InputError when it has none."""
    if rec.mag is None:
        raise InputError("the recording has no magnetometer", file=rec.source or None,
                         field="mag")
    return rec.mag * (MAG_UNITS_TO_TESLA[rec.mag_unit] / 1e-6)
