"""The live loop: a source, a filter fed sample by sample, sinks — until the stream ends.

::

    source thread ──(arrival_s, payload)──▶ bounded queue ──▶ parse ──▶ LiveFilter.push
        ──▶ Estimate chunks ──▶ sinks (file, UDP JSON, MCAP, MAVLink, the view)

The source reads in a thread of its own and hands each item to a queue of at most
``queue_size`` items: when the filter falls behind, new items are dropped and counted
(``dropped``), memory stays bounded (a replay waits instead: nothing of a file is ever
dropped). The loop stops at the end of the stream (or ``idle_timeout_s`` without a new
item), after ``duration_s``, after
``max_samples`` estimates (malformed lines do not count), or when ``stop`` is set (the
command line sets it on SIGINT and SIGTERM); every sink is then closed, so everything
estimated is written. Latency is measured per estimate, from the arrival of its gyro
sample to the estimate (µs; it includes the hold of ``LiveFilter``: about half a gyro
period, see ``hold_periods``), after the start: the rows of the warm-up wait for it once
(``startup_ms``, the first sample's wait).
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from gnomon.live.parse import Malformed
from gnomon.live.stream import LiveFilter

__all__ = ["LiveRun", "run_live"]


@dataclass
class LiveRun:
    """What a live run did: the summary ``gnomon live --json`` prints (``to_dict``)."""

    filter: str
    source: str
    samples: int = 0  #: estimates made
    lines: int = 0  #: items received (lines, datagrams' lines, messages, replayed samples)
    malformed: int = 0  #: items that were not samples
    dropped: int = 0  #: items dropped because the filter was behind (queue full)
    latencies_s: list = field(default_factory=list)  #: per estimate after the start
    startup_s: float = 0.0  #: the first sample's wait for the warm-up rows and the start
    stream: dict = field(default_factory=dict)
    ended_by: str = ""
    elapsed_s: float = 0.0  #: from the first item to the end
    cpu_s: float = 0.0  #: CPU time (all threads) over ``elapsed_s``
    malformed_reasons: dict = field(default_factory=dict)
    sinks: list = field(default_factory=list)

    def to_dict(self) -> dict:
        lat = np.asarray(self.latencies_s) * 1e6
        pct = (lambda p: float(np.percentile(lat, p))) if lat.size else (lambda p: None)
        return {"filter": self.filter, "samples": self.samples, "malformed": self.malformed,
                "dropped": self.dropped,
                "latency_us": {"p50": pct(50), "p99": pct(99), "max": pct(100)},
                "startup_ms": self.startup_s * 1e3,
                "source": self.source, "lines": self.lines, "ended_by": self.ended_by,
                "elapsed_s": self.elapsed_s, "cpu_share": self.cpu_s / self.elapsed_s
                if self.elapsed_s > 0 else None,
                "malformed_reasons": self.malformed_reasons, "stream": self.stream,
                "sinks": self.sinks}


def _reader(source, items: queue.Queue, stop: threading.Event, counts: dict) -> None:
    """The source thread: read, queue (drop when full, unless the source can wait)."""
    wait = getattr(source, "virtual_clock", False)
    try:
        while not stop.is_set():
            got = source.read(0.1)
            if got is None:
                break
            for item in got:
                if wait:
                    while not stop.is_set():
                        try:
                            items.put(item, timeout=0.1)
                            break
                        except queue.Full:
                            continue
                else:
                    try:
                        items.put_nowait(item)
                    except queue.Full:
                        counts["dropped"] += 1
    except Exception as err:  # noqa: BLE001 - the loop must end cleanly, saying why
        counts["error"] = f"{type(err).__name__}: {err}"
    finally:
        items.put(None)  # the end of the stream


def run_live(source, filt, sinks=(), *, duration_s: float | None = None,
             max_samples: int | None = None, stop: threading.Event | None = None,
             queue_size: int = 10_000, live: LiveFilter | None = None,
             on_estimate=None, idle_timeout_s: float | None = None) -> LiveRun:
    """Run ``filt`` on ``source`` (opened, ``gnomon.live.sources``) into ``sinks`` (objects
    with ``write(est, arrivals)`` and ``close()``) until the stream ends (module
    docstring). ``live``: the ``LiveFilter`` to use (default: one around ``filt``).
    ``idle_timeout_s``: end when nothing has arrived for that long after the first item
    (a sender that vanished; default: wait).
    Returns the :class:`LiveRun`; sinks are closed, the source too."""
    stop = stop or threading.Event()
    live = live or LiveFilter(filt)
    run = LiveRun(filter=filt.name, source=getattr(source, "url", str(source)))
    items: queue.Queue = queue.Queue(maxsize=queue_size)
    counts = {"dropped": 0}
    reader = threading.Thread(target=_reader, args=(source, items, stop, counts),
                              name="gnomon-live-source", daemon=True)
    t0, c0 = time.perf_counter(), time.process_time()
    started = last_item = t0  # --duration counts from here
    reader.start()
    virtual = getattr(source, "virtual_clock", False)

    def emit(chunks) -> bool:
        """Write ``chunks``; whether ``max_samples`` is reached."""
        now = time.perf_counter()
        for est, arrivals in chunks:
            n = len(est.t)
            if max_samples is not None and run.samples + n >= max_samples:
                keep = max_samples - run.samples
                est, arrivals, n = _head(est, keep), arrivals[:keep], keep
            if run.samples:  # the first chunk is the start (it waited for the warm-up)
                run.latencies_s.extend(now - a for a in arrivals)
            else:
                run.startup_s = max((now - a for a in arrivals), default=0.0)
            run.samples += n
            for sink in sinks:
                sink.write(est, arrivals)
            if on_estimate is not None:
                on_estimate(est)
        return max_samples is not None and run.samples >= max_samples

    try:
        while True:
            if stop.is_set():
                run.ended_by = "signal"
                break
            if duration_s is not None and time.perf_counter() - started >= duration_s:
                run.ended_by = "duration"
                break
            if idle_timeout_s is not None and run.lines and \
                    time.perf_counter() - last_item > idle_timeout_s:
                run.ended_by = f"end of stream: nothing arrived for {idle_timeout_s:g} s"
                break
            try:
                item = items.get(timeout=0.02)
            except queue.Empty:
                if not virtual:  # nothing new: the rows held for late samples run now
                    now = time.perf_counter()
                    got = live.poll(now)
                    if got and emit([(est, list(live.row_arrivals)) for est in got]):
                        run.ended_by = "max samples"
                        break
                continue
            if item is None:
                if stop.is_set():  # the signal closed the source before this loop saw it
                    run.ended_by = "signal"
                    break
                why = getattr(source, "ended", "")  # a source that gave up says why
                run.ended_by = "error: " + counts["error"] if "error" in counts \
                    else "end of stream" + (f": {why}" if why else "")
                break
            arrival, payload = item
            last_item = time.perf_counter()
            if not run.lines:  # time and CPU count from the first item on (not the wait)
                t0, c0 = time.perf_counter(), time.process_time()
            run.lines += 1
            try:
                samples = source.samples(payload)
            except Malformed as err:
                run.malformed += 1
                why = str(err)
                run.malformed_reasons[why] = run.malformed_reasons.get(why, 0) + 1
                continue
            chunks = []
            for sensor, t, value in samples:
                got = live.push(sensor, t, value, arrival_s=t if virtual else arrival)
                chunks.extend((est, _real(live.row_arrivals, arrival, virtual))
                              for est in got)
            if chunks and emit(chunks):
                run.ended_by = "max samples"
                break
        if run.ended_by in ("signal", "duration") or \
                run.ended_by.startswith(("end of stream", "error")):
            now = time.perf_counter()
            emit([(est, _real(live.row_arrivals, now, virtual)) for est in live.flush()])
    finally:
        stop.set()
        reader.join(timeout=2.0)
        source.close()
        run.dropped = counts["dropped"]
        for sink in sinks:
            try:
                sink.close()
                run.sinks.append(sink.describe())
            except Exception as err:  # noqa: BLE001 - close the others
                run.sinks.append({"sink": type(sink).__name__, "error": str(err)})
        run.stream = live.stats.to_dict()
        run.elapsed_s = time.perf_counter() - t0
        run.cpu_s = time.process_time() - c0
    return run


def _real(arrivals, arrival: float, virtual: bool) -> list[float]:
    """Arrival times (perf_counter) of a chunk's rows: a replay's rows are stamped on the
    replay's clock, so they count from the arrival of the item that completed them."""
    return [arrival] * len(arrivals) if virtual else list(arrivals)


def _head(est, n: int):
    """The first ``n`` rows of an ``Estimate``."""
    import dataclasses

    return dataclasses.replace(est, t=est.t[:n], q=est.q[:n],
                               signals={k: np.asarray(v)[:n] for k, v in est.signals.items()})
