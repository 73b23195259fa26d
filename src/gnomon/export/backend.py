"""Running the exported C from Python: ``gnomon estimate`` and ``gnomon live`` with
``--backend c`` or ``auto`` (the default).

``run_c(name, rec, precision, params)`` exports the filter (``gnomon.export.export_c``)
into the user's cache folder, builds its runner as a shared library (``make shared``:
the same sources and strict flags as the device build, plus ``-fPIC``) once per filter,
precision, parameters and gnomon version, loads it with ``ctypes`` and runs every row of
``rec`` through it: the attitude the device would compute and, for the exports that name
them (``FilterSpec.signals``), the Python filter's signals. ``c_filter_class(name)`` is
the same library as a streaming filter (``gnomon live``). ``auto_backend`` picks the C
where it gives all that the Python gives and a compiler is found: a build of about a
second instead of the numba kernels' first compilation (11-16 s per filter on 2 cores),
the same numbers. The cache folder: ``gnomon.datasets.cache_dir() / "c"``
(``GNOMON_DATA_DIR`` moves it).
"""

from __future__ import annotations

import ctypes
import hashlib
import json

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate

__all__ = ["auto_backend", "build_dir", "c_compiler_found", "c_filter_class", "run_c"]

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
    """One export's runner library (``ctypes.CDLL``: ``gnomon_run_signals``, the streaming
    ``gnomon_filter_*``) and its ``GN_N_SIGNALS``: built (export, ``make shared``) when the
    cache does not hold it, with a line on stderr."""
    from gnomon.export import SPECS, export_c
    from gnomon.export.cost import make

    key = (name, precision, json.dumps(params, sort_keys=True, default=str))
    if key in _LIBS:
        return _LIBS[key]
    out = build_dir(name, precision, params)
    lib = out / f"libgnomon_{SPECS[name].prefix}_run.so"
    if not lib.exists():
        import os
        import shutil
        import sys
        import time

        t0 = time.perf_counter()
        tmp = out.with_name(f"{out.name}.build-{os.getpid()}")  # another process may build
        export_c(name, tmp, precision, params)                 # the same export now: each
        make(tmp, "shared")                                    # in its own folder, the
        try:                                                   # first renamed in place
            tmp.rename(out)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
        print(f"gnomon: built {name}'s C ({precision}) for this machine in "
              f"{time.perf_counter() - t0:.1f} s, once (cached in {out})", file=sys.stderr)
    dll = ctypes.CDLL(str(lib))
    p = ctypes.c_void_p
    dll.gnomon_run_signals.argtypes = [ctypes.c_long, p, p, p, p, p, p, p, ctypes.c_int, p, p, p]
    dll.gnomon_run_signals.restype = ctypes.c_long
    dll.gnomon_n_signals.restype = ctypes.c_int
    dll.gnomon_filter_size.restype = ctypes.c_long
    dll.gnomon_filter_start.argtypes = [p, ctypes.c_double, ctypes.c_double, ctypes.c_double]
    dll.gnomon_filter_start.restype = None
    dll.gnomon_filter_rows.argtypes = [p, ctypes.c_long, p, p, p, p, p, p]
    dll.gnomon_filter_rows.restype = None
    _LIBS[key] = dll, int(dll.gnomon_n_signals())
    return _LIBS[key]


def c_compiler_found() -> bool:
    """Whether ``make`` and a C compiler (``$CC``, else ``cc``) are on the PATH: what
    ``run_c`` needs to build an export it has not built yet."""
    import os
    import shutil

    return shutil.which("make") is not None and \
        shutil.which(os.environ.get("CC") or "cc") is not None


def auto_backend(name: str, streaming: bool = False) -> tuple[str, str]:
    """``--backend auto`` of ``gnomon estimate`` (``streaming`` False) and ``gnomon live``
    (True): ``("c", why)`` when filter ``name`` has an IMU export that reports all of its
    Python signals (and, streaming, starts without rows: ``FilterSpec.streams``) and this
    machine can build it (a C compiler: built once, about a second, instead of the numba
    kernels' first compilation: 12-16 s for robust-ahrs, 35 s for mahony, on 2 cores), else
    ``("python", why)``. Both give the same numbers (the twins are held equal sample by
    sample)."""
    from gnomon.export import SPECS

    spec = SPECS.get(name)
    if spec is None or spec.kind != "imu" or not spec.signals:
        return "python", f"{name} has no C export that reports its signals"
    if streaming and not spec.streams:
        return "python", f"{name}'s C export starts from a recording's first rows, not a stream"
    if not c_compiler_found():
        return "python", "no C compiler on the PATH (make and $CC or cc)"
    return "c", f"{name}'s C export, built with this machine's C compiler"


def run_c(name: str, rec, precision: str = "double", params: dict | None = None) -> Estimate:
    """``rec`` through filter ``name``'s exported C (module docstring): an ``Estimate``
    with ``q`` (N, 4) and the signals the export reports (``FilterSpec.signals``: for
    robust-ahrs all of those of its Python ``run``; none for the others)."""
    from gnomon.estimators import registry
    from gnomon.export import SPECS
    if name not in SPECS:
        raise InputError(f"no C export of {name!r}; exported filters: "
                         f"{', '.join(sorted(SPECS))}", field="--backend")
    cls = registry.get(name)
    p = cls.Params.from_dict(params or {})
    f = cls(p)
    f.check_inputs(rec)
    spec = SPECS[name]
    if spec.kind != "imu":
        raise InputError(f"--backend c runs the IMU exports; {name!r} is run by its "
                         f"gnomon_run on `gnomon convert REC rec.csv`", field="--backend")
    dll, n_sig = _library(name, precision, p.as_dict())
    run = dll.gnomon_run_signals
    if n_sig != sum(width for _, width, _ in spec.signals):
        raise RuntimeError(f"{name}'s C reports {n_sig} signals per estimate; its spec names "
                           f"{spec.signals}")
    from gnomon.io.csv import sample_events

    ev = sample_events(rec)  # each sample at its own stamp, as gnomon_run reads a CSV
    t = np.ascontiguousarray(ev["t"], dtype=float)
    g, a, m = (np.ascontiguousarray(ev[k], dtype=float) for k in ("gyro", "accel", "mag"))
    g_ok, a_ok, m_ok = (np.ascontiguousarray(np.isfinite(x).all(axis=1)) for x in (g, a, m))
    q = np.empty((len(rec), 4))
    sig = np.empty((len(rec), n_sig))
    ptr = ctypes.c_void_p
    got = run(len(t), ptr(t.ctypes.data), ptr(g.ctypes.data), ptr(a.ctypes.data),
              ptr(g_ok.ctypes.data), ptr(a_ok.ctypes.data), ptr(m.ctypes.data),
              ptr(m_ok.ctypes.data), int(rec.mag is not None), None, ptr(q.ctypes.data),
              ptr(sig.ctypes.data) if n_sig else None)
    if got != len(rec):
        raise InputError(f"the C made {got} estimates for {len(rec)} gyro samples",
                         field="--backend")
    return Estimate(t=rec.t, q=q, estimator=f"{name} (C, {precision})", params=p.as_dict(),
                    frames={"reference": rec.frames.get("reference", "ENU"), "body": "sensor"},
                    signals=_signals(spec.signals, sig))


def _signals(columns, sig: np.ndarray) -> dict:
    """``gnomon_run_signals``' (N, GN_N_SIGNALS) doubles as named signals (``columns``:
    ``FilterSpec.signals``): a width-1 column as (N,), a wider one as (N, width)."""
    out, k = {}, 0
    for name, width, dtype in columns:
        x = sig[:, k:k + width]
        x = x[:, 0] if width == 1 else np.ascontiguousarray(x)
        out[name] = x != 0.0 if dtype == "bool" else x
        k += width
    return out


def c_filter_class(name: str, precision: str = "double"):
    """The exported C of filter ``name`` as a streaming filter class: what ``gnomon live``
    (``gnomon.live.LiveFilter``) calls on a filter, ``Cls(params)``, ``check_inputs(rec)``,
    ``prepare(rec)`` and ``update_many(dt_s, gyro, accel, mag, t_s=...)`` (an ``Estimate``
    with the signals of the Python filter's), run by the C in this process's memory
    (``gnomon_filter_start`` / ``gnomon_filter_rows`` of the runner library: built once,
    about a second, where the numba kernels compile for 12-16 s). For the exports that name
    their signals and start from the nominal sample times alone (``FilterSpec.signals``,
    ``FilterSpec.streams``); the numbers equal the Python filter's
    (``tests/test_export.py``, ``tests/test_live.py``)."""
    from gnomon.estimators import registry
    from gnomon.export import SPECS

    spec = SPECS.get(name)
    if spec is None or spec.kind != "imu" or not spec.signals or not spec.streams:
        raise InputError(f"no streaming C export of {name!r}; those with one: "
                         f"{', '.join(sorted(n for n, s in SPECS.items() if s.streams))}",
                         field="--backend")
    py = registry.get(name)

    class CFilter:
        __doc__ = f"{name}'s exported C ({precision}) as a streaming filter (c_filter_class)."
        Params = py.Params
        kind = "imu"
        offline = False
        backend = f"c ({precision})"  # what `gnomon live` says it runs

        def __init__(self, params=None, **kw):
            if params is None or isinstance(params, dict):
                params = py.Params.from_dict({**(params or {}), **kw})
            self.params = params
            self.name = name
            self._py = py(params)  # the input checks and the nominal sample times
            self._dll, self._n_sig = _library(name, precision, params.as_dict())
            self._mem = ctypes.create_string_buffer(int(self._dll.gnomon_filter_size()))
            self._started = False

        def check_inputs(self, rec) -> None:
            self._py.check_inputs(rec)

        def prepare(self, rec) -> None:
            """The nominal sample times from ``rec``, as the Python filter's ``prepare``."""
            self._py.prepare(rec)
            self._start(*self._py.ts)

        def _start(self, ts, ts_acc, ts_mag) -> None:
            self._dll.gnomon_filter_start(ctypes.addressof(self._mem), ts, ts_acc, ts_mag)
            self._started = True

        def update_many(self, dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None, *,
                        t_s=None) -> Estimate:
            """N rows through the C, as the Python filter's ``update_many`` (the same checks;
            without ``prepare`` the first ``dt_s`` is the nominal sample time)."""
            from gnomon.estimators.base import imu_buffer

            dt, gyro, acc, mag = (np.ascontiguousarray(x) for x in
                                  imu_buffer(dt_s, gyro_rad_s, accel_m_s2, mag_uT))
            n = len(dt)
            if not self._started and n:
                if not dt[0] > 0:
                    raise InputError("call prepare(rec) first or pass dt_s > 0", field="dt_s")
                self._start(float(dt[0]), float(dt[0]), float(dt[0]))
            q = np.empty((n, 4))
            sig = np.empty((n, self._n_sig))
            ptr = ctypes.c_void_p
            self._dll.gnomon_filter_rows(ctypes.addressof(self._mem), n, ptr(dt.ctypes.data),
                                         ptr(gyro.ctypes.data), ptr(acc.ctypes.data),
                                         ptr(mag.ctypes.data), ptr(q.ctypes.data),
                                         ptr(sig.ctypes.data) if self._n_sig else None)
            return Estimate(t=np.cumsum(dt) if t_s is None else np.asarray(t_s, dtype=float),
                            q=q, estimator=f"{name} (C, {precision})",
                            params=self.params.as_dict(),
                            frames={"reference": "ENU", "body": "sensor"},
                            signals=_signals(spec.signals, sig))

    CFilter.__name__ = CFilter.__qualname__ = f"C_{spec.prefix}"
    return CFilter
