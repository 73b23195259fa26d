"""Where live estimates go: a file, a UDP socket as JSON (and, in their own modules, MCAP,
MAVLink and the view).

A sink has ``write(est, arrivals)`` (an ``Estimate`` chunk of one or more rows, in order;
``arrivals`` the perf_counter arrival times of their gyro samples), ``close()`` (flush and
release; everything written before is on disk after it) and ``describe()`` (a dict for
``gnomon live --json``). Sinks never raise on a write for a reason outside the program
(a full socket buffer, an unreachable peer): they count it (``errors``) and go on.
"""

from __future__ import annotations

import json
import math
import socket
from pathlib import Path

import numpy as np

from gnomon.errors import InputError
from gnomon.io.estimate import CSV_FORMAT, estimate_columns

__all__ = ["EstimateFileSink", "UdpJsonSink", "estimate_rows"]


class EstimateFileSink:
    """``--out FILE.csv|.h5``: the columns of ``gnomon estimate --out`` (``gnomon.io.estimate``),
    written as the estimates come: CSV rows appended (flushed every ``flush_rows`` rows),
    HDF5 datasets grown in chunks. A file cut by a crash holds every row up to the last
    flush; ``close`` writes the rest."""

    def __init__(self, path, flush_rows: int = 200):
        self.path = Path(path)
        self.kind = self.path.suffix.lower()
        if self.kind not in (".csv", ".h5", ".hdf5"):
            raise InputError(f"unknown output type {self.kind!r}: use .csv, .h5 or .hdf5",
                             file=str(self.path), field="--out")
        self.flush_rows = flush_rows
        self.rows = 0
        self._fh = None
        self._h5 = None
        self._unflushed = 0

    def write(self, est, arrivals=None) -> None:
        if self.kind == ".csv":
            self._write_csv(est)
        else:
            self._write_h5(est)
        self.rows += len(est.t)

    def _write_csv(self, est) -> None:
        cols = estimate_columns(est)
        if self._fh is None:
            self._fh = open(self.path, "w", newline="")  # noqa: SIM115 - kept open to append
            self._fh.write(",".join(cols) + "\n")
        np.savetxt(self._fh, np.column_stack(list(cols.values())), delimiter=",",
                   fmt=CSV_FORMAT)
        self._unflushed += len(est.t)
        if self._unflushed >= self.flush_rows:
            self._fh.flush()
            self._unflushed = 0

    def _write_h5(self, est) -> None:
        import h5py

        n = len(est.t)
        if self._h5 is None:
            self._h5 = f = h5py.File(self.path, "w")
            f.attrs["format"] = "gnomon-estimate"
            f.attrs["estimator"] = est.estimator
            f.attrs["params"] = json.dumps(est.params)
            f.attrs["frame_reference"] = est.frames.get("reference", "")
            f.attrs["frame_body"] = est.frames.get("body", "")
            f.create_dataset("t", shape=(0,), maxshape=(None,), chunks=(4096,), dtype="f8")
            f.create_dataset("q", shape=(0, 4), maxshape=(None, 4), chunks=(4096, 4))
            g = f.create_group("signals")
            for name, v in est.signals.items():
                v = np.asarray(v)
                g.create_dataset(name, shape=(0, *v.shape[1:]), maxshape=(None, *v.shape[1:]),
                                 chunks=(4096, *v.shape[1:]), dtype=v.dtype)
        f = self._h5
        start = f["t"].shape[0]
        items = [("t", est.t), ("q", est.q)] + [(f"signals/{k}", v) for k, v in
                                                est.signals.items()]
        for name, v in items:
            d = f[name]
            d.resize(start + n, axis=0)
            d[start:] = np.asarray(v)
        self._unflushed += n
        if self._unflushed >= self.flush_rows * 20:
            f.flush()
            self._unflushed = 0

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        if self._h5 is not None:
            self._h5.close()
            self._h5 = None

    def describe(self) -> dict:
        return {"sink": "file", "path": str(self.path), "rows": self.rows}


def estimate_rows(est):
    """One JSON-ready dict per row of ``est``: ``t`` (s), ``q`` ``[w, x, y, z]`` (q_rb),
    ``euler_deg`` ``[roll, pitch, yaw]`` (z-y'-x'', degrees), every 3-vector signal as a
    list (``bias_rad_s``, ...), every flag as a bool and every scalar signal as a number."""
    from gnomon.rotation import euler_from_quat

    euler = np.degrees(euler_from_quat(est.q))
    signals = {k: np.asarray(v) for k, v in est.signals.items()}
    for k in range(len(est.t)):
        row = {"t": float(est.t[k]), "q": est.q[k].tolist(), "euler_deg": euler[k].tolist()}
        for name, v in signals.items():
            x = v[k]
            if v.dtype == bool:
                row[name] = bool(x)
            elif v.ndim == 1:
                row[name] = float(x) if math.isfinite(float(x)) else None
            else:
                row[name] = [float(c) if math.isfinite(float(c)) else None for c in x]
        yield row


class UdpJsonSink:
    """``--udp-out HOST:PORT``: one JSON object per estimate (:func:`estimate_rows`), one
    datagram each."""

    def __init__(self, target: str):
        host, _, port = target.rpartition(":")
        try:
            self.address = (host or "127.0.0.1", int(port))
        except ValueError:
            raise InputError(f"expected HOST:PORT, got {target!r}", field="--udp-out") from None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = self.errors = 0

    def write(self, est, arrivals=None) -> None:
        for row in estimate_rows(est):
            try:
                self.sock.sendto(json.dumps(row).encode(), self.address)
                self.sent += 1
            except OSError:
                self.errors += 1

    def close(self) -> None:
        self.sock.close()

    def describe(self) -> dict:
        return {"sink": "udp", "to": f"{self.address[0]}:{self.address[1]}",
                "sent": self.sent, "errors": self.errors}
