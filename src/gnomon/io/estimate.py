"""Writing an ``Estimate`` to disk: CSV for spreadsheets, HDF5 for everything.

CSV (``.csv``): header ``t,q_w,q_x,q_y,q_z`` then one column per component of
each numeric signal (``bias_rad_s_x`` ..., flags as 0/1). HDF5 (``.h5``/``.hdf5``):
datasets ``t``, ``q`` (N, 4) ``[w, x, y, z]`` and ``signals/<name>``; root
attributes ``format="gnomon-estimate"``, ``estimator``, ``params`` (JSON) and
``frame_reference`` / ``frame_body``. ``q`` is ``q_rb``: reference frame from body.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gnomon.errors import InputError

__all__ = ["write_estimate", "estimate_columns", "CSV_FORMAT"]

#: the number format of a CSV estimate's cells
CSV_FORMAT = "%.10g"


def estimate_columns(est) -> dict:
    """The CSV columns of ``est``: name -> (N,) float array, in the order written."""
    cols = {"t": est.t, "q_w": est.q[:, 0], "q_x": est.q[:, 1], "q_y": est.q[:, 2],
            "q_z": est.q[:, 3]}
    for name, v in est.signals.items():
        v = np.asarray(v)
        if v.ndim == 1:
            cols[name] = v.astype(float)
        elif v.ndim == 2:
            labels = "xyz" if v.shape[1] == 3 else [str(i) for i in range(v.shape[1])]
            for i, lab in enumerate(labels):
                cols[f"{name}_{lab}"] = v[:, i].astype(float)
    return cols


def write_estimate(path, est) -> Path:
    """Write ``est`` to ``path`` (``.csv``, ``.h5`` or ``.hdf5``); returns the path."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        cols = estimate_columns(est)
        data = np.column_stack(list(cols.values()))
        np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="", fmt=CSV_FORMAT)
    elif suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "w") as f:
            f.attrs["format"] = "gnomon-estimate"
            f.attrs["estimator"] = est.estimator
            f.attrs["params"] = json.dumps(est.params)
            f.attrs["frame_reference"] = est.frames.get("reference", "")
            f.attrs["frame_body"] = est.frames.get("body", "")
            f.create_dataset("t", data=est.t)
            f.create_dataset("q", data=est.q)
            g = f.create_group("signals")
            for name, v in est.signals.items():
                g.create_dataset(name, data=np.asarray(v))
    else:
        raise InputError(f"unknown output type {suffix!r}: use .csv, .h5 or .hdf5",
                         file=str(path), field="--out")
    return path
