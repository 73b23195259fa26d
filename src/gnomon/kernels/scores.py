"""Numba kernel of a campaign run's scores: the metrics of ``gnomon.metrics.score_run`` and
``score_run_budget`` of one run, in one pass over its samples.

:func:`run_scores` computes, for a run whose ``q_true`` and ``q_est`` are finite, what
those two functions compute with numpy (``gnomon.campaign.scoring`` calls it once per
run of a chunk and the tests compare the two): the total error angle's RMS, maximum
and mean, BROAD's heading / inclination RMS, and per body axis the RMS and the 99th
percentile of the rotation-vector error (and of the total angle). The numbers agree
to about 1e-13 of their size: the sums run in another order than numpy's pairwise
ones; the percentiles are numpy's ``quantile(..., method="linear")`` arithmetic on the
same selected values.

Why a kernel: numpy forms a dozen (R, N) temporaries per metric; one compiled pass
over each run's samples was about 5x faster (the campaign spent more time scoring
than in its batched filter).

Conventions (``docs/conventions.md``): Hamilton quaternions ``[w, x, y, z]``; errors
in degrees.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["N_SCORES", "run_scores"]

#: rms, max, mean, heading rms, inclination rms; x, y, z rms; x, y, z, total p99
N_SCORES = 12
DEG = 180.0 / math.pi


@njit(cache=True)
def _quantile99(x):
    """``numpy.quantile(x, 0.99)`` (linear; ``x`` (n,) is reordered, n >= 1)."""
    n = x.shape[0]
    pos = 0.99 * (n - 1)
    lo = int(math.floor(pos))
    frac = pos - lo
    y = np.partition(x, lo)
    a = y[lo]
    if lo + 1 >= n:
        return a
    b = np.min(y[lo + 1:])
    diff = b - a
    if frac >= 0.5:
        return b - diff * (1.0 - frac)
    return a + diff * frac


@njit(cache=True, error_model="numpy")
def run_scores(qt, qe, k0, vertical, use, out):
    """The scores of one run over its samples ``k >= k0`` with ``use[k]`` into ``out``
    (:data:`N_SCORES`,).

    ``qt``, ``qe`` (N, 4): the true and the estimated attitude (same frames, finite);
    ``k0``: the first sample scored (the settling time's); ``vertical``: whether the
    reference frame has a vertical axis (ENU, NWU: heading and inclination are
    scored, else ``out[3:5]`` is NaN); ``use`` (N,) bool: the samples of the phase
    scored (all, or the sunlit or eclipse ones). ``out``: ``rms_deg``, ``max_deg``,
    ``mean_deg``, ``heading_rms_deg``, ``inclination_rms_deg``, ``x/y/z_rms_deg``,
    ``x/y/z_p99_deg``, ``p99_deg`` (all NaN when no sample is scored).
    """
    axes = np.empty((4, max(qt.shape[0] - k0, 0)))
    s_err2 = s_err = s_h2 = s_i2 = 0.0
    mx = -np.inf
    s_ax = np.zeros(3)
    h_ok = True
    i = 0
    for k in range(max(k0, 0), qt.shape[0]):
        if not use[k]:
            continue
        tw, tx, ty, tz = qt[k, 0], -qt[k, 1], -qt[k, 2], -qt[k, 3]
        ew, ex, ey, ez = qe[k, 0], qe[k, 1], qe[k, 2], qe[k, 3]
        # d = conj(qt) ⊗ qe: the total angle and the body-axis rotation vector
        dw = tw * ew - tx * ex - ty * ey - tz * ez
        dx = tw * ex + tx * ew + ty * ez - tz * ey
        dy = tw * ey - tx * ez + ty * ew + tz * ex
        dz = tw * ez + tx * ey - ty * ex + tz * ew
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        w = abs(dw)
        angle = 2.0 * math.atan2(s, w)
        err = math.degrees(angle)
        s_err2 += err * err
        s_err += err
        mx = max(mx, err)
        sign = -1.0 if dw < 0.0 else 1.0
        if s < 1e-9:
            kk = 2.0 / (w if w > 0.0 else 1.0)
        else:
            kk = angle / s
        vx = math.degrees(kk * (dx * sign))
        vy = math.degrees(kk * (dy * sign))
        vz = math.degrees(kk * (dz * sign))
        axes[0, i], axes[1, i], axes[2, i] = abs(vx), abs(vy), abs(vz)
        axes[3, i] = math.sqrt(vx * vx + vy * vy + vz * vz)
        s_ax[0] += vx * vx
        s_ax[1] += vy * vy
        s_ax[2] += vz * vz
        if vertical:
            # e = qe ⊗ conj(qt): BROAD's heading and inclination split
            fw = ew * tw - ex * tx - ey * ty - ez * tz
            fx = ew * tx + ex * tw + ey * tz - ez * ty
            fy = ew * ty - ex * tz + ey * tw + ez * tx
            fz = ew * tz + ex * ty - ey * tx + ez * tw
            norm = math.sqrt(((fw * fw + fx * fx) + fy * fy) + fz * fz)
            fw, fz = fw / norm, fz / norm
            if fw == 0.0:
                heading = math.nan if fz == 0.0 else 180.0
            else:
                heading = math.degrees(2.0 * math.atan(abs(fz / fw)))
            c = min(max(math.sqrt(fw * fw + fz * fz), 0.0), 1.0)
            incl = math.degrees(2.0 * math.acos(c))
            h_ok = h_ok and math.isfinite(heading) and math.isfinite(incl)
            s_h2 += heading * heading
            s_i2 += incl * incl
        i += 1
    n = i
    if n == 0:
        out[:] = np.nan
        return
    out[0] = math.sqrt(s_err2 / n)
    out[1] = mx
    out[2] = s_err / n
    if vertical and h_ok:
        out[3] = math.sqrt(s_h2 / n)
        out[4] = math.sqrt(s_i2 / n)
    else:
        out[3] = out[4] = np.nan
    for j in range(3):
        out[5 + j] = math.sqrt(s_ax[j] / n)
    for j in range(4):
        out[8 + j] = _quantile99(axes[j, :n])
