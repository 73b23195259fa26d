"""Numba kernel: spherical-harmonic geomagnetic field at many points.

See :mod:`gnomon.environment.magnetic`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def sh_field_ecef(r_e, g, h, a_ref, nmax):
    """Field (nT) in ECEF at ECEF positions ``r_e`` (N, 3) in the units of ``a_ref``.

    ``g``, ``h``: Schmidt semi-normalised Gauss coefficients (nmax+1, nmax+1), nT,
    indexed ``[n, m]``. Recursion for P_n^m and dP/dθ as in Wertz (1978), App. G.
    """
    npts = r_e.shape[0]
    out = np.empty((npts, 3))
    P = np.zeros((nmax + 1, nmax + 1))
    dP = np.zeros((nmax + 1, nmax + 1))
    S = np.zeros((nmax + 1, nmax + 1))
    S[0, 0] = 1.0
    for n in range(1, nmax + 1):
        S[n, 0] = S[n - 1, 0] * (2.0 * n - 1.0) / n
        for m in range(1, n + 1):
            f = 2.0 if m == 1 else 1.0
            S[n, m] = S[n, m - 1] * np.sqrt((n - m + 1.0) * f / (n + m))
    cosm = np.empty(nmax + 1)
    sinm = np.empty(nmax + 1)
    for k in range(npts):
        x = r_e[k, 0]
        y = r_e[k, 1]
        z = r_e[k, 2]
        rho = np.sqrt(x * x + y * y)
        r = np.sqrt(rho * rho + z * z)
        ct = z / r
        st = rho / r
        if rho > 0.0:
            cp = x / rho
            sp = y / rho
        else:
            cp = 1.0
            sp = 0.0
        # Gauss-normalised associated Legendre functions and derivatives
        P[0, 0] = 1.0
        dP[0, 0] = 0.0
        for n in range(1, nmax + 1):
            for m in range(0, n + 1):
                if n == m:
                    P[n, n] = st * P[n - 1, n - 1]
                    dP[n, n] = st * dP[n - 1, n - 1] + ct * P[n - 1, n - 1]
                elif n == 1:
                    P[n, m] = ct * P[n - 1, m]
                    dP[n, m] = ct * dP[n - 1, m] - st * P[n - 1, m]
                else:
                    K = ((n - 1.0) ** 2 - m * m) / ((2.0 * n - 1.0) * (2.0 * n - 3.0))
                    P[n, m] = ct * P[n - 1, m] - K * P[n - 2, m]
                    dP[n, m] = ct * dP[n - 1, m] - st * P[n - 1, m] - K * dP[n - 2, m]
        cosm[0] = 1.0
        sinm[0] = 0.0
        for m in range(1, nmax + 1):
            cosm[m] = cosm[m - 1] * cp - sinm[m - 1] * sp
            sinm[m] = sinm[m - 1] * cp + cosm[m - 1] * sp
        br = 0.0
        bt = 0.0
        bp = 0.0
        ar = a_ref / r
        arn = ar * ar
        for n in range(1, nmax + 1):
            arn *= ar
            sr = 0.0
            stt = 0.0
            sph = 0.0
            for m in range(0, n + 1):
                c = g[n, m] * cosm[m] + h[n, m] * sinm[m]
                pnm = P[n, m] * S[n, m]
                sr += c * pnm
                stt += c * dP[n, m] * S[n, m]
                sph += m * (-g[n, m] * sinm[m] + h[n, m] * cosm[m]) * pnm
            br += arn * (n + 1.0) * sr
            bt -= arn * stt
            bp -= arn * sph
        if st > 1e-12:
            bp /= st
        else:
            bp = 0.0
        # spherical (r, theta, phi) -> ECEF
        out[k, 0] = br * st * cp + bt * ct * cp - bp * sp
        out[k, 1] = br * st * sp + bt * ct * sp + bp * cp
        out[k, 2] = br * ct - bt * st
    return out
