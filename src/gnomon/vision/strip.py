"""The strip matcher of seed 003: one-parameter SSD shift search on de-rotated strips.

Paper (seed 003, "Method for determining the orientation of an aerial vehicle from an
optical camera and a triad of angular-rate sensors"): de-rotate the current image by the
SINS roll, shift it by the SINS yaw, cut a vertical strip of ``w`` pixels, and find the
vertical shift ``s`` minimising ``J(s) = Σ (h(i) − y_s(i))²`` against the same strip of a
reference image taken at the start of the flight; pitch from ``s``. The same on a
horizontal strip gives yaw; the project adds a roll search on a ring around the
principal point, parabolic sub-pixel refinement of ``J`` and a confidence gate from the
shape of ``J``.

Geometry (frames as in :mod:`gnomon.vision.camera`; ``R_nb = Rz(ψ) Ry(θ) Rx(φ)``). All
strips are sampled along *rays*, so the de-rotation is exact rather than an image warp:

* vertical strip, resampled in angle (``conversion="resampled"``): body rays
  ``g(k, j) = Ry(α_k) Rz(β_j) e_x``, ``α_k = −k·dα`` (elevation above the boresight,
  ``k`` grows downwards like image rows), ``β_j`` the strip's column angles around the
  principal-point column. The reference strip is seen along ``Rx(−φ0) g`` (reference
  de-rolled) and the current strip along ``C g`` with
  ``C = Rx(−φ̂) Ry(−θ̂) Rz(ψ0 − ψ̂) Ry(θ̂)`` — de-roll by the SINS roll, and undo the
  yaw difference (about the vertical; ``θ̂ → 0`` gives the paper's horizontal shift by
  ``f·tan(ψ̂ − ψ0)``). With the true roll and yaw, world rays of the current strip are
  ``Rz(ψ0) Ry(θ + α) Rz(β) e_x`` and of the reference ``Rz(ψ0) Ry(θ0 + α) Rz(β) e_x``:
  a pure shift by ``θ − θ0``, exactly, at every row and every column of the strip
  (``θ̂`` enters only through the yaw term, and a second pass with the visual pitch
  removes that, see ``iterations``).
* vertical strip in pixels (``"atan"``, ``"linear"``): rays through the pixel rows of
  the principal-point column; a pitch change is then not a pure shift (perspective), and
  ``θ − θ0 = atan(s/f)`` or the paper's ``s·VFOV/rows`` carry scale errors that grow with
  the reference's and the current pitch.
* horizontal strip (yaw): world rays ``Rz(ψ + β_j) Ry(θ0 + α_k) e_x`` (a band at the
  reference boresight's elevation) — a yaw change is an exact shift in ``β``.
* ring (roll): body rays ``Rx(ρ_m) [cos κ, 0, −sin κ]`` on a circle of radius ``κ``
  around the optical axis — roll is an exact circular shift in ``ρ``; the reference ring
  is the reference image seen along the current (visual) pitch and yaw.

Sign of the shift: ``J(s) = mean_i (h_i − y_{i+s})²`` over valid pairs, where ``h`` is
the reference strip and ``y`` the current strip extended by ``max_shift`` samples on both
sides; positive ``s`` = the current content appears ``s`` samples further along the
strip's axis (down for the vertical strip).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError
from gnomon.vision.camera import PinholeCamera, rot_x, rot_y, rot_z

__all__ = [
    "ShiftResult",
    "ssd_curve",
    "parabolic_offset",
    "match_shift",
    "detail_residual",
    "StripMatcher",
    "CONVERSIONS",
]

CONVERSIONS = ("resampled", "atan", "linear")


@dataclass
class ShiftResult:
    """Outcome of a one-parameter shift search.

    ``shift``: best shift in samples (sub-sample if refined; NaN if no valid overlap);
    ``cost``: ``J(s)`` for ``s = -M..M``; ``residual``: ``J_min / (2 var(h))`` (0 = perfect
    match, ~1 = unrelated signals); ``distinct``: ``J_min / J_2nd`` with ``J_2nd`` the
    lowest local minimum more than 2 samples away (small = unambiguous);
    ``detail``: the same normalised residual for the strips' differences along the
    strip axis at the best integer shift (the fine texture: a strip that matches only the
    coarse sky/ground profile — the typical failure — has ``detail`` near 1);
    ``confidence`` in [0, 1]; ``ok``: passes the gate.
    """

    shift: float
    shift_int: int
    cost: np.ndarray = field(repr=False)
    residual: float
    distinct: float
    confidence: float
    ok: bool
    valid_fraction: float
    detail: float = np.nan


def ssd_curve(ref: np.ndarray, cur: np.ndarray, max_shift: int,
              min_valid: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """``J(s) = mean (h_i − y_{i+s})²`` for ``s = -M..M`` over pairs where both are finite.

    ``ref``: shape ``(N, w)`` (strip axis first); ``cur``: ``(N + 2M, w)``, its sample
    ``i + M`` aligned with ``ref[i]`` at zero shift. Returns ``(J, valid_fraction)``;
    ``J`` is NaN where fewer than ``min_valid`` of the reference's samples overlap.
    """
    ref = np.asarray(ref, dtype=float)
    cur = np.asarray(cur, dtype=float)
    if ref.ndim == 1:
        ref = ref[:, None]
    if cur.ndim == 1:
        cur = cur[:, None]
    N, M = ref.shape[0], int(max_shift)
    if cur.shape != (N + 2 * M, ref.shape[1]):
        raise ValueError(f"cur: expected shape {(N + 2 * M, ref.shape[1])}, got {cur.shape}")
    mh = np.isfinite(ref)
    my = np.isfinite(cur)
    if mh.all() and my.all():
        # fast path: J = Σh² − 2 Σ h·y_s + Σ y_s² (one correlation per strip column)
        cross = np.zeros(2 * M + 1)
        for c in range(ref.shape[1]):
            cross += np.correlate(cur[:, c], ref[:, c], mode="valid")
        cs = np.concatenate([[0.0], np.cumsum((cur * cur).sum(axis=1))])
        yy = cs[N:] - cs[:-N]
        n = float(ref.size)
        return (float((ref * ref).sum()) - 2.0 * cross + yy) / n, np.ones(2 * M + 1)
    h = np.where(mh, ref, 0.0)
    y = np.where(my, cur, 0.0)
    Y = np.lib.stride_tricks.sliding_window_view(y, N, axis=0)  # (2M+1, w, N)
    MY = np.lib.stride_tricks.sliding_window_view(my, N, axis=0)
    hT, mhT = h.T[None], mh.T[None]
    m = MY & mhT
    d = np.where(m, hT - Y, 0.0)
    num = np.einsum("swn,swn->s", d, d)
    cnt = m.sum(axis=(1, 2)).astype(float)
    frac = cnt / max(mh.sum(), 1)
    J = np.where(frac >= min_valid, num / np.maximum(cnt, 1.0), np.nan)
    return J, frac


def parabolic_offset(jm: float, j0: float, jp: float) -> float:
    """Vertex of the parabola through ``(-1, jm), (0, j0), (1, jp)``, clipped to ``[-0.5, 0.5]``."""
    den = jm - 2.0 * j0 + jp
    if not np.isfinite(den) or den <= 0.0:
        return 0.0
    return float(np.clip(0.5 * (jm - jp) / den, -0.5, 0.5))


def detail_residual(ref: np.ndarray, cur: np.ndarray, max_shift: int, s_int: int) -> float:
    """Normalised residual of the strips' first differences along the strip at shift ``s_int``.

    ``mean (Δh − Δy)² / (2 var Δh)``: ~0 for a true match (up to noise), ~1 for unrelated
    fine texture.
    """
    ref = np.asarray(ref, dtype=float).reshape(len(ref), -1)
    cur = np.asarray(cur, dtype=float).reshape(len(cur), -1)
    N, M = ref.shape[0], int(max_shift)
    y = cur[M + s_int:M + s_int + N]
    dh, dy = np.diff(ref, axis=0), np.diff(y, axis=0)
    m = np.isfinite(dh) & np.isfinite(dy)
    if m.sum() < 8:
        return np.inf
    var = float(np.var(dh[m]))
    if var <= 0:
        return np.inf
    return float(np.mean((dh[m] - dy[m]) ** 2) / (2.0 * var))


def match_shift(ref: np.ndarray, cur: np.ndarray, max_shift: int, subpixel: bool = True,
                max_residual: float = 0.25, max_distinct: float = 0.7,
                max_detail: float = 0.5, min_valid: float = 0.5) -> ShiftResult:
    """Best shift of ``cur`` against ``ref`` (see :func:`ssd_curve`) with a confidence gate.

    Integer search over ``-M..M``, then (``subpixel``) the parabola through the minimum and
    its neighbours. The gate rejects matches whose minimum is on the search boundary,
    whose normalised residual exceeds ``max_residual`` or whose minimum is not clearly
    below the next-best local minimum (``distinct > max_distinct``) or whose fine
    texture does not match (``detail > max_detail``, see :func:`detail_residual`).
    """
    J, frac = ssd_curve(ref, cur, max_shift, min_valid)
    M = int(max_shift)
    if not np.any(np.isfinite(J)):
        return ShiftResult(np.nan, 0, J, np.inf, 1.0, 0.0, False, 0.0, np.inf)
    i = int(np.nanargmin(J))
    s_int = i - M
    j0 = J[i]
    off = 0.0
    interior = 0 < i < 2 * M and np.isfinite(J[i - 1]) and np.isfinite(J[i + 1])
    if subpixel and interior:
        off = parabolic_offset(J[i - 1], j0, J[i + 1])
    href = np.asarray(ref, dtype=float)
    fin = np.isfinite(href)
    var = float(href.var()) if fin.all() else (float(np.var(href[fin])) if fin.any() else 0.0)
    residual = float(j0 / (2.0 * var)) if var > 0 else np.inf
    # lowest local minimum more than 2 samples away from the best one
    Jf = np.where(np.isfinite(J), J, np.inf)
    Jp = np.concatenate([[np.inf], Jf, [np.inf]])
    loc = (Jf <= Jp[:-2]) & (Jf <= Jp[2:]) & np.isfinite(Jf)
    loc[max(i - 2, 0):i + 3] = False
    j2 = float(Jf[loc].min()) if loc.any() else np.inf
    distinct = float(j0 / j2) if j2 > 0 and np.isfinite(j2) else 0.0
    detail = detail_residual(ref, cur, M, s_int)
    conf = float(np.clip((1.0 - residual / max(max_residual, 1e-12)), 0.0, 1.0)
                 * np.clip(1.0 - distinct, 0.0, 1.0)
                 * np.clip(1.0 - detail / max(max_detail, 1e-12), 0.0, 1.0))
    ok = bool(interior and residual <= max_residual and distinct <= max_distinct
              and detail <= max_detail)
    return ShiftResult(float(s_int + off), s_int, J, residual, distinct, conf, ok,
                       float(frac[i]), detail)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class StripMatcher:
    """Pitch, yaw and roll from one-parameter strip searches against a reference frame.

    Parameters
    ----------
    reference : frame with ``camera`` and ``sample(u, v)`` (a :mod:`render` frame)
    rpy_ref : ``[roll, pitch, yaw]`` (rad) of the reference frame (from the SINS at the
        start of the flight, when its errors are still small)
    strip_px : strip width ``w`` in pixels (vertical strip columns, horizontal strip rows)
    max_shift_deg : search range of each one-parameter search, ± deg
    strip_len_frac : length of the reference strips as a fraction of the image height
        (vertical) or width (horizontal)
    ring_radius_frac : radius of the roll ring as a fraction of ``min(cx, cy)``
    gate : keyword arguments for :func:`match_shift` (residual / distinctness limits)
    column_offset_px : the vertical strip's column relative to the principal point (keep 0:
        off-centre, a residual roll error ``δφ`` becomes a pitch bias ``≈ x·δφ/f``)
    """

    def __init__(self, reference, rpy_ref, strip_px: int = 11, max_shift_deg: float = 10.0,
                 strip_len_frac: float = 0.85, ring_radius_frac: float = 0.55,
                 roll_max_shift_deg: float = 10.0, gate: dict | None = None,
                 column_offset_px: float = 0.0):
        if int(strip_px) < 1:
            raise InputError(f"strip width must be >= 1 px, got {strip_px}", field="strip_px")
        self.ref = reference
        self.cam: PinholeCamera = reference.camera
        self.rpy_ref = np.asarray(rpy_ref, dtype=float)
        self.w = int(strip_px)
        self.gate = dict(gate or {})
        cam = self.cam
        f = cam.f_px
        self.d_ang = float(np.arctan(1.0 / f))  # one pixel at the principal point
        self.M = int(np.ceil(np.radians(max_shift_deg) / self.d_ang))
        half_v = int(0.5 * strip_len_frac * cam.height)
        half_h = int(0.5 * strip_len_frac * cam.width)
        jw = np.arange(self.w) - 0.5 * (self.w - 1)
        self._jw = jw
        # vertical strip, angle grid: g = Ry(alpha) Rz(beta) e_x
        kv = np.arange(-half_v - self.M, half_v + self.M + 1)
        alpha = -kv * self.d_ang
        jv = jw + float(column_offset_px)  # vertical strip's columns relative to cx
        beta = np.arctan(jv / f)
        ca, sa = np.cos(alpha)[:, None], np.sin(alpha)[:, None]
        cb, sb = np.cos(beta)[None, :], np.sin(beta)[None, :]
        self._g_ang = np.stack(np.broadcast_arrays(ca * cb, sb + 0 * ca, -sa * cb), -1)
        # vertical strip, pixel grid: rays through rows v = cy + k of the centre columns
        self._g_pix = _unit(np.stack(np.broadcast_arrays(
            np.ones((kv.size, 1)), (jv / f)[None, :], (kv / f)[:, None]), -1))
        self._kv_core = slice(self.M, self.M + 2 * half_v + 1)
        # horizontal strip: world rays Rz(psi + beta) Ry(theta0 + alpha) e_x
        jh = np.arange(-half_h - self.M, half_h + self.M + 1)
        self._beta_h = jh * self.d_ang
        self._alpha_h = np.arctan(jw / f)
        self._kh_core = slice(self.M, self.M + 2 * half_h + 1)
        # ring for roll
        r0 = ring_radius_frac * min(cam.cx, cam.cy)
        self.n_ring = int(round(2 * np.pi * r0))
        self.d_rho = 2 * np.pi / self.n_ring
        self.Mr = int(np.ceil(np.radians(roll_max_shift_deg) / self.d_rho))
        self._kappa = np.arctan((r0 + jw) / f)
        # reference strips (fixed for the flight)
        phi0, th0, psi0 = self.rpy_ref
        self._R0 = rot_z(psi0) @ rot_y(th0) @ rot_x(phi0)
        self.ref_vert = {
            "resampled": self._sample(self.ref, self._g_ang[self._kv_core], rot_x(-phi0)),
            "pixel": self._sample(self.ref, self._g_pix[self._kv_core], rot_x(-phi0)),
        }
        self.ref_horiz = self._sample(self.ref, self._horiz_rays(psi0, th0)[self._kh_core],
                                      self._R0.T)

    # ---------------------------------------------------------------- sampling
    def _sample(self, frame, rays_b, R=None) -> np.ndarray:
        """Frame intensities along body rays ``R @ rays`` (``R`` None = identity)."""
        d = rays_b if R is None else rays_b @ np.asarray(R).T
        u, v, _ = self.cam.project(d)
        return frame.sample(u, v)

    def _horiz_rays(self, psi_c, theta_band):
        b = psi_c + self._beta_h[:, None]
        a = theta_band + self._alpha_h[None, :]
        return np.stack(np.broadcast_arrays(np.cos(a) * np.cos(b), np.cos(a) * np.sin(b),
                                            -np.sin(a)), -1)

    # ---------------------------------------------------------------- searches
    def pitch(self, frame, rpy_hat, conversion: str = "resampled", iterations: int = 2,
              subpixel: bool = True):
        """Visual pitch (rad) of ``frame`` given the SINS ``[roll, pitch, yaw]`` estimate.

        Returns ``(pitch_rad, ShiftResult)``; the SINS pitch is used only in the
        yaw-difference term, and replaced by the visual pitch on later ``iterations``.
        """
        if conversion not in CONVERSIONS:
            raise InputError(f"unknown pitch conversion {conversion!r}; known: {CONVERSIONS}",
                             field="conversion")
        phi, th, psi = (float(x) for x in rpy_hat)
        psi0, th0 = self.rpy_ref[2], self.rpy_ref[1]
        g = self._g_ang if conversion == "resampled" else self._g_pix
        ref = self.ref_vert["resampled" if conversion == "resampled" else "pixel"]
        res = None
        theta = th
        for _ in range(max(1, int(iterations))):
            C = rot_x(-phi) @ rot_y(-theta) @ rot_z(psi0 - psi) @ rot_y(theta)
            cur = self._sample(frame, g, C)
            res = match_shift(ref, cur, self.M, subpixel=subpixel, **self.gate)
            if not np.isfinite(res.shift):
                return np.nan, res
            s = res.shift
            if conversion == "resampled":
                dth = s * self.d_ang
            elif conversion == "atan":
                dth = float(np.arctan(s / self.cam.f_px))
            else:
                dth = s * self.cam.vfov_rad / self.cam.height
            theta = th0 + dth
        return float(theta), res

    def yaw(self, frame, rpy_hat, subpixel: bool = True):
        """Visual yaw (rad) from the horizontal strip, given ``[roll, pitch, yaw]`` estimates."""
        phi, th, psi = (float(x) for x in rpy_hat)
        R_hat = rot_z(psi) @ rot_y(th) @ rot_x(phi)
        rays_n = self._horiz_rays(psi, self.rpy_ref[1])
        cur = self._sample(frame, rays_n, R_hat.T)
        res = match_shift(self.ref_horiz, cur, self.M, subpixel=subpixel, **self.gate)
        if not np.isfinite(res.shift):
            return np.nan, res
        return float(self.rpy_ref[2] - res.shift * self.d_ang), res

    def _ring(self, rho):
        k = self._kappa[None, :]
        r = rho[:, None]
        ck, sk = np.cos(k), np.sin(k)
        return np.stack(np.broadcast_arrays(ck + 0 * r, sk * np.sin(r), -sk * np.cos(r)), -1)

    def roll(self, frame, rpy_hat, subpixel: bool = True):
        """Visual roll (rad) from a circular search on a ring around the principal point.

        Uses the (visual) pitch and yaw in ``rpy_hat`` to see the reference along the
        current boresight; the SINS roll centres the search.
        """
        phi, th, psi = (float(x) for x in rpy_hat)
        m = np.arange(self.n_ring)
        rho = m * self.d_rho
        ref_world = self._ring(rho) @ (rot_z(psi) @ rot_y(th)).T
        ref = self._sample(self.ref, ref_world, self._R0.T)
        mm = np.arange(-self.Mr, self.n_ring + self.Mr)
        cur = self._sample(frame, self._ring(mm * self.d_rho - phi))
        res = match_shift(ref, cur, self.Mr, subpixel=subpixel, **self.gate)
        if not np.isfinite(res.shift):
            return np.nan, res
        return float(phi - res.shift * self.d_rho), res
