"""The readable reference of the error-state AHRS filter (``eskf-r3``, ``eskf-r6``): its
model and correction as numpy matrices, one function per equation.

``gnomon.estimators.eskf.Eskf.update_reference`` runs these in the phases of the compiled
kernel (``gnomon.kernels.eskf``) on the same ``STATE`` record; the tests hold the kernel
to them sample by sample. Frames, error state and measurement models: the docstring of
``gnomon.estimators.eskf`` (re-exported there under the same names).
"""

from __future__ import annotations

import numpy as np

from gnomon.rotation import dcm_from_quat, quat_from_rotvec, quat_mul, skew

__all__ = [
    "transition_matrix", "process_noise", "propagate", "measurement_r6", "measurement_r3",
    "measurement_function_r6", "measurement_function_r3", "measurement_matrix_r3_nav",
    "update", "update_dip", "accel_lowpass", "reference_field", "continuous_matrix",
    "gate_factor", "MAX_ABS_DIP",
]


# ---------------------------------------------------------------- model (readable reference)
def transition_matrix(w_hat_b, dt: float) -> np.ndarray:
    """First-order transition ``Φ = I + F dt``, ``F = [-[ω̂×]  -½I; 0  0]`` (6x6).

    ``w_hat_b`` (3,) bias-corrected rate, rad/s, body frame; ``dt`` s.
    """
    F = continuous_matrix(w_hat_b)
    return np.eye(6) + F * dt


def continuous_matrix(w_b) -> np.ndarray:
    """The paper's ``F = [-[ω×]  -½I₃; 0₃  0₃]`` (6x6) for the rate ``w_b`` (rad/s, body)."""
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(np.asarray(w_b, float))
    F[:3, 3:] = -0.5 * np.eye(3)
    return F


def process_noise(dt: float, gyro_noise: float, bias_rw: float) -> np.ndarray:
    """Discrete ``Q = diag(¼ σ_g² dt I, σ_b² dt I)``: gyro noise density σ_g (rad/s/√Hz)
    enters ``δė`` with the factor -½; bias random walk σ_b (rad/s/√s)."""
    return np.diag([0.25 * gyro_noise**2 * dt] * 3 + [bias_rw**2 * dt] * 3)


def propagate(q, b, P, gyro_b, dt, gyro_noise, bias_rw):
    """Strapdown step: ``q ← normalise(q ⊗ exp((ω̃ - b̂) dt))``, ``P ← Φ P Φᵀ + Q`` (symmetrised).

    q (4,) ``q_nb``; b (3,) bias estimate rad/s; P (6, 6); gyro_b (3,) rad/s.
    Returns new ``(q, P)``.
    """
    w = np.asarray(gyro_b, float) - b
    q = quat_mul(q, quat_from_rotvec(w * dt))
    q = q / np.linalg.norm(q)
    Phi = transition_matrix(w, dt)
    P = Phi @ P @ Phi.T + process_noise(dt, gyro_noise, bias_rw)
    return q, 0.5 * (P + P.T)


def measurement_function_r6(q, g, mag_h, mag_z) -> np.ndarray:
    """Predicted ``[Ĉ_bn g_n; Ĉ_bn m_n]`` (6,) for ``q = q_nb`` (noise-free readings in body)."""
    C_bn = dcm_from_quat(q).T
    return np.concatenate([C_bn @ [0.0, 0.0, g], C_bn @ [0.0, mag_h, -mag_z]])


def measurement_r6(q, accel_b, mag_b, g, mag_h, mag_z):
    """Full model: innovation ``y`` (6,) and ``D`` (6, 6) = ``[2[â×] 0; 2[m̂×] 0]``."""
    h = measurement_function_r6(q, g, mag_h, mag_z)
    y = np.concatenate([accel_b, mag_b]) - h
    D = np.zeros((6, 6))
    D[:3, :3] = 2.0 * skew(h[:3])
    D[3:, :3] = 2.0 * skew(h[3:])
    return y, D


def measurement_function_r3(q, accel_b, mag_b, g, mag_h) -> np.ndarray:
    """``[ã_x/g, ã_y/g, m̃_x/H]`` with ``ã = Ĉ_nb a``, ``m̃ = Ĉ_nb m`` for the estimate ``q``."""
    C_nb = dcm_from_quat(q)
    a_n = C_nb @ accel_b
    m_n = C_nb @ mag_b
    return np.array([a_n[0] / g, a_n[1] / g, m_n[0] / mag_h])


def measurement_matrix_r3_nav(tan_i: float) -> np.ndarray:
    """``D_n`` (3x3): reduced measurement vs the error rotation in the computed navigation frame.

    The paper prints ``[[0, 2, 0], [-2, 0, 0], [0, -2 tan I, -2]] = -D_n`` for its
    own error definition.
    """
    return np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0 * tan_i, 2.0]])


def measurement_r3(q, accel_b, mag_b, g, mag_h, mag_z):
    """Reduced model: measurement ``y`` (3,) (predicted 0), ``D`` (3, 6) = ``[D_n Ĉ_nb 0]``."""
    y = measurement_function_r3(q, accel_b, mag_b, g, mag_h)
    D = np.zeros((3, 6))
    D[:, :3] = measurement_matrix_r3_nav(mag_z / mag_h) @ dcm_from_quat(q)
    return y, D


def update(q, b, P, y, D, R, bias_limit: float = np.inf):
    """Kalman update (Joseph form, symmetrised) and injection of the error estimate; each
    component of the bias stays within ``±bias_limit`` (rad/s).

    Returns ``(q, b, P, dx)`` with ``dx = K y`` the estimated error ``[δe; δb]``.
    """
    S = D @ P @ D.T + R
    K = np.linalg.solve(S, D @ P).T          # P Dᵀ S⁻¹ (S, P symmetric)
    dx = K @ y
    IKD = np.eye(6) - K @ D
    P = IKD @ P @ IKD.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    q = quat_mul(q, np.array([1.0, dx[0], dx[1], dx[2]]))
    q = q / np.linalg.norm(q)
    return q, np.clip(b + dx[3:], -bias_limit, bias_limit), P, dx


# ---------------------------------------------------------------- initialisation
def accel_lowpass(q_nb, accel_b, lp_n, w: float):
    """Low-pass of the accelerometer in the computed navigation frame.

    ``lp_n ← lp_n + w (Ĉ_nb a - lp_n)`` (``lp_n`` None or ``w = 1``: restart), returns
    ``(Ĉ_bn lp_n, lp_n)``: the filtered reading in the body frame and the new state.
    Gravity is constant in the navigation frame while a linear acceleration averages
    out there (cf. VQF's inertial-frame low-pass, Laidig & Seel, Inf. Fusion 2023).
    """
    C = dcm_from_quat(q_nb)
    a_n = C @ np.asarray(accel_b, float)
    lp = a_n.copy() if lp_n is None else lp_n + w * (a_n - lp_n)
    return C.T @ lp, lp


#: |sin I| at most (inclination below 87.4 deg) for the reference field: nearer the pole
#: (or with |a| > g making a·m/(g|m|) exceed 1) H = sqrt(1 - s²) would vanish or be NaN
MAX_ABS_DIP = 0.999


def update_dip(dip_s: float, count: float, accel_b, mag_b, dt: float, tau: float, g: float):
    """Running mean of ``a·m / (g |m|)`` ≈ ``cos(angle(a, m))`` = ``-Z`` of the normalised
    field (rotation invariant, so it can be averaged while the body moves; dividing by
    ``g`` rather than ``|a|`` keeps accelerometer noise from biasing it: ``E|a| > g``).

    ``count += 1``, ``w = max(1/count, dt/tau)``, ``s += w (cos - s)``; ``tau <= 0``
    leaves it unchanged. Returns ``(s, count)`` with ``|s| <= 0.999``; the reference is
    ``Z = -s``, ``H = sqrt(1 - s²)``.
    """
    if tau <= 0.0:
        return dip_s, count
    a = np.asarray(accel_b, float)
    m = np.asarray(mag_b, float)
    count = count + 1.0
    w = max(1.0 / count, dt / tau)
    cos = (a @ m) / (g * np.sqrt(m @ m))
    s = dip_s + w * (cos - dip_s)
    return min(max(s, -MAX_ABS_DIP), MAX_ABS_DIP), count


def reference_field(q_nb, mag_b) -> tuple[float, float, float]:
    """``(|B0|, H, Z)``: field magnitude (input unit) and normalised horizontal / downward
    components of ``mag_b`` seen in the navigation frame of ``q_nb``."""
    m = np.asarray(mag_b, float)
    b0 = float(np.linalg.norm(m))
    m_n = dcm_from_quat(q_nb) @ (m / b0)
    return b0, float(np.hypot(m_n[0], m_n[1])), float(-m_n[2])


def gate_factor(dev: float, gate: float) -> float:
    """Variance inflation ``1 + (dev/gate)²`` (1 when ``gate <= 0``), as the kernel."""
    if gate <= 0.0:
        return 1.0
    return 1.0 + (dev / gate) ** 2


