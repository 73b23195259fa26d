"""Magnetometer calibration: hard iron (offset) and soft iron (a symmetric positive-definite
matrix) from the device's own samples, with a quality report and a clear refusal.

Model (units µT; ``m`` the raw reading in the sensor's axes, ``h`` the corrected one)::

    h = S (m - o),    |h| = B  for every undisturbed sample,  i.e.  m = S^-1 h + o

``o = offset_uT`` (3,), ``S = soft_iron`` (3, 3) symmetric positive definite, ``B =
field_uT`` the field's magnitude: the local IGRF value when the caller gives it (place and
date, :func:`igrf_field_uT`, or a number), else the geometric mean radius of the raw
ellipsoid (then ``det S = 1``: the correction keeps the raw readings' scale). A symmetric
``S`` fixes the rotation that a general 3x3 correction would leave free; the frame of ``h``
is the sensor's (the usual choice, Vasconcelos et al., IEEE TAES 47(2), 2011).

How the fit works (:func:`fit_mag`)
-----------------------------------
1. **Starts.** Li & Griffiths' ellipsoid-specific least squares (GMP 2004: the quadric's
   coefficients under the constraint ``4J - I^2 = 1``, a 6x6 generalised eigenproblem)
   on the data centred and scaled to unit RMS radius: an ellipsoid whenever the data lie
   near one that is not too elongated (magnetometer ellipsoids are nearly spheres); a
   sphere fit re-weighted with Huber weights; and, when the caller has one, an
   independent offset (``offset_hint_uT``; :func:`calibrate_mag` passes the gyro's,
   :func:`gyro_offset_uT`).
2. **Geometric refinement** from every start. ``scipy.optimize.least_squares`` on the
   residual ``|S (m - o)| - B`` (relative to ``B``) with the Huber loss (``huber_rel``: a
   sample whose residual exceeds this fraction of ``B`` — a magnetic disturbance — counts
   linearly, not quadratically). ``S = L L^T`` with a lower-triangular ``L`` whose
   diagonal is ``exp(.)``: positive definite by construction. The lowest cost wins among
   the refinements the data determine (step 4); with a hint, only among those whose
   offset lies within ``hint_gate_rel`` x B of it (in a disturbed field the sphere's cost
   can prefer a wrong centre: the tyrex trials with magnetic disturbances do).
3. **Balance.** Each sample is weighted by ``1 / (samples in its coverage cell)`` (cells
   below, seen from the robust sphere's centre or the hint), so that every direction the
   data visit weighs the same however long the device stayed there (a phone in a pocket
   for a minute must not outweigh the turn that visited the other directions).
   ``balance=False`` weighs every sample equally.
4. **Model choice** (``model="auto"``): the richest of three models whose parameters the
   data determine — ``full`` (o and the 6 elements of S), ``scale`` (o and a diagonal S),
   ``offset`` (o alone; S = I·B/r with the radius r fixed to B when B is given, fitted
   otherwise) — judged by the coverage (``MIN_COVERAGE[model]``), the condition number of
   the fit (``MAX_CONDITION[model]``) and the soft iron's eigenvalue ratio
   (``MAX_ANISOTROPY``: beyond it the fit has degenerated). ``model`` names one model to
   force it (still reported, and refused where it is undetermined). On synthetic data
   (tests): the full model to 0.5 % from 30 % of the sphere in a band; a cap of the same
   area does not determine it (it falls back to ``scale``/``offset``; the offset then
   carries the bias of the soft iron it cannot see, 3-6 % of B for a 2 % soft iron).
5. **Ambiguity check.** Data on (or near) a circle — a device turned only about one axis
   — fit two centres equally well, mirror images through the circle's plane. The chosen
   model is refitted from the mirrored start and from every other start that ended
   elsewhere (all samples weighted alike); if one of them fits within
   ``_AMBIGUOUS_COST`` of the cost, more than ``_AMBIGUOUS_DISTANCE`` x B away, the
   result is refused.

:func:`calibrate_mag` (a ``Recording``) adds the gyro: :func:`gyro_offset_uT` solves
``dh/dt = -w x h`` for the offset, linear, from the rotation alone (no sphere geometry,
little sensitivity to a disturbance the device passes through); it is the fit's hint,
and when the ellipsoid is refused it is the result itself (model ``"gyro-offset"``).

Quality report (:class:`MagCalibration`)
----------------------------------------
* ``residual_uT``: RMS over all samples of ``|h| - B`` (µT), after calibration;
  ``raw_residual_uT`` the same spread of the raw magnitudes about their mean. A good
  calibration in a clean field leaves about the sensor's noise (0.5-1 µT on phones);
  several µT mean a disturbed field, a time-varying offset or a poor fit.
* ``coverage`` (0..1): the fraction of the ``COVERAGE_CELLS = 100`` cells of the
  recursive zonal equal-area partition of the unit sphere (Leopardi, ETNA 25, 2006:
  two polar caps and 8 collars, every cell 4π/100 sr, about 20°x20°) that hold at least
  one corrected direction ``h/|h|`` (:func:`sphere_coverage`). 1 means every direction
  was visited; a figure-eight "calibration dance" reaches 0.5-0.9; a phone only turned
  about its vertical axis stays near 0.1-0.2.
* ``condition``: the condition number of the weighted Jacobian of the relative residual
  with respect to the dimensionless parameters (offset / radius, elements of S): 2-4 for
  data all around the sphere, growing as the data shrink to a cap or a band; a parameter's
  error grows with it. ``offset_std_uT``/``soft_iron_std`` are the 1-sigma uncertainties
  from the same Jacobian and the residual (white-noise assumption: optimistic when the
  errors are correlated in time).
* ``ok`` / ``reason``: refused (``ok=False``, ``reason`` says why) when the coverage is
  below ``MIN_COVERAGE["offset"]``, when even the offset is ill-conditioned, or when two
  centres fit equally well. ``require_ok=True`` raises :class:`gnomon.errors.InputError`
  instead; :func:`apply_mag_calibration` refuses a calibration that is not ok.

Why written here rather than taken from a package (checked on PyPI, 2026): ``magcal``
(1.0.1) is an interactive serial-port tool whose fit is an unconstrained quadric least
squares with ``abs()`` applied to negative eigenvalues (no positive-definite constraint,
no geometric refinement, no coverage or refusal) and it pulls pyserial, rich, click and
questionary; ``circuitpython-mag-cal`` (1.4.1, 2023) targets CircuitPython cave-survey
instruments and fits magnetometer and accelerometer jointly with their axes aligned (it
needs both, reports no coverage); ``ctef`` is a general Cayley-transform ellipsoid fitter
for clustering; ``magcc`` is a live UDP/browser tool. None does a constrained, weighted,
quality-reported fit with a refusal, so the code below uses numpy and scipy only.

On orbit, where the field model gives ``|B|`` at every sample: :mod:`gnomon.twostep`
(TWOSTEP, the bias alone, attitude-independent) returns the same ``MagCalibration``
(model ``"twostep"``).

Applying it: :func:`apply_mag_calibration` returns a new ``Recording``
(``dataclasses.replace``) whose ``mag`` is ``h`` in µT (``mag_unit="uT"``), on the
magnetometer's own time stamps; nothing else changes. Calibrations are stored as JSON
(:meth:`MagCalibration.to_dict`, :func:`save_mag_calibration`, :func:`load_mag_calibration`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording

__all__ = ["MagCalibration", "fit_mag", "calibrate_mag", "apply_mag_calibration",
           "save_mag_calibration", "load_mag_calibration", "sphere_coverage", "coverage_cells",
           "igrf_field_uT", "gyro_offset_uT", "mag_uT_of", "plot_mag_calibration", "MODELS",
           "MIN_COVERAGE", "MAX_CONDITION", "COVERAGE_CELLS",
           "MIN_SAMPLES"]

#: the models, richest first
MODELS = ("full", "scale", "offset")
#: number of equal-area cells of the coverage measure
COVERAGE_CELLS = 100
#: fewest samples accepted (the full model has 9 parameters)
MIN_SAMPLES = 30
#: smallest coverage at which each model is used; below the offset's, the fit is refused
MIN_COVERAGE = {"full": 0.25, "scale": 0.18, "offset": 0.08}
#: largest condition number at which each model is used (see the module docstring)
MAX_CONDITION = {"full": 40.0, "scale": 40.0, "offset": 30.0}
#: largest ratio of the soft-iron matrix's eigenvalues accepted: beyond it the fit has
#: run off to a degenerate ellipsoid (a far centre and a flat S that make every corrected
#: sample nearly the same vector) rather than found a sensor's soft iron (the phones of
#: the tyrex data set: 1.10-1.17)
MAX_ANISOTROPY = 3.0
#: :func:`gyro_offset_uT` needs rotation about more than one axis: the condition number
#: of its normal equations at most this (rotation about the weakest axis ~3 % of the
#: strongest)
MAX_GYRO_CONDITION = 1e3
#: a mirrored start that fits within this relative cost of the fit makes it ambiguous
_AMBIGUOUS_COST = 1.1
#: and only when the two centres are this far apart (fraction of B)
_AMBIGUOUS_DISTANCE = 0.1


# ---------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class MagCalibration:
    """A magnetometer calibration and its quality report (module docstring).

    ``offset_uT`` (3,) µT and ``soft_iron`` (3, 3) symmetric positive definite: the
    corrected field is ``soft_iron @ (m_uT - offset_uT)``, of magnitude ``field_uT``."""

    offset_uT: np.ndarray
    soft_iron: np.ndarray
    field_uT: float
    residual_uT: float
    coverage: float
    ok: bool
    reason: str = ""
    model: str = "full"
    condition: float = math.nan
    offset_std_uT: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    soft_iron_std: float = math.nan
    raw_residual_uT: float = math.nan
    n_samples: int = 0
    field_source: str = "data"
    source: str = ""
    tried: tuple = ()
    offset_hint_uT: np.ndarray | None = None

    def correct(self, mag_uT) -> np.ndarray:
        """Corrected field ``S (m - o)`` (N, 3) µT of raw readings ``mag_uT`` (N, 3) µT."""
        m = np.asarray(mag_uT, dtype=float)
        return (m - self.offset_uT) @ self.soft_iron.T

    def to_dict(self) -> dict:
        """The JSON form: ``offset_uT``, ``soft_iron``, ``residual_uT``, ``coverage``,
        ``ok`` and the rest of the report (``model``, ``condition``, ``reason``, ...)."""
        return {"offset_uT": [float(v) for v in self.offset_uT],
                "soft_iron": [[float(v) for v in row] for row in self.soft_iron],
                "residual_uT": float(self.residual_uT), "coverage": float(self.coverage),
                "ok": bool(self.ok), "reason": self.reason, "model": self.model,
                "field_uT": float(self.field_uT), "field_source": self.field_source,
                "condition": float(self.condition),
                "offset_std_uT": [float(v) for v in self.offset_std_uT],
                "soft_iron_std": float(self.soft_iron_std),
                "raw_residual_uT": float(self.raw_residual_uT),
                "n_samples": int(self.n_samples), "source": self.source,
                "offset_hint_uT": None if self.offset_hint_uT is None else
                [float(v) for v in self.offset_hint_uT],
                "tried": [dict(t) for t in self.tried]}

    @classmethod
    def from_dict(cls, d: dict, file: str | None = None) -> MagCalibration:
        """Build from :meth:`to_dict`'s form (``offset_uT`` and ``soft_iron`` required),
        validated: a bad value raises ``InputError`` naming the field."""
        if not isinstance(d, dict):
            raise InputError(f"expected a JSON object, got {type(d).__name__}", file=file)
        for key in ("offset_uT", "soft_iron"):
            if key not in d:
                raise InputError("missing", file=file, field=key)
        try:
            o = np.asarray(d["offset_uT"], dtype=float)
            S = np.asarray(d["soft_iron"], dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"not numbers: {exc}", file=file, field="offset_uT/soft_iron"
                             ) from None
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise InputError(f"expected 3 finite numbers, got {d['offset_uT']!r}", file=file,
                             field="offset_uT")
        _check_soft_iron(S, file)
        num = {}
        for key, default in (("residual_uT", math.nan), ("coverage", math.nan),
                             ("field_uT", math.nan), ("condition", math.nan),
                             ("soft_iron_std", math.nan), ("raw_residual_uT", math.nan)):
            v = d.get(key, default)
            num[key] = math.nan if v is None else float(v)
        std = d.get("offset_std_uT")
        return cls(offset_uT=o, soft_iron=S, ok=bool(d.get("ok", True)),
                   reason=str(d.get("reason", "")), model=str(d.get("model", "full")),
                   offset_std_uT=np.full(3, np.nan) if std is None else
                   np.asarray([math.nan if v is None else v for v in std], dtype=float),
                   n_samples=int(d.get("n_samples", 0)),
                   field_source=str(d.get("field_source", "data")),
                   source=str(d.get("source", "")),
                   tried=tuple(d.get("tried", ())), **num)


def _check_soft_iron(S: np.ndarray, file: str | None = None) -> None:
    if S.shape != (3, 3) or not np.all(np.isfinite(S)):
        raise InputError(f"expected a finite 3x3 matrix, got shape {S.shape}", file=file,
                         field="soft_iron")
    if not np.allclose(S, S.T, rtol=1e-6, atol=1e-9 * max(1.0, float(np.abs(S).max()))):
        raise InputError(f"not symmetric: {S.tolist()}", file=file, field="soft_iron")
    w = np.linalg.eigvalsh(0.5 * (S + S.T))
    if w[0] <= 0:
        raise InputError(f"not positive definite (eigenvalues {w.tolist()})", file=file,
                         field="soft_iron")


# ---------------------------------------------------------------------- coverage
def coverage_cells(n: int = COVERAGE_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """Leopardi's recursive zonal equal-area partition of the unit sphere into ``n``
    cells: ``(colatitude edges (K+1,) rad, cells per zone (K,))``, zones from the north
    pole (a cap of one cell) to the south pole (a cap of one cell); every cell has the
    area ``4π/n``. Zone ``k`` spans ``edges[k] <= colatitude < edges[k+1]`` and is split
    into ``counts[k]`` equal sectors of longitude."""
    if n < 2:
        raise InputError(f"expected at least 2 cells, got {n}", field="cells")
    if n == 2:
        return np.array([0.0, math.pi / 2, math.pi]), np.array([1, 1])
    area = 4 * math.pi / n
    polar = 2 * math.asin(math.sqrt(1.0 / n))  # a cap of one cell's area
    n_collars = max(1, round((math.pi - 2 * polar) / math.sqrt(area)))
    step = (math.pi - 2 * polar) / n_collars
    counts, carry = [1], 0.0
    for i in range(n_collars):
        a, b = polar + i * step, polar + (i + 1) * step
        ideal = n * (math.cos(a) - math.cos(b)) / 2
        k = round(ideal + carry)
        carry += ideal - k
        counts.append(int(k))
    counts.append(1)
    cum = np.cumsum(counts)
    edges = np.concatenate([[0.0], np.arccos(np.clip(1 - 2 * cum / n, -1, 1))])
    edges[-1] = math.pi
    return edges, np.asarray(counts)


def _cell_index(directions: np.ndarray, n: int = COVERAGE_CELLS) -> np.ndarray:
    """The cell (0..n-1) of each unit vector (N, 3)."""
    edges, counts = coverage_cells(n)
    d = np.asarray(directions, dtype=float)
    colat = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    zone = np.clip(np.searchsorted(edges, colat, side="right") - 1, 0, counts.size - 1)
    lon = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * math.pi)
    k = counts[zone]
    sector = np.minimum((lon / (2 * math.pi) * k).astype(np.int64), k - 1)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return start[zone] + sector


def sphere_coverage(vectors, n: int = COVERAGE_CELLS) -> float:
    """Fraction (0..1) of the ``n`` equal-area cells (:func:`coverage_cells`) holding the
    direction of at least one of ``vectors`` (N, 3), any length (zero vectors ignored)."""
    v = np.asarray(vectors, dtype=float)
    norm = np.linalg.norm(v, axis=1)
    v = v[norm > 0] / norm[norm > 0, None]
    if not v.size:
        return 0.0
    return float(np.unique(_cell_index(v, n)).size / n)


# ---------------------------------------------------------------------- field
def igrf_field_uT(latitude_deg: float, longitude_deg: float, altitude_m: float = 0.0,
                  date: str = "2025-01-01") -> float:
    """Magnitude (µT) of the IGRF-14 main field (:mod:`gnomon.environment.magnetic`) at a
    geodetic place (WGS-84 latitude and longitude in degrees, height in m) and a date
    (``YYYY-MM-DD``, or anything ``gnomon.frames.parse_epoch`` takes)."""
    import datetime as dt

    from gnomon.environment.magnetic import GeomagneticField, _decimal_year
    from gnomon.frames import parse_epoch

    lat, lon, h = (math.radians(float(latitude_deg)), math.radians(float(longitude_deg)),
                   float(altitude_m))
    if not (abs(latitude_deg) <= 90 and math.isfinite(lon) and math.isfinite(h)):
        raise InputError(f"expected latitude in [-90, 90] deg, finite longitude and height, "
                         f"got {latitude_deg}, {longitude_deg}, {altitude_m}",
                         field="location")
    a, f = 6378137.0, 1 / 298.257223563  # WGS-84
    e2 = f * (2 - f)
    n = a / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    r_e = np.array([(n + h) * math.cos(lat) * math.cos(lon),
                    (n + h) * math.cos(lat) * math.sin(lon),
                    (n * (1 - e2) + h) * math.sin(lat)])
    epoch = parse_epoch(str(date))
    noon = dt.datetime(epoch.year, epoch.month, epoch.day, 12)
    b = GeomagneticField().b_e_nT(r_e, _decimal_year(noon))
    return float(np.linalg.norm(b) / 1000.0)


# ---------------------------------------------------------------------- validation
def _as_mag(mag_uT) -> np.ndarray:
    try:
        m = np.asarray(mag_uT, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"not numbers: {exc}", field="mag") from None
    if m.ndim != 2 or m.shape[1] != 3:
        raise InputError(f"expected shape (N, 3), got {m.shape}", field="mag")
    bad = ~np.isfinite(m).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InputError(f"non-finite value {m[row].tolist()}", field="mag", row=row)
    zero = ~np.any(m != 0, axis=1)
    if zero.any():
        row = int(np.flatnonzero(zero)[0])
        raise InputError(f"zero vector {m[row].tolist()} (a missing reading? "
                         f"{int(zero.sum())} such rows)", field="mag", row=row)
    if m.shape[0] < MIN_SAMPLES:
        raise InputError(f"too few samples: {m.shape[0]} (at least {MIN_SAMPLES})",
                         field="mag")
    return m


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
    if model not in ("auto", *MODELS):
        raise InputError(f"unknown model {model!r}; use auto, full, scale or offset",
                         field="model")
    if field_uT is not None and not (math.isfinite(field_uT) and field_uT > 0):
        raise InputError(f"expected a positive field magnitude in uT, got {field_uT!r}",
                         field="field_uT")
    if not (math.isfinite(huber_rel) and huber_rel > 0):
        raise InputError(f"expected a positive number, got {huber_rel!r}", field="huber_rel")
    n_all = m.shape[0]
    if n_all > max_samples:
        m = m[:: int(math.ceil(n_all / max_samples))]
    # normalise: centred on the mean, unit RMS distance
    centre = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - centre) ** 2, axis=1))))
    if not scale > 0:
        raise InputError("all samples are equal: the device did not move", field="mag")
    x = (m - centre) / scale
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
    hint = None
    if offset_hint_uT is not None:
        hint = np.asarray(offset_hint_uT, dtype=float)
        if hint.shape != (3,) or not np.all(np.isfinite(hint)):
            raise InputError(f"expected 3 finite numbers, got {offset_hint_uT!r}",
                             field="offset_hint_uT")
        hint = (hint - centre) / scale
        r = float(np.sqrt(np.average(np.sum((x - hint) ** 2, axis=1), weights=w)))
        starts.append((hint, np.eye(3) / max(r, 1e-9)))
        gate = hint_gate_rel * (field_uT if field_uT is not None else r * scale) / scale

    def why_not(f: _Fit) -> str:
        why = _unusable(f)
        if not why and hint is not None and np.linalg.norm(f.o - hint) > gate:
            why = (f"offset {np.linalg.norm(f.o - hint) * scale:.1f} uT from the independent "
                   f"estimate (gyro), more than {gate * scale:.1f} uT: a disturbed field or a "
                   "wrong centre")
        return why
    # with B given, the offset model's radius is B: in normalised units |x - o| = B / scale
    k_fixed = scale / field_uT if field_uT is not None else None

    def ladder(w, starts):
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

    if balance and hint is not None:  # the balance cells seen from the independent centre
        w = _balance_weights(x, hint)
    tried, fits = ladder(w, starts)
    fit, kf, reason, cands = fits[tried[-1]["model"]]
    if not reason:  # data near a circle fit two centres (mirror images) equally well
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
                reason = (f"ambiguous: two centres {gap:.1f} uT apart fit about equally well "
                          f"(cost ratio {ratio:.2f}); the data lie near a circle or are "
                          "disturbed: turn the device about another axis too, away from iron")
                break
    ok = not reason
    tried[-1]["used"] = True
    # back to µT: o = centre + scale·o_n; S = (B/scale)·S_n, B given or det S = 1
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
    h = (m - o) @ S.T
    norm_h = np.linalg.norm(h, axis=1)
    raw_norm = np.linalg.norm(m, axis=1)
    o_std = fit.std[:3] * scale
    s_std = float(np.max(fit.std[3:]) / np.abs(np.linalg.eigvalsh(fit.S)).max()) \
        if fit.std.size > 3 else 0.0
    cal = MagCalibration(
        offset_uT=o, soft_iron=S, field_uT=B,
        residual_uT=float(np.sqrt(np.mean((norm_h - B) ** 2))), coverage=fit.coverage,
        ok=ok, reason=reason, model=fit.model, condition=fit.condition, offset_std_uT=o_std,
        soft_iron_std=s_std, raw_residual_uT=float(np.std(raw_norm)), n_samples=n_all,
        field_source=src, source=source, tried=tuple(tried),
        offset_hint_uT=None if hint is None else centre + scale * hint)
    if require_ok and not ok:
        raise InputError(f"magnetometer calibration refused: {reason}", field="mag")
    return cal


def mag_uT_of(rec: Recording) -> np.ndarray:
    """The recording's magnetometer samples in µT (N, 3); InputError when it has none."""
    if rec.mag is None:
        raise InputError("the recording has no magnetometer", file=rec.source or None,
                         field="mag")
    return rec.mag * (MAG_UNITS_TO_TESLA[rec.mag_unit] / 1e-6)


def gyro_offset_uT(rec: Recording, window_s: float = 0.25, max_dt_s: float = 0.2,
                   iterations: int = 10) -> np.ndarray | None:
    """The hard-iron offset (µT, (3,)) that makes the magnetometer turn as the gyro says,
    or None when the rotation does not determine it.

    In a constant field the corrected reading ``h = m - o`` obeys ``dh/dt = -w × h``
    (``w`` the gyro, rad/s), linear in ``o``: over each window of ``window_s``
    (trapezoidal sums, no window across a gap longer than ``max_dt_s``)
    ``Δm + Σ dt/2 (w_i × m_i + w_i+1 × m_i+1) = (Σ dt/2 (w_i + w_i+1)) × o``. Solved by
    least squares re-weighted with Huber weights (a disturbed or unmodelled window counts
    less); soft iron is neglected (a few per cent of the field). Independent of the
    sphere's geometry, it tells apart the two centres that data on a circle fit equally
    well: :func:`calibrate_mag` gives it to :func:`fit_mag` as a start. Gyro sampled at
    the magnetometer's time stamps by linear interpolation."""
    if rec.mag is None or rec.gyro is None:
        return None
    t_m = rec.times("mag")
    m = mag_uT_of(rec)
    w = np.column_stack([np.interp(t_m, rec.t, rec.gyro[:, k]) for k in range(3)])
    dt = np.diff(t_m)
    good = (dt > 0) & (dt <= max_dt_s)
    wbar = 0.5 * dt[:, None] * (w[:-1] + w[1:])
    rhs = np.diff(m, axis=0) + 0.5 * dt[:, None] * (np.cross(w[:-1], m[:-1])
                                                    + np.cross(w[1:], m[1:]))
    # windows: consecutive good steps, cut at gaps and every window_s
    seg = np.cumsum(~good)
    win = np.floor((t_m[:-1] - t_m[0]) / window_s).astype(np.int64)
    key = seg * (int(win.max()) + 1) + win
    key = key[good]
    _, idx = np.unique(key, return_inverse=True)
    W = np.zeros((idx.max() + 1, 3)) if idx.size else np.zeros((0, 3))
    R = np.zeros_like(W)
    np.add.at(W, idx, wbar[good])
    np.add.at(R, idx, rhs[good])
    if W.shape[0] < 10:
        return None

    def cross_matrix(v):
        z = np.zeros(len(v))
        return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1),
                         np.stack([v[:, 2], z, -v[:, 0]], -1),
                         np.stack([-v[:, 1], v[:, 0], z], -1)], 1)

    A = cross_matrix(W)  # (K, 3, 3): A_k o = W_k × o
    weights = np.ones(W.shape[0])
    o = np.zeros(3)
    for _ in range(iterations):
        AtA = np.einsum("k,kji,kjl->il", weights, A, A)
        if np.linalg.cond(AtA) > MAX_GYRO_CONDITION:
            return None
        o = np.linalg.solve(AtA, np.einsum("k,kji,kj->i", weights, A, R))
        res = np.linalg.norm(R - np.einsum("kij,j->ki", A, o), axis=1)
        k = 1.5 * np.median(res) + 1e-12
        weights = np.where(res <= k, 1.0, k / res)
    return o


def calibrate_mag(rec: Recording, *, field_uT: float | None = None,
                  location: dict | None = None, gyro: bool = True, gyro_fallback: bool = True,
                  **options) -> MagCalibration:
    """:func:`fit_mag` on a recording's magnetometer (any ``mag_unit``, converted to µT).

    ``location``: ``{"latitude_deg", "longitude_deg", "altitude_m", "date"}`` sets
    ``field_uT`` to the IGRF magnitude there (when ``field_uT`` is not given). ``gyro``:
    give :func:`gyro_offset_uT` to the fit as ``offset_hint_uT`` (a start and a gate).
    ``gyro_fallback``: when the ellipsoid is refused but the gyro determines the offset,
    return the gyro's offset alone (model ``"gyro-offset"``: ``S = I·B/r``, r the median
    distance of the samples from it; the ellipsoid's refusal is kept in ``tried``); its
    ``ok`` needs the coverage of the offset model (``require_ok`` applies to the result)."""
    src = None
    if field_uT is None and location is not None:
        missing = [k for k in ("latitude_deg", "longitude_deg", "date") if k not in location]
        if missing:
            raise InputError(f"missing {', '.join(missing)}", field="location")
        field_uT = igrf_field_uT(location["latitude_deg"], location["longitude_deg"],
                                 location.get("altitude_m", 0.0), location["date"])
        src = (f"IGRF-14 at {location['latitude_deg']:.4f}, {location['longitude_deg']:.4f}"
               f" deg on {location['date']}")
    options.setdefault("source", rec.source)
    src = options.pop("field_source", None) or src
    if gyro and options.get("offset_hint_uT") is None:
        options["offset_hint_uT"] = gyro_offset_uT(rec)
    require = options.pop("require_ok", False)
    try:
        cal = fit_mag(mag_uT_of(rec), field_uT=field_uT, field_source=src, **options)
        if not cal.ok and gyro_fallback and options.get("offset_hint_uT") is not None:
            cal = _gyro_calibration(mag_uT_of(rec), cal)
        if require and not cal.ok:
            raise InputError(f"magnetometer calibration refused: {cal.reason}", field="mag")
        return cal
    except InputError as err:
        if rec.source and err.file is None:
            raise err.with_file(rec.source) from None
        raise


def _gyro_calibration(m: np.ndarray, refused: MagCalibration) -> MagCalibration:
    """The offset of ``refused.offset_hint_uT`` alone, reported like a fit."""
    o = np.asarray(refused.offset_hint_uT, dtype=float)
    r = float(np.median(np.linalg.norm(m - o, axis=1)))
    given = refused.field_source != "data"
    B = refused.field_uT if given else r
    S = np.eye(3) * (B / r)
    h = (m - o) @ S.T
    cov = sphere_coverage(h)
    ok = cov >= MIN_COVERAGE["offset"]
    tried = (*({**t, "used": False} for t in refused.tried),
             {"model": "gyro-offset", "coverage": cov, "condition": math.nan,
              "anisotropy": 1.0, "used": True,
              "why_not": "" if ok else f"coverage {cov:.2f} below {MIN_COVERAGE['offset']}"})
    return dataclasses.replace(
        refused, offset_uT=o, soft_iron=S, field_uT=B, ok=ok, model="gyro-offset",
        reason="" if ok else f"ellipsoid refused ({refused.reason}) and gyro offset "
                             f"coverage {cov:.2f} below {MIN_COVERAGE['offset']}",
        residual_uT=float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - B) ** 2))),
        coverage=cov, condition=math.nan, offset_std_uT=np.full(3, np.nan),
        soft_iron_std=math.nan, tried=tried)


def apply_mag_calibration(rec: Recording, cal: MagCalibration, *,
                          allow_refused: bool = False) -> Recording:
    """A new ``Recording`` whose ``mag`` is ``cal.correct(mag)`` in µT (``mag_unit="uT"``),
    same time stamps, everything else unchanged; ``meta["mag_calibration"]`` records the
    calibration and ``meta["assumed"]`` says so. A calibration that is not ``ok`` raises
    ``InputError`` (with its reason) unless ``allow_refused``."""
    if not cal.ok and not allow_refused:
        raise InputError(f"the magnetometer calibration was refused: {cal.reason}",
                         file=cal.source or None, field="mag_calibration")
    corrected = cal.correct(mag_uT_of(rec))
    meta = dict(rec.meta)
    meta["mag_calibration"] = cal.to_dict()
    meta["assumed"] = list(meta.get("assumed", [])) + [
        f"Magnetometer corrected by a {cal.model} calibration (offset "
        f"{np.round(cal.offset_uT, 2).tolist()} uT, coverage {cal.coverage:.2f}, residual "
        f"{cal.residual_uT:.2f} uT): h = S (m - o), in uT."]
    return dataclasses.replace(rec, mag=corrected, mag_unit="uT", meta=meta)


def save_mag_calibration(path: str | os.PathLike, cal: MagCalibration) -> Path:
    """Write ``cal.to_dict()`` as JSON."""
    p = Path(path)
    p.write_text(json.dumps(cal.to_dict(), indent=2) + "\n", encoding="utf-8")
    return p


def load_mag_calibration(path: str | os.PathLike) -> MagCalibration:
    """Read a calibration JSON (``gnomon calibrate mag --out``); InputError naming the
    file and field when it is not one."""
    p = Path(path)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no such file", file=str(p)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a calibration JSON: {exc}", file=str(p)) from None
    cal = MagCalibration.from_dict(d, file=str(p))
    return dataclasses.replace(cal, source=cal.source or str(p))


def plot_mag_calibration(mag_uT, cal: MagCalibration, path: str | os.PathLike,
                         title: str = "") -> Path:
    """A figure of a calibration (``gnomon calibrate mag --plot``): the raw samples (µT)
    with the fitted ellipsoid, the corrected samples with the sphere of radius B, the
    magnitudes before and after along the samples, and the coverage cells the corrected
    directions visit (longitude/latitude of ``h/|h|``, sensor axes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = _as_mag(mag_uT)
    h = cal.correct(m)
    step = max(1, len(m) // 3000)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 37), np.linspace(0, np.pi, 19))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
    fig = plt.figure(figsize=(12, 9))
    status = "ok" if cal.ok else f"REFUSED: {cal.reason}"
    fig.suptitle((title + "\n" if title else "") +
                 f"{cal.model} model, coverage {cal.coverage:.2f}, residual "
                 f"{cal.residual_uT:.2f} uT (raw spread {cal.raw_residual_uT:.2f} uT), "
                 f"condition {cal.condition:.3g}; {status}", fontsize=10)
    ell = (cal.field_uT * sphere) @ np.linalg.inv(cal.soft_iron).T + cal.offset_uT
    for k, (pts, surf, name) in enumerate(((m, ell, "raw m (uT) and the fitted ellipsoid"),
                                           (h, cal.field_uT * sphere,
                                            f"corrected h = S (m - o) (uT), sphere |h| = "
                                            f"{cal.field_uT:.1f} uT"))):
        ax = fig.add_subplot(2, 2, k + 1, projection="3d")
        ax.plot_wireframe(surf[..., 0], surf[..., 1], surf[..., 2], color="0.75",
                          linewidth=0.4)
        ax.scatter(*pts[::step].T, s=2, c=np.arange(len(pts))[::step], cmap="viridis")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        lo, hi = pts.min(0), pts.max(0)
        mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, cal.field_uT)
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, strict=True):
            setter(c - half, c + half)
        ax.set_box_aspect((1, 1, 1))
    ax = fig.add_subplot(2, 2, 3)
    raw_norm = np.linalg.norm(m, axis=1)
    ax.plot(raw_norm - np.median(raw_norm) + cal.field_uT, lw=0.6, color="0.5",
            label="|m| raw, shifted to B at its median")
    ax.plot(np.linalg.norm(h, axis=1), lw=0.6, color="C0", label="|h| corrected")
    ax.axhline(cal.field_uT, color="k", lw=0.8, ls="--", label=f"B = {cal.field_uT:.1f} uT")
    ax.set_xlabel("sample")
    ax.set_ylabel("field magnitude (uT)")
    ax.legend(fontsize=8)
    ax.set_title("magnitude along the recording: flat = a good calibration in a clean "
                 "field", fontsize=9)
    ax = fig.add_subplot(2, 2, 4)
    d = h / np.linalg.norm(h, axis=1)[:, None]
    cells = np.unique(_cell_index(d))
    edges, counts = coverage_cells()
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for zone, (k, s0) in enumerate(zip(counts, start, strict=True)):
        lat_hi, lat_lo = 90 - np.degrees(edges[zone]), 90 - np.degrees(edges[zone + 1])
        for j in range(k):
            lon0, lon1 = 360.0 * j / k, 360.0 * (j + 1) / k
            ax.add_patch(plt.Rectangle((lon0, lat_lo), lon1 - lon0, lat_hi - lat_lo,
                                       facecolor="C2" if s0 + j in cells else "white",
                                       edgecolor="0.8", alpha=0.5, lw=0.5))
    lon = np.degrees(np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi))
    ax.scatter(lon[::step], np.degrees(np.arcsin(np.clip(d[::step, 2], -1, 1))), s=1,
               color="C0")
    ax.set_xlim(0, 360)
    ax.set_ylim(-90, 90)
    ax.set_xlabel("longitude of h/|h| (deg, from +x towards +y)")
    ax.set_ylabel("latitude of h/|h| (deg, +z up)")
    ax.set_title(f"coverage: {len(cells)} of {COVERAGE_CELLS} equal-area cells visited",
                 fontsize=9)
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p
