"""``gnomon inspect``: what a log holds, from the Recording its reader makes
(:func:`gnomon.io.inspect` reads, :func:`summarise` describes).

For each sensor (gyro, accelerometer, magnetometer): ``rate_hz`` (median), ``samples``,
``unit``, first and last time stamp (s), gaps (intervals longer than ``GAP_FACTOR`` = 5
median intervals: how many and the longest, s) and where it came from (topic, message,
file). Then the device's own estimate (``q_onboard``: what it is, how many gyro samples
it covers), the truth when the log has one, the duration, the frames, the device, what
else the file offers (``available``: topics and instances with message counts), whether
the file is cut short (``truncated``: ``{"at_byte", "message_bytes", "bytes_present",
"data_up_to_s"}`` or None; ULog, DataFlash), the samples dropped for a non-finite value
(``dropped``: ``{sensor: count}``, sensors with drops only, or None), why there is no own
estimate (``onboard_absent``, or None) and the reader's ``assumed`` sentences. The result
is JSON-able. :func:`reader_notes` is the part ``gnomon estimate`` shows.
"""

from __future__ import annotations

import numpy as np

from gnomon.io._common import GAP_FACTOR, gaps

__all__ = ["summarise", "reader_notes"]

_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
_ORIGIN = {"gyro": ("topic", "imu"), "accel": ("topic", "imu"), "mag": ("mag_topic", "mag")}


def summarise(rec, path: str = "", fmt: str = "") -> dict:
    """The summary (module docstring) of a Recording ``rec`` read from ``path``."""
    meta = rec.meta
    sensors = []
    ends = []
    for name in ("gyro", "accel", "mag"):
        if name != "gyro" and getattr(rec, name) is None:
            continue
        t = rec.times(name)
        g = gaps(t)
        origin = next((meta[k] for k in _ORIGIN[name] if meta.get(k)), None)
        sensors.append({
            "name": name, "rate_hz": rec.rate_hz(name), "samples": int(t.size),
            "unit": rec.mag_unit if name == "mag" else _UNITS[name],
            "start_s": float(t[0]), "end_s": float(t[-1]),
            "gaps": g["count"], "longest_gap_s": g["longest_s"],
            "from": str(origin) if origin is not None else None,
            "dropped": int((meta.get("dropped") or {}).get(name, 0)),
        })
        ends += [float(t[0]), float(t[-1])]

    def series(q, what):
        if q is None:
            return None
        ok = np.isfinite(q).all(axis=1)
        return {"what": what, "samples": int(ok.sum()), "coverage": float(ok.mean())}

    return {
        "file": str(path), "format": fmt or meta.get("format", ""), "source": rec.source,
        "frames": rec.frames, "duration_s": max(ends) - min(ends),
        "single_rate": rec.single_rate, "sensors": sensors,
        "onboard": series(rec.q_onboard, meta.get("onboard") or "the device's own estimate"),
        "onboard_gravity_deg": meta.get("onboard_gravity_deg"),
        "onboard_absent": meta.get("onboard_absent"),
        "truth": series(rec.q_true, "q_true"),
        "device": meta.get("device"), "available": meta.get("available"),
        "truncated": meta.get("truncated"), "dropped": meta.get("dropped") or None,
        "assumed": list(meta.get("assumed", [])), "gap_factor": GAP_FACTOR,
    }


def reader_notes(rec) -> dict:
    """What the reader of ``rec`` noted, for a command's output: ``notes`` (the ``assumed``
    sentences, which say the truncation and the drops in words too), and when there are
    any ``dropped`` (``{sensor: count}``) and ``truncated`` (as in :func:`summarise`)."""
    meta = rec.meta
    out = {"notes": list(meta.get("assumed", []))}
    for key in ("dropped", "truncated"):
        if meta.get(key):
            out[key] = meta[key]
    return out
