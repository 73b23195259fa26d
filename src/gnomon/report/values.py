"""How numbers and paths are shown in reports and printed results.

* :func:`sig`: a number to a few significant digits (``59.99999999999999`` -> ``60``).
* :func:`display_path`: a path without the machine's absolute prefix: relative to the
  gnomon package (``gnomon/data/images/meadow_cube_256.jpg``), to a data set's folder
  (``$GNOMON_IMAGES_DIR/aero1.jpg``, named by its setting) or the download cache
  (``$GNOMON_DATA_DIR/...``), to the working directory, or to the home directory
  (``~/...``); otherwise only its last two parts (``…/images/aero1.jpg``).
* :func:`tidy`: both applied through a JSON-like value (dicts, lists): floats rounded to
  significant digits, absolute paths shown as above.
* :func:`text`: a value of a parameter table as text (``60``, ``[0.4, 0.006]``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

__all__ = ["sig", "display_path", "tidy", "text"]


def sig(v, digits: int = 4) -> str:
    """``v`` as text with ``digits`` significant digits (``"—"`` for None, NaN or inf).
    Integers and strings are shown as they are."""
    if v is None:
        return "—"
    if isinstance(v, bool) or isinstance(v, str):
        return str(v)
    if isinstance(v, int):
        return str(v)
    v = float(v)
    if not math.isfinite(v):
        return "—"
    return f"{v:.{digits}g}"


def _round(v: float, digits: int) -> float:
    return float(f"{v:.{digits}g}") if math.isfinite(v) else v


def _data_roots() -> list[tuple[Path, str]]:
    """``(folder, $SETTING)`` of every data set found here (``gnomon.datasets``), then the
    download cache (``$GNOMON_DATA_DIR``)."""
    roots = []
    try:
        from gnomon import datasets

        for name in getattr(datasets, "CATALOGUE", ()):
            folder = datasets.dataset_dir(name)
            if folder is not None:
                roots.append((Path(folder), f"${datasets.dataset(name).env}"))
    except (ImportError, AttributeError, OSError, KeyError):
        pass   # paths are then shown relative to the other roots
    if os.environ.get("GNOMON_DATA_DIR"):
        roots.append((Path(os.environ["GNOMON_DATA_DIR"]), "$GNOMON_DATA_DIR"))
    return roots


def display_path(p) -> str:
    """``p`` (a path) as shown to a reader: never the machine's absolute prefix (module
    docstring). A relative path is returned as it is."""
    path = Path(p)
    if not path.is_absolute():
        return str(p)
    import gnomon

    roots = [(Path(gnomon.__file__).resolve().parent, "gnomon")] + _data_roots()
    if Path.cwd().parent != Path.cwd():     # not the file system's root
        roots.append((Path.cwd(), ""))
    roots.append((Path.home(), "~"))
    for root, name in roots:
        for candidate in {path, path.resolve()}:
            try:
                rel = candidate.relative_to(root.resolve() if root.exists() else root)
            except ValueError:
                continue
            return f"{name}/{rel.as_posix()}" if name else rel.as_posix()
    return "…/" + "/".join(path.parts[-2:])


def _is_local_path(s: str) -> bool:
    """An absolute path of something on this machine (a ROS topic such as ``/imu/data``
    is not one)."""
    try:
        return os.path.isabs(s) and len(s) < 4096 and Path(s).exists()
    except (OSError, ValueError):
        return False


def tidy(obj, digits: int = 6):
    """``obj`` (dicts, lists, tuples, numbers, strings) with floats rounded to ``digits``
    significant digits and absolute paths of this machine's files shown by
    :func:`display_path`."""
    if isinstance(obj, dict):
        return {k: tidy(v, digits) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [tidy(v, digits) for v in obj]
    if isinstance(obj, Path):
        return display_path(obj)
    if isinstance(obj, str):
        return display_path(obj) if _is_local_path(obj) else obj
    if isinstance(obj, float):
        return _round(obj, digits)
    if hasattr(obj, "item") and not isinstance(obj, bool):  # numpy scalars
        return tidy(obj.item(), digits)
    return obj


def text(v, digits: int = 6) -> str:
    """A value as a report shows it in a table: numbers to ``digits`` significant digits,
    lists element by element, absolute paths by :func:`display_path`."""
    v = tidy(v, digits)
    if isinstance(v, float):
        return sig(v, digits)
    if isinstance(v, list):
        return "[" + ", ".join(text(x, digits) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {text(x, digits)}" for k, x in v.items()) + "}"
    return str(v)
