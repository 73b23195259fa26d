"""The overlapping Allan deviation of a rate series and the noise terms read off its curve.

Input: a uniformly sampled rate series ``y`` (N,) or (N, k) (gyro rad/s or accelerometer
m/s², one column per axis) at ``rate_hz`` samples per second; the cluster times are
``tau_s = m / rate_hz`` for integer cluster sizes ``m``.

**Overlapping Allan deviation** (NIST SP 1065, Riley 2008, eq. 12; IEEE Std 952-1997
annex C): with the integrated series ("phase") ``x_j = τ0 Σ_{i<j} y_i``, ``x_0 = 0``
(N + 1 values, ``τ0 = 1 / rate_hz``)::

    σ²(mτ0) = Σ_{j=0}^{N-2m} (x_{j+2m} - 2 x_{j+m} + x_j)² / (2 (mτ0)² (N + 1 - 2m))

one cumulative sum and one pass per cluster size. Written here rather than imported:
it is these few lines of numpy, while ``allantools`` (2024.6, the reference the tests
compare with to 1e-10) is LGPL-3 and installs pytest and numpydoc (hence sphinx) as run
time dependencies. The mean rate is removed before the sum (the second difference
cancels it exactly; removing it keeps ``x`` small and the differences precise).

**Noise terms** (IEEE Std 952-1997 annex C; Freescale/NXP AN5087, "Allan Variance: Noise
Analysis for Gyroscopes", 2015), each read from the log-log curve where its slope
dominates:

========================  =======  =============================  ========================
term                      slope    read off                       units (gyro / accel)
========================  =======  =============================  ========================
white noise N             -1/2     the -1/2 line at τ = 1 s       rad/s/√Hz / m/s²/√Hz
                                                                  (angle / velocity
                                                                  random walk)
bias instability B        0        the flat minimum / 0.664       rad/s / m/s²
                                   (√(2 ln 2 / π))
rate random walk K        +1/2     the +1/2 line at τ = 3 s       rad/s²/√Hz / m/s³/√Hz
========================  =======  =============================  ========================

How each is found (the graphical method of the standard, made robust for noisy curves):

* N from the point before the curve's minimum whose local slope (least squares of
  ``log σ`` on ``log τ`` within ±``SLOPE_HALF_WINDOW_DECADES``) is closest to -1/2, when
  within ``SLOPE_TOLERANCE``: the -1/2 line through it, ``N = σ(τ) √τ``. Short cluster
  times hold many clusters, so this point is precise (0.6 % scatter on a 2-hour
  synthetic log) and a sensor's low-pass filter (slope below -1/2 at the shortest τ) is
  stepped over.
* The IEEE 952 model ``σ²(τ) = N²/τ + (2 ln 2/π) B² + K² τ/3`` (white, flicker, rate
  random walk) is fitted with non-negative coefficients to the curve from that point on
  (weighted least squares, each point weighted by the inverse of its expected standard
  deviation, which falls as the square root of its number of clusters; five
  re-weightings): its +1/2 asymptote read at τ = 3 s is K. One point read off the
  noisy long-τ part scatters twice as much (13 % against 8 % over 60 synthetic axes).
* B from the curve's lowest point, ``σ_min / 0.664``, when the fitted model is flat there
  (its slope >= -``FLAT_SLOPE``); when the curve still falls (a short log), B is None and
  ``σ_min / 0.664`` is only its upper bound, ``bias_instability_bound``. The standard's
  reading includes the white and random-walk parts still present at the minimum (on a
  4-hour synthetic MEMS log 17-26 % above the true B for the gyro, 29-55 % for the
  accelerometer, whose flat part is narrow: ``benchmarks/allan_doc.py``); the fitted
  model's flat term ``√c / 0.664`` is returned beside it, ``bias_instability_fit``
  (there within 3 % and 7 %).
* K only when the fitted model's slope at the longest cluster time read is at least
  ``1/2 - RANDOM_WALK_SLOPE_MARGIN``: the curve is seen rising at +1/2; otherwise None
  with the reason (a short log does not reach that part: no number is made up).

Only cluster times with at least ``MIN_CLUSTERS`` independent clusters (``N / m``) are
read: beyond them the curve's relative uncertainty exceeds about 25 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError

__all__ = ["allan_deviation", "cluster_sizes", "local_slopes", "model_slope",
           "read_noise_terms", "NoiseTerms", "BIAS_INSTABILITY_FACTOR", "MIN_CLUSTERS",
           "SLOPE_TOLERANCE", "SLOPE_HALF_WINDOW_DECADES", "RANDOM_WALK_SLOPE_MARGIN",
           "FLAT_SLOPE", "TAU_WHITE_S", "TAU_RANDOM_WALK_S"]

#: σ of flicker (bias-instability) noise on the flat part is B·√(2 ln 2 / π) = 0.664 B
BIAS_INSTABILITY_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: the -1/2 line is read at τ = 1 s (σ(1 s) = N)
TAU_WHITE_S = 1.0
#: the +1/2 line σ = K √(τ/3) is read at τ = 3 s (σ(3 s) = K)
TAU_RANDOM_WALK_S = 3.0
#: cluster times with fewer independent clusters (N / m) than this are drawn, not read
MIN_CLUSTERS = 10
#: N is read only where the local slope is within this of -1/2
SLOPE_TOLERANCE = 0.1
#: the lowest point is the flat part (B) only when the fitted model's slope there is >= -this
FLAT_SLOPE = 0.25
#: K only when the fitted model's slope at the longest τ read is >= 1/2 - this
RANDOM_WALK_SLOPE_MARGIN = 0.15
#: half-width (decades of τ) of the window of each local slope
SLOPE_HALF_WINDOW_DECADES = 0.2


def cluster_sizes(n: int, per_decade: int = 20) -> np.ndarray:
    """Log-spaced integer cluster sizes ``m`` (ascending, unique) from 1 to the largest
    one the overlapping estimator allows for ``n`` samples, ``(n - 1) // 2``: about
    ``per_decade`` per decade."""
    m_max = (int(n) - 1) // 2
    if m_max < 1:
        raise InputError(f"an Allan deviation needs at least 3 samples, got {n}",
                         field="samples")
    k = max(2, int(math.ceil(per_decade * math.log10(m_max))) + 1)
    return np.unique(np.round(np.logspace(0.0, math.log10(m_max), k)).astype(np.int64))


def allan_deviation(y, rate_hz: float, m=None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation (module docstring) of the rate series ``y`` ((N,) or
    (N, k), any unit U) sampled at ``rate_hz`` (Hz): ``(tau_s (M,), adev (M,) or (M, k))``
    in s and U, at the cluster sizes ``m`` (default :func:`cluster_sizes`)."""
    y = np.asarray(y, dtype=float)
    one = y.ndim == 1
    y2 = y[:, None] if one else y
    if y2.ndim != 2:
        raise InputError(f"expected shape (N,) or (N, k), got {y.shape}", field="y")
    if not np.all(np.isfinite(y2)):
        raise InputError("non-finite value in the rate series", field="y")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise InputError(f"must be > 0, got {rate_hz!r}", field="rate_hz")
    n = y2.shape[0]
    m = cluster_sizes(n) if m is None else np.asarray(m, dtype=np.int64)
    if m.size and (m.min() < 1 or 2 * m.max() > n):
        raise InputError(f"cluster sizes must lie in 1..{n // 2} for {n} samples",
                         field="m")
    tau0 = 1.0 / float(rate_hz)
    x = np.zeros((n + 1, y2.shape[1]))
    np.cumsum((y2 - y2.mean(axis=0)) * tau0, axis=0, out=x[1:])
    adev = np.empty((m.size, y2.shape[1]))
    for i, mi in enumerate(m):
        d = x[2 * mi:] - 2.0 * x[mi:n + 1 - mi] + x[:n + 1 - 2 * mi]
        adev[i] = np.sqrt(np.einsum("ij,ij->j", d, d) / (2.0 * (mi * tau0) ** 2 * d.shape[0]))
    tau = m * tau0
    return tau, adev[:, 0] if one else adev


def local_slopes(tau_s, adev, half_window_decades: float = SLOPE_HALF_WINDOW_DECADES
                 ) -> np.ndarray:
    """``d log σ / d log τ`` (M,) at each point of one curve (``tau_s``, ``adev``, (M,)):
    the least-squares slope over the points within ±``half_window_decades`` of it (NaN
    where the window holds fewer than two points or σ is not positive)."""
    lt = np.log10(np.asarray(tau_s, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        ls = np.log10(np.asarray(adev, float))
    out = np.full(lt.size, np.nan)
    for i in range(lt.size):
        w = (np.abs(lt - lt[i]) <= half_window_decades + 1e-12) & np.isfinite(ls)
        if w.sum() >= 2:
            a, b = lt[w] - lt[w].mean(), ls[w] - ls[w].mean()
            denom = float(a @ a)
            out[i] = float(a @ b) / denom if denom > 0 else np.nan
    return out


@dataclass(frozen=True)
class NoiseTerms:
    """The noise terms of one axis (units: those of the rate series U; see the module
    docstring): ``white`` N (U·√s = U/√Hz), ``bias_instability`` B (U),
    ``random_walk`` K (U/s/√Hz = U/√s), each None when the curve does
    not show it, with the sentence why in ``reasons`` (keyed by the term's name);
    ``*_tau_s`` where each was read; ``bias_instability_bound`` the upper bound
    ``σ_min / 0.664`` when B itself is None; ``bias_instability_fit`` the flat term of
    the fitted model, ``√c / 0.664`` (when B is read: free of the white and random-walk
    parts the minimum also holds, which the standard's reading adds); ``max_tau_s`` the
    longest cluster time read (``MIN_CLUSTERS``); ``model`` the fitted
    ``(N², (2 ln 2/π) B², K²)`` of the IEEE 952 model (U²·s, U², U²/s)."""

    white: float | None
    bias_instability: float | None
    random_walk: float | None
    white_tau_s: float | None
    bias_instability_tau_s: float | None
    random_walk_tau_s: float | None
    bias_instability_bound: float | None
    bias_instability_fit: float | None
    max_tau_s: float
    model: tuple = (float("nan"),) * 3
    reasons: dict = field(default_factory=dict)


def read_noise_terms(tau_s, adev, n_samples: int, rate_hz: float,
                     unit: str = "U") -> NoiseTerms:
    """N, B and K (module docstring) from one Allan deviation curve (``tau_s``, ``adev``
    (M,), from :func:`allan_deviation` of ``n_samples`` samples at ``rate_hz``);
    ``unit`` names the series' unit in the reasons."""
    tau = np.asarray(tau_s, float)
    sig = np.asarray(adev, float)
    m_all = np.maximum(np.round(tau * float(rate_hz)), 1.0)
    ok = (n_samples / m_all >= MIN_CLUSTERS) & np.isfinite(sig) & (sig > 0)
    reasons: dict[str, str] = {}
    if ok.sum() < 3:
        why = (f"too few samples ({n_samples}): fewer than 3 cluster times with "
               f"{MIN_CLUSTERS} independent clusters")
        return NoiseTerms(None, None, None, None, None, None, None, None,
                          float(tau[ok][-1]) if ok.any() else float("nan"),
                          reasons={"white": why, "bias_instability": why, "random_walk": why})
    tau, sig = tau[ok], sig[ok]
    slope = local_slopes(tau, sig)
    i_min = int(np.argmin(sig))
    max_tau = float(tau[-1])

    # white noise: slope -1/2 before (or at) the minimum
    white = white_tau = None
    before = np.arange(i_min + 1)
    dev = np.abs(slope[before] + 0.5)
    if dev.size and np.isfinite(dev).any() and np.nanmin(dev) <= SLOPE_TOLERANCE:
        j = int(before[np.nanargmin(dev)])
        white_tau = float(tau[j])
        white = float(sig[j] * math.sqrt(tau[j] / TAU_WHITE_S))
    else:
        near = (float(slope[before][np.nanargmin(dev)]) if np.isfinite(dev).any()
                else float("nan"))
        reasons["white"] = (f"the curve never falls at slope -1/2 (+-{SLOPE_TOLERANCE}) "
                            f"from {tau[0]:.3g} s to its minimum at {tau[i_min]:.3g} s "
                            f"(the nearest slope {near:.2f}): white noise does not "
                            f"dominate at any cluster time read")

    # the IEEE 952 model fitted past the white-noise point: its slope decides whether the
    # curve has flattened at its lowest point (B) and rises at +1/2 by the end (K)
    start = 0 if white_tau is None else int(np.searchsorted(tau, white_tau))
    coef = _fit_avar_model(tau[start:], sig[start:], m_all[ok][start:], n_samples)

    bias = bias_tau = bound = bias_fit = None
    flat = model_slope(coef, tau[i_min])
    if flat >= -FLAT_SLOPE:
        bias = float(sig[i_min] / BIAS_INSTABILITY_FACTOR)
        bias_tau = float(tau[i_min])
        bias_fit = float(math.sqrt(coef[1]) / BIAS_INSTABILITY_FACTOR)
    else:
        bound = float(sig[i_min] / BIAS_INSTABILITY_FACTOR)
        reasons["bias_instability"] = (
            f"no flat part: the curve still falls at its lowest point read ({tau[i_min]:.3g}"
            f" s; slope {flat:.2f} there, flat needs >= {-FLAT_SLOPE}; longest cluster time "
            f"read {max_tau:.3g} s, {MIN_CLUSTERS} clusters): the log is too short; only "
            f"the bound B <= {bound:.3g} {unit} is known")

    rw = rw_tau = None
    rise = model_slope(coef, max_tau)
    if rise >= 0.5 - RANDOM_WALK_SLOPE_MARGIN and coef[2] > 0:
        rw = float(math.sqrt(coef[2]))
        rw_tau = max_tau
    else:
        reasons["random_walk"] = (
            f"the curve does not reach slope +1/2 by the longest cluster time read "
            f"({max_tau:.3g} s, {MIN_CLUSTERS} clusters; slope there {rise:.2f}, needs >= "
            f"{0.5 - RANDOM_WALK_SLOPE_MARGIN:.2f}): record longer for the rate random walk "
            f"to show")
    return NoiseTerms(white, bias, rw, white_tau, bias_tau, rw_tau, bound, bias_fit, max_tau,
                      tuple(float(c) for c in coef), reasons)


def model_slope(coef, tau_s: float) -> float:
    """``d log σ / d log τ`` of the model ``N²/τ + c + K² τ/3`` (``coef = (N², c, K²)``)
    at ``tau_s``: ``(K² τ/3 - N²/τ) / (2 σ²)``."""
    w, c, k = coef[0] / tau_s, coef[1], coef[2] * tau_s / 3.0
    total = w + c + k
    return float(0.5 * (k - w) / total) if total > 0 else float("nan")


def _fit_avar_model(tau, sig, m, n_samples: int, iterations: int = 5) -> np.ndarray:
    """Non-negative ``(N², c, K²)`` of the Allan variance model ``N²/τ + c + K² τ/3``
    (IEEE Std 952 annex C, white, flicker and rate random walk) fitted to ``sig²`` by
    weighted least squares: each point's weight the inverse of its expected standard
    deviation, ``model · √(m / n)`` (the relative uncertainty of an Allan variance falls
    as the square root of the number of clusters), the model from the previous
    iteration (the first: the data)."""
    from scipy.optimize import nnls

    A = np.column_stack([1.0 / tau, np.ones_like(tau), tau / 3.0])
    model = sig**2
    coef = np.zeros(3)
    for _ in range(iterations):
        w = np.sqrt(n_samples / m) / np.maximum(model, 1e-300)
        coef, _ = nnls(A * w[:, None], sig**2 * w)
        model = A @ coef
    return coef
