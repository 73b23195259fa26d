"""Where live samples come from: a UDP socket, a serial port, a MAVLink connection, or a
replay of any recording gnomon reads — one interface, chosen by a URL.

A source is read by :mod:`gnomon.live.runner` in a thread of its own: ``read(timeout_s)``
returns the items that arrived (``(arrival_s, payload)``, ``arrival_s`` from
``time.perf_counter`` when the bytes came in), ``[]`` when none did, and ``None`` when the
stream has ended; ``samples(payload)`` turns one payload into ``[(sensor, t_s, value)]``
in SI units, or raises :class:`~gnomon.live.parse.Malformed`. Nothing here runs a filter.

URLs (``open_source``):

==================================  ==================================================
``udp://HOST:PORT``                 one sample per datagram or line (CSV or JSON lines,
                                    :mod:`gnomon.live.parse`); listens on HOST
``serial://DEVICE?baud=N``          the same line formats from a serial port (pyserial);
                                    a vanished device is waited for and reopened
``mavlink://udpin:HOST:PORT``       MAVLink IMU messages (pymavlink); also
``mavlink://DEVICE?baud=N``         ``udpout:``, ``tcp:`` and serial devices
``replay://FILE?speed=X``           any recording gnomon reads, each sensor at its own
                                    stamps, X times real time (0: as fast as it goes)
==================================  ==================================================

Every socket listens on 127.0.0.1 unless the URL names another address.
"""

from __future__ import annotations

import socket
import time
from urllib.parse import parse_qs, urlsplit

import numpy as np

from gnomon.errors import InputError
from gnomon.live.parse import LineParser, Malformed

__all__ = ["open_source", "Source", "UdpSource", "SerialSource", "ReplaySource", "SCHEMES"]

SCHEMES = ("udp", "serial", "mavlink", "replay")
#: longest line kept while waiting for its end (bytes): longer ones are garbage
MAX_LINE_BYTES = 4096


class Source:
    """Base class (module docstring). ``virtual_clock``: the samples' stamps are the
    stream's clock (a replay), so the stream never reads their steps as clock jumps."""

    url = ""
    virtual_clock = False
    #: what the source assumed (units, frames), said by ``gnomon live``
    assumed: tuple[str, ...] = ()
    #: why ``read`` returned None, when the stream did not simply end (one line: a device
    #: that vanished and did not come back), said in ``LiveRun.ended_by``
    ended = ""

    def open(self) -> None:
        """Open the connection (raises ``InputError`` naming the URL when it cannot)."""

    def read(self, timeout_s: float):  # pragma: no cover - every source overrides
        raise NotImplementedError

    def samples(self, payload) -> list:
        raise NotImplementedError  # pragma: no cover

    def close(self) -> None:
        """Release the connection (safe to call twice)."""


class _Broken:
    """An item that is not a line: a line longer than ``MAX_LINE_BYTES`` without its end, or
    the partial line a vanished device left. ``samples`` raises ``Malformed(reason)``."""

    def __init__(self, reason: str):
        self.reason = reason


class _Lines:
    """Bytes in, complete lines out; a line longer than ``MAX_LINE_BYTES`` is dropped (up to
    its end, when that has not come yet) and reported once, however the bytes were cut (a
    :class:`_Broken` item, counted by the loop as malformed); ``cut()``: the partial line
    left when the bytes stop for good."""

    def __init__(self):
        self.buffer = b""
        self.overlong = 0
        self._skipping = False  # inside an overlong line: drop up to the next newline

    def feed(self, data: bytes) -> list:
        self.buffer += data
        *lines, self.buffer = self.buffer.split(b"\n")
        if self._skipping:
            if not lines:  # still no end: keep nothing of it
                self.buffer = b""
                return []
            lines = lines[1:]  # the overlong line's tail
            self._skipping = False
        out = [line.rstrip(b"\r") if len(line) <= MAX_LINE_BYTES else
               _Broken(f"a line longer than {MAX_LINE_BYTES} bytes")
               for line in lines if line.strip()]
        if len(self.buffer) > MAX_LINE_BYTES:
            self.buffer = b""
            self.overlong += 1
            self._skipping = True
            out.append(_Broken(f"a line longer than {MAX_LINE_BYTES} bytes"))
        return out

    def cut(self) -> list:
        """The partial line left (as a :class:`_Broken` item), and a fresh start."""
        left = self.buffer.strip() and not self._skipping
        self.buffer, self._skipping = b"", False
        return [_Broken("a partial line (the device vanished)")] if left else []


def _host_port(netloc: str, url: str) -> tuple[str, int]:
    host, _, port = netloc.rpartition(":")
    try:
        port = int(port)
    except ValueError:
        raise InputError(f"expected HOST:PORT, got {netloc!r}", field="source") from None
    if not 0 <= port < 65536:
        raise InputError(f"port out of range in {url!r}", field="source")
    return host or "127.0.0.1", port


class UdpSource(Source):
    """``udp://HOST:PORT``: datagrams of one or more lines (a datagram is a line even
    without its newline)."""

    def __init__(self, url: str, parser: LineParser):
        self.url = url
        self.host, self.port = _host_port(urlsplit(url).netloc, url)
        self.parser = parser
        self.sock = None

    def open(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        try:
            self.sock.bind((self.host, self.port))
        except OSError as err:
            self.sock.close()
            raise InputError(f"cannot listen on {self.host}:{self.port} ({err.strerror})",
                             field="source") from None
        self.port = self.sock.getsockname()[1]  # port 0: the one the system chose

    def read(self, timeout_s: float):
        self.sock.settimeout(timeout_s)
        out = []
        try:
            data, _ = self.sock.recvfrom(65536)
        except TimeoutError:
            return out
        except OSError:
            return None
        arrival = time.perf_counter()
        out.extend((arrival, line) for line in data.split(b"\n") if line.strip())
        self.sock.setblocking(False)
        try:  # whatever else is already waiting, without blocking
            while len(out) < 256:
                data, _ = self.sock.recvfrom(65536)
                arrival = time.perf_counter()
                out.extend((arrival, line) for line in data.split(b"\n") if line.strip())
        except (BlockingIOError, OSError):
            pass
        return out

    def samples(self, payload) -> list:
        return self.parser.parse(payload)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class SerialSource(Source):
    """``serial://DEVICE?baud=N`` (pyserial; ``DEVICE`` a path such as ``/dev/ttyUSB0``):
    lines as for UDP. When the device vanishes (a read fails) the source waits for it,
    reopening every ``retry_s`` (``reconnects``), and ends after ``give_up_s`` without it,
    saying so in ``ended``. A line cut by the vanishing and a line longer than
    ``MAX_LINE_BYTES`` are each one malformed item."""

    def __init__(self, url: str, parser: LineParser, give_up_s: float = 10.0,
                 retry_s: float = 0.5):
        parts = urlsplit(url)
        self.url = url
        self.device = parts.netloc + parts.path
        query = parse_qs(parts.query)
        try:
            self.baud = int(query.get("baud", ["115200"])[0])
        except ValueError:
            raise InputError(f"baud must be a number in {url!r}", field="source") from None
        if not self.device:
            raise InputError(f"no device in {url!r}: serial:///dev/ttyUSB0?baud=115200",
                             field="source")
        self.parser = parser
        self.lines = _Lines()
        self.give_up_s, self.retry_s = give_up_s, retry_s
        self.port = None
        self.lost_at = None  # perf_counter time the device was lost
        self.reconnects = 0
        self.error = ""  # why the device could not be opened, last time

    def _connect(self) -> bool:
        try:
            import serial
        except ImportError:
            raise InputError("serial sources need pyserial: pip install 'gnomon[live]'",
                             field="source") from None
        try:
            self.port = serial.Serial(self.device, self.baud, timeout=0.1)
        except (OSError, serial.SerialException) as err:
            self.port = None
            self.error = str(err)
            return False
        return True

    def open(self) -> None:
        if not self._connect():
            raise InputError(f"cannot open {self.device} ({self.error})", field="source")

    def read(self, timeout_s: float):
        import serial

        if self.port is None:  # lost: wait for the device to come back
            if time.perf_counter() - self.lost_at > self.give_up_s:
                self.ended = (f"{self.device} vanished and was not back after "
                              f"{self.give_up_s:g} s ({self.reconnects} reconnects before)")
                return None
            time.sleep(min(self.retry_s, timeout_s))
            if self._connect():
                self.reconnects += 1
                self.lost_at = None
            return []
        try:
            if self.port.timeout != timeout_s:  # pyserial reconfigures the port on each set
                self.port.timeout = timeout_s
            data = self.port.read(max(1, self.port.in_waiting))
        except (OSError, serial.SerialException):
            self.close()
            self.lost_at = time.perf_counter()
            return [(self.lost_at, item) for item in self.lines.cut()]
        arrival = time.perf_counter()
        return [(arrival, line) for line in self.lines.feed(data)]

    def samples(self, payload) -> list:
        if isinstance(payload, _Broken):
            raise Malformed(payload.reason)
        return self.parser.parse(payload)

    def close(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # noqa: BLE001 - a vanished device may fail to close
                pass
            self.port = None


class ReplaySource(Source):
    """``replay://FILE?speed=X``: a recording (any format ``gnomon.io.read`` knows; reader
    options as ``read_options``) sample by sample, each sensor at its own stamps, in time
    order (at equal stamps the accelerometer and magnetometer before the gyro, as
    ``Recording.on_time_base`` puts them in the gyro's row), at ``X`` times real time
    (default 1; 0: as fast as the filter takes them)."""

    virtual_clock = True

    def __init__(self, url: str, read_options: dict | None = None, chunk: int = 64):
        parts = urlsplit(url)
        self.url = url
        self.path = parts.netloc + parts.path
        query = parse_qs(parts.query)
        try:
            self.speed = float(query.get("speed", ["1"])[0])
        except ValueError:
            raise InputError(f"speed must be a number in {url!r}", field="source") from None
        if not self.speed >= 0:
            raise InputError(f"speed must be >= 0 in {url!r}", field="source")
        self.read_options = dict(read_options or {})
        self.chunk = chunk
        self.rec = None

    def open(self) -> None:
        from gnomon.io import read

        self.rec = read(self.path, **self.read_options)
        self.events = _replay_events(self.rec)
        self.next = 0
        self.start = None
        self.assumed = (f"replay of {self.path}: {len(self.rec)} gyro samples at "
                        f"{self.speed:g}x real time",)

    def read(self, timeout_s: float):
        t, sensor, rows = self.events
        if self.next >= len(t):
            return None
        now = time.perf_counter()
        if self.start is None:
            self.start = now - 0.0
        i = self.next
        stop = min(len(t), i + self.chunk)
        if self.speed > 0:  # wait for the first one that is due
            due = self.start + (t[i] - t[0]) / self.speed
            if due > now:
                time.sleep(min(due - now, timeout_s))
                now = time.perf_counter()
            elapsed = (now - self.start) * self.speed
            stop = i + int(np.searchsorted(t[i:stop], t[0] + elapsed, side="right"))
            if stop == i:
                return []
        self.next = stop
        return [(now, (sensor[k], t[k], rows[k])) for k in range(i, stop)]

    def samples(self, payload) -> list:
        return [payload]


def _replay_events(rec):
    """Every sample of ``rec`` as (stamps, sensor names, values) in the order of their
    stamps, the gyro after the others at equal stamps; the magnetometer in µT."""
    from gnomon.recording import MAG_UNITS_TO_TESLA

    parts = [(rec.times(name), getattr(rec, name), rank, name)
             for rank, name in ((1, "accel"), (2, "mag"), (3, "gyro"))
             if getattr(rec, name) is not None]
    t = np.concatenate([p[0] for p in parts])
    rank = np.concatenate([np.full(len(p[0]), p[2]) for p in parts])
    values = np.concatenate([p[1] * (MAG_UNITS_TO_TESLA[rec.mag_unit] * 1e6
                                     if p[3] == "mag" else 1.0) for p in parts])
    names = np.concatenate([np.full(len(p[0]), p[3]) for p in parts])
    order = np.lexsort((rank, t))
    return t[order], names[order].tolist(), values[order]


def open_source(url: str, parser: LineParser | None = None, *, read_options=None,
                give_up_s: float = 10.0) -> Source:
    """The source for ``url`` (module docstring), opened."""
    scheme = urlsplit(url).scheme
    parser = parser or LineParser()
    if scheme == "udp":
        src = UdpSource(url, parser)
    elif scheme == "serial":
        src = SerialSource(url, parser, give_up_s=give_up_s)
    elif scheme == "replay":
        src = ReplaySource(url, read_options)
    elif scheme == "mavlink":
        from gnomon.live.mavlink import MavlinkSource

        src = MavlinkSource(url, give_up_s=give_up_s)
    else:
        raise InputError(f"unknown source {url!r}; use one of "
                         f"{', '.join(s + '://' for s in SCHEMES)}", field="source")
    src.open()
    return src


__all__ += ["Malformed"]
