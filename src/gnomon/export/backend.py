"""Running the exported C on a recording from Python: ``gnomon estimate --backend c``.

``run_c(name, rec, precision, params)`` exports the filter (``gnomon.export.export_c``)
into the user's cache folder, builds its runner as a shared library (``make shared``:
the same sources and strict flags as the device build, plus ``-fPIC``) once per filter,
precision, parameters and gnomon version, loads it with ``ctypes`` and runs every row of
``rec`` through it: the attitude the device would compute, to check the C on one's own
logs. The cache folder: ``gnomon.datasets.cache_dir() / "c"`` (``GNOMON_DATA_DIR``
moves it).
"""

from __future__ import annotations

import ctypes
import hashlib
import json

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate

__all__ = ["run_c", "build_dir"]

_LIBS: dict = {}


def build_dir(name: str, precision: str, params: dict):
    """The cache folder of one export (a digest of what it is built from)."""
    from gnomon import __version__
    from gnomon.datasets import cache_dir
    from gnomon.export import SPECS, _source

    spec = SPECS[name]
    digest = hashlib.sha256(json.dumps([name, precision, params, __version__],
                                       sort_keys=True, default=str).encode())
    for fname in spec.sources + spec.headers + (spec.adapter, spec.runner, "gnomon_quat.h",
                                                "gnomon_real.h"):
        digest.update(_source(fname).encode())
    return cache_dir() / "c" / f"{name}-{precision}-{digest.hexdigest()[:12]}"


def _library(name: str, precision: str, params: dict):
    from gnomon.export import SPECS, export_c
    from gnomon.export.cost import make

    key = (name, precision, json.dumps(params, sort_keys=True, default=str))
    if key in _LIBS:
        return _LIBS[key]
    out = build_dir(name, precision, params)
    lib = out / f"libgnomon_{SPECS[name].prefix}_run.so"
    if not lib.exists():
        export_c(name, out, precision, params)
        make(out, "shared")
    dll = ctypes.CDLL(str(lib))
    fn = dll.gnomon_run_rows
    p = ctypes.c_void_p
    fn.argtypes = [ctypes.c_long, p, p, p, p, p, p, p, ctypes.c_int, p]
    fn.restype = ctypes.c_long
    _LIBS[key] = fn
    return fn


def run_c(name: str, rec, precision: str = "double", params: dict | None = None) -> Estimate:
    """``rec`` through filter ``name``'s exported C (module docstring): an ``Estimate``
    with ``q`` (N, 4) (no signals: the C returns the attitude)."""
    from gnomon.estimators import registry
    from gnomon.export import SPECS
    if name not in SPECS:
        raise InputError(f"no C export of {name!r}; exported filters: "
                         f"{', '.join(sorted(SPECS))}", field="--backend")
    cls = registry.get(name)
    p = cls.Params.from_dict(params or {})
    f = cls(p)
    f.check_inputs(rec)
    if SPECS[name].kind != "imu":
        raise InputError(f"--backend c runs the IMU exports; {name!r} is run by its "
                         f"gnomon_run on `gnomon convert REC rec.csv`", field="--backend")
    run = _library(name, precision, p.as_dict())
    from gnomon.io.csv import sample_events

    ev = sample_events(rec)  # each sample at its own stamp, as gnomon_run reads a CSV
    t = np.ascontiguousarray(ev["t"], dtype=float)
    g, a, m = (np.ascontiguousarray(ev[k], dtype=float) for k in ("gyro", "accel", "mag"))
    g_ok, a_ok, m_ok = (np.ascontiguousarray(np.isfinite(x).all(axis=1)) for x in (g, a, m))
    q = np.empty((len(rec), 4))
    ptr = ctypes.c_void_p
    got = run(len(t), ptr(t.ctypes.data), ptr(g.ctypes.data), ptr(a.ctypes.data),
              ptr(g_ok.ctypes.data), ptr(a_ok.ctypes.data), ptr(m.ctypes.data),
              ptr(m_ok.ctypes.data), int(rec.mag is not None), ptr(q.ctypes.data))
    if got != len(rec):
        raise InputError(f"the C made {got} estimates for {len(rec)} gyro samples",
                         field="--backend")
    return Estimate(t=rec.t, q=q, estimator=f"{name} (C, {precision})", params=p.as_dict(),
                    frames={"reference": rec.frames.get("reference", "ENU"), "body": "sensor"})
