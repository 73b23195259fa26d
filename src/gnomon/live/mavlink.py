"""MAVLink in and out (pymavlink): a flight controller's or a simulator's IMU messages as
live samples, and the estimate sent back as ``ATTITUDE_QUATERNION``.

URLs (``gnomon live mavlink://...``; pymavlink's connection strings after the scheme):

===========================================  ===============================================
``mavlink://udpin:HOST:PORT``                listen on HOST (``udpin::PORT`` or
                                             ``udpin:PORT``: 127.0.0.1; port 0: the system
                                             picks one, ``MavlinkSource.address`` says it)
``mavlink://udpout:HOST:PORT``               send to HOST:PORT and read the answers
``mavlink://tcp:HOST:PORT``                  connect to a TCP server (SITL's 5760)
``mavlink:///dev/ttyACM0?baud=N``            a serial device (default 115200 baud)
===========================================  ===============================================

Query options: ``baud=N``; ``instance=N`` (which IMU; default: the first seen);
``message=NAME`` (one of :data:`IMU_MESSAGES`; default: the first seen of the chosen IMU);
``sysid=N``, ``compid=N`` (what this end sends as; default 255 and 191, an onboard
computer); ``out_hz=X`` (at most X ``ATTITUDE_QUATERNION`` a second of the sensor clock; 0:
every estimate; default 0, 50 on a serial device). On the ``udpout`` and ``tcp`` client
links a ``HEARTBEAT`` is sent once a second, so that the other end knows where to answer.

Messages read (units as MAVLink's ``common.xml``), converted to gnomon's units (s, rad/s,
m/s², µT):

==================  ===========  ===========  ===========  =======  ==================
message             accel        gyro         mag          time     IMU instance
==================  ===========  ===========  ===========  =======  ==================
``HIGHRES_IMU``     m/s²         rad/s        gauss (100   µs       ``id`` (MAVLink 2;
                                              µT)          (usec)   0 in MAVLink 1)
``SCALED_IMU``,     mG (g/1000,  mrad/s       mgauss (0.1  ms       0, 1, 2
``…2``, ``…3``      g = 9.80665               µT)          (boot)
                    m/s²)
``RAW_IMU``         mG           mrad/s       mgauss       µs       ``id``
==================  ===========  ===========  ===========  =======  ==================

* ``HIGHRES_IMU``'s ``fields_updated`` bits say which sensors are new (any of a sensor's
  three bits: a sample of it); a message with none is no sample.
* ``SCALED_IMU*`` and ``RAW_IMU`` have no such bits: every message is a new sample of all
  three sensors, except an all-zero magnetometer (an autopilot without a compass sends
  zeros), which is no sample.
* ``RAW_IMU`` is read in ``SCALED_IMU``'s units, as ArduPilot fills it (the message's
  definition allows raw ADC counts, which other senders may put there: then it is wrong).
* One IMU stream: the first message of an IMU message type and instance (matching
  ``instance`` and ``message`` when given) chooses the stream; other IMU messages are
  counted (``describe``) and ignored, so an ArduPilot sending ``RAW_IMU`` and
  ``SCALED_IMU`` of the same IMU is not read twice. ``assumed`` says which was chosen.
* Time: the sender's stamps (``time_usec``: boot or Unix time as the sender keeps it;
  ``time_boot_ms``), in s. Nothing is stamped on arrival.

Frames: MAVLink's body frame is FRD (x forward, y right, z down) and its reference NED.
Vectors become FLU (``[x, -y, -z]``, :func:`gnomon.io._common.frd_to_flu`, as the ULog and
DataFlash readers do), so that a resting accelerometer reads ``+g`` on z; the estimate is
``q_ENU_FLU``. :class:`MavlinkOutSink` sends it back as MAVLink's ``q_NED_FRD``
(``q1..q4 = w, x, y, z``): :func:`enu_flu_to_ned_frd`, the inverse of the readers'
``ned_frd_to_enu_flu``.

Bad streams: a run of garbage bytes (one item however the bytes were read: pymavlink
reports a serial port's garbage in pieces), a packet with a wrong checksum (pymavlink's
``BAD_DATA``) and an IMU message with a non-finite value are malformed items (counted by
the live loop); a device or TCP peer that fails is reopened every ``retry_s``; a stream
that stays silent (or lost) ``give_up_s`` after it started ends, saying why in one line
(``ended``; before its first message a stream is waited for without end). Nothing of
pymavlink's own printing reaches stdout (``gnomon live --json`` prints there).

Protocol version: pymavlink reads MAVLink 1 and, once it has seen a MAVLink 2 packet,
switches itself (the whole process) to MAVLink 2; the answers go out in the version it is
in (MAVLink 1 until the other end speaks 2).
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from collections import OrderedDict
from typing import NamedTuple
from urllib.parse import parse_qs

import numpy as np

from gnomon.errors import InputError
from gnomon.io._common import Q_ENU_NED, Q_FRD_FLU, frd_to_flu
from gnomon.live.parse import Malformed
from gnomon.rotation import quat_conj, quat_mul

__all__ = ["MavlinkSource", "MavlinkOutSink", "enu_flu_to_ned_frd", "IMU_MESSAGES",
           "G0_M_S2"]

#: standard gravity (m/s² per g): MAVLink's mG
G0_M_S2 = 9.80665
_NETWORK = ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")
_CLIENTS = ("udpout:", "tcp:")  # links on which the other end waits to hear from us
_MAV_TYPE_ONBOARD_CONTROLLER = 18
_MAV_AUTOPILOT_INVALID = 8
_RECENT = 4096  # gyro samples kept for the rates of ATTITUDE_QUATERNION


class _Units(NamedTuple):
    time: str  # the time field
    time_s: float  # s per unit of it
    accel: float  # m/s² per unit
    gyro: float  # rad/s per unit
    mag: float  # µT per unit
    instance: int | None  # the IMU instance, None: the message's ``id`` field


_SCALED = dict(accel=G0_M_S2 / 1000.0, gyro=1e-3, mag=0.1)
#: the IMU messages read, with their units
IMU_MESSAGES = {
    "HIGHRES_IMU": _Units("time_usec", 1e-6, 1.0, 1.0, 100.0, None),
    "SCALED_IMU": _Units("time_boot_ms", 1e-3, **_SCALED, instance=0),
    "SCALED_IMU2": _Units("time_boot_ms", 1e-3, **_SCALED, instance=1),
    "SCALED_IMU3": _Units("time_boot_ms", 1e-3, **_SCALED, instance=2),
    "RAW_IMU": _Units("time_usec", 1e-6, **_SCALED, instance=None),
}
_UNITS_TEXT = {
    "HIGHRES_IMU": "HIGHRES_IMU: m/s^2, rad/s, gauss (x100 -> uT), time_usec (us); "
                   "fields_updated says which sensors are new",
    "SCALED_IMU": "{name}: mG (x 9.80665e-3 -> m/s^2), mrad/s, mgauss (x0.1 -> uT), "
                  "time_boot_ms; every message a sample of the three sensors (an all-zero "
                  "magnetometer: none)",
    "RAW_IMU": "RAW_IMU: read in SCALED_IMU's units (mG, mrad/s, mgauss), as ArduPilot "
               "fills it, time_usec (us); every message a sample of the three sensors (an "
               "all-zero magnetometer: none)",
}
#: HIGHRES_IMU fields_updated bits of each sensor
_UPDATED = {"accel": 0x007, "gyro": 0x038, "mag": 0x1C0}


def enu_flu_to_ned_frd(q_enu_flu) -> np.ndarray:
    """gnomon's ``q_ENU_FLU`` (..., 4) to MAVLink's ``q_NED_FRD = q_NED_ENU ⊗ q_ENU_FLU ⊗
    q_FLU_FRD`` (``[w, x, y, z]``, MAVLink's ``q1..q4``)."""
    return quat_mul(quat_mul(quat_conj(Q_ENU_NED), np.asarray(q_enu_flu, dtype=float)),
                    quat_conj(Q_FRD_FLU))


def _instance(msg) -> int:
    """The IMU instance of an IMU message: fixed by its type, or its ``id`` field (a MAVLink
    2 extension: 0 when the message came as MAVLink 1, whose ``msg.id`` is the message's
    own number)."""
    fixed = IMU_MESSAGES[msg.get_type()].instance
    if fixed is not None:
        return fixed
    buf = msg.get_msgbuf() or b""
    return int(msg.id) if "id" in msg.get_fieldnames() and buf[:1] == b"\xfd" else 0


def _bad_reason(reason: str) -> str:
    """pymavlink's ``BAD_DATA`` reason in a few words (one key per kind in the summary)."""
    if reason.startswith("Bad prefix") or "prefix" in reason:
        return "garbage bytes (not MAVLink)"
    if "CRC" in reason:
        return "MAVLink packet with a wrong checksum"
    return "MAVLink packet that does not decode"


class MavlinkSource:
    """``mavlink://...``: IMU messages of one IMU as samples (module docstring).

    The interface of :class:`gnomon.live.sources.Source` (``open``, ``read``, ``samples``,
    ``close``, ``url``, ``virtual_clock``, ``assumed``, ``ended``), written out rather than
    inherited: ``sources.open_source`` imports this module, and a module importing it
    back would close an import cycle (``tests/test_architecture.py``).

    ``read`` returns ``(arrival_s, message)`` items of the chosen IMU stream and of bad
    data; ``samples(message)`` converts one (FRD -> FLU, SI units, µT). ``conn`` is the
    pymavlink connection (``None`` while a device is lost), ``address`` the ``(host,
    port)`` a UDP or TCP link is on, ``give_up_s`` how long a silent or lost stream is
    waited for, ``retry_s`` how often a lost one is reopened."""

    virtual_clock = False  # the stamps are the sender's clock, not a replay's

    def __init__(self, url: str, give_up_s: float = 10.0, retry_s: float = 0.5):
        self.url = url
        rest = url.split("://", 1)[1] if "://" in url else ""
        device, _, query = rest.partition("?")
        opts = {k: v[-1] for k, v in parse_qs(query).items()}
        known = {"baud", "instance", "message", "sysid", "compid", "out_hz"}
        if set(opts) - known:
            raise InputError(f"unknown option(s) {sorted(set(opts) - known)} in {url!r}; "
                             f"known: {', '.join(sorted(known))}", field="source")

        def number(key, default, kind=int):
            try:
                return kind(opts.get(key, default))
            except ValueError:
                raise InputError(f"{key} must be a number in {url!r}", field="source") from None

        self.baud = number("baud", 115200)
        self.instance = number("instance", None) if "instance" in opts else None
        self.message = opts.get("message")
        if self.message is not None and self.message.upper() not in IMU_MESSAGES:
            raise InputError(f"message must be one of {', '.join(IMU_MESSAGES)} in {url!r}",
                             field="source")
        self.message = self.message.upper() if self.message else None
        self.sysid, self.compid = number("sysid", 255), number("compid", 191)
        self.network = device.startswith(_NETWORK)
        self.out_hz = number("out_hz", 0.0 if self.network else 50.0, float)
        if not device:
            raise InputError(f"no connection in {url!r}: mavlink://udpin:127.0.0.1:14550 or "
                             "mavlink:///dev/ttyACM0?baud=57600", field="source")
        self.device = _with_host(device, url) if self.network else device
        self.give_up_s, self.retry_s = float(give_up_s), float(retry_s)
        self.conn = None
        self.address = None
        self.stream = None  # (message type, instance) chosen
        self.other_imu: dict = {}  # (type, instance) -> messages ignored
        self.ignored = 0  # other messages (HEARTBEAT, ...)
        self.reconnects = 0
        self.link_lost = 0  # packets the link lost (pymavlink, from sequence numbers)
        self.lost_at = None  # perf_counter time the link was lost
        self.last_message = None  # perf_counter time of the last message
        self.ended = ""
        self.send_lock = threading.Lock()  # the sink and the heartbeat send from two threads
        self._last_heartbeat = -math.inf
        self._in_garbage = False  # the last message was garbage bytes (pymavlink's "prefix")
        self._gyro = OrderedDict()  # recent gyro stamps (s) -> (stamp, gyro FRD rad/s)
        self.assumed = self._assumptions()

    # ------------------------------------------------------------------ connection
    def _connect(self) -> None:
        """Open the pymavlink connection (raises what pymavlink raises)."""
        from pymavlink import mavutil

        opts = {}
        if self.device.startswith("tcp:"):  # pymavlink reopens on EOF, quickly, once
            opts = dict(autoreconnect=True, retries=1, reconnect_delay=0.1)
        with contextlib.redirect_stdout(sys.stderr):
            conn = mavutil.mavlink_connection(self.device, baud=self.baud,
                                              source_system=self.sysid,
                                              source_component=self.compid,
                                              robust_parsing=True, **opts)
        port = getattr(conn, "port", None)
        if self.device.startswith(("udpin:", "udp:")) and hasattr(port, "setsockopt"):
            import socket

            port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        if hasattr(port, "getsockname"):
            self.address = port.getsockname()[:2]
            if self.device.startswith("udpin:"):  # port 0: reopen on the one chosen
                self.device = f"udpin:{self.address[0]}:{self.address[1]}"
        self.conn = conn
        self._heartbeat(time.perf_counter())

    def open(self) -> None:
        try:
            self._connect()
        except ImportError:
            raise InputError("MAVLink sources need pymavlink: pip install 'gnomon[live]'",
                             field="source") from None
        except Exception as err:  # noqa: BLE001 - pymavlink raises many kinds
            raise InputError(f"cannot open {self.device} ({type(err).__name__}: {err})",
                             field="source") from None

    def _heartbeat(self, now: float) -> None:
        if self.conn is None or not self.device.startswith(_CLIENTS) \
                or now - self._last_heartbeat < 1.0:
            return
        self._last_heartbeat = now
        with self.send_lock, contextlib.suppress(OSError):
            self.conn.mav.heartbeat_send(_MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID,
                                         0, 0, 0)

    def _lost(self) -> None:
        self.close()
        self.lost_at = time.perf_counter()

    # ------------------------------------------------------------------ reading
    def read(self, timeout_s: float):
        now = time.perf_counter()
        if self.conn is None:  # lost: wait for it to come back
            if now - self.lost_at > self.give_up_s:
                self.ended = (f"{self.device} lost and not back after {self.give_up_s:g} s "
                              f"({self.reconnects} reconnects before)")
                return None
            time.sleep(min(self.retry_s, timeout_s))
            try:
                self._connect()
            except Exception:  # noqa: BLE001 - not back yet
                self.conn = None
                return []
            self.reconnects += 1
            self.lost_at = None
            self.last_message = time.perf_counter()
            return []
        try:
            with contextlib.redirect_stdout(sys.stderr):
                msgs = self._receive(timeout_s)
        except Exception:  # noqa: BLE001 - a vanished device, a reset TCP peer
            self._lost()
            return []
        now = time.perf_counter()
        self._heartbeat(now)
        self.link_lost = int(getattr(self.conn, "mav_loss", 0))
        if msgs:
            self.last_message = now
        elif self.last_message is not None and now - self.last_message > self.give_up_s:
            self.ended = f"no MAVLink message for {self.give_up_s:g} s"
            return None
        out = []
        for m in msgs:
            kind = m.get_type()
            garbage = kind == "BAD_DATA" and "prefix" in str(getattr(m, "reason", ""))
            if garbage and self._in_garbage:  # one run of garbage bytes, however read
                continue
            self._in_garbage = garbage
            if kind == "BAD_DATA":
                out.append((now, m))
            elif kind in IMU_MESSAGES:
                if self._chosen(m):
                    out.append((now, m))
                else:
                    key = (kind, _instance(m))
                    self.other_imu[key] = self.other_imu.get(key, 0) + 1
            else:
                self.ignored += 1
        return out

    def _receive(self, timeout_s: float) -> list:
        """The messages that arrive within ``timeout_s`` (those already waiting, or the
        first ones to come), at most 256."""
        conn = self.conn
        deadline = time.perf_counter() + timeout_s
        msgs = []
        while len(msgs) < 256:
            m = conn.recv_msg()
            if m is not None:
                msgs.append(m)
                continue
            remaining = deadline - time.perf_counter()
            if msgs or remaining <= 0:
                break
            conn.select(min(remaining, 0.05))
        return msgs

    def _chosen(self, msg) -> bool:
        """Whether ``msg`` is of the IMU stream read (the first one matching chooses it)."""
        key = (msg.get_type(), _instance(msg))
        if self.stream is None:
            if self.instance is not None and key[1] != self.instance:
                return False
            if self.message is not None and key[0] != self.message:
                return False
            self.stream = key
            self.assumed = self._assumptions()
        return key == self.stream

    def _assumptions(self) -> tuple[str, ...]:
        out = ["MAVLink body frame FRD converted to FLU ([x, -y, -z]); the estimate is "
               "q_ENU_FLU (sent back as q_NED_FRD)"]
        if self.stream is None:
            out.append("IMU: " + ("the first seen" if self.instance is None and
                                  self.message is None else
                                  f"instance {self.instance}, message {self.message}"))
            return tuple(out)
        kind, inst = self.stream
        how = "chosen by ?instance/?message" if (self.instance is not None or
                                                 self.message is not None) else \
            "the first IMU message seen (?instance=N&message=NAME to choose)"
        out.append(f"IMU: {kind} instance {inst}, {how}; other IMU messages ignored")
        text = _UNITS_TEXT.get(kind) or _UNITS_TEXT["SCALED_IMU"].format(name=kind)
        out.append(text)
        return tuple(out)

    def samples(self, payload) -> list:
        kind = payload.get_type()
        if kind == "BAD_DATA":
            raise Malformed(_bad_reason(str(getattr(payload, "reason", ""))))
        units = IMU_MESSAGES[kind]
        try:
            t = float(getattr(payload, units.time)) * units.time_s
            acc = np.array([payload.xacc, payload.yacc, payload.zacc], dtype=float)
            gyro = np.array([payload.xgyro, payload.ygyro, payload.zgyro], dtype=float)
            mag = np.array([payload.xmag, payload.ymag, payload.zmag], dtype=float)
            if kind == "HIGHRES_IMU":
                bits = int(payload.fields_updated)
                new = {name: bool(bits & mask) for name, mask in _UPDATED.items()}
            else:
                new = {"accel": True, "gyro": True, "mag": bool(np.any(mag != 0.0))}
        except (AttributeError, TypeError, ValueError, OverflowError):
            raise Malformed(f"{kind}: fields missing or not numbers") from None
        if not math.isfinite(t):
            raise Malformed(f"{kind}: time not finite")
        out = []
        for name, v, scale in (("accel", acc, units.accel), ("mag", mag, units.mag),
                               ("gyro", gyro, units.gyro)):  # the gyro last (parse.py)
            if not new[name]:
                continue
            if not np.all(np.isfinite(v)):
                raise Malformed(f"{kind}: {name} not finite")
            out.append((name, t, frd_to_flu(v * scale)))
        if new["gyro"]:
            self._gyro[t] = (t, gyro * units.gyro)
            if len(self._gyro) > _RECENT:
                self._gyro.popitem(last=False)
        return out

    def gyro_frd(self, t_s: float):
        """The gyro sample (FRD, rad/s) stamped ``t_s``, if it is among the recent ones."""
        got = self._gyro.get(t_s)
        return None if got is None else got[1]

    def close(self) -> None:
        if self.conn is not None:
            with contextlib.suppress(Exception):
                self.conn.close()
            self.conn = None

    def describe(self) -> dict:
        return {"source": "mavlink", "connection": self.device,
                "stream": list(self.stream) if self.stream else None,
                "ignored_imu": {f"{k} {i}": n for (k, i), n in self.other_imu.items()},
                "ignored": self.ignored, "reconnects": self.reconnects,
                "link_lost": self.link_lost}


def _with_host(device: str, url: str) -> str:
    """``udpin:PORT`` and ``udpin::PORT`` -> ``udpin:127.0.0.1:PORT``; ports checked."""
    kind, _, where = device.partition(":")
    host, _, port = where.rpartition(":")
    try:
        port_n = int(port)
    except ValueError:
        raise InputError(f"expected {kind}:HOST:PORT, got {device!r} in {url!r}",
                         field="source") from None
    if not 0 <= port_n < 65536:
        raise InputError(f"port out of range in {url!r}", field="source")
    return f"{kind}:{host or '127.0.0.1'}:{port_n}"


class MavlinkOutSink:
    """``--mavlink-out``: each estimate back to the MAVLink source's link as
    ``ATTITUDE_QUATERNION`` (module docstring): ``q1..q4`` the estimate as ``q_NED_FRD``,
    ``time_boot_ms`` the gyro sample's stamp in ms (the sender's clock, mod 2³²),
    ``rollspeed, pitchspeed, yawspeed`` the gyro sample of that row (FRD, rad/s) less the
    filter's bias estimate when it has one (NaN when the sample is not known: a stamp
    shifted by a clock jump). At most ``source.out_hz`` messages a second of the sensor
    clock (0: all). Never raises on a send: failures are counted (``errors``)."""

    def __init__(self, source: MavlinkSource):
        if not isinstance(source, MavlinkSource):
            raise InputError("--mavlink-out answers a mavlink:// source", field="--mavlink-out")
        self.source = source
        self.min_dt_s = 1.0 / source.out_hz if source.out_hz > 0 else 0.0
        self.sent = self.errors = self.skipped = 0
        self._last_t = -math.inf

    def write(self, est, arrivals=None) -> None:
        q = enu_flu_to_ned_frd(est.q)
        bias = est.signals.get("bias_rad_s")
        bias = None if bias is None else frd_to_flu(np.asarray(bias))  # FLU -> FRD: the same
        for k in range(len(est.t)):
            t = float(est.t[k])
            if t - self._last_t < self.min_dt_s:
                self.skipped += 1
                continue
            gyro = self.source.gyro_frd(t)
            if gyro is None:
                rates = (math.nan,) * 3
            else:
                rates = gyro - bias[k] if bias is not None and np.all(np.isfinite(bias[k])) \
                    else gyro
                rates = tuple(float(r) for r in rates)
            conn = self.source.conn
            if conn is None:
                self.errors += 1
                continue
            try:
                with self.source.send_lock:
                    conn.mav.attitude_quaternion_send(
                        int(round(t * 1000.0)) % (1 << 32), *(float(c) for c in q[k]), *rates)
            except Exception:  # noqa: BLE001 - a closed port, a full buffer
                self.errors += 1
                continue
            self._last_t = t
            self.sent += 1

    def close(self) -> None:
        """Nothing to release: the link is the source's."""

    def describe(self) -> dict:
        return {"sink": "mavlink", "to": self.source.device, "sent": self.sent,
                "skipped": self.skipped, "errors": self.errors}
