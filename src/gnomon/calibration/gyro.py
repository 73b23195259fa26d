"""The hard-iron offset from the gyro: the offset that makes the magnetometer turn as the
gyro says.

:func:`gnomon.calibration.apply.calibrate_mag` (a ``Recording``) adds the gyro:
:func:`gyro_offset_uT` solves ``dh/dt = -w x h`` for the offset (µT, (3,), sensor axes;
``w`` the gyro in rad/s, the same axes), linear, from the rotation alone (no sphere
geometry, little sensitivity to a disturbance the device passes through); it is the fit's
hint, and when the ellipsoid is refused it is the result itself (model ``"gyro-offset"``).
"""

from __future__ import annotations

import numpy as np

from gnomon.calibration.samples import mag_uT_of
from gnomon.recording import Recording

__all__ = ["gyro_offset_uT", "MAX_GYRO_CONDITION"]

#: :func:`gyro_offset_uT` needs rotation about more than one axis: the condition number
#: of its normal equations at most this (rotation about the weakest axis ~3 % of the
#: strongest)
MAX_GYRO_CONDITION = 1e3


def gyro_offset_uT(rec: Recording, window_s: float = 0.25, max_dt_s: float = 0.2,
                   iterations: int = 10) -> np.ndarray | None:
    """The hard-iron offset (µT, (3,)) that makes the magnetometer turn as the gyro says,
    or None when the rotation does not determine it.

    In a constant field the corrected reading ``h = m - o`` obeys ``dh/dt = -w × h``
    (``w`` the gyro, rad/s), linear in ``o``: over each window of ``window_s``
    (trapezoidal sums, no window across a gap longer than ``max_dt_s``)
    ``Δm + Σ dt/2 (w_i × m_i + w_i+1 × m_i+1) = (Σ dt/2 (w_i + w_i+1)) × o``. Solved by
    least squares re-weighted with Huber weights (a disturbed or unmodelled window counts
    less); soft iron is neglected (a few per cent of the field). Independent of the
    sphere's geometry, it tells apart the two centres that data on a circle fit equally
    well: :func:`calibrate_mag` gives it to :func:`fit_mag` as a start. Gyro sampled at
    the magnetometer's time stamps by linear interpolation."""
    if rec.mag is None or rec.gyro is None:
        return None
    t_m = rec.times("mag")
    m = mag_uT_of(rec)
    w = np.column_stack([np.interp(t_m, rec.t, rec.gyro[:, k]) for k in range(3)])
    dt = np.diff(t_m)
    good = (dt > 0) & (dt <= max_dt_s)
    wbar = 0.5 * dt[:, None] * (w[:-1] + w[1:])
    rhs = np.diff(m, axis=0) + 0.5 * dt[:, None] * (np.cross(w[:-1], m[:-1])
                                                    + np.cross(w[1:], m[1:]))
    # windows: consecutive good steps, cut at gaps and every window_s
    seg = np.cumsum(~good)
    win = np.floor((t_m[:-1] - t_m[0]) / window_s).astype(np.int64)
    key = seg * (int(win.max()) + 1) + win
    key = key[good]
    _, idx = np.unique(key, return_inverse=True)
    W = np.zeros((idx.max() + 1, 3)) if idx.size else np.zeros((0, 3))
    R = np.zeros_like(W)
    np.add.at(W, idx, wbar[good])
    np.add.at(R, idx, rhs[good])
    if W.shape[0] < 10:
        return None

    def cross_matrix(v):
        z = np.zeros(len(v))
        return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1),
                         np.stack([v[:, 2], z, -v[:, 0]], -1),
                         np.stack([-v[:, 1], v[:, 0], z], -1)], 1)

    A = cross_matrix(W)  # (K, 3, 3): A_k o = W_k × o
    weights = np.ones(W.shape[0])
    o = np.zeros(3)
    for _ in range(iterations):
        AtA = np.einsum("k,kji,kjl->il", weights, A, A)
        if np.linalg.cond(AtA) > MAX_GYRO_CONDITION:
            return None
        o = np.linalg.solve(AtA, np.einsum("k,kji,kj->i", weights, A, R))
        res = np.linalg.norm(R - np.einsum("kij,j->ki", A, o), axis=1)
        k = 1.5 * np.median(res) + 1e-12
        weights = np.where(res <= k, 1.0, k / res)
    return o
