"""Rigid-body attitude dynamics of a spacecraft with reaction wheels and magnetorquers.

Equations (body frame b, inertial frame i; seed 001's model):

    J dω/dt = -ω × (J ω + h) - dh/dt + m × B_b + T_d
    dq_ib/dt = ½ q_ib ⊗ [0, ω],    ω = w_ib_b

* ``J``: full inertia tensor (kg m²), symmetric positive definite.
* ``h``: wheel angular momentum in b (N m s); ``dh/dt`` the wheel torque command,
  limited in torque and momentum (a saturated wheel cannot take more momentum).
* ``m``: magnetorquer dipole (A m²), each axis limited to ``max_dipole``.
* ``T_d``: disturbances: gravity gradient ``3 μ/r³ n̂ × (J n̂)`` (n̂ nadir in b) and a
  residual magnetic dipole ``m_res × B_b``.

Control laws (held constant over a step; ideal knowledge of the state, as a
flight controller after its own attitude determination):

* ``bdot``: ``m = -k Ḃ_b`` (detumbling, Stickler & Alfriend 1976).
* ``magnetic_pd``: desired torque ``τ = -kp vec(q_ob) - kd w_ob_b`` mapped to a
  dipole ``m = B_b × τ / |B_b|²`` (the component of τ perpendicular to B is
  realised — a slowly rotating satellite stabilised close to the orbital frame).
* ``bdot_then_pd``: B-dot until ``|w_ob_b|`` < ``switch_rate``, then ``magnetic_pd``.
* ``wheel_pd``: τ by the wheels (torque-limited), magnetorquers dump wheel momentum
  (``m = B_b × (-k_dump h) / |B_b|²``).

Integration: fixed-step RK4 (:func:`gnomon.kernels.dynamics.rk4_attitude`, numba),
quaternion renormalised after every step; the environment (position, field) is
supplied on the half-step grid so that the RK4 stages see it exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.environment.orbit import MU_EARTH
from gnomon.errors import InputError

__all__ = ["CONTROL_MODES", "check_inertia", "integrate_attitude", "AttitudeHistory"]

CONTROL_MODES = {"none": 0, "bdot": 1, "magnetic_pd": 2, "bdot_then_pd": 3, "wheel_pd": 4}


def check_inertia(J, field: str = "spacecraft.inertia_kg_m2") -> np.ndarray:
    """Validate an inertia tensor: (3,) principal moments or (3, 3) symmetric positive definite.

    Returns the (3, 3) tensor; raises ``InputError`` naming ``field`` otherwise.
    """
    a = np.asarray(J, dtype=float)
    if a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise InputError(f"expected 3 principal moments or a 3x3 matrix, got {J!r}", field=field)
    if np.any(np.diag(a) <= 0):
        raise InputError(f"moments of inertia must be positive, got diagonal {np.diag(a).tolist()}",
                         field=field)
    if not np.allclose(a, a.T, rtol=1e-9, atol=1e-12):
        i, j = np.unravel_index(np.argmax(np.abs(a - a.T)), a.shape)
        raise InputError(f"inertia tensor must be symmetric: element [{i}][{j}] = {a[i, j]:g} "
                         f"but [{j}][{i}] = {a[j, i]:g} (products of inertia appear twice)",
                         field=field)
    ev = np.linalg.eigvalsh(a)
    if ev[0] <= 0:
        raise InputError(f"inertia tensor is not positive definite (eigenvalues "
                         f"{np.round(ev, 6).tolist()})", field=field)
    if ev[2] > ev[0] + ev[1] + 1e-12 * ev[2]:
        raise InputError(f"principal moments {np.round(ev, 6).tolist()} violate the triangle "
                         f"inequality J1 + J2 >= J3 ({ev[0]:.6g} + {ev[1]:.6g} < {ev[2]:.6g}: "
                         "no rigid body has them)", field=field)
    return a


@dataclass(frozen=True)
class AttitudeHistory:
    """Integrated attitude at the samples: ``q_ib`` (N, 4), ``w_ib_b`` (N, 3) rad/s,
    wheel momentum ``h_b`` (N, 3) N m s, dipole ``m_b`` (N, 3) A m², wheel momentum rate
    ``hdot_b`` (N, 3) N m, disturbance torque ``torque_dist_b`` (N, 3) N m."""

    q_ib: np.ndarray
    w_ib_b: np.ndarray
    h_b: np.ndarray
    m_b: np.ndarray
    hdot_b: np.ndarray
    torque_dist_b: np.ndarray


def integrate_attitude(q0_ib, w0_ib_b, h0_b, inertia, dt, r_half_i, b_half_i_T, q_io, w_io_o,
                       mode="none", k_bdot=0.0, kp=0.0, kd=0.0, switch_rate=0.0, k_dump=0.0,
                       max_dipole=np.inf, max_wheel_torque=0.0, max_wheel_momentum=np.inf,
                       residual_dipole=(0.0, 0.0, 0.0), gravity_gradient=True,
                       compiled=True) -> AttitudeHistory:
    """Integrate the attitude over ``N = len(q_io)`` samples spaced ``dt`` (s).

    ``r_half_i`` (2N-1, 3) m and ``b_half_i_T`` (2N-1, 3) tesla: position and field in i
    at times ``k dt/2``. ``q_io`` (N, 4), ``w_io_o`` (N, 3) rad/s: orbital frame at the
    samples (used by the control laws). ``compiled=False`` runs the readable Python version.
    """
    from gnomon.kernels import dynamics as K

    if mode not in CONTROL_MODES:
        raise InputError(f"unknown control mode {mode!r}; use one of {list(CONTROL_MODES)}",
                         field="controller.mode")
    J = check_inertia(inertia)
    n = len(q_io)
    c = K.coefficients(J, dt, CONTROL_MODES[mode], k_bdot, kp, kd, switch_rate, k_dump,
                       max_dipole, max_wheel_torque, max_wheel_momentum, residual_dipole,
                       MU_EARTH, gravity_gradient)
    fn = K.rk4_attitude if compiled else K.rk4_attitude.py_func
    out = fn(c, np.asarray(q0_ib, float), np.asarray(w0_ib_b, float), np.asarray(h0_b, float),
             n - 1, np.ascontiguousarray(r_half_i, float), np.ascontiguousarray(b_half_i_T, float),
             np.ascontiguousarray(q_io, float), np.ascontiguousarray(w_io_o, float))
    return AttitudeHistory(*out)
