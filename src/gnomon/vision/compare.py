"""Shift estimators compared on the same frames (seed 003): the strip SSD (integer and
parabolic sub-pixel) against OpenCV's ``phaseCorrelate`` and ``findTransformECC``.

Frames with an *exact* vertical translation: a view rendered with the principal point
moved by ``s`` rows is the same view translated by exactly ``s`` pixels (every pixel is
ray-cast independently), so the true shift needs no resampling of a resampled image.
OpenCV is optional (``pip install opencv-python-headless``); methods that need it are
reported as unavailable when it is missing.
"""

from __future__ import annotations

import time

import numpy as np

from gnomon.vision.camera import PinholeCamera
from gnomon.vision.render import render_view
from gnomon.vision.strip import match_shift

__all__ = ["shifted_pair", "ssd_strip_shift", "phase_correlation_shift", "ecc_shift",
           "compare_methods", "have_opencv"]


def have_opencv() -> bool:
    """True if ``cv2`` can be imported."""
    try:
        import cv2  # noqa: F401
    except ImportError:
        return False
    return True


def shifted_pair(scene, camera: PinholeCamera, R_nb, shift_px: float, noise_std: float = 0.0,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(ref, cur)`` images where ``cur`` is ``ref`` translated down by ``shift_px`` rows."""
    ref = render_view(scene, camera, R_nb, noise_std, seed)
    cam2 = camera.with_principal_point(camera.cx, camera.cy + shift_px)
    cur = render_view(scene, cam2, R_nb, noise_std, seed + 1)
    return ref, cur


def ssd_strip_shift(ref: np.ndarray, cur: np.ndarray, strip_px: int = 11, max_shift: int = 30,
                    subpixel: bool = True) -> float:
    """Vertical shift (px, positive = ``cur`` content lower) from the centre-column strip SSD."""
    H, W = ref.shape
    c0 = (W - strip_px) // 2
    h = ref[max_shift:H - max_shift, c0:c0 + strip_px]
    y = cur[:, c0:c0 + strip_px]
    return match_shift(h, y, max_shift, subpixel=subpixel).shift


def _filled(img, dtype):
    """Contiguous copy with NaN (outside a warped photo) replaced by the image mean."""
    a = np.asarray(img, dtype=float)
    if not np.all(np.isfinite(a)):
        a = np.where(np.isfinite(a), a, np.nanmean(a))
    return np.ascontiguousarray(a, dtype=dtype)


def phase_correlation_shift(ref: np.ndarray, cur: np.ndarray, window: np.ndarray | None = None):
    """Vertical shift (px) from ``cv2.phaseCorrelate`` on the full images (Hann window)."""
    import cv2

    a = _filled(ref, np.float64)
    b = _filled(cur, np.float64)
    (dx, dy), _ = cv2.phaseCorrelate(a, b, window)
    return float(dy)


def ecc_shift(ref: np.ndarray, cur: np.ndarray, iterations: int = 50, eps: float = 1e-5):
    """Vertical shift (px) from ``cv2.findTransformECC`` (translation model, full images)."""
    import cv2

    a = _filled(ref, np.float32)
    b = _filled(cur, np.float32)
    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, eps)
    _, warp = cv2.findTransformECC(a, b, warp, cv2.MOTION_TRANSLATION, crit, None, 1)
    return float(warp[1, 2])


def _timed(fn, *args, repeat: int = 1):
    t0 = time.perf_counter()
    for _ in range(repeat):
        out = fn(*args)
    return out, (time.perf_counter() - t0) / repeat


def compare_methods(scene, camera: PinholeCamera, R_nb, n_trials: int = 20,
                    max_shift_px: float = 20.0, strip_px: int = 11, noise_std: float = 0.004,
                    rng: np.random.Generator | None = None, repeat: int = 3) -> dict:
    """RMSE of the vertical shift (px) and mean time per estimate (µs) for each method.

    Returns ``{"ssd": {...}, "ssd_subpixel": {...}, "phase_correlation": {...}, "ecc": {...}}``
    with ``rmse_px``, ``time_us``, ``max_abs_error_px`` and ``n`` (``available: False`` and
    NaNs for the OpenCV methods when OpenCV is missing).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    shifts = rng.uniform(-max_shift_px, max_shift_px, n_trials)
    M = int(np.ceil(max_shift_px)) + 2
    cv = have_opencv()
    win = None
    if cv:
        import cv2

        win = cv2.createHanningWindow((camera.width, camera.height), cv2.CV_64F)
    methods = {
        "ssd": lambda a, b: ssd_strip_shift(a, b, strip_px, M, subpixel=False),
        "ssd_subpixel": lambda a, b: ssd_strip_shift(a, b, strip_px, M, subpixel=True),
        "phase_correlation": (lambda a, b: phase_correlation_shift(a, b, win)) if cv else None,
        "ecc": ecc_shift if cv else None,
    }
    errs = {k: [] for k in methods}
    times = {k: [] for k in methods}
    for i, s in enumerate(shifts):
        ref, cur = shifted_pair(scene, camera, R_nb, float(s), noise_std, seed=2 * i)
        for k, fn in methods.items():
            if fn is None:
                continue
            try:
                est, dt = _timed(fn, ref, cur, repeat=repeat)
            except Exception:  # an OpenCV failure (e.g. ECC not converging) counts as a miss
                est, dt = np.nan, np.nan
            errs[k].append(est - s)
            times[k].append(dt)
    out = {}
    for k in methods:
        e = np.asarray(errs[k], dtype=float)
        if e.size == 0:
            out[k] = {"rmse_px": float("nan"), "time_us": float("nan"), "available": False}
            continue
        out[k] = {
            "rmse_px": float(np.sqrt(np.nanmean(e ** 2))),
            "max_abs_error_px": float(np.nanmax(np.abs(e))),
            "time_us": float(1e6 * np.nanmean(times[k])),
            "n": int(np.sum(np.isfinite(e))),
            "available": True,
        }
    return out
