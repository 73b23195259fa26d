"""Real images for the seed-003 simulations: where they are and how they are loaded.

Full-size originals are looked up through :func:`gnomon.datasets.images_dir`
(``$GNOMON_IMAGES_DIR``, else ``../shared/data/images`` beside the repository, else the
copy fetched by ``gnomon datasets fetch images``); if absent, the small copies shipped
in the package data ``gnomon/data/images`` are used (the cube map downscaled to 256x256
px faces; the 640x480 OpenCV aerial samples as they are). See ``README.md`` there for
the sources and licences.

Images are returned as grayscale ``float32`` arrays in [0, 1], row 0 at the top.
"""

from __future__ import annotations

import functools
import pathlib

import numpy as np

from gnomon import datasets
from gnomon.errors import InputError

__all__ = ["images_dir", "find_image", "load_gray", "load_cube_faces", "CUBE_FACES"]

_BUNDLED_NAMES = {"meadow_cube.jpg": "meadow_cube_256.jpg"}

#: Face order of ``meadow_cube.jpg`` (stacked vertically): OpenGL cube-map order.
CUBE_FACES = ("+x", "-x", "+y", "-y", "+z", "-z")


def images_dir() -> pathlib.Path | None:
    """Directory of the full-size images, or None (:func:`gnomon.datasets.images_dir`)."""
    return datasets.images_dir()


def find_image(name: str, prefer_full: bool = True) -> tuple[pathlib.Path, bool]:
    """Path of image ``name`` and whether it is the full-size original.

    Falls back to the bundled small copy; raises ``InputError`` if neither exists.
    """
    full = images_dir()
    if prefer_full and full is not None and (full / name).is_file():
        return full / name, True
    shipped = datasets.bundled("images")
    b = shipped / _BUNDLED_NAMES.get(name, name)
    if b.is_file():
        return b, False
    where = f"{full} nor in {shipped}" if full is not None else str(shipped)
    raise InputError(f"image {name!r} not found in {where}", file=name)


def _pil():
    try:
        from PIL import Image
    except ImportError as e:  # pragma: no cover - pillow is a runtime dependency
        raise InputError("reading images needs pillow (pip install pillow)") from e
    return Image


@functools.lru_cache(maxsize=8)
def _load_gray_cached(path: str) -> np.ndarray:
    Image = _pil()
    with Image.open(path) as im:
        a = np.asarray(im.convert("L"), dtype=np.float32) / 255.0
    a.setflags(write=False)
    return a


def load_gray(name: str, prefer_full: bool = True) -> np.ndarray:
    """Grayscale image ``name`` as ``float32`` in [0, 1], shape ``(rows, cols)`` (read-only)."""
    path, _ = find_image(name, prefer_full)
    return _load_gray_cached(str(path))


@functools.lru_cache(maxsize=4)
def load_cube_faces(face_px: int = 1024, prefer_full: bool = True) -> np.ndarray:
    """The six faces of ``meadow_cube.jpg``, grayscale, shape ``(6, face_px, face_px)``.

    Faces in OpenGL order ``+x, -x, +y (sky), -y (ground), +z, -z``; each is
    box-filtered down to ``face_px``, never upsampled (the bundled copy has 256-px faces).
    """
    Image = _pil()
    path, _ = find_image("meadow_cube.jpg", prefer_full)
    with Image.open(path) as im:
        g = im.convert("L")
        w, h = g.size
        if h != 6 * w:
            raise InputError(f"cube map must be 6 square faces stacked vertically, got {w}x{h}",
                             file=str(path))
        faces = []
        for k in range(6):
            f = g.crop((0, k * w, w, (k + 1) * w))
            if face_px < w:
                f = f.resize((face_px, face_px), Image.Resampling.BOX)
            faces.append(np.asarray(f, dtype=np.float32) / 255.0)
    out = np.stack(faces)
    out.setflags(write=False)
    return out
