"""Units and quaternion order found from the data, each with the evidence in a sentence.

Pure functions over arrays, used by :func:`gnomon.io.mapping.propose_map`; every one
returns ``(decision, sentence)`` so that what was decided and why can be printed and
written into a map.

* **time** (:func:`time_unit`): the median spacing of the raw stamps read as s, ms, µs or
  ns gives a sample rate; the unit whose rate is a usual IMU rate (10–2000 Hz, then
  1–20000 Hz) wins, a unit in the column's name breaks ties. MATLAB ``datenum`` (days,
  values near 7.3e5, or ``MATLABtime``/``datenum`` in the name) is read as days since
  the first sample (a double near 7.3e5 days resolves about 10 µs).
* **accelerometer** (:func:`accel_unit`): the median norm over the quietest fifth of the
  rows (the smallest gyro magnitudes) is the rest norm, ≈1 in g, ≈9.8 in m/s², ≈1000 in
  mg.
* **magnetometer** (:func:`mag_unit`): the median norm in each unit against the Earth's
  field range, 22–67 µT (its minimum and maximum at the surface, IGRF); the factors
  between the units are 10 or more and the range is 3x wide, so one unit fits at most.
* **gyro** (:func:`gyro_unit`): without a reference from the magnitudes (a 99th
  percentile above 6 is read as deg/s: 6 rad/s = 344 deg/s); with a reference from the
  scale :func:`rate_fit` finds between the gyro and the reference's rate (≈1 rad/s,
  ≈57.3 deg/s).
* **quaternion order** (:func:`quat_order`): wxyz against xyzw. The norm, the angle
  between successive rows and therefore the magnitude of the rate are the same for any
  order of the components (a permutation keeps dot products), so neither can decide.
  What does: the body rate of the reference computed in each order, fitted to the gyro
  by one constant rotation and scale (:func:`rate_fit`, Kabsch's SVD). Reading the
  components in the wrong cyclic order gives ``a ⊗ conj(q) ⊗ b`` for constant ``a``,
  ``b`` (the 4-cycle is an odd permutation of R⁴, so it is a rotation of R⁴ times the
  conjugation), whose body rate is the *world*-frame rate, turned: a constant rotation
  cannot match it to the gyro unless the body turns about one fixed axis only. Hence
  the order is decided when the better fit's residual is small and the other's at least
  twice it; with rotation about one axis only (the gyro's directions span a line) it is
  not, and the names decide.
"""

from __future__ import annotations

import math

import numpy as np

from gnomon.rotation import quat_conj, quat_mul, rotvec_from_quat

__all__ = ["TIME_TO_S", "GYRO_TO_RAD_S", "ACCEL_TO_M_S2", "MAG_TO_UT", "EARTH_FIELD_UT",
           "time_unit", "accel_unit", "mag_unit", "gyro_unit", "rate_fit", "quat_order",
           "body_rate", "unit_from_name"]

TIME_TO_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "datenum": 86400.0}
GYRO_TO_RAD_S = {"rad/s": 1.0, "deg/s": math.pi / 180.0}
ACCEL_TO_M_S2 = {"m/s^2": 1.0, "g": 9.80665, "mg": 9.80665e-3}
MAG_TO_UT = {"uT": 1.0, "nT": 1e-3, "mT": 1e3, "T": 1e6, "gauss": 100.0, "mG": 0.1}
#: the Earth's field magnitude at the surface, min and max (µT)
EARTH_FIELD_UT = (22.0, 67.0)

_NAME_UNITS = {  # unit spellings in column names (lower case) -> (quantity, unit)
    "s": ("time", "s"), "sec": ("time", "s"), "secs": ("time", "s"), "seconds": ("time", "s"),
    "ms": ("time", "ms"), "msec": ("time", "ms"), "us": ("time", "us"), "usec": ("time", "us"),
    "µs": ("time", "us"), "ns": ("time", "ns"), "nsec": ("time", "ns"),
    "rad/s": ("gyro", "rad/s"), "rad/sec": ("gyro", "rad/s"), "rads": ("gyro", "rad/s"),
    "rps": ("gyro", "rad/s"), "deg/s": ("gyro", "deg/s"), "°/s": ("gyro", "deg/s"),
    "dps": ("gyro", "deg/s"), "deg/sec": ("gyro", "deg/s"),
    "m/s^2": ("accel", "m/s^2"), "m/s2": ("accel", "m/s^2"), "m/s²": ("accel", "m/s^2"),
    "ms2": ("accel", "m/s^2"), "mps2": ("accel", "m/s^2"), "g": ("accel", "g"),
    "mg": ("accel", "mg"),
    "ut": ("mag", "uT"), "µt": ("mag", "uT"), "μt": ("mag", "uT"), "nt": ("mag", "nT"),
    "mt": ("mag", "mT"), "t": ("mag", "T"), "gauss": ("mag", "gauss"), "ga": ("mag", "gauss"),
    "mgauss": ("mag", "mG"), "milligauss": ("mag", "mG"),
}


def unit_from_name(quantity: str, *hints: str | None) -> str | None:
    """The unit of ``quantity`` (``time``, ``gyro``, ``accel``, ``mag``) that a column
    name's unit part (``"rad/s"`` of ``"Gyroscope X (rad/s)"``) or trailing token names,
    or None."""
    for h in hints:
        if not h:
            continue
        h = h.strip().lower()
        hit = _NAME_UNITS.get(h)
        if hit is None and "_" in h:
            hit = _NAME_UNITS.get(h.rsplit("_", 1)[-1])
        if hit is not None and hit[0] == quantity:
            return hit[1]
    return None


def _rate_text(hz: float) -> str:
    return f"{hz:.4g} Hz"


def time_unit(raw: np.ndarray, name: str = "", hint: str | None = None) -> tuple[str, str]:
    """The unit of raw time stamps (module docstring): ``s``/``ms``/``us``/``ns`` or
    ``datenum`` (days), and the evidence."""
    raw = np.asarray(raw, float)
    ok = raw[np.isfinite(raw)]
    dt = np.diff(ok)
    dt = dt[dt > 0]
    if dt.size == 0:
        return "s", "no increasing stamps: read as s"
    step = float(np.median(dt))
    low = name.lower().replace("_", "")
    if "datenum" in low or "matlabtime" in low or (6e5 < np.median(ok) < 8e5 and step < 1e-3):
        hz = 1.0 / (step * 86400.0)
        return "datenum", (f"values near {np.median(ok):.6g} with spacing {step:.3g}: MATLAB "
                           f"datenum days ({_rate_text(hz)}), read as s since the first")
    rates = {u: 1.0 / (step * TIME_TO_S[u]) for u in ("s", "ms", "us", "ns")}
    named = unit_from_name("time", hint)
    for lo, hi in ((10.0, 2000.0), (1.0, 20000.0)):
        fits = [u for u, hz in rates.items() if lo <= hz <= hi]
        if fits:
            unit = named if named in fits else fits[0]
            why = (f"median spacing {step:.6g} (raw): {_rate_text(rates[unit])} in {unit}"
                   + (f", the unit in its name ({hint})" if named == unit else "")
                   + ("" if len(fits) == 1 else
                      f" (also plausible: {', '.join(u for u in fits if u != unit)})"))
            return unit, why
    unit = named or "s"
    return unit, (f"median spacing {step:.6g} (raw) gives no usual sample rate in any unit; "
                  f"read as {unit}")


def accel_unit(acc: np.ndarray, gyro: np.ndarray | None = None,
               hint: str | None = None) -> tuple[str, str]:
    """``m/s^2``, ``g`` or ``mg`` from the rest norm (module docstring), with the evidence."""
    norm = np.linalg.norm(np.asarray(acc, float), axis=1)
    ok = np.isfinite(norm)
    quiet = ok
    if gyro is not None:
        w = np.linalg.norm(np.asarray(gyro, float), axis=1)
        if np.isfinite(w[ok]).any():
            quiet = ok & (w <= np.nanpercentile(w[ok], 20))
    rest = float(np.median(norm[quiet])) if quiet.any() else math.nan
    named = unit_from_name("accel", hint)
    if named and 2.0 < rest * ACCEL_TO_M_S2[named] < 50.0:
        return named, (f"rest norm {rest:.4g}: {rest * ACCEL_TO_M_S2[named]:.3g} m/s^2 in "
                       f"{named}, the unit in its name")
    g = 9.80665
    best = min(ACCEL_TO_M_S2, key=lambda u: abs(math.log(max(rest, 1e-12) *
                                                         ACCEL_TO_M_S2[u] / g)))
    value = rest * ACCEL_TO_M_S2[best]
    sure = 0.5 * g < value < 2.0 * g
    return best, (f"rest norm {rest:.4g} (median over the quietest fifth of the rows): "
                  f"{value:.3g} m/s^2 in {best}"
                  + ("" if sure else ", far from 1 g in every unit: check it"))


def mag_unit(mag: np.ndarray, hint: str | None = None) -> tuple[str, str]:
    """The magnetometer's unit from its norm against the Earth's field range (module
    docstring), with the evidence."""
    norm = np.linalg.norm(np.asarray(mag, float), axis=1)
    m = float(np.median(norm[np.isfinite(norm)])) if np.isfinite(norm).any() else math.nan
    lo, hi = EARTH_FIELD_UT
    named = unit_from_name("mag", hint)
    if named and 10.0 < m * MAG_TO_UT[named] < 700.0:
        return named, (f"median norm {m:.4g}: {m * MAG_TO_UT[named]:.3g} uT in {named}, the "
                       f"unit in its name (Earth's field {lo:g}-{hi:g} uT)")
    fits = [u for u, f in MAG_TO_UT.items() if lo <= m * f <= hi]
    if fits:
        u = fits[0]
        return u, (f"median norm {m:.4g}: {m * MAG_TO_UT[u]:.3g} uT in {u}, within the "
                   f"Earth's field range {lo:g}-{hi:g} uT")
    mid = math.sqrt(lo * hi)
    u = min(MAG_TO_UT, key=lambda k: abs(math.log(max(m, 1e-30) * MAG_TO_UT[k] / mid)))
    return u, (f"median norm {m:.4g}: no unit puts it within the Earth's field range "
               f"{lo:g}-{hi:g} uT (hard iron, or not a magnetometer?); nearest: "
               f"{m * MAG_TO_UT[u]:.3g} uT in {u}")


def gyro_unit(gyro: np.ndarray, hint: str | None = None,
              scale: float | None = None) -> tuple[str, str]:
    """``rad/s`` or ``deg/s``: from ``scale`` (the gyro over the reference's rate in rad/s,
    :func:`rate_fit`) when given and close to 1 or 180/π, else from the name, else from the
    99th percentile of the magnitude (module docstring)."""
    w = np.linalg.norm(np.asarray(gyro, float), axis=1)
    p99 = float(np.nanpercentile(w, 99)) if np.isfinite(w).any() else math.nan
    if scale is not None and np.isfinite(scale) and scale > 0:
        for unit, f in GYRO_TO_RAD_S.items():
            if abs(math.log(scale * f)) < math.log(1.25):
                return unit, (f"the gyro is {scale:.4g} x the reference's rate in rad/s: "
                              f"{unit}")
    named = unit_from_name("gyro", hint)
    if named:
        return named, f"the unit in its name ({hint}); 99th percentile of |w| {p99:.4g}"
    if p99 > 6.0:
        return "deg/s", (f"99th percentile of |w| {p99:.4g}: too fast for rad/s "
                         f"({math.degrees(p99):.0f} deg/s), read as deg/s")
    return "rad/s", (f"99th percentile of |w| {p99:.4g}: read as rad/s "
                     f"({math.degrees(p99):.0f} deg/s; in deg/s it would be a slow motion)")


def body_rate(t_s: np.ndarray, q: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The body rate of a quaternion series ``q`` (N, 4) ``[w, x, y, z]`` over intervals of
    ``stride`` rows: ``rotvec(conj(q_k) ⊗ q_{k+stride}) / (t_{k+stride} - t_k)`` (rad/s, in
    the axes of ``q_k``'s second frame), sign-safe; rows k = 0, stride, 2 stride, ...
    Returns (the start rows (M,), the rates (M, 3); NaN where either end is NaN)."""
    k = np.arange(0, q.shape[0] - stride, stride)
    ok = np.isfinite(q).all(axis=1)
    q = np.where(ok[:, None], q, np.array([1.0, 0.0, 0.0, 0.0]))  # NaN rows: out below
    d = quat_mul(quat_conj(q[k]), q[k + stride])
    d = d * np.where(d[:, :1] < 0, -1.0, 1.0)
    w = rotvec_from_quat(d) / (t_s[k + stride] - t_s[k])[:, None]
    w[~(ok[k] & ok[k + stride])] = np.nan
    return k, w


def rate_fit(w_ref: np.ndarray, w_gyro: np.ndarray) -> dict:
    """The rotation ``R`` and scale ``s`` that make ``s R w_ref`` closest to ``w_gyro`` (both
    (M, 3), finite rows), by Kabsch's SVD of ``sum w_ref w_gyroᵀ``: ``{"R", "scale",
    "residual"`` (RMS of ``w_gyro - s R w_ref`` over RMS of ``w_gyro``), ``"angle_deg"``
    (of ``R``), ``"planarity"`` (the gyro directions' second singular value over the
    first: 0 when the body turns about one axis only)}``."""
    a, b = np.asarray(w_ref, float), np.asarray(w_gyro, float)
    h = a.T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    ra = a @ r.T
    den = float(np.sum(ra * ra))
    s = float(np.sum(ra * b) / den) if den > 0 else math.nan
    res = math.sqrt(float(np.sum((b - s * ra) ** 2)) / max(float(np.sum(b * b)), 1e-300))
    sv = np.linalg.svd(b, compute_uv=False)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))))
    return {"R": r, "scale": s, "residual": res, "angle_deg": angle,
            "planarity": float(sv[1] / sv[0]) if sv[0] > 0 else 0.0}


def _windows(t_s, gyro, window_s: float):
    """The stride (rows) of about ``window_s`` and the gyro averaged over each interval."""
    dt = np.median(np.diff(t_s))
    stride = max(1, int(round(window_s / dt)))
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(np.nan_to_num(gyro), axis=0)])
    k = np.arange(0, t_s.size - stride, stride)
    g = (c[k + stride] - c[k]) / stride
    return stride, k, g


def quat_order(q_raw: np.ndarray, t_s: np.ndarray, gyro: np.ndarray | None,
               valid: np.ndarray | None = None, window_s: float = 0.05,
               max_lag_s: float = 0.2) -> tuple[str | None, dict, str]:
    """``"wxyz"`` or ``"xyzw"`` for the components of ``q_raw`` (N, 4) as stored, from the
    fit of each order's body rate to the gyro (module docstring; the gyro in any unit,
    rows ``valid`` only, the reference shifted by up to ``max_lag_s`` for the best fit);
    None when the data cannot tell. Returns (order, the fits ``{"wxyz": {...}, "xyzw":
    {...}}`` of :func:`rate_fit` plus ``"lag_s"``, the evidence)."""
    q_raw = np.asarray(q_raw, float)
    norm = np.linalg.norm(q_raw, axis=1)
    ok = np.isfinite(norm) & (np.abs(norm - 1.0) < 0.1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    facts = []
    if ok.any():
        facts.append(f"norm {np.median(norm[ok]):.6f} (median of {int(ok.sum())} rows)")
        pos = [j for j in range(4) if np.all(q_raw[ok, j] >= -1e-9)]
        flips = int(np.sum(np.einsum("ij,ij->i", q_raw[:-1], q_raw[1:])[ok[:-1] & ok[1:]] < 0))
        facts.append(f"{flips} sign flips between rows")
        if len(pos) == 1:
            facts.append(f"component {pos[0] + 1} never negative")
    if gyro is None or ok.sum() < 20:
        return None, {}, "; ".join(facts + ["no gyro to compare the rate with"])
    qn = np.where(ok[:, None], q_raw / np.where(ok, norm, 1.0)[:, None], np.nan)
    stride, k, g = _windows(t_s, gyro, window_s)
    fits = {}
    shifts = range(-int(round(max_lag_s / window_s)), int(round(max_lag_s / window_s)) + 1)
    for order, perm in (("wxyz", [0, 1, 2, 3]), ("xyzw", [3, 0, 1, 2])):
        kq, w = body_rate(t_s, qn[:, perm], stride)
        best = None
        for s in shifts:  # window j of the reference against window j + s of the gyro
            lo, hi = max(0, -s), min(len(kq), len(g) - s)
            if hi - lo < 10:
                continue
            a, b = w[lo:hi], g[lo + s:hi + s]
            keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
            if keep.sum() < 10:
                continue
            f = rate_fit(a[keep], b[keep])
            if best is None or f["residual"] < best["residual"]:
                best = {**f, "lag_s": -s * stride * float(np.median(np.diff(t_s)))}
        if best is not None:
            fits[order] = best
    if len(fits) < 2:
        return None, fits, "; ".join(facts + ["too few valid rows to fit the rate"])
    a, b = fits["wxyz"], fits["xyzw"]
    line = (f"rate fit to the gyro: wxyz residual {a['residual']:.3f} (rotation "
            f"{a['angle_deg']:.1f} deg, scale {a['scale']:.4g}), xyzw residual "
            f"{b['residual']:.3f} (rotation {b['angle_deg']:.1f} deg, scale {b['scale']:.4g})")
    facts.append(line)
    planar = a["planarity"]
    lo, hi = sorted((a["residual"], b["residual"]))
    if planar < 0.05:
        facts.append(f"the body turns about one axis only (planarity {planar:.3f}): the rate "
                     "cannot tell the order")
        return None, fits, "; ".join(facts)
    if lo < 0.35 and hi > 2.0 * lo + 0.05:
        order = "wxyz" if a["residual"] < b["residual"] else "xyzw"
        return order, fits, "; ".join(facts + [f"order {order} from the data"])
    facts.append("neither order fits the gyro clearly")
    return None, fits, "; ".join(facts)
