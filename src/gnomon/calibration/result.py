"""The result of a magnetometer calibration: :class:`MagCalibration`, its quality report,
its JSON form, and the thresholds at which a model is used or the fit is refused.

A calibration is ``offset_uT`` ``o`` (3,) µT and ``soft_iron`` ``S`` (3, 3), symmetric
positive definite, in the sensor's axes: the corrected field is ``h = S (m - o)`` (µT) of
magnitude ``field_uT`` (the package docstring, :mod:`gnomon.calibration`, states the model).

Quality report (:class:`MagCalibration`)
----------------------------------------
* ``residual_uT``: RMS over all samples of ``|h| - B`` (µT), after calibration;
  ``raw_residual_uT`` the same spread of the raw magnitudes about their mean. A good
  calibration in a clean field leaves about the sensor's noise (0.5-1 µT on phones);
  several µT mean a disturbed field, a time-varying offset or a poor fit.
* ``coverage`` (0..1): the fraction of the ``COVERAGE_CELLS = 100`` cells of the
  recursive zonal equal-area partition of the unit sphere (Leopardi, ETNA 25, 2006:
  two polar caps and 8 collars, every cell 4π/100 sr, about 20°x20°) that hold at least
  one corrected direction ``h/|h|`` (:func:`gnomon.calibration.coverage.sphere_coverage`).
  1 means every direction was visited; a figure-eight "calibration dance" reaches
  0.5-0.9; a phone only turned about its vertical axis stays near 0.1-0.2.
* ``condition``: the condition number of the weighted Jacobian of the relative residual
  with respect to the dimensionless parameters (offset / radius, elements of S): 2-4 for
  data all around the sphere, growing as the data shrink to a cap or a band; a parameter's
  error grows with it. ``offset_std_uT``/``soft_iron_std`` are the 1-sigma uncertainties
  from the same Jacobian and the residual (white-noise assumption: optimistic when the
  errors are correlated in time).
* ``ok`` / ``reason``: refused (``ok=False``, ``reason`` says why) when the coverage is
  below ``MIN_COVERAGE["offset"]``, when even the offset is ill-conditioned, or when two
  centres fit equally well. ``require_ok=True`` raises :class:`gnomon.errors.InputError`
  instead; :func:`gnomon.calibration.apply.apply_mag_calibration` refuses a calibration
  that is not ok.

Calibrations are stored as JSON (:meth:`MagCalibration.to_dict`,
:func:`save_mag_calibration`, :func:`load_mag_calibration`).
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

__all__ = ["MagCalibration", "save_mag_calibration", "load_mag_calibration", "MODELS",
           "MIN_COVERAGE", "MAX_CONDITION", "MAX_ANISOTROPY"]

#: the models, richest first
MODELS = ("full", "scale", "offset")
#: smallest coverage at which each model is used; below the offset's, the fit is refused
MIN_COVERAGE = {"full": 0.25, "scale": 0.18, "offset": 0.08}
#: largest condition number at which each model is used (see the module docstring)
MAX_CONDITION = {"full": 40.0, "scale": 40.0, "offset": 30.0}
#: largest ratio of the soft-iron matrix's eigenvalues accepted: beyond it the fit has
#: run off to a degenerate ellipsoid (a far centre and a flat S that make every corrected
#: sample nearly the same vector) rather than found a sensor's soft iron (the phones of
#: the tyrex data set: 1.10-1.17)
MAX_ANISOTROPY = 3.0


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


# ---------------------------------------------------------------------- JSON
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
