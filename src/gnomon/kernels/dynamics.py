"""Numba kernel: rigid spacecraft with wheels and magnetorquers, fixed-step RK4.

See :mod:`gnomon.dynamics`.

Every function is ``@njit``; ``rk4_attitude.py_func`` is the readable (slow)
Python version the tests compare the compiled one against.
"""

from __future__ import annotations

import numpy as np
from numba import njit

MODE_NONE = 0
MODE_BDOT = 1
MODE_MAGNETIC_PD = 2
MODE_BDOT_THEN_PD = 3
MODE_WHEEL_PD = 4


@njit(cache=True)
def qmul(p, q):
    return np.array([
        p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
        p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
        p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
        p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]])


@njit(cache=True)
def rot_t(q, v):
    """``R(q)^T v``: for ``q = q_ib`` and ``v`` in i, the vector in b."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    r02 = 2 * (x * z + w * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r12 = 2 * (y * z - w * x)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    return np.array([r00 * v[0] + r10 * v[1] + r20 * v[2],
                     r01 * v[0] + r11 * v[1] + r21 * v[2],
                     r02 * v[0] + r12 * v[1] + r22 * v[2]])


@njit(cache=True)
def cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def derivs(q, w, h, J, Jinv, r_i, b_i, m_cmd, hdot, res_dipole, mu, use_gg):
    """Time derivatives of ``q_ib``, ``w_ib_b`` and wheel momentum ``h_b``; and the disturbance."""
    b_b = rot_t(q, b_i)
    torque = cross(m_cmd, b_b) + cross(res_dipole, b_b)
    dist = cross(res_dipole, b_b)
    if use_gg:
        rn = np.sqrt(r_i[0] ** 2 + r_i[1] ** 2 + r_i[2] ** 2)
        nad = rot_t(q, -r_i / rn)
        gg = 3.0 * mu / rn**3 * cross(nad, J @ nad)
        torque = torque + gg
        dist = dist + gg
    Jw = J @ w
    wdot = Jinv @ (-cross(w, Jw + h) - hdot + torque)
    qdot = 0.5 * qmul(q, np.array([0.0, w[0], w[1], w[2]]))
    return qdot, wdot, dist


@njit(cache=True)
def control(mode, gains, q_ib, w_ib_b, q_io, w_io_o, b_i, b_prev_b, h, dt, m_max, tw_max,
            state):
    """Magnetic dipole command (A m^2) and wheel momentum rate (N m s/s) held over one step.

    ``gains = [k_bdot (A m^2 s/T), kp (N m), kd (N m s), switch_rate (rad/s), k_dump (1/s)]``.
    ``state[0]``: 1 once the B-dot phase has handed over to the pointing law.
    """
    m = np.zeros(3)
    hdot = np.zeros(3)
    b_b = rot_t(q_ib, b_i)
    q_io_c = np.array([q_io[0], -q_io[1], -q_io[2], -q_io[3]])
    q_ob = qmul(q_io_c, q_ib)
    w_ob_b = w_ib_b - rot_t(q_ob, w_io_o)
    bb = b_b[0] ** 2 + b_b[1] ** 2 + b_b[2] ** 2
    sgn = 1.0 if q_ob[0] >= 0 else -1.0
    tau = -gains[1] * sgn * q_ob[1:] - gains[2] * w_ob_b
    if mode == MODE_BDOT_THEN_PD and state[0] == 0.0:
        if np.sqrt(w_ob_b[0] ** 2 + w_ob_b[1] ** 2 + w_ob_b[2] ** 2) < gains[3]:
            state[0] = 1.0
    if mode == MODE_BDOT or (mode == MODE_BDOT_THEN_PD and state[0] == 0.0):
        m = -gains[0] * (b_b - b_prev_b) / dt
    elif mode == MODE_MAGNETIC_PD or mode == MODE_BDOT_THEN_PD:
        if bb > 0:
            m = cross(b_b, tau) / bb
    elif mode == MODE_WHEEL_PD:
        for k in range(3):
            hdot[k] = min(max(-tau[k], -tw_max), tw_max)
        if bb > 0:
            m = cross(b_b, -gains[4] * h) / bb
    for k in range(3):
        m[k] = min(max(m[k], -m_max), m_max)
    return m, hdot, b_b


@njit(cache=True)
def rk4_attitude(q0, w0, h0, J, Jinv, dt, nsteps, r_half, b_half, q_io, w_io_o,
                 mode, gains, m_max, tw_max, hw_max, res_dipole, mu, use_gg):
    """Integrate ``nsteps`` RK4 steps of size ``dt``; environment given on the half-step grid.

    ``r_half`` (2*nsteps+1, 3) m and ``b_half`` (2*nsteps+1, 3) T: position and field in i
    at ``k*dt/2``; ``q_io`` (nsteps+1, 4), ``w_io_o`` (nsteps+1, 3) at the samples.
    Returns, at the nsteps+1 samples: q_ib, w_ib_b, h_b, m_cmd, hdot, disturbance torque.
    """
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
    state = np.zeros(1)
    b_prev = rot_t(q, b_half[0])
    for k in range(n):
        Q[k] = q
        W[k] = w
        Hs[k] = h
        m, hdot, b_b = control(mode, gains, q, w, q_io[k], w_io_o[k], b_half[2 * k], b_prev,
                               h, dt, m_max, tw_max, state)
        # wheel saturation: no further momentum beyond the limit
        for j in range(3):
            if (h[j] >= hw_max and hdot[j] > 0) or (h[j] <= -hw_max and hdot[j] < 0):
                hdot[j] = 0.0
        M[k] = m
        HD[k] = hdot
        dq1, dw1, d1 = derivs(q, w, h, J, Jinv, r_half[2 * k], b_half[2 * k], m, hdot,
                              res_dipole, mu, use_gg)
        D[k] = d1
        b_prev = b_b
        if k == n - 1:
            break
        i2 = 2 * k + 1
        i3 = 2 * k + 2
        dq2, dw2, _ = derivs(q + 0.5 * dt * dq1, w + 0.5 * dt * dw1, h + 0.5 * dt * hdot, J,
                             Jinv, r_half[i2], b_half[i2], m, hdot, res_dipole, mu, use_gg)
        dq3, dw3, _ = derivs(q + 0.5 * dt * dq2, w + 0.5 * dt * dw2, h + 0.5 * dt * hdot, J,
                             Jinv, r_half[i2], b_half[i2], m, hdot, res_dipole, mu, use_gg)
        dq4, dw4, _ = derivs(q + dt * dq3, w + dt * dw3, h + dt * hdot, J, Jinv, r_half[i3],
                             b_half[i3], m, hdot, res_dipole, mu, use_gg)
        q = q + dt / 6.0 * (dq1 + 2 * dq2 + 2 * dq3 + dq4)
        q = q / np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
        w = w + dt / 6.0 * (dw1 + 2 * dw2 + 2 * dw3 + dw4)
        h = h + dt * hdot
    return Q, W, Hs, M, HD, D
