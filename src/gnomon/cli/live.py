"""``gnomon live SOURCE``: a filter on a live stream (UDP, serial, MAVLink, a replay), the
estimates to files, sockets, MCAP and a browser view, until the stream ends."""

from __future__ import annotations

import signal
import sys
import threading

from gnomon.cli.common import (
    add_backend_option,
    add_csv_options,
    fall_back_from_c,
    parse_pairs,
    print_json,
)
from gnomon.errors import InputError


def add_parser(sub) -> None:
    s = sub.add_parser(
        "live", help="run a filter on a live stream: udp://, serial://, mavlink://, replay://",
        description="Sources: udp://HOST:PORT (CSV or JSON lines, one sample per datagram or "
                    "line; a first header line names the columns, or --columns), "
                    "serial://DEVICE?baud=N (the same lines), mavlink://udpin:HOST:PORT or "
                    "mavlink://DEVICE?baud=N (HIGHRES_IMU, SCALED_IMU*, RAW_IMU), "
                    "replay://FILE?speed=X (any recording gnomon reads, X times real time, "
                    "0 as fast as it goes). Stops at the end of the stream, --duration, "
                    "--max-samples or Ctrl-C, and writes everything it estimated.")
    s.add_argument("source", metavar="SOURCE", help="udp://, serial://, mavlink:// or "
                                                    "replay:// URL")
    from gnomon.estimators.registry import DEFAULT_ORDER

    s.add_argument("--filter", default=None,
                   help=f"filter name (default: the first of {', '.join(DEFAULT_ORDER)} "
                        "that runs on the stream's sensors, decided on its first samples)")
    s.add_argument("--param", action="append", metavar="KEY=VALUE", help="filter parameter")
    add_backend_option(s, "the filters whose export streams (robust-ahrs), run in this "
                          "process")
    s.add_argument("--out", help="write the estimates (.csv or .h5; the columns of `gnomon "
                                 "estimate --out`)")
    s.add_argument("--udp-out", metavar="HOST:PORT",
                   help="send one JSON object per estimate (t, q, euler_deg, bias, flags)")
    s.add_argument("--mcap", metavar="FILE", help="write an MCAP file (Foxglove schemas: "
                                                  "the pose, the frame transform, the state)")
    s.add_argument("--mavlink-out", action="store_true",
                   help="with a mavlink:// source: send ATTITUDE_QUATERNION back")
    s.add_argument("--view", metavar="PORT|foxglove:PORT",
                   help="serve a live view at http://127.0.0.1:PORT/ (3-D body, roll/pitch/"
                        "yaw, gyro bias, flags; 0: a free port); foxglove:PORT serves "
                        "Foxglove's WebSocket protocol instead (open it in Foxglove)")
    s.add_argument("--bind", default="127.0.0.1",
                   help="the address the view listens on (default 127.0.0.1: this computer "
                        "only)")
    s.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    s.add_argument("--idle-timeout", type=float, metavar="S",
                   help="stop when nothing has arrived for S seconds (a sender that "
                        "vanished; default: wait; a serial or MAVLink device that vanished "
                        "is reopened for 10 s, then the stream ends)")
    s.add_argument("--max-samples", type=int, metavar="N", help="stop after N estimates")
    s.add_argument("--hold", type=float, default=0.5, metavar="PERIODS",
                   help="gyro periods a row waits for late samples (default 0.5; 0: a row "
                        "runs as soon as its gyro sample arrives, the lowest latency)")
    s.add_argument("--json", action="store_true",
                   help='print {"filter", "samples", "malformed", "dropped", "latency_us": '
                        '{"p50", "p99"}, ...} at the end')
    add_csv_options(s)
    s.set_defaults(func=run)


def _view(spec: str, host: str):
    """``--view PORT`` (the page) or ``--view foxglove:PORT`` (Foxglove's protocol)."""
    from gnomon.live.view import FoxgloveViewSink, ViewSink

    kind, _, port = spec.rpartition(":")
    if kind not in ("", "foxglove") or not port.isdigit():
        raise InputError(f"expected PORT or foxglove:PORT, got {spec!r}", field="--view")
    return (FoxgloveViewSink if kind else ViewSink)(int(port), host=host)


def _sinks(args, source, sinks: list) -> None:
    """The sinks the options ask for, appended to ``sinks`` as each opens (the caller
    closes those that opened when a later one fails)."""
    from gnomon.live.sinks import EstimateFileSink, UdpJsonSink

    if args.out:
        sinks.append(EstimateFileSink(args.out))
    if args.udp_out:
        sinks.append(UdpJsonSink(args.udp_out))
    if args.mcap:
        from gnomon.live.mcap import McapSink

        sinks.append(McapSink(args.mcap))
    if args.mavlink_out:
        if not args.source.startswith("mavlink://"):
            raise InputError("--mavlink-out answers a mavlink:// source", field="--mavlink-out")
        from gnomon.live.mavlink import MavlinkOutSink

        sinks.append(MavlinkOutSink(source))
    if args.view is not None:
        sinks.append(_view(args.view, args.bind))


def _filter(args, source):
    """The filter: ``--filter``, else the registry's default for the stream (a replay:
    its recording; another stream: a 9-axis IMU's)."""
    from gnomon.estimators import registry

    name = args.filter
    if name is None:
        rec = getattr(source, "rec", None)
        name = registry.default_for(rec, False)[0] if rec is not None else "robust-ahrs"
    filt = registry.create(name, parse_pairs(args.param))
    if getattr(filt, "offline", False) or filt.kind != "imu":
        raise InputError(f"{name!r} cannot run live: live filters are the causal IMU ones "
                         f"({', '.join(n for n in registry.names('imu', offline=False))})",
                         field="--filter")
    return _backend(args, name, filt)


def _backend(args, name, filt):
    """``filt`` or, by ``--backend`` (``auto``: ``gnomon.export.backend.auto_backend``),
    its exported C as a streaming filter (``c_filter_class``); under ``auto`` a C build
    that fails leaves ``filt``, said on stderr."""
    from gnomon.export.backend import auto_backend, c_filter_class

    backend = auto_backend(name, streaming=True)[0] if args.backend == "auto" else args.backend
    if backend != "c":
        return filt
    try:
        return c_filter_class(name)(filt.params)
    except (InputError, OSError) as e:  # the build, or a parameter the C does not take
        if fall_back_from_c(args.backend, e) is None:
            raise
        return filt


def _mapped(args, given) -> tuple:
    """``--map``: a replay reads its file with the map (``gnomon.io.read(path, map=)``); CSV
    lines (udp://, serial://) take the map's column names and units
    (:func:`gnomon.io.mapping.live_options`); MAVLink has its own messages."""
    if given:
        raise InputError("the map names the columns and units: give them there",
                         field="--map")
    if args.source.startswith("replay://"):
        return None, {}, {"map": args.map}
    if args.source.startswith(("udp://", "serial://")):
        from gnomon.io.mapping import live_options

        opts = live_options(args.map)
        return opts.pop("columns"), opts, None
    raise InputError("a MAVLink stream has its own messages: --map applies to replay://, "
                     "udp:// and serial:// sources", field="--map")


def run(args) -> int:
    """``gnomon.live.run_live(open_source(SOURCE), make_filter(NAME), sinks)``; exit status
    0 at the end of the stream, --duration, --max-samples or a signal."""
    from gnomon.live import LineParser, LiveFilter, open_source, run_live

    columns = None
    if args.columns:
        columns = parse_pairs(args.columns.split(","), option="--columns")
        columns = {k: int(v) if v.isdigit() else v for k, v in columns.items()}
    units = {opt: getattr(args, opt) for opt in ("gyro_unit", "accel_unit", "mag_unit",
                                                  "time_unit") if getattr(args, opt, None)}
    read_options = None
    if args.map:
        columns, units, read_options = _mapped(args, columns or units)
    source = open_source(args.source, LineParser(columns, **units), read_options=read_options)
    stop = threading.Event()
    sinks = []
    try:
        filt = _filter(args, source)
        _sinks(args, source, sinks)
        previous = {sig: signal.signal(sig, lambda *_: stop.set())
                    for sig in (signal.SIGINT, signal.SIGTERM)}
        if not args.json:
            for line in getattr(source, "assumed", ()):
                print(f"  assumed: {line}", file=sys.stderr)
            views = [sink.url for sink in sinks if hasattr(sink, "url")]
            print(f"gnomon live: {filt.name} ({getattr(filt, 'backend', 'python')}) "
                  f"on {args.source}"
                  + "".join(f"; view at {url}" for url in views) + " (Ctrl-C to stop)",
                  file=sys.stderr)
        try:
            run_ = run_live(source, filt, sinks, duration_s=args.duration,
                            max_samples=args.max_samples, stop=stop,
                            idle_timeout_s=args.idle_timeout,
                            live=LiveFilter(filt, hold_periods=args.hold))
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    except BaseException:
        source.close()
        for sink in sinks:
            sink.close()
        raise
    summary = run_.to_dict()
    summary["assumed"] = list(getattr(source, "assumed", ()))
    summary["backend"] = getattr(filt, "backend", "python")
    if args.json:
        print_json(summary)
        return 0
    lat = summary["latency_us"]
    print(f"{summary['filter']} on {summary['source']}: {summary['samples']} estimates, "
          f"{summary['malformed']} malformed, {summary['dropped']} dropped; ended by "
          f"{summary['ended_by']}")
    if lat["p50"] is not None:
        print(f"  latency from arrival to estimate: p50 {lat['p50']:.0f} us, p99 "
              f"{lat['p99']:.0f} us; CPU {100 * (summary['cpu_share'] or 0):.1f} %")
    st = summary["stream"]
    faults = {k: st[k] for k in ("late", "out_of_order", "invalid", "clock_jumps", "gaps",
                                 "filter_errors", "restarts") if st[k]}
    if faults or st["clock_offset"]:
        print(f"  stream: {faults}" + (f"; clocks shifted onto the gyro's: "
                                       f"{st['clock_offset']}" if st["clock_offset"] else ""))
    for s in summary["sinks"]:
        print(f"  {s}")
    return 0
