"""Pinhole camera with intrinsics from the field of view (seed 003).

Frames: the camera frame is the body frame — x along the optical axis (forward),
y to the right (image column ``u`` grows), z down (image row ``v`` grows). A ray
``d = [x, y, z]`` (``x > 0``) projects to ``u = cx + f*y/x``, ``v = cy + f*z/x``
(square pixels, one focal length ``f`` in pixels). Pixel centres are at integer
``(u, v)``; the principal point of an undistorted ``W x H`` image is the image
centre ``((W-1)/2, (H-1)/2)``.

An optional lens-distortion hook maps normalised image coordinates
``(xn, yn) = (y/x, z/x)`` to distorted ones and back (``RadialDistortion``:
Brown's k1, k2 model with an iterative inverse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError

__all__ = ["PinholeCamera", "RadialDistortion", "rot_x", "rot_y", "rot_z", "rpy_dcm"]


def _rot(axis: int, a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    if axis == 0:
        m = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == 1:
        m = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        m = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.stack([np.stack(r, -1) for r in m], -2)


def rot_x(a) -> np.ndarray:
    """Elementary rotation matrix about x by ``a`` rad (active, right-handed), ``(..., 3, 3)``."""
    return _rot(0, a)


def rot_y(a) -> np.ndarray:
    """Elementary rotation matrix about y by ``a`` rad, ``(..., 3, 3)``."""
    return _rot(1, a)


def rot_z(a) -> np.ndarray:
    """Elementary rotation matrix about z by ``a`` rad, ``(..., 3, 3)``."""
    return _rot(2, a)


def rpy_dcm(roll, pitch, yaw) -> np.ndarray:
    """``R_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (z-y'-x'', as ``gnomon.rotation``)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


@dataclass(frozen=True)
class RadialDistortion:
    """Brown radial distortion ``x_d = x (1 + k1 r² + k2 r⁴)`` on normalised coordinates."""

    k1: float = 0.0
    k2: float = 0.0

    def distort(self, xn, yn):
        r2 = xn * xn + yn * yn
        g = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        return xn * g, yn * g

    def undistort(self, xd, yd, iterations: int = 30):
        xn, yn = np.array(xd, dtype=float), np.array(yd, dtype=float)
        for _ in range(iterations):
            r2 = xn * xn + yn * yn
            g = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
            xn, yn = xd / g, yd / g
        return xn, yn


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole camera: image ``width x height`` px, focal length ``f_px``, principal point.

    Build it from a field of view with :meth:`from_fov`. ``distortion`` is any object
    with ``distort(xn, yn)`` and ``undistort(xd, yd)`` (normalised coordinates), or None.
    """

    width: int
    height: int
    f_px: float
    cx: float
    cy: float
    distortion: object | None = None

    def __post_init__(self):
        if int(self.width) < 2 or int(self.height) < 2:
            raise InputError(f"camera size must be >= 2x2 px, got {self.width}x{self.height}",
                             field="width/height")
        if not (np.isfinite(self.f_px) and self.f_px > 0):
            raise InputError(f"focal length must be > 0 px, got {self.f_px}", field="f_px")

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_rad: float, distortion=None):
        """Square-pixel camera whose horizontal field of view (edge to edge) is ``hfov_rad``."""
        if not (0.0 < hfov_rad < np.pi):
            raise InputError(f"horizontal FOV must be in (0, pi) rad, got {hfov_rad}",
                             field="hfov_rad")
        f = 0.5 * width / np.tan(0.5 * hfov_rad)
        return cls(int(width), int(height), float(f), 0.5 * (width - 1), 0.5 * (height - 1),
                   distortion)

    @property
    def hfov_rad(self) -> float:
        """Horizontal field of view (edge to edge of the pixel array), rad."""
        return 2.0 * float(np.arctan(0.5 * self.width / self.f_px))

    @property
    def vfov_rad(self) -> float:
        """Vertical field of view (edge to edge), rad."""
        return 2.0 * float(np.arctan(0.5 * self.height / self.f_px))

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix for the body-aligned camera frame (maps ``[y, z, x]`` to pixels)."""
        return np.array([[self.f_px, 0.0, self.cx], [0.0, self.f_px, self.cy], [0.0, 0.0, 1.0]])

    def with_principal_point(self, cx: float, cy: float) -> PinholeCamera:
        """Same camera with another principal point (an exact image translation)."""
        return PinholeCamera(self.width, self.height, self.f_px, cx, cy, self.distortion)

    def project(self, d):
        """Pixel coordinates of rays ``d`` (camera/body frame, ``(..., 3)``).

        Returns ``(u, v, in_front)``; ``u, v`` are NaN for rays with ``x <= 0``.
        """
        d = np.asarray(d, dtype=float)
        x = d[..., 0]
        front = x > 1e-12
        xs = np.where(front, x, 1.0)
        xn, yn = d[..., 1] / xs, d[..., 2] / xs
        if self.distortion is not None:
            xn, yn = self.distortion.distort(xn, yn)
        u = np.where(front, self.cx + self.f_px * xn, np.nan)
        v = np.where(front, self.cy + self.f_px * yn, np.nan)
        return u, v, front

    def rays(self, u, v) -> np.ndarray:
        """Unit rays (camera/body frame, ``(..., 3)``) through pixel coordinates ``(u, v)``."""
        xn = (np.asarray(u, dtype=float) - self.cx) / self.f_px
        yn = (np.asarray(v, dtype=float) - self.cy) / self.f_px
        if self.distortion is not None:
            xn, yn = self.distortion.undistort(xn, yn)
        d = np.stack([np.ones_like(xn), xn, yn], -1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)
