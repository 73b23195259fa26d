"""The metrics of many campaign runs at once: ``score_run`` + ``score_run_budget`` of
:mod:`gnomon.metrics`, vectorised over runs that share their time stamps.

:func:`score_runs` gives, for each run, the dict ``{**score_run(rec, q, settle),
**score_run_budget(rec, q, settle)}``: the same keys and the same numbers (the same
numpy operations in the same order on (R, N) arrays instead of R times (N,); the
tests compare them). The error quaternion ``conj(q_true) ⊗ q_est`` is formed once for
the error angle and the body-axis errors, and the NaN handling is skipped when every
value is finite. Runs that do not fit (other time stamps, a sun sensor, a NaN, another
reference frame) are scored by the ``gnomon.metrics`` functions themselves.
"""

from __future__ import annotations

import numpy as np

from gnomon.metrics import BODY_AXES, score_run, score_run_budget

__all__ = ["score_runs"]


def _one(rec, q, settle_s: float) -> dict:
    return {**score_run(rec, q, settle_s), **score_run_budget(rec, q, settle_s)}


def _conj_mul(qt, qe):
    """``conj(qt) ⊗ qe`` of component-first arrays (4, ...), as
    ``quat_mul(quat_conj(qt), qe)`` (the same operations)."""
    pw, px, py, pz = qt[0], -qt[1], -qt[2], -qt[3]
    qw, qx, qy, qz = qe
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def _mul_conj(qe, qt):
    """``qe ⊗ conj(qt)`` of component-first arrays (4, ...), as
    ``quat_mul(qe, quat_conj(qt))``."""
    pw, px, py, pz = qe
    qw, qx, qy, qz = qt[0], -qt[1], -qt[2], -qt[3]
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def _score_together(recs, qs, settle_s: float) -> list[dict]:
    """The fast path: runs with the same ``t``, finite ``q_true``/``q_est``, no sun sensor."""
    t = recs[0].t
    # component-first (4, R, N): contiguous operands for the elementwise products
    qt = np.stack([r.q_true for r in recs], axis=-1).transpose(1, 2, 0).copy()
    qe = np.stack([np.asarray(q, dtype=float) for q in qs], axis=-1).transpose(1, 2, 0).copy()
    keep = (t - t[0]) >= settle_s
    dw, dx, dy, dz = _conj_mul(qt, qe)
    # score_run: the total error angle 2 atan2(|d_xyz|, |d_w|), in degrees
    err = np.degrees(2.0 * np.arctan2(np.sqrt(dx * dx + dy * dy + dz * dz), np.abs(dw)))
    m = keep                                   # every value is finite here
    sel = np.ascontiguousarray(err[:, m])
    n_sel = sel.shape[1]
    rms = np.sqrt(np.mean(sel * sel, axis=1)) if n_sel else np.full(len(recs), np.nan)
    mx = np.max(sel, axis=1) if n_sel else np.full(len(recs), np.nan)
    mean = np.mean(sel, axis=1) if n_sel else np.full(len(recs), np.nan)
    vertical = recs[0].frames.get("reference") in ("ENU", "NWU")
    if vertical:
        ew, ex, ey, ez = _mul_conj(qe, qt)
        norm = np.sqrt(((ew * ew + ex * ex) + ey * ey) + ez * ez)
        ew, ez = ew / norm, ez / norm
        with np.errstate(divide="ignore"):
            heading = np.degrees(2.0 * np.arctan(np.abs(ez / ew)))
        incl = np.degrees(2.0 * np.arccos(np.clip(np.sqrt(ew * ew + ez * ez), 0.0, 1.0)))
        parts = {}
        for name, x in (("heading_rms_deg", heading), ("inclination_rms_deg", incl)):
            xs = np.ascontiguousarray(x[:, m])
            ok = np.isfinite(xs).all(axis=1)
            val = np.sqrt(np.mean(xs * xs, axis=1)) if n_sel else np.full(len(recs), np.nan)
            parts[name] = np.where(ok, val, np.nan)
    # score_run_budget: body-axis errors (the rotation vector of d), degrees
    mb = keep
    w = dw[:, mb]
    sign = np.where(w < 0.0, -1.0, 1.0)
    v = np.stack([dx[:, mb] * sign, dy[:, mb] * sign, dz[:, mb] * sign], axis=-1)
    w = np.abs(w)
    s = np.sqrt(np.einsum("rij,rij->ri", v, v))
    small = s < 1e-9
    k = np.where(small, 2.0 / np.where(w > 0.0, w, 1.0),
                 2.0 * np.arctan2(s, w) / np.where(small, 1.0, s))
    e = np.degrees(k[..., None] * v)
    errs = np.empty((len(recs), 4, e.shape[1]))
    np.abs(np.swapaxes(e, 1, 2), out=errs[:, :3])
    errs[:, 3] = np.sqrt(np.einsum("rij,rij->ri", e, e))
    if errs.shape[2]:
        ms = np.sqrt(np.einsum("rij,rij->ri", errs[:, :3], errs[:, :3]) / errs.shape[2])
        p99 = np.quantile(errs, 0.99, axis=2)
    else:
        ms = np.full((len(recs), 3), np.nan)
        p99 = np.full((len(recs), 4), np.nan)
    out = []
    for r in range(len(recs)):
        row = {"rms_deg": float(rms[r]), "max_deg": float(mx[r]), "mean_deg": float(mean[r])}
        if vertical:
            row.update({name: float(x[r]) for name, x in parts.items()})
        for i, a in enumerate(BODY_AXES):
            row[f"{a}_rms_deg"] = float(ms[r, i])
            row[f"{a}_p99_deg"] = float(p99[r, i])
        row["p99_deg"] = float(p99[r, 3])
        out.append(row)
    return out


def score_runs(recs, qs, settle_s: float) -> list[dict]:
    """``[{**score_run(rec, q, settle_s), **score_run_budget(rec, q, settle_s)} ...]`` for
    the recordings ``recs`` and their estimates ``qs`` ((N, 4) each), computed together
    for the runs that share time stamps and frames (see the module docstring)."""
    recs = list(recs)
    qs = list(qs)
    if len(recs) < 2:
        return [_one(r, q, settle_s) for r, q in zip(recs, qs, strict=True)]
    first = recs[0]
    fits = all(r.sun_valid is None and r.q_true is not None
               and r.t.shape == first.t.shape and np.array_equal(r.t, first.t)
               and r.frames.get("reference") == first.frames.get("reference")
               and np.shape(q) == r.q_true.shape
               and np.isfinite(r.q_true).all() and np.isfinite(q).all()
               for r, q in zip(recs, qs, strict=True))
    if not fits:
        return [_one(r, q, settle_s) for r, q in zip(recs, qs, strict=True)]
    return _score_together(recs, qs, settle_s)
