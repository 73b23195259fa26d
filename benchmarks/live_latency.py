"""Latency and CPU share of ``gnomon live`` on a UDP stream at a real sample rate.

A sender on 127.0.0.1 streams a 9-axis recording (the bundled BROAD excerpt, resampled to
the rate's stamps) as CSV lines, one datagram per sample, at the rate's pace (each
datagram sent at its due time); ``gnomon live udp://...`` runs in its own process and
prints its ``--json`` summary: latency from the arrival of a gyro sample to its estimate
(p50, p99) and the share of one core it used. Run for each rate and each ``--hold``:

    python benchmarks/live_latency.py --rates 200 1000 --seconds 20 --filter robust-ahrs

Writes a Markdown table to stdout (and ``--json FILE``): the numbers of docs/live.md.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import time

import numpy as np


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _lines(rate_hz: float, seconds: float) -> list[bytes]:
    """CSV lines of the BROAD excerpt at ``rate_hz`` (its samples repeated and restamped)."""
    import gnomon
    from gnomon.datasets import bundled

    rec = gnomon.read(sorted(bundled("broad").glob("*.hdf5"))[0])
    n = int(rate_hz * seconds)
    k = np.arange(n) % len(rec)
    t = np.arange(n) / rate_hz
    rows = np.column_stack([t, rec.gyro[k], rec.accel[k], rec.mag[k]])
    return [",".join(f"{v:.9g}" for v in row).encode() for row in rows]


def measure(rate_hz: float, seconds: float, filter_name: str, hold: float) -> dict:
    port = _free_port()
    lines = _lines(rate_hz, seconds)
    cmd = [sys.executable, "-m", "gnomon.cli", "live", f"udp://127.0.0.1:{port}", "--filter",
           filter_name, "--json", "--hold", str(hold), "--max-samples", str(len(lines)),
           "--duration", str(seconds + 60)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)  # the process starts and listens
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.sendto(b"t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z", ("127.0.0.1", port))
    start = time.perf_counter()
    late = 0.0
    for k, line in enumerate(lines):
        due = start + k / rate_hz
        while True:  # sleep most of the wait, spin the rest: datagrams at their due times
            now = time.perf_counter()
            if now >= due:
                break
            if due - now > 0.002:
                time.sleep(due - now - 0.001)
        late = max(late, now - due)
        sock.sendto(line, ("127.0.0.1", port))
    out, err = proc.communicate(timeout=seconds + 120)
    if proc.returncode != 0:
        raise RuntimeError(err)
    s = json.loads(out)
    return {"rate_hz": rate_hz, "hold_periods": hold, "filter": filter_name,
            "samples": s["samples"], "sent": len(lines), "dropped": s["dropped"],
            "malformed": s["malformed"], "latency_us": s["latency_us"],
            "cpu_share": s["cpu_share"], "sender_late_max_ms": late * 1e3}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[200.0, 1000.0])
    ap.add_argument("--holds", type=float, nargs="+", default=[0.5, 0.0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--filter", default="robust-ahrs")
    ap.add_argument("--json", help="also write the results to this file")
    args = ap.parse_args(argv)
    rows = [measure(r, args.seconds, args.filter, h) for r in args.rates for h in args.holds]
    print(f"`gnomon live udp://` with {args.filter}, {args.seconds:g} s per run, "
          "sender and receiver on this 2-core machine:\n")
    print("| rate (Hz) | hold (periods) | estimates | dropped | latency p50 (µs) | "
          "latency p99 (µs) | CPU (% of a core) |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        lat = r["latency_us"]
        print(f"| {r['rate_hz']:g} | {r['hold_periods']:g} | {r['samples']} of {r['sent']} | "
              f"{r['dropped']} | {lat['p50']:.0f} | {lat['p99']:.0f} | "
              f"{100 * r['cpu_share']:.1f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
