"""On-orbit magnetometer bias by TWOSTEP: attitude-independent, from the field's magnitude.

R. Alonso and M. D. Shuster, "TWOSTEP: a fast robust algorithm for attitude-independent
magnetometer-bias determination", J. Astronautical Sciences 50(4), 433-451, 2002.

Model (body frame b, nT; ``k`` the sample)::

    B_k = R_bo,k H_k + b + e_k,     e_k ~ N(0, s^2 I)   (white, isotropic, s per axis)

``B_k`` the magnetometer, ``H_k`` the field model (reference frame, e.g. ``o``), ``b`` the
constant bias. The attitude ``R_bo,k`` is unknown, but it keeps lengths, so the scalar

    z_k = |B_k|^2 - |H_k|^2 = 2 B_k.b - |b|^2 + v_k,    v_k = 2 h_k.e_k + |e_k|^2

(``h_k = R_bo,k H_k``, ``|h_k| = |H_k|``) depends on ``b`` alone. Conditioned on the truth,
``E[v_k] = 3 s^2`` and ``var v_k = s_k^2 = 4 s^2 |H_k|^2 + 6 s^4`` (exact for Gaussian
``e_k``: ``|e_k|^2 / s^2`` is chi-square with 3 dof; ``|H_k|`` is known, so the weights
``w_k = 1 / s_k^2`` do not depend on ``b``).

1. **Centred estimate** (step 1). With the weighted means ``zbar = sum w z / sum w`` and
   ``Bbar`` likewise, ``z~_k = z_k - zbar``, ``B~_k = B_k - Bbar``, the quadratic ``|b|^2``
   and the noise mean drop out: ``z~_k ~= 2 B~_k.b + v~_k``, linear least squares::

       F~ = sum_k 4 w_k B~_k B~_k^T,   b* = F~^-1 sum_k 2 w_k z~_k B~_k,   P* = F~^-1

2. **Gauss-Newton** on the full problem from ``b*``: the residual
   ``r_k(b) = z_k - 2 B_k.b + |b|^2 - mu`` with Jacobian ``-2 (B_k - b)``, information
   ``F = sum_k 4 w_k (B_k - b)(B_k - b)^T``, step ``db = F^-1 sum_k 2 w_k r_k (B_k - b)``,
   until ``|db| <= tol_nT`` (or ``max_iterations``); covariance ``P = F^-1`` at the result.

The constant ``mu``: the paper takes ``mu_k = E[v_k]`` computed as if ``B_k - b`` carried
no noise (``-tr Sigma_k = -3 s^2``). The regressor ``B_k - b = h_k + e_k`` does carry it:
at the true ``b`` the Gauss-Newton score has the mean
``sum_k 2 w_k E[(v_k - mu)(h_k + e_k)] = sum_k 2 w_k (5 s^2 - mu) h_k``, which vanishes for
``mu = 5 s^2`` (``3 s^2`` from ``E[v_k]``, ``2 s^2`` from ``E[v_k e_k] = 2 s^2 h_k``). That
value is used here (``NOISE_MEAN_S2``); with the paper's ``-3 s^2`` the estimate is biased
by ``F^-1 sum_k 16 w_k s^2 h_k``, amplified along the weakly determined direction: on one
orbit of seed 001 at its own 300 nT, +46 nT on y (mean of 20 noise draws, against a
1-sigma of 24 nT; at 1000 nT, +675 nT), where ``5 s^2`` leaves no bias
(tests/test_twostep.py measures both). Step 1 does not depend on ``mu`` (the centring
removes any constant).

The noise ``s``: given (``noise_nT``, the sensor's data sheet or a ground test), or
estimated from the data (``noise_nT=None``): a first pass with ``s = 0`` (weights
``1/|H_k|^2``), then ``s^2`` from the residual ``|B_k - b|^2 - |H_k|^2`` (its variance
``4 s^2 |H_k|^2 + 6 s^4``), then the full solution with that ``s``. The estimate is
consistent for white noise; time-correlated errors (field-model error, an unmodelled
scale factor) make ``P`` optimistic.

Refusals (:class:`gnomon.errors.InputError`, naming the field): fewer than
``MIN_SAMPLES`` samples, a non-finite value (first bad row), a zero field model, and a
geometry that does not determine ``b``: the field direction in body axes must vary. The
condition number of ``F`` (largest over smallest eigenvalue) is reported
(``TwostepResult.condition``) and refused above ``MAX_CONDITION``; a constant direction
gives ``F`` of rank one.

The result converts to a :class:`gnomon.calibration.MagCalibration` (offset only,
identity soft iron, model ``"twostep"``) so that ``apply_mag_calibration`` and
``gnomon estimate --mag-calibration cal.json`` use it unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gnomon.calibration.coverage import sphere_coverage
from gnomon.calibration.result import MagCalibration
from gnomon.errors import InputError
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording

__all__ = ["TwostepResult", "twostep", "calibrate_mag_orbit", "MIN_SAMPLES",
           "MAX_CONDITION", "NOISE_MEAN_S2"]

#: fewest samples accepted (3 unknowns; fewer than this leaves no margin for the noise)
MIN_SAMPLES = 10
#: largest condition number of the information matrix accepted: above it the weakest
#: direction of ``b`` gets less than 1/1000 of the strongest's information
#: (its sigma 30 times larger)
MAX_CONDITION = 1.0e3
#: the constant of the residual ``mu = NOISE_MEAN_S2 * s^2`` (module docstring; the
#: paper's is -3)
NOISE_MEAN_S2 = 5.0
#: the field-model keys of a spacecraft recording, the on-board model first
FIELD_KEYS = ("b_o_model_nT", "b_o_nT")


@dataclass(frozen=True, eq=False)
class TwostepResult:
    """TWOSTEP's estimate and report (module docstring).

    ``bias_nT`` (3,) nT in the magnetometer's axes (b), ``cov_nT2`` (3, 3) nT^2 its
    covariance; ``centred_bias_nT``/``centred_cov_nT2`` the same of step 1 alone;
    ``iterations`` Gauss-Newton steps taken, ``converged`` whether the last one was below
    the tolerance; ``residual_nT`` the RMS of ``|B_k - b| - |H_k|`` (nT) after the
    correction, ``raw_residual_nT`` the RMS of ``|B_k| - |H_k|`` before; ``noise_nT`` the
    per-axis noise sigma used and ``noise_source`` (``"given"`` or ``"estimated"``);
    ``condition`` of the information matrix; ``n_samples``; ``field_source`` what ``H``
    was (e.g. ``"extra.b_o_model_nT"``); ``source`` the recording."""

    bias_nT: np.ndarray
    cov_nT2: np.ndarray
    centred_bias_nT: np.ndarray
    centred_cov_nT2: np.ndarray
    iterations: int
    converged: bool
    residual_nT: float
    raw_residual_nT: float
    noise_nT: float
    noise_source: str
    condition: float
    n_samples: int
    mean_field_nT: float
    coverage: float
    field_source: str = ""
    source: str = ""

    @property
    def std_nT(self) -> np.ndarray:
        """1-sigma of each bias component (3,) nT."""
        return np.sqrt(np.diag(self.cov_nT2))

    def calibration(self) -> MagCalibration:
        """The bias as a :class:`~gnomon.calibration.MagCalibration`: ``offset_uT`` =
        ``bias_nT / 1000``, ``soft_iron = I``, ``field_uT`` the mean ``|H|``, model
        ``"twostep"``; ``ok`` when converged."""
        return MagCalibration(
            offset_uT=self.bias_nT / 1e3, soft_iron=np.eye(3),
            field_uT=self.mean_field_nT / 1e3, residual_uT=self.residual_nT / 1e3,
            coverage=self.coverage, ok=self.converged,
            reason="" if self.converged else "TWOSTEP did not converge",
            model="twostep", condition=self.condition, offset_std_uT=self.std_nT / 1e3,
            soft_iron_std=0.0, raw_residual_uT=self.raw_residual_nT / 1e3,
            n_samples=self.n_samples,
            field_source=f"TWOSTEP against the field model {self.field_source}".strip(),
            source=self.source)

    def to_dict(self) -> dict:
        """JSON form: ``bias_nT``, ``std_nT``, ``cov_nT2``, ``centred_bias_nT``,
        ``centred_std_nT``, ``iterations``, ``converged``, ``residual_nT``,
        ``raw_residual_nT``, ``noise_nT``, ``noise_source``, ``condition``, ``n_samples``,
        ``mean_field_nT``, ``coverage``, ``field_source``, ``source``."""
        return {"bias_nT": [float(v) for v in self.bias_nT],
                "std_nT": [float(v) for v in self.std_nT],
                "cov_nT2": [[float(v) for v in row] for row in self.cov_nT2],
                "centred_bias_nT": [float(v) for v in self.centred_bias_nT],
                "centred_std_nT": [float(v) for v in np.sqrt(np.diag(self.centred_cov_nT2))],
                "iterations": int(self.iterations), "converged": bool(self.converged),
                "residual_nT": float(self.residual_nT),
                "raw_residual_nT": float(self.raw_residual_nT),
                "noise_nT": float(self.noise_nT), "noise_source": self.noise_source,
                "condition": float(self.condition), "n_samples": int(self.n_samples),
                "mean_field_nT": float(self.mean_field_nT), "coverage": float(self.coverage),
                "field_source": self.field_source, "source": self.source}


def _finite_rows(name: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a).reshape(len(a), -1).all(axis=1)
    if bad.any():
        raise InputError(f"non-finite value (the first of {int(bad.sum())})", field=name,
                         row=int(np.flatnonzero(bad)[0]))


def _centred(B, H2, w):
    """Step 1: (b*, F~) from the weighted, centred linear problem (units of ``B``)."""
    z = np.einsum("ij,ij->i", B, B) - H2
    sw = w.sum()
    Bc = B - (w @ B) / sw
    zc = z - (w @ z) / sw
    F = 4.0 * (Bc * w[:, None]).T @ Bc
    g = 2.0 * (Bc * (w * zc)[:, None]).sum(axis=0)
    b, *_ = np.linalg.lstsq(F, g, rcond=None)
    return b, F


def _gauss_newton(B, H2, w, mu, b, tol, max_iterations):
    """Step 2: (b, F at b, iterations, converged)."""
    z = np.einsum("ij,ij->i", B, B) - H2
    for it in range(1, max_iterations + 1):
        D = B - b
        r = z - 2.0 * B @ b + b @ b - mu
        F = 4.0 * (D * w[:, None]).T @ D
        step = np.linalg.lstsq(F, 2.0 * (D * (w * r)[:, None]).sum(axis=0), rcond=None)[0]
        b = b + step
        if np.linalg.norm(step) <= tol:
            D = B - b
            return b, 4.0 * (D * w[:, None]).T @ D, it, True
    D = B - b
    return b, 4.0 * (D * w[:, None]).T @ D, max_iterations, False


def _condition(F) -> float:
    """Largest over smallest eigenvalue of the symmetric ``F`` (inf when singular or not
    finite: a Gauss-Newton run that diverged)."""
    if not np.all(np.isfinite(F)):
        return math.inf
    ev = np.linalg.eigvalsh(0.5 * (F + F.T))
    return math.inf if ev[0] <= ev[-1] * 1e-15 else float(ev[-1] / ev[0])


def twostep(mag_nT, field_nT, noise_nT: float | None = None, *, tol_nT: float = 1e-7,
            max_iterations: int = 20, field_source: str = "",
            source: str = "") -> TwostepResult:
    """Magnetometer bias (nT, body axes) by TWOSTEP (Alonso & Shuster 2002; module
    docstring), attitude-independent.

    ``mag_nT`` (N, 3) nT: the magnetometer in its own axes. ``field_nT`` the reference
    field at the same instants: (N, 3) vectors in any frame (only their lengths are used)
    or (N,) magnitudes, nT. ``noise_nT``: the magnetometer's white-noise sigma per axis
    (nT); None estimates it from the residuals. Gauss-Newton stops when a step is below
    ``tol_nT`` or after ``max_iterations``. Raises :class:`InputError` (naming the field)
    for fewer than ``MIN_SAMPLES`` samples, non-finite values, a zero field or a geometry
    whose information matrix has a condition number above ``MAX_CONDITION``."""
    B = np.asarray(mag_nT, dtype=float)
    H = np.asarray(field_nT, dtype=float)
    if B.ndim != 2 or B.shape[1] != 3:
        raise InputError(f"expected shape (N, 3), got {B.shape}", field="mag")
    if H.ndim == 2 and H.shape[1] == 3:
        H_norm = None
    elif H.ndim == 1:
        H_norm = H
    else:
        raise InputError(f"expected shape (N, 3) or (N,), got {H.shape}", field="field_nT")
    if len(H) != len(B):
        raise InputError(f"{len(H)} samples for {len(B)} magnetometer samples",
                         field="field_nT")
    if len(B) < MIN_SAMPLES:
        raise InputError(f"{len(B)} samples, TWOSTEP needs at least {MIN_SAMPLES}",
                         field="mag")
    _finite_rows("mag", B)
    _finite_rows("field_nT", H)
    H_norm = np.linalg.norm(H, axis=1) if H_norm is None else np.abs(H_norm)
    if not np.all(H_norm > 0):
        raise InputError("zero field magnitude", field="field_nT",
                         row=int(np.flatnonzero(~(H_norm > 0))[0]))
    if noise_nT is not None and not (math.isfinite(noise_nT) and noise_nT >= 0):
        raise InputError(f"expected a finite number >= 0, got {noise_nT!r}", field="noise_nT")
    if not (tol_nT > 0 and max_iterations >= 1):
        raise InputError(f"expected tol_nT > 0 and max_iterations >= 1, got {tol_nT!r}, "
                         f"{max_iterations!r}", field="tol_nT")

    # work in units of the RMS field: z ~ 1, b ~ 1e-2 (better conditioned sums)
    scale = float(np.sqrt(np.mean(H_norm ** 2)))
    Bs, H2 = B / scale, (H_norm / scale) ** 2
    tol = tol_nT / scale

    def solve(s):
        w = 1.0 / (4.0 * H2 + 6.0 * s * s)     # 1 / var v_k, times s^2
        w = w / w.mean()
        b0, F0 = _centred(Bs, H2, w)
        b, F, it, ok = _gauss_newton(Bs, H2, w, NOISE_MEAN_S2 * s * s, b0, tol,
                                      max_iterations)
        return b0, F0, b, F, it, ok, w

    if noise_nT is None:
        b = solve(0.0)[2]
        s = 0.0
        r = np.einsum("ij,ij->i", Bs - b, Bs - b) - H2
        r = r - r.mean()
        for _ in range(5):  # s^2 = mean(r^2 / (4 H^2 + 6 s^2)), fixed point
            s = math.sqrt(float(np.sum(r * r / (4.0 * H2 + 6.0 * s * s))) / (len(r) - 4))
        noise_source = "estimated"
    else:
        s = noise_nT / scale
        noise_source = "given"
    b0, F0, b, F, it, converged, w = solve(s)
    # the weights were s^2 / var v_k normalised to mean 1: F and P back to absolute units
    var_unit = s * s / float(np.mean(1.0 / (4.0 * H2 + 6.0 * s * s)))
    cond = _condition(F)
    if not cond <= MAX_CONDITION:
        raise InputError(
            f"the field direction in the magnetometer's axes does not vary enough to "
            f"determine the bias: condition number {cond:.3g} of the information matrix "
            f"(limit {MAX_CONDITION:.0e}); use a longer arc or a rotating attitude",
            field="mag")
    cov = np.linalg.inv(F) * var_unit * scale ** 2
    cov0 = (np.linalg.pinv(F0) * var_unit * scale ** 2 if _condition(F0) < 1e12
            else np.full((3, 3), math.inf))
    bias = b * scale
    corrected = B - bias
    return TwostepResult(
        bias_nT=bias, cov_nT2=0.5 * (cov + cov.T), centred_bias_nT=b0 * scale,
        centred_cov_nT2=0.5 * (cov0 + cov0.T), iterations=it, converged=converged,
        residual_nT=float(np.sqrt(np.mean((np.linalg.norm(corrected, axis=1)
                                           - H_norm) ** 2))),
        raw_residual_nT=float(np.sqrt(np.mean((np.linalg.norm(B, axis=1) - H_norm) ** 2))),
        noise_nT=s * scale, noise_source=noise_source, condition=cond, n_samples=len(B),
        mean_field_nT=float(H_norm.mean()), coverage=sphere_coverage(corrected),
        field_source=field_source, source=source)


def calibrate_mag_orbit(rec: Recording, noise_nT: float | None = None,
                        **options) -> TwostepResult:
    """:func:`twostep` on a spacecraft recording: ``rec.mag`` (in ``rec.mag_unit``,
    converted to nT) against the field model ``rec.extra["b_o_model_nT"]`` (the on-board
    model, as the filters use it) or else ``rec.extra["b_o_nT"]``; magnitudes only, so
    the attitude is not used. ``options`` go to :func:`twostep`. InputError naming
    ``extra.b_o_nT`` when the recording has no field model, ``mag`` when no magnetometer."""
    where = rec.source or None
    if rec.mag is None:
        raise InputError("the recording has no magnetometer", file=where, field="mag")
    key = next((k for k in FIELD_KEYS if rec.extra.get(k) is not None), None)
    if key is None:
        raise InputError("the recording has no field model (a spacecraft simulation "
                         "carries it; TWOSTEP needs |H| at every magnetometer sample)",
                         file=where, field="extra.b_o_nT")
    if rec.mag_t is not None and not np.array_equal(rec.mag_t, rec.t):
        raise InputError("the magnetometer has its own time stamps; the field model is on "
                         "the main time base", file=where, field="mag")
    mag_nT = rec.mag * (MAG_UNITS_TO_TESLA[rec.mag_unit] / 1e-9)
    options.setdefault("field_source", f"extra.{key}")
    options.setdefault("source", rec.source)
    try:
        return twostep(mag_nT, rec.extra[key], noise_nT, **options)
    except InputError as err:
        field = f"extra.{key}" if err.field == "field_nT" else err.field
        raise InputError(err.message, file=err.file or where, field=field,
                         row=err.row) from None
