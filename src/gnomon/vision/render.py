"""Images with exact attitude truth: views rendered from a real cube map, real aerial
photos warped by a camera rotation (seed 003).

A *scene* maps world rays to intensity: ``scene.radiance(r_n)`` with ``r_n`` unit
vectors in the navigation frame n (North-East-Down), shape ``(..., 3)``, returning
grayscale intensities (NaN where the scene is undefined). Because every scene is a
function of direction only, the views are those of a distant scene seen by a camera
that only rotates: a pure pitch of the camera is an exact shift of the image sampled
on an elevation grid — the truth is exact.

* :class:`CubeMapScene` — the six faces of a cube map (``meadow_cube.jpg``; OpenGL face
  order and orientation; world axes: GL ``+x`` = East, ``+y`` = Up, ``-z`` = North).
* :class:`PhotoScene` — a photograph taken by a pinhole camera at a known attitude;
  rendering it at another attitude is the homography ``K R K⁻¹`` (undefined outside the
  photo's field of view).
* :class:`HorizonScene` — an ideal azimuth-invariant horizon (intensity a function of
  elevation only), the best case for a vertical strip.

A *frame* is one camera image: :class:`SimulatedFrame` renders its pixel grid lazily
(only the pixels a matcher touches, with optional per-pixel noise that is a fixed
function of the pixel and frame seed) and interpolates bilinearly between pixel
centres, exactly as a matcher working on a stored image would; :class:`ArrayFrame`
wraps a stored image.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from gnomon.vision.camera import PinholeCamera

__all__ = [
    "CubeMapScene",
    "PhotoScene",
    "HorizonScene",
    "SimulatedFrame",
    "ArrayFrame",
    "render_view",
    "warp_homography",
    "bilinear",
]


class CubeMapScene:
    """Radiance from a cube map (faces ``(6, S, S)`` in OpenGL order +x, -x, +y, -y, +z, -z).

    World (navigation, NED) to GL axes: ``x_gl = East``, ``y_gl = Up``, ``z_gl = South``;
    ``heading_rad`` rotates the cube about the vertical (which azimuth is "North").
    Sampling is bilinear within a face (clamped at the face border, so the radiance is a
    fixed function of direction; seams are continuous to a texel).
    """

    def __init__(self, faces: np.ndarray, heading_rad: float = 0.0, name: str = "cube"):
        faces = np.asarray(faces, dtype=np.float32)
        if faces.ndim != 3 or faces.shape[0] != 6 or faces.shape[1] != faces.shape[2]:
            raise ValueError(f"faces: expected (6, S, S), got {faces.shape}")
        self.faces = faces
        self.size = faces.shape[1]
        self.heading_rad = float(heading_rad)
        self.name = name

    def radiance(self, r_n) -> np.ndarray:
        r = np.asarray(r_n, dtype=float)
        if self.heading_rad:
            c, s = np.cos(self.heading_rad), np.sin(self.heading_rad)
            rn, re = c * r[..., 0] - s * r[..., 1], s * r[..., 0] + c * r[..., 1]
        else:
            rn, re = r[..., 0], r[..., 1]
        gx, gy, gz = re, -r[..., 2], -rn
        ax, ay, az = np.abs(gx), np.abs(gy), np.abs(gz)
        xmaj = (ax >= ay) & (ax >= az)
        ymaj = ~xmaj & (ay >= az)
        zmaj = ~xmaj & ~ymaj
        face = np.zeros(gx.shape, dtype=float)
        sc = np.zeros(gx.shape)
        tc = np.zeros(gx.shape)
        ma = np.ones(gx.shape)
        # OpenGL table (major axis -> face, sc, tc)
        m = xmaj & (gx > 0)
        face[m], sc[m], tc[m], ma[m] = 0, -gz[m], -gy[m], ax[m]
        m = xmaj & (gx <= 0)
        face[m], sc[m], tc[m], ma[m] = 1, gz[m], -gy[m], ax[m]
        m = ymaj & (gy > 0)
        face[m], sc[m], tc[m], ma[m] = 2, gx[m], gz[m], ay[m]
        m = ymaj & (gy <= 0)
        face[m], sc[m], tc[m], ma[m] = 3, gx[m], -gz[m], ay[m]
        m = zmaj & (gz > 0)
        face[m], sc[m], tc[m], ma[m] = 4, gx[m], -gy[m], az[m]
        m = zmaj & (gz <= 0)
        face[m], sc[m], tc[m], ma[m] = 5, -gx[m], -gy[m], az[m]
        S = self.size
        col = np.clip(0.5 * (sc / ma + 1.0) * S - 0.5, 0.0, S - 1.0)
        row = np.clip(0.5 * (tc / ma + 1.0) * S - 0.5, 0.0, S - 1.0)
        out = ndimage.map_coordinates(self.faces, [face.ravel(), row.ravel(), col.ravel()],
                                      order=1, mode="nearest", prefilter=False)
        return out.reshape(gx.shape).astype(float)


class PhotoScene:
    """A photograph ``image`` taken by ``camera`` with attitude ``R_n_cam`` (nav from camera).

    Radiance outside the photo's field of view is NaN. Rendering this scene with
    another attitude ``R_nb`` is the rotation homography ``K R_cb K⁻¹``.
    """

    def __init__(self, image: np.ndarray, camera: PinholeCamera, R_n_cam=None,
                 name: str = "photo"):
        self.image = np.asarray(image, dtype=np.float32)
        if self.image.shape != (camera.height, camera.width):
            raise ValueError(f"image: shape {self.image.shape} does not match camera "
                             f"{camera.height}x{camera.width}")
        self.camera = camera
        self.R_n_cam = np.eye(3) if R_n_cam is None else np.asarray(R_n_cam, dtype=float)
        self.name = name

    def radiance(self, r_n) -> np.ndarray:
        d = np.asarray(r_n, dtype=float) @ self.R_n_cam  # = R^T r per row
        u, v, _ = self.camera.project(d)
        return bilinear(self.image, u, v)


class HorizonScene:
    """Ideal azimuth-invariant horizon: intensity is a function of elevation only.

    Sky brighter than ground, a soft horizon edge and a few elevation bands of texture
    (deterministic), so a vertical strip always matches and yaw is unobservable.
    """

    def __init__(self, name: str = "horizon"):
        self.name = name

    def radiance(self, r_n) -> np.ndarray:
        r = np.asarray(r_n, dtype=float)
        e = np.arcsin(np.clip(-r[..., 2], -1.0, 1.0))  # elevation, rad (up positive)
        base = 0.45 + 0.25 * np.tanh(e / 0.01)
        tex = (0.06 * np.sin(e * 97.0) + 0.04 * np.sin(e * 233.0 + 1.0)
               + 0.03 * np.sin(e * 411.0 + 2.0))
        return base + np.where(e < 0, tex, 0.3 * tex)


_EDGE_TOL = 1e-6  # px: pixel centres on the border survive a round trip through rays


def _inside(u, v, W, H):
    t = _EDGE_TOL
    return (np.isfinite(u) & np.isfinite(v) & (u >= -t) & (u <= W - 1 + t)
            & (v >= -t) & (v <= H - 1 + t))


def bilinear(image: np.ndarray, u, v) -> np.ndarray:
    """Bilinear interpolation of ``image[row, col]`` at ``(col=u, row=v)``; NaN outside."""
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    H, W = image.shape
    ok = _inside(u, v, W, H)
    uu = np.clip(np.where(ok, u, 0.0), 0.0, W - 1.0)
    vv = np.clip(np.where(ok, v, 0.0), 0.0, H - 1.0)
    out = ndimage.map_coordinates(image, [vv.ravel(), uu.ravel()], order=1, mode="nearest",
                                  prefilter=False).reshape(u.shape).astype(float)
    return np.where(ok, out, np.nan)


_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_G = np.uint64(0x9E3779B97F4A7C15)


def _splitmix(x: np.ndarray) -> np.ndarray:
    z = x + _G
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def hash_normal(index: np.ndarray, seed: int) -> np.ndarray:
    """Standard-normal numbers that are a fixed function of (``index``, ``seed``)."""
    with np.errstate(over="ignore"):
        k = np.asarray(index, dtype=np.int64).astype(np.uint64) * np.uint64(2)
        s = _splitmix(np.asarray([seed], dtype=np.uint64))
        a = _splitmix(k ^ s)
        b = _splitmix((k + np.uint64(1)) ^ s)
    u1 = ((a >> np.uint64(11)).astype(float) + 0.5) / 2.0**53
    u2 = ((b >> np.uint64(11)).astype(float) + 0.5) / 2.0**53
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


class SimulatedFrame:
    """Camera image of ``scene`` at attitude ``R_nb`` (nav from body = camera), lazily rendered.

    ``noise_std`` adds Gaussian pixel noise (intensity units) that is a fixed function of
    the pixel and ``seed``. ``sample(u, v)`` interpolates bilinearly between pixel centres.
    """

    def __init__(self, scene, camera: PinholeCamera, R_nb, noise_std: float = 0.0,
                 seed: int = 0):
        self.scene = scene
        self.camera = camera
        self.R_nb = np.asarray(R_nb, dtype=float)
        self.noise_std = float(noise_std)
        self.seed = int(seed)
        self.rendered_px = 0

    def pixels(self, iu: np.ndarray, iv: np.ndarray) -> np.ndarray:
        """Intensities of integer pixels ``(col=iu, row=iv)``."""
        d = self.camera.rays(iu, iv)
        val = self.scene.radiance(d @ self.R_nb.T)
        self.rendered_px += np.size(iu)
        if self.noise_std > 0:
            idx = np.asarray(iv, dtype=np.int64) * self.camera.width + np.asarray(iu, np.int64)
            val = val + self.noise_std * hash_normal(idx, self.seed)
        return val

    def sample(self, u, v) -> np.ndarray:
        """Bilinear interpolation of the pixel grid at ``(u, v)``; NaN outside the image."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        W, H = self.camera.width, self.camera.height
        ok = _inside(u, v, W, H)
        uu = np.clip(np.where(ok, u, 0.0), 0.0, W - 1.0)
        vv = np.clip(np.where(ok, v, 0.0), 0.0, H - 1.0)
        i0 = np.minimum(np.floor(uu).astype(np.int64), W - 2)
        j0 = np.minimum(np.floor(vv).astype(np.int64), H - 2)
        fu = uu - i0
        fv = vv - j0
        lin = np.concatenate([(j0 + dj) * W + (i0 + di) for dj in (0, 1) for di in (0, 1)])
        uniq, inv = np.unique(lin, return_inverse=True)
        val = self.pixels(uniq % W, uniq // W)[inv].reshape((4,) + u.shape)
        out = ((1 - fv) * ((1 - fu) * val[0] + fu * val[1])
               + fv * ((1 - fu) * val[2] + fu * val[3]))
        return np.where(ok, out, np.nan)

    def image(self) -> np.ndarray:
        """The whole image, ``(height, width)``."""
        W, H = self.camera.width, self.camera.height
        iv, iu = np.mgrid[0:H, 0:W]
        return self.pixels(iu, iv)


class ArrayFrame:
    """A stored image as a frame (``sample`` = bilinear interpolation, NaN outside)."""

    def __init__(self, image: np.ndarray, camera: PinholeCamera):
        self.img = np.asarray(image, dtype=float)
        self.camera = camera

    def sample(self, u, v) -> np.ndarray:
        return bilinear(self.img, u, v)

    def image(self) -> np.ndarray:
        return self.img


def render_view(scene, camera: PinholeCamera, R_nb, noise_std: float = 0.0,
                seed: int = 0) -> np.ndarray:
    """Full image of ``scene`` seen by ``camera`` at attitude ``R_nb``, ``(height, width)``."""
    return SimulatedFrame(scene, camera, R_nb, noise_std, seed).image()


def warp_homography(image: np.ndarray, camera: PinholeCamera, R_ref_cur) -> np.ndarray:
    """Warp a photo taken at attitude ``ref`` to the view of a camera rotated by ``R_ref_cur``.

    ``R_ref_cur`` maps current-camera rays to reference-camera rays; the result is the
    image warped by the homography ``K R_ref_cur K⁻¹`` (NaN where it leaves the photo).
    """
    return render_view(PhotoScene(image, camera), camera, R_ref_cur)
