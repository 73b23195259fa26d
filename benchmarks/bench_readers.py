"""Read speed and peak memory of gnomon's log readers against the format library's own load
of the same topics, on generated one-hour logs (not committed; cached in ``--work``).

    python benchmarks/bench_readers.py [--seconds 3600] [--rate 400] [--work /tmp/gnomon-bench]
        [--formats ulog,rosbag] [--repeats 2] [--json docs/figures/readers_speed.json]
        [--doc docs/benchmarks.md]

Logs (gyro+accelerometer at ``--rate`` Hz, magnetometer and the device's attitude at a
quarter of it):

* PX4 ULog, written with pyulog's own writer from the fixture
  ``src/gnomon/data/logs/px4/sample_imu_113s_6s.ulg`` (its messages repeated with new time
  stamps): ``sensor_combined`` (gyro, accelerometer, older firmware's magnetometer) and
  ``vehicle_attitude``;
* ROS 1 bag, written with rosbags' writer: ``sensor_msgs/Imu`` and
  ``sensor_msgs/MagneticField``.

Baselines (what a user of the library alone would run to get the same numbers into
memory): ``pyulog.ULog(path, [the same topics])``; rosbags' ``AnyReader`` deserialising
every message of the two topics and keeping its fields in a list. Each measurement runs in
a fresh process (peak RSS: the process's ``VmHWM``, else ``getrusage``; its own baseline
after imports subtracted);
time is the best of ``--repeats``. The ratio is gnomon's time over the baseline's.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "src" / "gnomon" / "data" / "logs" / "px4" / "sample_imu_113s_6s.ulg"


def make_ulog(path: Path, seconds: float, rate_hz: float) -> Path:
    from pyulog import ULog

    u = ULog(str(FIXTURE), ["sensor_combined", "vehicle_attitude"])
    u._initial_parameters = {}
    u._changed_parameters = []
    u._logged_messages = []
    for d in u.data_list:
        step_us = int(1e6 / rate_hz) * (1 if d.name == "sensor_combined" else 4)
        k = int(seconds * 1e6 / step_us)
        src = d.data
        idx = np.arange(k) % src["timestamp"].size
        new = {key: v[idx] for key, v in src.items()}
        new["timestamp"] = (1_000_000 + np.arange(k, dtype=np.uint64) * step_us).astype(
            src["timestamp"].dtype)
        if "magnetometer_timestamp_relative" in new:
            new["magnetometer_timestamp_relative"][:] = 0
            m = np.arange(k) % 4 != 0  # the magnetometer at a quarter rate: repeated sample
            for j in range(3):
                f = new[f"magnetometer_ga[{j}]"]
                f[m] = f[np.maximum(np.flatnonzero(m) - (np.flatnonzero(m) % 4), 0)]
            new["magnetometer_timestamp_relative"][m] = -(np.flatnonzero(m) % 4) * step_us
        d.data = new
    u.write_ulog(str(path))
    return path


def make_rosbag(path: Path, seconds: float, rate_hz: float) -> Path:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    Imu, Mag = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/MagneticField"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    rng = np.random.default_rng(0)
    n = int(seconds * rate_hz)
    zeros = np.zeros(9)
    with Writer(path) as w:
        ci = w.add_connection("/imu/data", Imu.__msgtype__, typestore=store)
        cm = w.add_connection("/imu/mag", Mag.__msgtype__, typestore=store)
        g = rng.normal(0, 0.01, (n, 3))
        for k in range(n):
            t_ns = 1_000_000_000 + k * int(1e9 / rate_hz)
            h = Header(seq=k, stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                       frame_id="imu")
            msg = Imu(header=h, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
                      orientation_covariance=zeros,
                      angular_velocity=V3(x=g[k, 0], y=g[k, 1], z=g[k, 2]),
                      angular_velocity_covariance=zeros,
                      linear_acceleration=V3(x=0.0, y=0.0, z=9.81),
                      linear_acceleration_covariance=zeros)
            w.write(ci, t_ns, store.serialize_ros1(msg, Imu.__msgtype__))
            if k % 4 == 0:
                m = Mag(header=h, magnetic_field=V3(x=2e-5, y=0.0, z=-4e-5),
                        magnetic_field_covariance=zeros)
                w.write(cm, t_ns, store.serialize_ros1(m, Mag.__msgtype__))
    return path


BASELINES = {
    "ulog": """
from pyulog import ULog
from gnomon.io.ulog import IMU_TOPICS, MAG_TOPICS, _OTHER
u = ULog(PATH, list(dict.fromkeys(IMU_TOPICS + MAG_TOPICS + _OTHER)), True)
""",
    "rosbag": """
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
rows = []
with AnyReader([Path(PATH)], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
    conns = [c for c in r.connections if c.topic in ("/imu/data", "/imu/mag")]
    for c, t, raw in r.messages(connections=conns):
        m = r.deserialize(raw, c.msgtype)
        if c.topic == "/imu/data":
            w, a = m.angular_velocity, m.linear_acceleration
            rows.append((m.header.stamp.sec, m.header.stamp.nanosec, w.x, w.y, w.z,
                         a.x, a.y, a.z))
        else:
            f = m.magnetic_field
            rows.append((m.header.stamp.sec, m.header.stamp.nanosec, f.x, f.y, f.z))
""",
}
GNOMON = """
from gnomon.io import read
rec = read(PATH)
"""
RUNNER = """
import resource, sys, time
from pathlib import Path
PATH = {path!r}
import numpy, gnomon.io  # imported before the baseline RSS is taken


def peak_kb():  # this process's own high-water mark: ru_maxrss can carry the parent's
    try:        # over the exec (a parent that has just generated the log)
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


base = peak_kb()
t0 = time.perf_counter()
{code}
dt = time.perf_counter() - t0
peak = peak_kb()
print(dt, (peak - base) / 1024.0)
"""


def measure(path: Path, code: str) -> tuple[float, float]:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.run([sys.executable, "-c", RUNNER.format(path=str(path), code=code)],
                         capture_output=True, text=True, env=env, check=True)
    dt, mb = out.stdout.split()[-2:]
    return float(dt), float(mb)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=3600.0)
    p.add_argument("--rate", type=float, default=400.0)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--work", default="/tmp/gnomon-bench-readers")
    p.add_argument("--formats", default="ulog,rosbag")
    p.add_argument("--json", help="write the result here")
    p.add_argument("--doc", help="replace the \"Reading logs\" section of this page (e.g. "
                   "docs/benchmarks.md) with the result")
    args = p.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    for fmt in args.formats.split(","):
        suffix = "ulg" if fmt == "ulog" else "bag"
        path = work / f"log_{int(args.seconds)}s_{int(args.rate)}hz.{suffix}"
        if not path.exists():
            t0 = time.perf_counter()
            (make_ulog if fmt == "ulog" else make_rosbag)(path, args.seconds, args.rate)
            print(f"made {path} ({path.stat().st_size / 1e6:.0f} MB) in "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
        lib = [measure(path, BASELINES[fmt]) for _ in range(args.repeats)]
        gno = [measure(path, GNOMON) for _ in range(args.repeats)]
        t_lib, t_gno = min(x[0] for x in lib), min(x[0] for x in gno)
        results[fmt] = {
            "file_mb": path.stat().st_size / 1e6, "seconds": args.seconds, "rate_hz": args.rate,
            "library_s": t_lib, "gnomon_s": t_gno, "ratio": t_gno / t_lib,
            "repeats": args.repeats,
            "library_peak_mb": max(x[1] for x in lib), "gnomon_peak_mb": max(x[1] for x in gno),
        }
        r = results[fmt]
        print(f"{fmt}: {r['file_mb']:.0f} MB file; library {t_lib:.1f} s, gnomon {t_gno:.1f} s "
              f"(ratio {r['ratio']:.2f}); peak memory library {r['library_peak_mb']:.0f} MB, "
              f"gnomon {r['gnomon_peak_mb']:.0f} MB", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    if args.doc:
        write_section(Path(args.doc), results, args.repeats)
    return 0


LABELS = {"ulog": "PX4 ULog (pyulog)",
          "rosbag": "ROS 1 bag (rosbags, every message deserialised)"}
SECTION = "## Reading logs"


def markdown_section(results: dict, repeats: int = 2) -> str:
    """The "Reading logs" section of ``docs/benchmarks.md`` from the results (the JSON of
    ``--json``), numbers untyped by hand."""
    repeats = next(iter(results.values()), {}).get("repeats", repeats)
    rows = "\n".join(
        f"| {LABELS.get(fmt, fmt)} | {r['file_mb']:.0f} MB | {r['library_s']:.1f} s | "
        f"{r['gnomon_s']:.1f} s | {r['ratio']:.2f} | {r['library_peak_mb']:.0f} MB | "
        f"{r['gnomon_peak_mb']:.0f} MB |" for fmt, r in results.items())
    b = results.get("rosbag")
    tuples = (f"; the library\nbaseline that keeps a tuple per message needs "
              f"{b['library_peak_mb'] / b['gnomon_peak_mb']:.1f}× more") if b else ""
    try:
        from gnomon.io._common import _CHUNK as chunk
    except ImportError:
        chunk = 16_384
    text = f"""{SECTION}

`python benchmarks/bench_readers.py` (`docs/figures/readers_speed.json`): a generated
one-hour log, gyro and accelerometer at 400 Hz, magnetometer and the device's attitude at
100 Hz, read by gnomon and by the format library alone loading the same topics (each in a
fresh process; best of {repeats}; peak memory above the process's own after imports).
2-core machine shared with other jobs: single runs vary by ±20 %.

| log | file | library alone | gnomon | ratio | peak memory, library | peak memory, gnomon |
| --- | ---: | ---: | ---: | ---: | ---: | ---: |
{rows}

Memory is bounded by the arrays themselves: the readers keep no per-message Python
object (ROS and DataFlash rows go into `array('d')` buffers, 8 bytes a value{tuples}).
"""
    u = results.get("ulog")
    if u:
        n = u["seconds"] * u["rate_hz"]  # gyro samples; magnetometer at a quarter of the rate
        rec_mb = (n * (8 + 24 + 24 + 32) + n / 4 * (8 + 24)) / 2**20
        lib_mb = u["library_peak_mb"]
        text += f"""
For the ULog, gnomon's peak is pyulog's own arrays ({lib_mb:.0f} MB, freed before the
resampling) plus the recording ({rec_mb:.0f} MB: time, gyro, accelerometer, magnetometer, the
estimate on the gyro time base) plus bounded temporaries (the slerp runs in blocks of
{chunk:,} rows). gnomon's ULog overhead ({u['gnomon_s'] - u['library_s']:.1f} s over pyulog's
{u['library_s']:.1f} s) is the float64 copies of the columns, the checks of every sensor
series, the `Recording` validation and slerping {n / 1e6:.2f} million onboard attitudes;
watching for a file cut inside a message costs nothing per message (pyulog's reads are
watched only in the last 64 KiB of the file). Target: a ratio of at most 1.5.
"""
    return text


def write_section(page: Path, results: dict, repeats: int = 2) -> None:
    """Replace (or append) the "Reading logs" section of ``page`` (up to the next ``## ``
    heading), leaving the rest as it is."""
    text = page.read_text()
    section = markdown_section(results, repeats)
    if SECTION in text:
        head, rest = text.split(SECTION, 1)
        after = rest.find("\n## ")
        text = head + section + ("\n" + rest[after + 1:] if after >= 0 else "")
    else:
        text = text.rstrip("\n") + "\n\n" + section
    page.write_text(text)


if __name__ == "__main__":
    sys.exit(main())
