"""Error metrics between an estimated and a true attitude (same frames: ``q_rb``, r from body).

* ``error_angle_rad``: total attitude error ``2·atan2(|δq_xyz|, |δq_w|)``, ``δq = conj(q_true) ⊗ q_est``.
* ``axis_errors_rad``: Euler angles ``[roll, pitch, yaw]`` (z-y'-x'') of ``δq``,
  the small-angle per-axis errors of the papers' plots (error expressed in the body frame).
* ``broad_errors_rad``: the BROAD benchmark's total / heading / inclination errors,
  exactly as it defines them (Laidig et al., Data 6(7):72, 2021): ``q_err = q_est ⊗ conj(q_true)``
  (error in the reference frame, whose z axis is vertical), total ``2·acos(|w|)``,
  heading ``2·atan(|z/w|)``, inclination ``2·acos(sqrt(w² + z²))``.
* ``rms``: root mean square over a boolean mask, NaN-free.

All inputs have shape ``(N, 4)`` (or ``(..., 4)``); outputs are radians.
"""

from __future__ import annotations

import numpy as np

from gnomon.rotation import as_quat, error_angle, euler_from_quat, quat_conj, quat_mul

__all__ = ["error_angle_rad", "axis_errors_rad", "broad_errors_rad", "rms", "rms_deg"]


def error_angle_rad(q_true, q_est) -> np.ndarray:
    """Total attitude error angle (rad, in [0, π]), sign-safe."""
    return error_angle(q_true, q_est)


def axis_errors_rad(q_true, q_est) -> np.ndarray:
    """Per-axis errors ``[roll, pitch, yaw]`` (rad): Euler angles of ``conj(q_true) ⊗ q_est``."""
    d = quat_mul(quat_conj(as_quat(q_true, "q_true")), as_quat(q_est, "q_est"))
    return euler_from_quat(d)


def broad_errors_rad(q_true, q_est) -> dict[str, np.ndarray]:
    """BROAD's ``total``, ``heading`` and ``inclination`` errors (rad), shape (...,) each.

    The reference frame's z axis must be vertical (ENU or NWU, as in BROAD).
    """
    e = quat_mul(as_quat(q_est, "q_est"), quat_conj(as_quat(q_true, "q_true")))
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    w, z = e[..., 0], e[..., 3]
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore"):
        heading = 2.0 * np.arctan(np.abs(z / w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return {"total": total, "heading": heading, "inclination": inclination}


def rms(x, mask=None) -> float:
    """Root mean square of ``x`` (N,) or (N, k) over the rows where ``mask`` is true.

    Rows with a NaN are an error unless masked out. An empty selection gives NaN.
    """
    x = np.asarray(x, dtype=float)
    if mask is not None:
        x = x[np.asarray(mask, dtype=bool)]
    if x.size == 0:
        return float("nan")
    if not np.all(np.isfinite(x)):
        raise ValueError("rms: non-finite values inside the mask")
    return float(np.sqrt(np.mean(x * x)))


def rms_deg(x_rad, mask=None) -> float:
    """``rms`` converted to degrees."""
    return float(np.degrees(rms(x_rad, mask)))
