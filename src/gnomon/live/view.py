"""The browser view of a live run: ``gnomon live SOURCE --view PORT``.

One port serves both halves (the ``websockets`` library, in a thread of its own running
asyncio): ``GET /`` returns the page (``view.html``, package data: inline JavaScript, no
file fetched from anywhere else), and ``/ws`` is a WebSocket that sends every connected
browser the latest state as JSON, at most ``rate_hz`` (30) times a second. The page draws
the body rotated by the estimate (a box on a canvas, a hand-written projection), the roll,
pitch and yaw of the last 20 s, the gyro bias and the filter's flags.

:meth:`ViewSink.write` never waits for the network: it hands the chunk to the server
thread (a list append under a lock held for a microsecond), which digests what came
``rate_hz`` times a second (the newest row; a thinned history, one point per
``trace_dt_s`` of stream time, the last ``history_s``) and sends the frames. A browser is
sent the newest state when it can take it, never a backlog of old ones: the page
acknowledges each frame it has drawn and is sent nothing while two are undrawn (a busy or
hidden tab), and each socket's buffers are kept small (``SEND_BUFFER_BYTES``) for a
client that reads slowly. The frames a browser missed are counted (``frames_dropped``).

A frame (one JSON object)::

    {"estimator": "mahony", "frames": {"reference": "ENU", "body": "sensor"},
     "t": s, "q": [w, x, y, z] (q_ENU<-body, Hamilton), "euler_deg": [roll, pitch, yaw]
     (z-y'-x''), "bias_deg_s": [x, y, z] or null, "flags": {name: bool}, "flag_rows":
     {name: rows the flag was set}, "values": {other signals: number or list},
     "rows": estimates so far, "rate_hz": estimates per second (wall clock, last 2 s),
     "clients": browsers connected, "history": true on the first frame after connecting,
     "trace": [[t, roll, pitch, yaw], ...] the points since the previous frame (the first
     frame: the whole history), "ended": true on the last frame (the run has ended)}

The page answers each frame with a text message ("ack") when it has drawn it.

Everything listens on 127.0.0.1 unless ``host`` (``--bind``) says otherwise.

**A Foxglove user** would rather open the stream in Foxglove: foxglove-sdk has its own
WebSocket server (``foxglove.start_server``) which Foxglove's app connects to
(``ws://HOST:PORT``), with the 3-D panel, plots and the raw messages.
:class:`FoxgloveViewSink` does that with the same data: a ``foxglove.FrameTransform``
``enu`` -> ``body`` (the attitude; the 3-D panel shows the body's axes), a
``foxglove.PoseInFrame`` and a JSON ``/gnomon/state`` (Euler angles, bias in deg/s, flags)
for the plots; Foxglove's schemas, as an MCAP file written with ``--mcap`` uses them.
``gnomon live`` does not offer it yet (``--view`` takes a port number).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import socket
import threading
import time
from collections import deque
from http import HTTPStatus
from importlib import resources

import numpy as np

from gnomon.errors import InputError
from gnomon.live.sinks import estimate_rows

__all__ = ["ViewSink", "FoxgloveViewSink", "page_html"]

#: the kernel's send buffer of each browser's socket (bytes): what a browser that reads
#: slowly can fall behind by, with the write limit (left to the kernel, it grows to MB)
SEND_BUFFER_BYTES = 65536


def page_html() -> bytes:
    """The page (``gnomon/live/view.html``)."""
    return resources.files("gnomon.live").joinpath("view.html").read_bytes()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


class ViewSink:
    """``--view PORT``: the page at ``http://HOST:PORT/`` and its data at ``/ws``.

    ``port`` 0 picks a free port (``self.port`` is the one chosen). Raises ``InputError``
    (field ``--view``) when the port cannot be opened. ``rate_hz``: frames per second and
    browser at most; ``history_s``: seconds of trace a browser gets when it connects;
    ``trace_dt_s``: stream seconds between the trace's points.
    """

    def __init__(self, port: int, host: str = "127.0.0.1", *, rate_hz: float = 30.0,
                 history_s: float = 30.0, trace_dt_s: float = 0.02):
        try:
            from websockets.asyncio.server import serve  # noqa: F401 - checked here
        except ImportError:
            raise InputError("the live view needs the websockets package: pip install "
                             "websockets", field="--view") from None
        self.host = host
        self.port = int(port)
        self.period_s = 1.0 / float(rate_hz)
        self.history_s = float(history_s)
        self.trace_dt_s = float(trace_dt_s)
        self.page = page_html()
        self.rows = 0  #: estimates written
        self.clients = 0  #: browsers (WebSocket clients) that connected, in all
        self.connected = 0  #: browsers connected now
        self.frames_sent = 0
        self.frames_dropped = 0  #: frames a slow browser missed while its last one was sent
        self.errors = 0  #: connections lost mid-frame
        # shared with the live loop (under _lock): the chunks written since the last digest
        self._lock = threading.Lock()
        self._inbox: list = []
        # the server thread's own: the digested state
        self._latest: dict | None = None  # the newest row, JSON-ready
        self._version = 0  # counts digests that brought something new
        self._trace: deque = deque(maxlen=int(2 * self.history_s / self.trace_dt_s) + 16)
        self._seq = 0  # sequence number of the next trace point
        self._bin = None  # stream-time bin of the last trace point
        self._t_last = -np.inf
        self._flag_rows: dict[str, int] = {}
        self._digested = 0  # rows digested
        self._marks: deque = deque()  # (perf_counter, rows digested) for the rate
        self._loop = None
        self._stop = None
        self._error = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="gnomon-live-view",
                                        daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None or self._loop is None:
            self._thread.join(timeout=1.0)
            raise InputError(f"cannot serve the view on {host}:{port}: {self._error}",
                             field="--view")
        self.url = f"http://{_url_host(host)}:{self.port}/"

    # ------------------------------------------------------------------ the live loop side
    def write(self, est, arrivals=None) -> None:
        """Hand ``est`` to the server thread; a few microseconds, never a wait on a
        browser (the rows are converted there, ``rate_hz`` times a second)."""
        n = len(est.t)
        if n:
            with self._lock:
                self._inbox.append(est)
                self.rows += n

    def close(self) -> None:
        """Send every browser a last frame (``ended``), then stop the server."""
        if self._loop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=5.0)

    def describe(self) -> dict:
        return {"sink": "view", "url": self.url, "clients": self.clients,
                "rows": self.rows, "frames": self.frames_sent,
                "frames_dropped": self.frames_dropped}

    # ------------------------------------------------------------------ the server side
    def _digest(self) -> None:
        """The chunks written since the last call: the newest row, the trace points, the
        flags' counts, the rate."""
        with self._lock:
            chunks, self._inbox = self._inbox, []
        now = time.perf_counter()
        if chunks:
            t = np.concatenate([np.asarray(c.t, dtype=float) for c in chunks])
            q = np.concatenate([np.asarray(c.q, dtype=float) for c in chunks])
            for c in chunks:
                for k, v in c.signals.items():
                    v = np.asarray(v)
                    if v.dtype == bool:
                        self._flag_rows[k] = self._flag_rows.get(k, 0) + int(np.count_nonzero(v))
            est = chunks[-1]
            last = dataclasses.replace(est, t=t[-1:], q=q[-1:],
                                       signals={k: np.asarray(v)[-1:]
                                                for k, v in est.signals.items()})
            row = next(estimate_rows(last))
            flags = {k: v for k, v in row.items() if isinstance(v, bool)}
            bias = row.get("bias_rad_s")
            self._latest = {
                "estimator": est.estimator, "frames": dict(est.frames),
                "t": row["t"], "q": row["q"], "euler_deg": row["euler_deg"],
                "bias_deg_s": None if bias is None else
                [None if b is None else float(np.degrees(b)) for b in bias],
                "flags": flags,
                "values": {k: v for k, v in row.items() if k not in
                           ("t", "q", "euler_deg", "bias_rad_s") and k not in flags},
            }
            self._add_points(t, q)
            self._digested += len(t)
            self._version += 1
        self._marks.append((now, self._digested))
        while len(self._marks) > 1 and now - self._marks[0][0] > 2.0:
            self._marks.popleft()

    def _add_points(self, t, q) -> None:
        """The trace: the first row in every new ``trace_dt_s`` bin of stream time, the
        last ``history_s``; a clock that goes back starts a new trace."""
        from gnomon.rotation import euler_from_quat

        if t[0] < self._t_last:
            self._trace.clear()
            self._bin = None
        self._t_last = float(t[-1])
        bins = np.floor(t / self.trace_dt_s)
        prev = np.concatenate([[np.nan if self._bin is None else self._bin], bins[:-1]])
        keep = np.flatnonzero(bins != prev)
        self._bin = float(bins[-1])
        if keep.size:
            euler = np.degrees(euler_from_quat(q[keep]))
            for k, e in zip(keep, euler, strict=True):
                self._trace.append((self._seq, [round(float(t[k]), 4),
                                                *np.round(e, 3).tolist()]))
                self._seq += 1
        while self._trace and self._trace[0][1][0] < self._t_last - self.history_s:
            self._trace.popleft()

    def _rate_hz(self) -> float:
        """Estimates per second over the last 2 s (wall clock)."""
        (t0, n0), (t1, n1) = self._marks[0], self._marks[-1]
        return (n1 - n0) / (t1 - t0) if t1 - t0 > 0.2 else 0.0

    def _frame(self, since: int, first: bool, ended: bool) -> tuple[str, int]:
        """The JSON frame for a browser that holds the trace up to point ``since``, and the
        last point it will hold."""
        trace = []
        for seq, p in reversed(self._trace):
            if seq <= since:
                break
            trace.append(p)
        last = self._trace[-1][0] if self._trace else since
        frame = dict(self._latest or {}, rows=self._digested,
                     rate_hz=round(self._rate_hz(), 1), flag_rows=dict(self._flag_rows),
                     clients=self.connected, trace=trace[::-1])
        if first:
            frame["history"] = True
        if ended:
            frame["ended"] = True
        return json.dumps(frame, allow_nan=False), last

    def _http(self, connection, request):
        """``process_request``: the page for ``GET /``, the handshake for ``/ws``."""
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]
        if path == "/ws":
            return None
        if path in ("/", "/index.html"):
            status, body, kind = HTTPStatus.OK, self.page, "text/html; charset=utf-8"
        else:
            status, kind = HTTPStatus.NOT_FOUND, "text/plain; charset=utf-8"
            body = b"not here: the view is at / and its data at /ws\n"
        headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))),
                           ("Cache-Control", "no-store"), ("Connection", "close")])
        return Response(status.value, status.phrase, headers, body)

    async def _client(self, ws) -> None:
        """One browser: a frame whenever there is something new, at most every
        ``period_s``; the newest state only, however slowly it reads. The page says "ack"
        after drawing each frame: a page that has not drawn the last two is sent nothing
        until it has (a busy or hidden tab). Any client is held to what its socket's
        buffer (``SEND_BUFFER_BYTES``) and the write limit take."""
        from websockets.exceptions import ConnectionClosed

        loop = asyncio.get_running_loop()
        self.clients += 1
        self.connected += 1
        sock = ws.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        acks = [0]

        async def read_acks():
            try:
                async for _ in ws:
                    acks[0] += 1
            except ConnectionClosed:
                pass

        closed = asyncio.ensure_future(read_acks())
        stopped = asyncio.ensure_future(self._stop.wait())
        version, since, first, sent = -1, -1, True, 0
        try:
            while True:
                ended = self._stop.is_set()
                if ended:
                    self._digest()  # what was written last
                if first or ended or self._version != version:
                    if acks[0] and sent - acks[0] >= 2 and not ended:
                        self.frames_dropped += 1  # the page is still drawing
                    else:
                        version = self._version
                        frame, since = self._frame(since, first, ended)
                        t0 = loop.time()
                        await ws.send(frame)
                        sent += 1
                        self.frames_sent += 1
                        self.frames_dropped += int((loop.time() - t0) / self.period_s)
                        first = False
                    if ended:
                        await ws.close(1001, "the live run has ended")
                        break
                done, _ = await asyncio.wait({closed, stopped}, timeout=self.period_s)
                if closed in done:
                    break
        except ConnectionClosed:
            self.errors += 1
        finally:
            self.connected -= 1
            closed.cancel()
            stopped.cancel()

    def _serve(self) -> None:
        try:
            asyncio.run(self._main())
        except Exception as err:  # noqa: BLE001 - said by the constructor
            self._error = err
            self._ready.set()

    async def _main(self) -> None:
        from websockets.asyncio.server import serve

        self._stop = asyncio.Event()
        try:
            server = await serve(self._client, self.host, self.port,
                                 process_request=self._http, compression=None,
                                 close_timeout=1.0, max_size=4096,
                                 write_limit=SEND_BUFFER_BYTES // 2)
        except OSError as err:
            self._error = err
            self._ready.set()
            return
        self.port = server.sockets[0].getsockname()[1]
        self._loop = asyncio.get_running_loop()
        self._ready.set()
        while not self._stop.is_set():  # the digest runs whether a browser is there or not
            self._digest()
            try:
                await asyncio.wait_for(self._stop.wait(), timeout=self.period_s)
            except TimeoutError:
                pass
        self._digest()
        for _ in range(50):  # the browsers get their last frame
            if self.connected == 0:
                break
            await asyncio.sleep(0.02)
        server.close()
        try:  # a connection still opening (a browser's spare socket) is not waited for
            await asyncio.wait_for(server.wait_closed(), timeout=0.5)
        except TimeoutError:
            pass


class FoxgloveViewSink:
    """``foxglove.start_server`` with the estimates: for a Foxglove user (module
    docstring). Topics: ``/gnomon/tf`` (``foxglove.FrameTransform``, parent ``enu``, child
    ``body``: q_ENU<-body), ``/gnomon/pose`` (``foxglove.PoseInFrame`` in ``enu``) and
    ``/gnomon/state`` (JSON: t, euler_deg, bias_deg_s, flags), each at most ``rate_hz``
    messages a second (the newest row). Stamped with this computer's clock (a live
    view); the stream's own time is ``t`` in the state. ``port`` 0: a free port
    (``self.port``)."""

    def __init__(self, port: int, host: str = "127.0.0.1", *, rate_hz: float = 100.0):
        try:
            import foxglove
            from foxglove.channels import FrameTransformChannel, PoseInFrameChannel
        except ImportError:
            raise InputError("the Foxglove view needs foxglove-sdk: pip install "
                             "foxglove-sdk", field="--view") from None
        self._foxglove = foxglove
        self.context = foxglove.Context()  # its own: nothing else logged goes to it
        try:
            self.server = foxglove.start_server(name="gnomon live", host=host, port=int(port),
                                                context=self.context)
        except Exception as err:  # noqa: BLE001 - foxglove raises its own error types
            raise InputError(f"cannot serve Foxglove on {host}:{port}: {err}",
                             field="--view") from None
        self.port = self.server.port
        self.url = f"ws://{_url_host(host)}:{self.port}"
        self.tf = FrameTransformChannel("/gnomon/tf", context=self.context)
        self.pose = PoseInFrameChannel("/gnomon/pose", context=self.context)
        self.state = foxglove.Channel("/gnomon/state", context=self.context)
        self.period_s = 1.0 / float(rate_hz)
        self._next = 0.0
        self.rows = self.sent = 0

    def write(self, est, arrivals=None) -> None:
        n = len(est.t)
        self.rows += n
        now = time.perf_counter()
        if n == 0 or now < self._next:
            return
        self._next = now + self.period_s
        from foxglove.messages import (
            FrameTransform,
            Pose,
            PoseInFrame,
            Quaternion,
            Timestamp,
            Vector3,
        )

        last = dataclasses.replace(est, t=est.t[-1:], q=np.asarray(est.q)[-1:],
                                   signals={k: np.asarray(v)[-1:]
                                            for k, v in est.signals.items()})
        row = next(estimate_rows(last))
        w, x, y, z = row["q"]
        stamp = Timestamp.now()
        rotation = Quaternion(x=x, y=y, z=z, w=w)
        origin = Vector3(x=0.0, y=0.0, z=0.0)
        self.tf.log(FrameTransform(timestamp=stamp, parent_frame_id="enu",
                                   child_frame_id="body", translation=origin,
                                   rotation=rotation))
        self.pose.log(PoseInFrame(timestamp=stamp, frame_id="enu",
                                  pose=Pose(position=origin, orientation=rotation)))
        bias = row.get("bias_rad_s")
        self.state.log({"t": row["t"], "euler_deg": dict(zip(("roll", "pitch", "yaw"),
                                                             row["euler_deg"], strict=True)),
                        "bias_deg_s": None if bias is None else
                        {a: None if b is None else float(np.degrees(b))
                         for a, b in zip("xyz", bias, strict=True)},
                        "flags": {k: v for k, v in row.items() if isinstance(v, bool)}})
        self.sent += 1

    def close(self) -> None:
        self.server.stop()

    def describe(self) -> dict:
        return {"sink": "foxglove", "url": self.url, "rows": self.rows, "sent": self.sent}
