"""Numba kernel: rigid spacecraft with wheels and magnetorquers, fixed-step RK4.

See :mod:`gnomon.dynamics` (the equations and the control laws).

Every function is ``@njit``; ``rk4_attitude.py_func`` is the readable (slow) Python
version the tests compare the compiled one against. Quaternion products, rotations and
cross products come from the kernel toolbox (``gnomon.kernels.quat``, ``linalg``).
``Coefficients`` (built by ``coefficients``) holds the body, the control law and its
limits; one RK4 step evaluates ``derivs`` (dynamics, kinematics, ``gravity_gradient``) four
times with the control held (``control``).

Control modes (``mode``; :data:`gnomon.dynamics.CONTROL_MODES` maps the names, mode 0 is
"none": no dipole, no wheel torque).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.linalg import cross_arr
from gnomon.kernels.quat import mul_arr, rotate_inv_arr

MODE_BDOT = 1
MODE_MAGNETIC_PD = 2
MODE_BDOT_THEN_PD = 3
MODE_WHEEL_PD = 4


class Coefficients(NamedTuple):
    """The body and its control: inertia ``J``/``Jinv`` (3, 3) kg m², step ``dt`` s, control
    ``mode`` and gains (``k_bdot`` A m² s/T, ``kp`` N m, ``kd`` N m s, ``switch_rate``
    rad/s, ``k_dump`` 1/s), limits (``max_dipole`` A m², ``max_wheel_torque`` N m,
    ``max_wheel_momentum`` N m s), ``residual_dipole`` (3,) A m², ``mu`` m³/s² and
    ``gravity_gradient``."""

    J: np.ndarray
    Jinv: np.ndarray
    dt: float
    mode: int
    k_bdot: float
    kp: float
    kd: float
    switch_rate: float
    k_dump: float
    max_dipole: float
    max_wheel_torque: float
    max_wheel_momentum: float
    residual_dipole: np.ndarray
    mu: float
    gravity_gradient: bool


def coefficients(J, dt, mode, k_bdot, kp, kd, switch_rate, k_dump, max_dipole,
                 max_wheel_torque, max_wheel_momentum, residual_dipole, mu,
                 gravity_gradient) -> Coefficients:
    """``Coefficients`` with every value converted to the kernel's types (``J`` (3, 3))."""
    J = np.ascontiguousarray(J, float)
    return Coefficients(J, np.linalg.inv(J), float(dt), int(mode), float(k_bdot), float(kp),
                        float(kd), float(switch_rate), float(k_dump), float(max_dipole),
                        float(max_wheel_torque), float(max_wheel_momentum),
                        np.asarray(residual_dipole, float), float(mu), bool(gravity_gradient))


@njit(cache=True)
def gravity_gradient(c, q, r_i):
    """Gravity-gradient torque ``3 μ/r³ n̂ × (J n̂)`` (3,) N m in b (``n̂`` nadir in b, from the
    position ``r_i`` m in i)."""
    rn = np.sqrt(r_i[0] ** 2 + r_i[1] ** 2 + r_i[2] ** 2)
    nad = rotate_inv_arr(q, -r_i / rn)
    return 3.0 * c.mu / rn**3 * cross_arr(nad, c.J @ nad)


@njit(cache=True)
def derivs(c, q, w, h, r_i, b_i, m_cmd, hdot):
    """Time derivatives of ``q_ib``, ``w_ib_b`` and the disturbance torque (residual dipole
    ``m_res × B_b``, gravity gradient if enabled), with the control ``m_cmd`` A m², ``hdot``
    N m held; position ``r_i`` m and field ``b_i`` T in i."""
    b_b = rotate_inv_arr(q, b_i)
    dist = cross_arr(c.residual_dipole, b_b)
    torque = cross_arr(m_cmd, b_b) + dist
    if c.gravity_gradient:
        gg = gravity_gradient(c, q, r_i)
        torque = torque + gg
        dist = dist + gg
    Jw = c.J @ w
    wdot = c.Jinv @ (-cross_arr(w, Jw + h) - hdot + torque)
    qdot = 0.5 * mul_arr(q, np.array([0.0, w[0], w[1], w[2]]))
    return qdot, wdot, dist


@njit(cache=True)
def control(c, q_ib, w_ib_b, q_io, w_io_o, b_i, b_prev_b, h, pointing):
    """Magnetic dipole command (A m²) and wheel momentum rate (N m s/s) held over one step.

    ``pointing``: the B-dot phase has handed over to the pointing law (``bdot_then_pd``).
    Returns ``(m, hdot, b_b, pointing)``.
    """
    m = np.zeros(3)
    hdot = np.zeros(3)
    b_b = rotate_inv_arr(q_ib, b_i)
    q_ob = mul_arr(np.array([q_io[0], -q_io[1], -q_io[2], -q_io[3]]), q_ib)
    w_ob_b = w_ib_b - rotate_inv_arr(q_ob, w_io_o)
    bb = b_b[0] ** 2 + b_b[1] ** 2 + b_b[2] ** 2
    sgn = 1.0 if q_ob[0] >= 0 else -1.0
    tau = -c.kp * sgn * q_ob[1:] - c.kd * w_ob_b
    mode = c.mode
    if mode == MODE_BDOT_THEN_PD and not pointing:
        if np.sqrt(w_ob_b[0] ** 2 + w_ob_b[1] ** 2 + w_ob_b[2] ** 2) < c.switch_rate:
            pointing = True
    if mode == MODE_BDOT or (mode == MODE_BDOT_THEN_PD and not pointing):
        m = -c.k_bdot * (b_b - b_prev_b) / c.dt
    elif mode == MODE_MAGNETIC_PD or mode == MODE_BDOT_THEN_PD:
        if bb > 0:
            m = cross_arr(b_b, tau) / bb
    elif mode == MODE_WHEEL_PD:
        for k in range(3):
            hdot[k] = min(max(-tau[k], -c.max_wheel_torque), c.max_wheel_torque)
        if bb > 0:
            m = cross_arr(b_b, -c.k_dump * h) / bb
    for k in range(3):
        m[k] = min(max(m[k], -c.max_dipole), c.max_dipole)
    return m, hdot, b_b, pointing


@njit(cache=True)
def rk4_attitude(c, q0, w0, h0, nsteps, r_half, b_half, q_io, w_io_o):
    """Integrate ``nsteps`` RK4 steps of size ``c.dt``; environment given on the half-step grid.

    ``r_half`` (2*nsteps+1, 3) m and ``b_half`` (2*nsteps+1, 3) T: position and field in i
    at ``k*dt/2``; ``q_io`` (nsteps+1, 4), ``w_io_o`` (nsteps+1, 3) at the samples.
    Returns, at the nsteps+1 samples: q_ib, w_ib_b, h_b, m_cmd, hdot, disturbance torque.
    """
    dt = c.dt
    n = nsteps + 1
    Q = np.empty((n, 4))
    W = np.empty((n, 3))
    Hs = np.empty((n, 3))
    M = np.zeros((n, 3))
    HD = np.zeros((n, 3))
    D = np.zeros((n, 3))
    q = q0.copy()
    w = w0.copy()
    h = h0.copy()
    pointing = False
    b_prev = rotate_inv_arr(q, b_half[0])
    for k in range(n):
        Q[k] = q
        W[k] = w
        Hs[k] = h
        m, hdot, b_b, pointing = control(c, q, w, q_io[k], w_io_o[k], b_half[2 * k], b_prev,
                                         h, pointing)
        # wheel saturation: no further momentum beyond the limit
        for j in range(3):
            if ((h[j] >= c.max_wheel_momentum and hdot[j] > 0)
                    or (h[j] <= -c.max_wheel_momentum and hdot[j] < 0)):
                hdot[j] = 0.0
        M[k] = m
        HD[k] = hdot
        dq1, dw1, d1 = derivs(c, q, w, h, r_half[2 * k], b_half[2 * k], m, hdot)
        D[k] = d1
        b_prev = b_b
        if k == n - 1:
            break
        i2 = 2 * k + 1
        i3 = 2 * k + 2
        dq2, dw2, _ = derivs(c, q + 0.5 * dt * dq1, w + 0.5 * dt * dw1, h + 0.5 * dt * hdot,
                             r_half[i2], b_half[i2], m, hdot)
        dq3, dw3, _ = derivs(c, q + 0.5 * dt * dq2, w + 0.5 * dt * dw2, h + 0.5 * dt * hdot,
                             r_half[i2], b_half[i2], m, hdot)
        dq4, dw4, _ = derivs(c, q + dt * dq3, w + dt * dw3, h + dt * hdot, r_half[i3],
                             b_half[i3], m, hdot)
        q = q + dt / 6.0 * (dq1 + 2 * dq2 + 2 * dq3 + dq4)
        q = q / np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
        w = w + dt / 6.0 * (dw1 + 2 * dw2 + 2 * dw3 + dw4)
        h = h + dt * hdot
    return Q, W, Hs, M, HD, D
