"""The magnetometer fit, :func:`fit_mag`: hard and soft iron from raw samples (N, 3) µT in
the sensor's axes, ``h = S (m - o)`` with ``|h| = B`` (the model: :mod:`gnomon.calibration`).
Internally the samples are centred on their mean and scaled to unit RMS radius (``x``,
dimensionless); the result is given back in µT.

How the fit works (:func:`fit_mag`)
-----------------------------------
1. **Starts.** Li & Griffiths' ellipsoid-specific least squares (GMP 2004: the quadric's
   coefficients under the constraint ``4J - I^2 = 1``, a 6x6 generalised eigenproblem)
   on the data centred and scaled to unit RMS radius: an ellipsoid whenever the data lie
   near one that is not too elongated (magnetometer ellipsoids are nearly spheres); a
   sphere fit re-weighted with Huber weights; and, when the caller has one, an
   independent offset (``offset_hint_uT``; :func:`gnomon.calibration.apply.calibrate_mag`
   passes the gyro's, :func:`gnomon.calibration.gyro.gyro_offset_uT`).
2. **Geometric refinement** from every start. ``scipy.optimize.least_squares`` on the
   residual ``|S (m - o)| - B`` (relative to ``B``) with the Huber loss (``huber_rel``: a
   sample whose residual exceeds this fraction of ``B`` — a magnetic disturbance — counts
   linearly, not quadratically). ``S = L L^T`` with a lower-triangular ``L`` whose
   diagonal is ``exp(.)``: positive definite by construction. The lowest cost wins among
   the refinements the data determine (step 4); with a hint, only among those whose
   offset lies within ``hint_gate_rel`` x B of it (in a disturbed field the sphere's cost
   can prefer a wrong centre: the tyrex trials with magnetic disturbances do).
3. **Balance.** Each sample is weighted by ``1 / (samples in its coverage cell)``
   (:mod:`gnomon.calibration.coverage`, seen from the robust sphere's centre or the hint),
   so that every direction the data visit weighs the same however long the device stayed
   there (a phone in a pocket for a minute must not outweigh the turn that visited the
   other directions). ``balance=False`` weighs every sample equally.
4. **Model choice** (``model="auto"``): the richest of three models whose parameters the
   data determine — ``full`` (o and the 6 elements of S), ``scale`` (o and a diagonal S),
   ``offset`` (o alone; S = I·B/r with the radius r fixed to B when B is given, fitted
   otherwise) — judged by the coverage (``MIN_COVERAGE[model]``), the condition number of
   the fit (``MAX_CONDITION[model]``) and the soft iron's eigenvalue ratio
   (``MAX_ANISOTROPY``: beyond it the fit has degenerated; the thresholds are in
   :mod:`gnomon.calibration.result`). ``model`` names one model to force it (still
   reported, and refused where it is undetermined). On synthetic data (tests): the full
   model to 0.5 % from 30 % of the sphere in a band; a cap of the same area does not
   determine it (it falls back to ``scale``/``offset``; the offset then carries the bias
   of the soft iron it cannot see, 3-6 % of B for a 2 % soft iron).
5. **Ambiguity check.** Data on (or near) a circle — a device turned only about one axis
   — fit two centres equally well, mirror images through the circle's plane. The chosen
   model is refitted from the mirrored start and from every other start that ended
   elsewhere (all samples weighted alike); if one of them fits within
   ``_AMBIGUOUS_COST`` of the cost, more than ``_AMBIGUOUS_DISTANCE`` x B away, the
   result is refused.

:func:`fit_mag` reads as these steps: :func:`_starts` (1, with the balance weights of
step 3), :func:`_hint_start`, :func:`_choose_model` (2 and 4), :func:`_ambiguity` (5),
then :func:`_to_uT` and :func:`_report` give the result in µT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gnomon.calibration.coverage import COVERAGE_CELLS, _cell_index, sphere_coverage
from gnomon.calibration.result import (
    MAX_ANISOTROPY,
    MAX_CONDITION,
    MIN_COVERAGE,
    MODELS,
    MagCalibration,
)
from gnomon.calibration.samples import _as_mag
from gnomon.errors import InputError

__all__ = ["fit_mag"]

#: a mirrored start that fits within this relative cost of the fit makes it ambiguous
_AMBIGUOUS_COST = 1.1
#: and only when the two centres are this far apart (fraction of B)
_AMBIGUOUS_DISTANCE = 0.1


# ---------------------------------------------------------------------- algebraic fits
def _sphere_fit(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Linear least squares sphere: ``|x|^2 = 2 x.c + (r^2 - |c|^2)``; (centre, radius)."""
    A = np.column_stack([2 * x, np.ones(len(x))])
    sw = np.sqrt(w)
    sol, *_ = np.linalg.lstsq(A * sw[:, None], np.sum(x * x, axis=1) * sw, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return c, math.sqrt(r2) if r2 > 0 else float(np.sqrt(np.average(np.sum((x - c) ** 2, 1),
                                                                      weights=w)))


def _ellipsoid_fit(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Li & Griffiths (2004) ellipsoid-specific fit (k = 4) of points ``x`` (N, 3), already
    centred and scaled: ``(centre (3,), M (3, 3))`` with ``(x - c)^T M (x - c) = 1``, M
    positive definite; None when no ellipsoid results."""
    X, Y, Z = x.T
    D = np.array([X * X, Y * Y, Z * Z, 2 * Y * Z, 2 * X * Z, 2 * X * Y,
                  2 * X, 2 * Y, 2 * Z, np.ones_like(X)])
    Sm = (D * w) @ D.T
    C = np.zeros((6, 6))
    C[:3, :3] = [[-1, 1, 1], [1, -1, 1], [1, 1, -1]]
    C[3:, 3:] = -4 * np.eye(3)
    S11, S12, S22 = Sm[:6, :6], Sm[:6, 6:], Sm[6:, 6:]
    try:
        T = np.linalg.solve(S22, S12.T)
        vals, vecs = np.linalg.eig(np.linalg.solve(C, S11 - S12 @ T))
    except np.linalg.LinAlgError:
        return None
    vals, vecs = np.real(vals), np.real(vecs)
    if not np.any(vals > 0):
        return None
    v1 = vecs[:, int(np.argmax(vals))]
    v = np.concatenate([v1, -T @ v1])
    a, b, c, f, g, h, p, q, r, d = v
    A = np.array([[a, h, g], [h, b, f], [g, f, c]])
    try:
        centre = -np.linalg.solve(A, [p, q, r])
    except np.linalg.LinAlgError:
        return None
    k = centre @ A @ centre - d
    if k == 0:
        return None
    M = A / k
    M = 0.5 * (M + M.T)
    if np.linalg.eigvalsh(M)[0] <= 0:
        return None
    return centre, M


def _sqrtm_spd(M: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return (V * np.sqrt(np.maximum(w, 1e-300))) @ V.T


# ---------------------------------------------------------------------- geometric fit
_TRIL = np.tril_indices(3)


def _soft_from(model: str, p: np.ndarray, k_fixed: float | None) -> np.ndarray:
    """S (normalised units) from the model's shape parameters ``p``."""
    if model == "full":
        L = np.zeros((3, 3))
        L[_TRIL] = p
        L[np.diag_indices(3)] = np.exp(np.diag(L))
        return L @ L.T
    if model == "scale":
        return np.diag(np.exp(p))
    return np.eye(3) * (k_fixed if k_fixed is not None else math.exp(p[0]))


def _shape_start(model: str, S: np.ndarray, k_fixed: float | None) -> np.ndarray:
    if model == "full":
        L = np.linalg.cholesky(0.5 * (S + S.T))
        L[np.diag_indices(3)] = np.log(np.diag(L))
        return L[_TRIL]
    if model == "scale":
        return np.log(np.clip(np.diag(S), 1e-6, None))
    return np.array([]) if k_fixed is not None else np.array([math.log(np.cbrt(np.linalg.det(S)))])


def _jacobian_sym(x, sw, o, S, model, free_k):
    """Jacobian of the weighted residual ``sqrt(w) (|S (x - o)| - 1)`` with respect to the
    dimensionless parameters: o (3) and S's free elements (full: 6 unique, scale: 3
    diagonal, offset: 1 common scale if free)."""
    u = x - o
    Su = u @ S.T
    nrm = np.linalg.norm(Su, axis=1)
    v = Su / nrm[:, None]
    cols = [-(v @ S)]
    if model == "full":
        cols.append(np.column_stack([v[:, 0] * u[:, 0], v[:, 1] * u[:, 1], v[:, 2] * u[:, 2],
                                     v[:, 1] * u[:, 2] + v[:, 2] * u[:, 1],
                                     v[:, 0] * u[:, 2] + v[:, 2] * u[:, 0],
                                     v[:, 0] * u[:, 1] + v[:, 1] * u[:, 0]]))
    elif model == "scale":
        cols.append(v * u)
    elif free_k:
        cols.append(np.sum(v * u, axis=1)[:, None])
    return np.column_stack(cols) * sw[:, None], nrm - 1.0


def _shape_jacobian(model: str, p: np.ndarray, k_fixed: float | None) -> np.ndarray:
    """d(S's free elements, as ``_jacobian_sym`` orders them) / d(shape parameters)."""
    if model == "scale":
        return np.diag(np.exp(p))
    if model == "offset":
        return np.zeros((0, 0)) if k_fixed is not None else np.array([[math.exp(p[0])]])
    L = np.zeros((3, 3))
    L[_TRIL] = p
    d = np.exp(np.diag(L))
    L[np.diag_indices(3)] = d
    out = np.empty((6, p.size))
    for k, (i, j) in enumerate(zip(*_TRIL, strict=True)):
        dL = np.zeros((3, 3))
        dL[i, j] = d[i] if i == j else 1.0
        dS = dL @ L.T + L @ dL.T
        out[:, k] = [dS[0, 0], dS[1, 1], dS[2, 2], dS[1, 2], dS[0, 2], dS[0, 1]]
    return out


def _refine(model, x, w, o0, S0, k_fixed, huber):
    """Huber least squares of ``sqrt(w) (|S (x - o)| - 1)`` over o and S's shape
    parameters (analytic Jacobian): ``(o, S, cost)``."""
    from scipy.optimize import least_squares

    sw = np.sqrt(w)
    p_shape = _shape_start(model, S0, k_fixed)

    def resid(p):
        S = _soft_from(model, p[3:], k_fixed)
        return sw * (np.linalg.norm((x - p[:3]) @ S.T, axis=1) - 1.0)

    def jac(p):
        S = _soft_from(model, p[3:], k_fixed)
        J, _ = _jacobian_sym(x, sw, p[:3], S, model, k_fixed is None)
        if p.size == 3:
            return J
        return np.column_stack([J[:, :3], J[:, 3:] @ _shape_jacobian(model, p[3:], k_fixed)])

    sol = least_squares(resid, np.concatenate([o0, p_shape]), jac=jac, loss="huber",
                        f_scale=huber, method="trf", tr_solver="lsmr", max_nfev=200)
    o = sol.x[:3]
    S = _soft_from(model, sol.x[3:], k_fixed)
    return o, S, float(sol.cost)


@dataclass
class _Fit:
    model: str
    o: np.ndarray
    S: np.ndarray
    cost: float
    condition: float
    std: np.ndarray
    coverage: float
    anisotropy: float


def _unusable(fit: _Fit) -> str:
    """Why a fit is not determined by the data (empty when it is)."""
    m = fit.model
    if fit.coverage < MIN_COVERAGE[m]:
        return (f"coverage {fit.coverage:.2f} below {MIN_COVERAGE[m]:.2f} for the {m} model: "
                "turn the device through more directions")
    if not fit.condition <= MAX_CONDITION[m]:
        return (f"condition {fit.condition:.3g} above {MAX_CONDITION[m]:g} for the {m} model: "
                "the directions visited do not determine it")
    if not fit.anisotropy <= MAX_ANISOTROPY:
        return (f"soft-iron eigenvalue ratio {fit.anisotropy:.3g} above {MAX_ANISOTROPY:g} "
                f"for the {m} model: a degenerate fit, the directions visited do not "
                "determine it")
    return ""


def _assess(model, x, w, o, S, cost, k_fixed) -> _Fit:
    sw = np.sqrt(w)
    J, r = _jacobian_sym(x, sw, o, S, model, k_fixed is None)
    sv = np.linalg.svd(J, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    dof = max(float(w.sum()) - J.shape[1], 1.0)
    sigma2 = float(np.sum((sw * r) ** 2) / dof)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        std = np.full(J.shape[1], np.inf)
    cov_frac = sphere_coverage((x - o) @ S.T)
    ev = np.linalg.eigvalsh(S)
    return _Fit(model, o, S, cost, cond, std, cov_frac, float(ev[-1] / ev[0]))


def _fit_from(model, x, w, o0, S0, k_fixed, huber) -> _Fit:
    """Refine ``model`` from the start ``(o0, S0)`` (S0 any positive-definite guess)."""
    if model == "offset":
        S = np.eye(3) * (k_fixed if k_fixed is not None else float(np.cbrt(np.linalg.det(S0))))
    elif model == "scale":
        S = np.diag(np.diag(S0))
    else:
        S = S0
    return _assess(model, x, w, *_refine(model, x, w, o0, S, k_fixed, huber), k_fixed)


def _huber_cost(x: np.ndarray, fit: _Fit, huber: float) -> float:
    """Mean Huber cost of the relative residual, every sample weighted alike."""
    r = np.abs(np.linalg.norm((x - fit.o) @ fit.S.T, axis=1) - 1.0)
    return float(np.mean(np.where(r <= huber, 0.5 * r * r, huber * r - 0.5 * huber ** 2)))


def _best(cands: list[_Fit], why_not=None) -> _Fit:
    """The lowest-cost candidate among the usable ones (among all when none is)."""
    usable = [c for c in cands if not (why_not or _unusable)(c)]
    return min(usable or cands, key=lambda c: c.cost)


def _robust_sphere(x, w, c, r, huber, iterations: int = 20) -> tuple[np.ndarray, float]:
    """Sphere fit re-weighted by the Huber weights of ``|x - c| - r`` (scale ``huber r``)."""
    for _ in range(iterations):
        res = np.abs(np.linalg.norm(x - c, axis=1) - r)
        k = huber * r
        hw = np.where(res <= k, 1.0, k / np.maximum(res, 1e-300))
        c_new, r_new = _sphere_fit(x, w * hw)
        done = np.linalg.norm(c_new - c) < 1e-9
        c, r = c_new, r_new
        if done:
            break
    return c, r


def _mirror(x: np.ndarray, w: np.ndarray, o: np.ndarray) -> np.ndarray:
    """The centre mirrored through the plane that best fits the data (its normal: the
    direction of least weighted spread)."""
    c = np.average(x, axis=0, weights=w)
    cov = ((x - c) * w[:, None]).T @ (x - c) / w.sum()
    normal = np.linalg.eigh(cov)[1][:, 0]
    return o - 2 * ((o - c) @ normal) * normal


def _balance_weights(x: np.ndarray, centre: np.ndarray) -> np.ndarray:
    cell = _cell_index((x - centre) / np.linalg.norm(x - centre, axis=1)[:, None])
    count = np.bincount(cell, minlength=COVERAGE_CELLS)[cell].astype(float)
    w = 1.0 / count
    return w * (len(x) / w.sum())



# ---------------------------------------------------------------------- public fit
def fit_mag(mag_uT, *, field_uT: float | None = None, model: str = "auto",
            balance: bool = True, huber_rel: float = 0.03, require_ok: bool = False,
            max_samples: int = 20000, offset_hint_uT=None, hint_gate_rel: float = 0.2,
            field_source: str | None = None, source: str = "") -> MagCalibration:
    """Fit hard and soft iron to raw magnetometer samples (module docstring).

    Parameters
    ----------
    mag_uT : (N, 3) raw readings, µT, sensor axes; N >= ``MIN_SAMPLES``, finite, no zero
        rows. Order and time do not matter.
    field_uT : the field's magnitude B (µT) the corrected samples should have (e.g.
        :func:`igrf_field_uT`); None: the raw ellipsoid's geometric mean radius (``det S =
        1``).
    model : ``"auto"`` (the richest determined model), ``"full"``, ``"scale"`` or
        ``"offset"``.
    balance : weight each sample by 1 / (samples in its coverage cell).
    huber_rel : Huber scale of the residual as a fraction of B.
    require_ok : raise ``InputError`` (field ``mag``, with the reason) instead of returning
        a refused calibration.
    max_samples : longer inputs are thinned to about this many by a regular stride.
    offset_hint_uT : an independent estimate of the offset (µT, (3,); e.g.
        :func:`gyro_offset_uT`, which :func:`calibrate_mag` passes): a further start
        besides the algebraic ellipsoid and a robust sphere, and a gate: a local minimum
        whose offset lies farther than ``hint_gate_rel`` x B from it is not accepted (in a
        disturbed field the sphere's cost can prefer a wrong centre; the gyro does not).

    Returns
    -------
    MagCalibration, with ``ok=False`` and a ``reason`` when the data do not determine it.
    """
    m = _as_mag(mag_uT)
    _check_options(model, field_uT, huber_rel)
    n_all = m.shape[0]
    if n_all > max_samples:
        m = m[:: int(math.ceil(n_all / max_samples))]
    centre, scale, x = _normalise(m)
    # 1. starts: the algebraic ellipsoid, a robust sphere (3. the balance weights from its
    # centre), the caller's offset
    w, starts = _starts(x, balance, huber_rel)
    hint = gate = None
    if offset_hint_uT is not None:
        hint, start, gate = _hint_start(offset_hint_uT, x, w, centre, scale, field_uT,
                                        hint_gate_rel)
        starts.append(start)
    why_not = _refusal(hint, gate, scale)
    # with B given, the offset model's radius is B: in normalised units |x - o| = B / scale
    k_fixed = scale / field_uT if field_uT is not None else None
    if balance and hint is not None:  # the balance cells seen from the independent centre
        w = _balance_weights(x, hint)
    # 2. and 4.: every start refined, the richest model the data determine
    tried, fits = _choose_model(model, x, w, starts, k_fixed, huber_rel, why_not)
    fit, kf, reason, cands = fits[tried[-1]["model"]]
    if not reason:  # 5. data near a circle fit two centres (mirror images) equally well
        reason = _ambiguity(fit, kf, cands, x, scale, field_uT, huber_rel, why_not)
    ok = not reason
    tried[-1]["used"] = True
    # back to µT, and the quality report
    o, S, B, src = _to_uT(fit, centre, scale, field_uT, field_source)
    cal = _report(m, fit, o, S, B, src, ok, reason, n_all, scale, source, tried,
                  None if hint is None else centre + scale * hint)
    if require_ok and not ok:
        raise InputError(f"magnetometer calibration refused: {reason}", field="mag")
    return cal


# ---------------------------------------------------------------------- fit_mag's steps
def _check_options(model: str, field_uT: float | None, huber_rel: float) -> None:
    """InputError naming the option when ``model``, ``field_uT`` or ``huber_rel`` is bad."""
    if model not in ("auto", *MODELS):
        raise InputError(f"unknown model {model!r}; use auto, full, scale or offset",
                         field="model")
    if field_uT is not None and not (math.isfinite(field_uT) and field_uT > 0):
        raise InputError(f"expected a positive field magnitude in uT, got {field_uT!r}",
                         field="field_uT")
    if not (math.isfinite(huber_rel) and huber_rel > 0):
        raise InputError(f"expected a positive number, got {huber_rel!r}", field="huber_rel")


def _normalise(m: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """``(centre (3,) µT, scale µT, x (N, 3))``: the samples centred on their mean, unit
    RMS distance, ``x = (m - centre) / scale``."""
    centre = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - centre) ** 2, axis=1))))
    if not scale > 0:
        raise InputError("all samples are equal: the device did not move", field="mag")
    x = (m - centre) / scale
    return centre, scale, x


def _starts(x: np.ndarray, balance: bool, huber_rel: float) -> tuple[np.ndarray, list]:
    """Step 1 (and step 3's weights): ``(w (N,), starts)``. ``w`` the balance weights seen
    from the robust sphere's centre (ones without ``balance``); ``starts`` a list of
    ``(o (3,), S (3, 3))`` in normalised units: the algebraic ellipsoid (when its centre
    is near the sphere's), the robust sphere on the weights ``w``."""
    w = np.ones(len(x))
    c0, r0 = _sphere_fit(x, w)
    c1, r1 = _robust_sphere(x, w, c0, r0, huber_rel)
    if balance:
        w = _balance_weights(x, c1)
    # starts: the algebraic ellipsoid, a robust sphere, the caller's offsets
    starts = []
    ell = _ellipsoid_fit(x, w)
    if ell is not None and np.linalg.norm(ell[0] - c1) < 3 * max(r1, 1e-9):
        starts.append((ell[0], _sqrtm_spd(ell[1])))
    c1, r1 = _robust_sphere(x, w, c1, r1, huber_rel)
    starts.append((c1, np.eye(3) / r1))
    return w, starts


def _hint_start(offset_hint_uT, x, w, centre, scale, field_uT, hint_gate_rel):
    """The caller's offset (µT, (3,)) as a start: ``(hint (3,), (hint, S), gate)`` in
    normalised units, ``S`` a sphere through the samples about it, ``gate`` the distance
    from it (``hint_gate_rel`` x B) beyond which an offset is not accepted."""
    hint = np.asarray(offset_hint_uT, dtype=float)
    if hint.shape != (3,) or not np.all(np.isfinite(hint)):
        raise InputError(f"expected 3 finite numbers, got {offset_hint_uT!r}",
                         field="offset_hint_uT")
    hint = (hint - centre) / scale
    r = float(np.sqrt(np.average(np.sum((x - hint) ** 2, axis=1), weights=w)))
    gate = hint_gate_rel * (field_uT if field_uT is not None else r * scale) / scale
    return hint, (hint, np.eye(3) / max(r, 1e-9)), gate


def _refusal(hint, gate, scale):
    """``why_not(fit) -> str``: why a fit is not accepted (empty when it is): the data do
    not determine it (:func:`_unusable`), or its offset lies beyond ``gate`` from the
    ``hint`` (normalised units; no gate without a hint)."""
    def why_not(f: _Fit) -> str:
        why = _unusable(f)
        if not why and hint is not None and np.linalg.norm(f.o - hint) > gate:
            why = (f"offset {np.linalg.norm(f.o - hint) * scale:.1f} uT from the independent "
                   f"estimate (gyro), more than {gate * scale:.1f} uT: a disturbed field or a "
                   "wrong centre")
        return why
    return why_not


def _choose_model(model, x, w, starts, k_fixed, huber_rel, why_not):
    """Steps 2 and 4: each model in turn, richest first (``model`` alone unless
    ``"auto"``), refined from every start; stop at the first the data determine.
    ``(tried, fits)``: the report of each model tried (dicts, in order) and
    ``fits[model] = (best fit, k_fixed of that model, why not, all candidates)``."""
    tried, fits = [], {}
    for name in (MODELS if model == "auto" else (model,)):
        kf = k_fixed if name == "offset" else None
        cands = [_fit_from(name, x, w, o, S, kf, huber_rel) for o, S in starts]
        fit = _best(cands, why_not)
        why = why_not(fit)
        fits[name] = (fit, kf, why, cands)
        tried.append({"model": name, "coverage": fit.coverage, "condition": fit.condition,
                      "anisotropy": fit.anisotropy, "used": False, "why_not": why})
        if not why:
            break
    return tried, fits


def _ambiguity(fit, kf, cands, x, scale, field_uT, huber_rel, why_not) -> str:
    """Step 5: the refusal's reason when a mirrored or another start fits about as well
    more than ``_AMBIGUOUS_DISTANCE`` x B away; empty when none does."""
    # compared with every sample weighted alike: balance weights belong to one
    # centre's directions and would favour it
    ones = np.ones(len(x))
    here = _fit_from(fit.model, x, ones, fit.o, fit.S, kf, huber_rel)
    B_est = field_uT if field_uT is not None else scale / float(np.cbrt(np.linalg.det(fit.S)))
    others = [(c.o, c.S) for c in cands
              if np.linalg.norm(c.o - fit.o) * scale > _AMBIGUOUS_DISTANCE * B_est]
    for o_r, S_r in [(_mirror(x, ones, fit.o), fit.S), *others]:
        rival = _fit_from(fit.model, x, ones, o_r, S_r, kf, huber_rel)
        gap = float(np.linalg.norm(rival.o - here.o)) * scale
        ratio = _huber_cost(x, rival, huber_rel) / _huber_cost(x, here, huber_rel)
        if gap > _AMBIGUOUS_DISTANCE * B_est and ratio < _AMBIGUOUS_COST and not why_not(
                rival):
            return (f"ambiguous: two centres {gap:.1f} uT apart fit about equally well "
                    f"(cost ratio {ratio:.2f}); the data lie near a circle or are "
                    "disturbed: turn the device about another axis too, away from iron")
    return ""


def _to_uT(fit, centre, scale, field_uT, field_source):
    """The fit back in µT: ``(o (3,), S (3, 3), B, field source)``; o = centre + scale·o_n,
    S = (B/scale)·S_n, B given or det S = 1."""
    o = centre + scale * fit.o
    if field_uT is not None:
        B = float(field_uT)
        S = fit.S * (B / scale)
        src = field_source or "given"
    else:
        d = float(np.cbrt(np.linalg.det(fit.S)))
        B = scale / d
        S = fit.S / d
        src = "data"
    S = 0.5 * (S + S.T)
    return o, S, B, src


def _report(m, fit, o, S, B, src, ok, reason, n_all, scale, source, tried, hint_uT):
    """The :class:`MagCalibration` of the fit in µT (``o``, ``S``, ``B``) on the samples
    ``m`` (N, 3) µT: residuals, coverage, condition, uncertainties (``scale``: µT per
    normalised unit), the models ``tried``."""
    h = (m - o) @ S.T
    norm_h = np.linalg.norm(h, axis=1)
    raw_norm = np.linalg.norm(m, axis=1)
    o_std = fit.std[:3] * scale
    s_std = float(np.max(fit.std[3:]) / np.abs(np.linalg.eigvalsh(fit.S)).max()) \
        if fit.std.size > 3 else 0.0
    return MagCalibration(
        offset_uT=o, soft_iron=S, field_uT=B,
        residual_uT=float(np.sqrt(np.mean((norm_h - B) ** 2))), coverage=fit.coverage,
        ok=ok, reason=reason, model=fit.model, condition=fit.condition, offset_std_uT=o_std,
        soft_iron_std=s_std, raw_residual_uT=float(np.std(raw_norm)), n_samples=n_all,
        field_source=src, source=source, tried=tuple(tried), offset_hint_uT=hint_uT)
