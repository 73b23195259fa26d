"""Reader for the BROAD benchmark trials (HDF5 and MATLAB .mat).

BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark for
Robust Inertial Orientation Estimation", *Data* 6(7):72, 2021,
doi:10.3390/data6070072 (data licence CC BY 4.0). Every trial ships in both
formats with the same fields:

=================  ========  =====  ===============================================
field              shape     unit   becomes
=================  ========  =====  ===============================================
``imu_gyr``        (N, 3)    rad/s  ``Recording.gyro``
``imu_acc``        (N, 3)    m/s²   ``Recording.accel``
``imu_mag``        (N, 3)    µT     ``Recording.mag`` (``mag_unit = "uT"``)
``opt_quat``       (N, 4)    1      ``Recording.q_true`` = ``q_ENU_sensor``
                                    ``[w, x, y, z]`` (v_E = q ⊗ v_S ⊗ q*); rows with
                                    any NaN (tracking lost) become all-NaN rows
``opt_pos``        (N, 3)    m      ``Recording.extra["pos_m"]`` (optional field)
``movement``       (N,)      bool   ``Recording.mask`` (HDF5 bool; .mat (N, 1) uint8)
``sampling_rate``  scalar    Hz     ``t = arange(N) / sampling_rate`` (HDF5: root
                                    attribute; .mat: (1, 1) array)
=================  ========  =====  ===============================================

``frames = {"reference": "ENU", "body": "sensor"}``; ``source`` is the trial
name (the file stem). Errors name the file and the field; a row in an error
from these array formats is the 0-based sample index.
"""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import build
from gnomon.recording import Recording

__all__ = ["read_broad", "broad_from_fields", "broad_trials", "broad_groups", "BROAD_FIELDS",
           "BROAD_SUFFIXES"]

#: required fields of a BROAD trial (``opt_pos`` is optional)
BROAD_FIELDS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")
#: file suffixes of BROAD trials, in order of preference when a trial exists twice
BROAD_SUFFIXES = (".hdf5", ".h5", ".mat")


def _load_hdf5(path: Path) -> dict:
    import h5py

    out = {}
    try:
        with h5py.File(path, "r") as f:
            for name in BROAD_FIELDS + ("opt_pos",):
                if name in f:
                    out[name] = f[name][()]
            if "sampling_rate" not in out and "sampling_rate" in f.attrs:
                out["sampling_rate"] = f.attrs["sampling_rate"]
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as err:
        raise InputError(f"cannot read as HDF5 ({err})", file=str(path)) from None
    return out


def _load_mat(path: Path) -> dict:
    import scipy.io

    try:
        d = scipy.io.loadmat(path, variable_names=BROAD_FIELDS + ("opt_pos",))
    except NotImplementedError:
        raise InputError("MATLAB v7.3 files are HDF5: save with -v7 or convert",
                         file=str(path)) from None
    except (OSError, ValueError, TypeError, KeyError, IndexError, EOFError, zlib.error,
            scipy.io.matlab.MatReadError) as err:
        raise InputError(f"cannot read as MATLAB .mat ({err})", file=str(path)) from None
    return {k: v for k, v in d.items() if not k.startswith("__")}


def _array(d: dict, name: str, path: Path, width: int | None, n: int | None) -> np.ndarray:
    if name not in d:
        raise InputError("required BROAD field missing", file=str(path), field=name)
    a = np.asarray(d[name])
    if width is None:
        a = a.reshape(-1) if a.ndim == 2 and 1 in a.shape else a
        ok = a.ndim == 1
        want = f"({n if n is not None else 'N'},)"
    else:
        ok = a.ndim == 2 and a.shape[1] == width
        want = f"({n if n is not None else 'N'}, {width})"
    if not ok or (n is not None and a.shape[0] != n):
        raise InputError(f"expected shape {want}, got {np.shape(d[name])}",
                         file=str(path), field=name)
    return a


def read_broad(path: str | os.PathLike, *, with_position: bool = True) -> Recording:
    """Read one BROAD trial (``.hdf5``/``.h5`` or ``.mat``) into a :class:`Recording`.

    Parameters
    ----------
    path : the trial file; the format follows the suffix.
    with_position : keep ``opt_pos`` (m, optical marker position) as
        ``extra["pos_m"]`` when the file has it.

    Returns a Recording with ``t`` (s), ``gyro`` (rad/s), ``accel`` (m/s²),
    ``mag`` (µT), ``q_true = q_ENU_sensor`` (NaN rows where tracking was lost),
    ``mask = movement`` and ``source`` = the trial name (module docstring).

    Raises :class:`InputError` naming the file and the field for a missing
    file, an unreadable file, a missing field, a wrong shape, a bad sampling
    rate or values that fail the Recording checks (a NaN sample of ``imu_gyr``,
    ``imu_acc`` or ``imu_mag`` is dropped and counted, ``gnomon.io._common.build``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", file=str(path))
    suffix = path.suffix.lower()
    if suffix in (".hdf5", ".h5"):
        d = _load_hdf5(path)
    elif suffix == ".mat":
        d = _load_mat(path)
    else:
        raise InputError(f"unknown BROAD file suffix {path.suffix!r}; expected "
                         f"{', '.join(BROAD_SUFFIXES)}", file=str(path))
    return broad_from_fields(d, path, with_position=with_position)


def broad_from_fields(d: dict, path: Path, *, with_position: bool = True) -> Recording:
    """A Recording from BROAD's fields already loaded into ``d`` (name -> array), as
    :func:`read_broad` makes it (also used for MATLAB v7.3 files with BROAD's names)."""
    gyro = _array(d, "imu_gyr", path, 3, None)
    n = gyro.shape[0]
    accel = _array(d, "imu_acc", path, 3, n)
    mag = _array(d, "imu_mag", path, 3, n)
    quat = _array(d, "opt_quat", path, 4, n).astype(float)
    movement = _array(d, "movement", path, None, n)
    if "sampling_rate" not in d:
        raise InputError("required BROAD field missing", file=str(path), field="sampling_rate")
    fs = np.asarray(d["sampling_rate"], dtype=float)
    if fs.size != 1 or not np.isfinite(fs.item()) or fs.item() <= 0:
        raise InputError(f"expected one positive sampling rate in Hz, got {fs.tolist()}",
                         file=str(path), field="sampling_rate")
    fs_hz = float(fs.item())
    quat[np.isnan(quat).any(axis=1)] = np.nan  # a partially lost row is a lost row
    extra = {}
    if with_position and "opt_pos" in d:
        extra["pos_m"] = _array(d, "opt_pos", path, 3, n).astype(float)
    broad_name = {"gyro": "imu_gyr", "accel": "imu_acc", "mag": "imu_mag",
                  "q_true": "opt_quat", "mask": "movement", "extra.pos_m": "opt_pos",
                  "t": "sampling_rate"}
    return build(path, broad_name, t=np.arange(n) / fs_hz, gyro=gyro, accel=accel, mag=mag,
                 mag_unit="uT", q_true=quat, mask=movement.astype(bool),
                 frames={"reference": "ENU", "body": "sensor"}, source=path.stem, extra=extra)


def broad_trials(directory: str | os.PathLike) -> list[Path]:
    """Every BROAD trial file in ``directory``, sorted by trial name.

    A trial present in several formats is listed once, preferring ``.hdf5``
    over ``.h5`` over ``.mat``. Files with other suffixes are ignored.
    Raises :class:`InputError` when ``directory`` is not a directory.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError("no such directory", file=str(directory))
    best: dict[str, Path] = {}
    for p in directory.iterdir():
        suffix = p.suffix.lower()
        if not p.is_file() or suffix not in BROAD_SUFFIXES:
            continue
        old = best.get(p.stem)
        if old is None or BROAD_SUFFIXES.index(suffix) < BROAD_SUFFIXES.index(old.suffix.lower()):
            best[p.stem] = p
    return [best[k] for k in sorted(best)]


def broad_groups(directory: str | os.PathLike) -> dict[str, list[str]]:
    """Groups of every trial from BROAD's ``trials.json`` in ``directory``.

    Returns ``{trial name: [group names]}`` (e.g. ``"01_undisturbed_slow_rotation_A":
    ["all_trials", "undisturbed", "rotation", "slow", "no_breaks"]``), or ``{}``
    when there is no ``trials.json``. A malformed file raises :class:`InputError`.
    """
    path = Path(directory) / "trials.json"
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        trials = doc["trials"]
        return {str(name): [str(g) for g in entry.get("groups", [])]
                for name, entry in trials.items()}
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"not valid JSON ({err})", file=str(path)) from None
    except (KeyError, TypeError, AttributeError):
        raise InputError("expected {'trials': {name: {'groups': [...]}}}", file=str(path),
                         field="trials") from None
