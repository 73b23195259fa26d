"""Reader for Qualisys Track Manager (QTM) MATLAB exports: a motion-capture reference.

QTM writes a MATLAB level-5 ``.mat`` file whose 116-byte header text starts with
``QTM_ver`` (not ``MATLAB 5.0``). It holds one struct (named after the measurement) with

==================  ===========================  ==============================================
field               shape                        meaning
==================  ===========================  ==============================================
``File``            text                         the ``.qtm`` measurement it was exported from
``Timestamp``       text                         wall-clock start of the capture
``StartFrame``      (1, 1)                       number of the first exported frame (1-based)
``Frames``          (1, 1)                       number of exported frames M
``FrameRate``       (1, 1) Hz                    capture rate
``RigidBodies``     struct                       ``Bodies`` (count B), ``Name`` (B names),
                                                 ``Positions`` (B, 3, M) mm, ``Rotations``
                                                 (B, 9, M), ``RPYs``, ``Residual``
==================  ===========================  ==============================================

``Rotations[b, :, i]`` is the body's 3×3 rotation matrix stored **column-major** (MATLAB's
``reshape(v, 3, 3)``): its columns are the body axes in the capture's global frame, i.e.
``R_global_body``. Frames where QTM lost the body are NaN.

This reader knows only the file format. It returns :class:`MocapReference` (the body's
attitude ``q_global_body``, NaN rows where not tracked, on the capture's clock
``t = (StartFrame - 1 + i) / FrameRate``); what the global frame *is* (ENU? which
north?) is a fact about a particular laboratory, said by the data set's reader
(:mod:`gnomon.io.tyrex` for Michel et al.'s smartphone data set).
"""

from __future__ import annotations

import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import as_path
from gnomon.rotation import quat_from_dcm

__all__ = ["MocapReference", "read_qtm", "is_qtm_mat", "QTM_MAGIC"]

#: the start of the header text of a QTM .mat export
QTM_MAGIC = b"QTM_ver"
#: a frame whose matrix is further than this from a rotation (max |R^T R - I|) is refused
_ORTHO_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class MocapReference:
    """One rigid body's attitude from a motion-capture export.

    ``t`` (M,) s on the capture's clock; ``q`` (M, 4) ``[w, x, y, z]`` ``q_global_body``
    (NaN rows where the body was not tracked); ``position_m`` (M, 3) in the global frame;
    ``frame_rate_hz``; ``body`` its name; ``source`` the file; ``meta`` what was read."""

    t: np.ndarray
    q: np.ndarray
    position_m: np.ndarray
    frame_rate_hz: float
    body: str
    source: str
    meta: dict = field(default_factory=dict)

    @property
    def valid(self) -> np.ndarray:
        """(M,) bool: frames with a tracked body."""
        return np.all(np.isfinite(self.q), axis=1)


def is_qtm_mat(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a file whose header text starts with ``QTM_ver``."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(QTM_MAGIC)) == QTM_MAGIC
    except OSError:
        return False


def _scalar(path: Path, s, name: str) -> float:
    if name not in s._fieldnames:
        raise InputError("missing from the QTM export", file=str(path), field=name)
    a = np.asarray(getattr(s, name))
    try:
        v = float(a.reshape(-1)[0]) if a.size == 1 else float("nan")
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v):
        raise InputError(f"expected one number, got {a.tolist()!r}"[:200], file=str(path),
                         field=name)
    return v


def _text(s, name: str) -> str:
    if name not in s._fieldnames:
        return ""
    a = np.asarray(getattr(s, name)).reshape(-1)
    return str(a[0]).strip() if a.size else ""


def read_qtm(path: str | os.PathLike, body: str | int | None = None) -> MocapReference:
    """Read one rigid body of a QTM ``.mat`` export (module docstring: layout, frames).

    ``body``: the rigid body's name or index (default: the only one; the first with a
    note in ``meta["assumed"]`` when there are several)."""
    import scipy.io

    path = as_path(path)
    try:
        d = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=False)
    except (OSError, ValueError, TypeError, KeyError, IndexError, EOFError, zlib.error,
            AttributeError, NotImplementedError, scipy.io.matlab.MatReadError) as err:
        raise InputError(f"cannot read as a MATLAB .mat file ({err})", file=str(path)) from None
    structs = [(k, v) for k, v in d.items() if not k.startswith("__")
               and isinstance(v, np.ndarray) and v.dtype == object and v.size == 1
               and hasattr(v.item(), "_fieldnames")]
    if len(structs) != 1:
        raise InputError(f"expected one struct (QTM's export), found {len(structs)} "
                         f"({', '.join(k for k, _ in structs) or 'none'})", file=str(path))
    name, s = structs[0][0], structs[0][1].item()
    rate = _scalar(path, s, "FrameRate")
    if rate <= 0:
        raise InputError(f"expected a positive rate (Hz), got {rate!r}", file=str(path),
                         field="FrameRate")
    start = _scalar(path, s, "StartFrame") if "StartFrame" in s._fieldnames else 1.0
    if "RigidBodies" not in s._fieldnames:
        raise InputError("no rigid body in the QTM export", file=str(path),
                         field="RigidBodies")
    rbs = np.asarray(s.RigidBodies)
    if rbs.dtype != object or rbs.size != 1 or not hasattr(rbs.item(), "_fieldnames"):
        raise InputError("expected a struct", file=str(path), field="RigidBodies")
    rb = rbs.item()
    for f in ("Rotations", "Positions"):
        if f not in rb._fieldnames:
            raise InputError("missing from the QTM export", file=str(path),
                             field=f"RigidBodies.{f}")
    rot = np.asarray(rb.Rotations, dtype=float)
    pos = np.asarray(rb.Positions, dtype=float)
    if rot.ndim == 2:  # one body, squeezed by the writer
        rot, pos = rot[None], pos[None] if pos.ndim == 2 else pos
    if rot.ndim != 3 or rot.shape[1] != 9:
        raise InputError(f"expected (bodies, 9, frames), got {rot.shape}", file=str(path),
                         field="RigidBodies.Rotations")
    if pos.shape != (rot.shape[0], 3, rot.shape[2]):
        raise InputError(f"expected {(rot.shape[0], 3, rot.shape[2])}, got {pos.shape}",
                         file=str(path), field="RigidBodies.Positions")
    names = []
    if "Name" in rb._fieldnames:
        for item in np.asarray(rb.Name, dtype=object).reshape(-1):
            a = np.asarray(item).reshape(-1)
            names.append(str(a[0]) if a.size else "")
    names += [f"body{i}" for i in range(len(names), rot.shape[0])]
    assumed = []
    if body is None:
        index = 0
        if rot.shape[0] > 1:
            assumed.append(f"{rot.shape[0]} rigid bodies ({', '.join(names)}): the first "
                           f"({names[0]}) read.")
    elif isinstance(body, str):
        if body not in names:
            raise InputError(f"no rigid body {body!r}; the export has {', '.join(names)}",
                             file=str(path), field="RigidBodies.Name")
        index = names.index(body)
    else:
        index = int(body)
        if not 0 <= index < rot.shape[0]:
            raise InputError(f"rigid body index {index} out of range (0..{rot.shape[0] - 1})",
                             file=str(path), field="RigidBodies")
    frames = int(_scalar(path, s, "Frames")) if "Frames" in s._fieldnames else rot.shape[2]
    if frames != rot.shape[2]:
        raise InputError(f"Frames says {frames}, Rotations holds {rot.shape[2]}",
                         file=str(path), field="Frames")
    m = rot[index].T.reshape(-1, 3, 3).transpose(0, 2, 1)  # column-major: R_global_body
    ok = np.all(np.isfinite(m), axis=(1, 2))
    err = np.abs(np.einsum("nji,njk->nik", m[ok], m[ok]) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(m[ok])
    bad = (err > _ORTHO_TOL) | (det < 0)
    if bad.any():
        row = int(np.flatnonzero(ok)[np.argmax(bad)])
        raise InputError(f"frame {row} is not a rotation matrix (max |R^T R - I| = "
                         f"{err[np.argmax(bad)]:.3g}, det {det[np.argmax(bad)]:.4g})",
                         file=str(path), field="RigidBodies.Rotations", row=row)
    q = np.full((m.shape[0], 4), np.nan)
    q[ok] = quat_from_dcm(m[ok])
    t = (start - 1.0 + np.arange(m.shape[0])) / rate
    position = pos[index].T / 1000.0
    assumed.append("Rotations: column-major 3x3 matrices, R_global_body (QTM's convention).")
    assumed.append(f"t = (StartFrame - 1 + frame) / FrameRate = ({start:g} - 1 + i) / {rate:g}"
                   " s.")
    meta = {"format": "qtm-mat", "struct": name, "file": _text(s, "File"),
            "timestamp": _text(s, "Timestamp"), "start_frame": start, "frames": int(frames),
            "bodies": names, "body": names[index], "tracked_fraction": float(ok.mean()),
            "assumed": assumed}
    return MocapReference(t=t, q=q, position_m=position, frame_rate_hz=rate,
                          body=names[index], source=str(path), meta=meta)
