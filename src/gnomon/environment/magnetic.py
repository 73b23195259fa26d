"""Geomagnetic field models: IGRF-14, a tilted dipole, and field-model errors.

IGRF-14 coefficients come from ``ppigrf`` (its bundled ``IGRF14.shc``; read
once and cached). They are interpolated linearly in time to the epoch day of
each point, then the spherical-harmonic sum is evaluated in a numba kernel
(:func:`gnomon.kernels.magnetic.sh_field_ecef`) over the whole trajectory at
once; ``ppigrf.igrf_gc`` is the reference it is tested against.

Field vectors are in nT. Frames: ``e`` (ECEF) from the model; ``i`` through
``R_ie = R_ei^T`` (GMST, :mod:`gnomon.frames`); orbital and body frames are
obtained by the caller with ``q_io``/``q_ob``.

Field-model errors (seed 001: "uncertainty of the Earth magnetic field model",
2 % and 10 %): :class:`PerturbedField` wraps a model and is named by ``kind``:

* ``scale``: ``B' = (1 + L) B`` (constant relative magnitude error L = level %).
* ``tilt``: ``B'`` is ``B`` rotated by the fixed angle ``atan(L)`` about a fixed
  random axis in ECEF (magnitude kept; direction error ``atan(L) sin(∠(B, axis))``,
  at most ``atan(L)``, so ``|B' - B| <= L |B|``).
* ``component``: ``B'_k = (1 + L z_k) B_k`` in ECEF, ``z_k ~ N(0, 1)`` drawn once.
* ``gauss``: every Gauss coefficient ``g_nm, h_nm`` multiplied by ``(1 + L z_nm)``,
  ``z_nm ~ N(0, 1)`` drawn once.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError
from gnomon.frames import dcm_ei, gmst_rad, julian_date, parse_epoch

__all__ = [
    "IGRF_REFERENCE_RADIUS_M",
    "igrf_coefficients",
    "GeomagneticField",
    "PerturbedField",
    "field_model",
    "field_e_nT",
    "field_i_nT",
    "FIELD_ERROR_KINDS",
]

IGRF_REFERENCE_RADIUS_M = 6371.2e3
FIELD_ERROR_KINDS = ("none", "scale", "tilt", "component", "gauss")


@functools.lru_cache(maxsize=1)
def _igrf_table():
    """(decimal years (K,), g (K, 14, 14), h (K, 14, 14)) from ppigrf's IGRF-14 file."""
    from ppigrf import ppigrf

    gdf, hdf = ppigrf.read_shc(ppigrf.shc_fn_igrf14)
    years = np.array([_decimal_year(d) for d in gdf.index.to_pydatetime()])
    nmax = max(k[0] for k in gdf.columns)
    G = np.zeros((len(years), nmax + 1, nmax + 1))
    H = np.zeros_like(G)
    for (n, m) in gdf.columns:
        G[:, n, m] = gdf[(n, m)].to_numpy(float)
        H[:, n, m] = np.asarray(hdf[(n, m)].to_numpy(float))
    return years, G, H


def _decimal_year(d) -> float:
    import datetime as dt

    d = d.replace(tzinfo=None)
    y0 = dt.datetime(d.year, 1, 1)
    y1 = dt.datetime(d.year + 1, 1, 1)
    return d.year + (d - y0).total_seconds() / (y1 - y0).total_seconds()


def igrf_coefficients(decimal_year: float, nmax: int = 13) -> tuple[np.ndarray, np.ndarray]:
    """IGRF-14 Gauss coefficients ``(g, h)`` (nT, shape (nmax+1, nmax+1)) at ``decimal_year``.

    Linear interpolation between the 5-yearly models (after the last definitive
    model, the predictive secular variation baked into the file).
    """
    years, G, H = _igrf_table()
    if not (years[0] <= decimal_year <= years[-1]):
        raise InputError(f"IGRF-14 covers {years[0]:.0f}-{years[-1]:.0f}, "
                         f"got {decimal_year:.2f}", field="epoch")
    k = int(np.clip(np.searchsorted(years, decimal_year) - 1, 0, len(years) - 2))
    w = (decimal_year - years[k]) / (years[k + 1] - years[k])
    g = (1 - w) * G[k] + w * G[k + 1]
    h = (1 - w) * H[k] + w * H[k + 1]
    return g[: nmax + 1, : nmax + 1].copy(), h[: nmax + 1, : nmax + 1].copy()


@dataclass(frozen=True)
class GeomagneticField:
    """IGRF-14 truncated at degree ``nmax`` (13 = full IGRF; 1 = tilted dipole).

    ``coeff_transform``: optional function ``(g, h) -> (g', h')`` applied to the
    interpolated coefficients (used by the ``gauss`` error model).
    """

    nmax: int = 13
    name: str = "igrf"
    coeff_transform: object = None

    def coefficients(self, decimal_year: float):
        g, h = igrf_coefficients(decimal_year, self.nmax)
        if self.coeff_transform is not None:
            g, h = self.coeff_transform(g, h)
        return g, h

    def b_e_nT(self, r_e_m, decimal_year: float) -> np.ndarray:
        """Field (nT) in ECEF at ECEF positions ``r_e_m`` (m), shape (..., 3)."""
        from gnomon.kernels.magnetic import sh_field_ecef

        r = np.ascontiguousarray(np.asarray(r_e_m, float).reshape(-1, 3))
        g, h = self.coefficients(decimal_year)
        out = sh_field_ecef(r, g, h, IGRF_REFERENCE_RADIUS_M, self.nmax)
        return out.reshape(np.shape(r_e_m))


@dataclass(frozen=True)
class PerturbedField:
    """A field model with an injected error (see the module docstring for ``kind``)."""

    base: GeomagneticField
    kind: str
    level_pct: float
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def name(self) -> str:
        return f"{self.base.name}+{self.kind}{self.level_pct:g}%"

    def b_e_nT(self, r_e_m, decimal_year: float) -> np.ndarray:
        return self.base.b_e_nT(r_e_m, decimal_year) @ self.matrix.T


def field_model(name: str = "igrf", error_kind: str = "none", error_level_pct: float = 0.0,
                rng: np.random.Generator | None = None, nmax: int | None = None):
    """A named field model: ``name`` in {"igrf", "dipole"}, optionally with an injected error.

    ``rng`` draws the random parts of the error (tilt axis, per-component or per-coefficient
    factors); required for ``tilt``, ``component`` and ``gauss``.
    """
    if name not in ("igrf", "dipole"):
        raise InputError(f"unknown field model {name!r}; use 'igrf' or 'dipole'",
                         field="environment.field_model")
    deg = nmax if nmax is not None else (13 if name == "igrf" else 1)
    if not 1 <= deg <= 13:
        raise InputError(f"degree must be 1..13, got {deg}", field="environment.field_degree")
    if error_kind not in FIELD_ERROR_KINDS:
        raise InputError(f"unknown field-model error {error_kind!r}; use one of "
                         f"{list(FIELD_ERROR_KINDS)}", field="environment.field_error.kind")
    L = float(error_level_pct) / 100.0
    base = GeomagneticField(deg, name)
    if error_kind == "none" or L == 0.0:
        return base
    if error_kind != "scale" and rng is None:
        raise ValueError(f"field-model error {error_kind!r} needs a random generator")
    if error_kind == "scale":
        return PerturbedField(base, "scale", error_level_pct, (1.0 + L) * np.eye(3))
    if error_kind == "tilt":
        from gnomon.rotation import dcm_from_quat, quat_from_rotvec

        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        R = dcm_from_quat(quat_from_rotvec(np.arctan(L) * axis))
        return PerturbedField(base, "tilt", error_level_pct, R)
    if error_kind == "component":
        return PerturbedField(base, "component", error_level_pct,
                              np.diag(1.0 + L * rng.standard_normal(3)))
    zg = 1.0 + L * rng.standard_normal((deg + 1, deg + 1))
    zh = 1.0 + L * rng.standard_normal((deg + 1, deg + 1))
    return GeomagneticField(deg, f"{name}+gauss{error_level_pct:g}%",
                            coeff_transform=lambda g, h: (g * zg, h * zh))


def field_e_nT(model, epoch, t_s, r_e_m) -> np.ndarray:
    """Field (nT) in ECEF at ``r_e_m`` (m, (N, 3)) and times ``t_s`` (N,) s after ``epoch``.

    Coefficients are interpolated once per UTC day spanned by ``t_s``.
    """
    import datetime as dt

    ep = parse_epoch(epoch)
    t = np.asarray(t_s, float).reshape(-1)
    r = np.asarray(r_e_m, float).reshape(-1, 3)
    out = np.empty_like(r)
    day0 = dt.datetime(ep.year, ep.month, ep.day, tzinfo=dt.UTC)
    offset = (ep - day0).total_seconds()
    day = np.floor((t + offset) / 86400.0).astype(int)
    for d in np.unique(day):
        sel = day == d
        noon = day0 + dt.timedelta(days=int(d), hours=12)
        out[sel] = model.b_e_nT(r[sel], _decimal_year(noon))
    return out


def field_i_nT(model, epoch, t_s, r_i_m) -> np.ndarray:
    """Field (nT) in the inertial frame ``i`` at ``r_i_m`` (m, (N, 3)), times ``t_s`` (N,)."""
    jd, fr = julian_date(epoch, t_s)
    R_ei = dcm_ei(gmst_rad(jd, fr))
    r_e = np.einsum("nij,nj->ni", R_ei, np.asarray(r_i_m, float))
    b_e = field_e_nT(model, epoch, t_s, r_e)
    return np.einsum("nji,nj->ni", R_ei, b_e)
