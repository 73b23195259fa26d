"""Make the log excerpts in src/gnomon/data/logs from the full sample logs (see README.md there).

Run once by hand (the tests never run it): ``python tests/data/make_log_fixtures.py``. It
reads ``$GNOMON_LOGS_DIR`` (default ``../shared/data/logs``) and ``$GNOMON_TYREX_DIR``
(default ``../shared/data/tyrex``) through ``gnomon.datasets``. PX4 excerpts are written
with pyulog's own writer (``ULog.write_ulog``) after keeping only the IMU, magnetometer
and attitude topics and cutting the data arrays to a time window; no value is altered.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from gnomon.datasets import logs_dir, tyrex_dir

#: the package data folder the excerpts ship in (found at run time through importlib.resources)
HERE = Path(__file__).resolve().parents[2] / "src" / "gnomon" / "data" / "logs"
PX4_TOPICS = ["sensor_combined", "vehicle_magnetometer", "vehicle_attitude", "vehicle_imu",
              "sensor_gyro", "sensor_accel", "sensor_mag", "vehicle_attitude_groundtruth"]


def ulog_excerpt(src: Path, dst: Path, start_s: float | None, seconds: float | None) -> None:
    from pyulog import ULog

    u = ULog(str(src), PX4_TOPICS)
    t_all = np.concatenate([d.data["timestamp"] for d in u.data_list]) * 1e-6
    t0 = t_all.min() if start_s is None else start_s
    t1 = np.inf if seconds is None else t0 + seconds
    for d in u.data_list:
        t = d.data["timestamp"] * 1e-6
        keep = (t >= t0) & (t <= t1)
        d.data = {k: v[keep] for k, v in d.data.items()}
    u._initial_parameters = {}  # parameters and log text are not needed by the tests
    u._changed_parameters = []
    u._logged_messages = []
    u._logged_messages_tagged = {}
    u.write_ulog(str(dst))
    print(f"{dst.name}: {dst.stat().st_size / 1024:.0f} kB")


def tyrex_excerpt(trial: Path, dst: Path, start_s: float, seconds: float) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    origin = float((trial / "accelerometer.txt").read_text().split(None, 1)[0])
    for f in sorted(trial.iterdir()):
        if f.name in ("timeAlignment.txt", "record.properties", "description.txt"):
            shutil.copy(f, dst / f.name)
            continue
        lines = f.read_text().splitlines()
        t = np.array([float(ln.split()[0]) for ln in lines])
        t_rel = t - origin
        keep = [ln for ln, tr in zip(lines, t_rel, strict=True)
                if start_s <= tr <= start_s + seconds]
        (dst / f.name).write_text("\n".join(keep) + "\n")
    print(f"{dst.name}: {sum(p.stat().st_size for p in dst.iterdir()) / 1024:.0f} kB")


def main() -> int:
    logs, tyrex = logs_dir(), tyrex_dir()
    if logs is None or tyrex is None:
        print("full data not found: set GNOMON_LOGS_DIR and GNOMON_TYREX_DIR")
        return 1
    px4 = HERE / "px4"
    px4.mkdir(parents=True, exist_ok=True)
    ulog_excerpt(logs / "px4" / "sample_log_small.ulg", px4 / "sample_log_small_imu.ulg",
                 None, None)
    ulog_excerpt(logs / "px4" / "sample.ulg", px4 / "sample_imu_113s_6s.ulg", 113.0, 6.0)
    ulog_excerpt(logs / "px4" / "sample_logging_tagged_and_default_params.ulg",
                 px4 / "sitl_groundtruth_4s.ulg", 2.0, 4.0)
    shutil.copy(logs / "px4" / "LICENSE.md", px4 / "LICENSE.md")
    ap = HERE / "ardupilot"
    ap.mkdir(parents=True, exist_ok=True)
    shutil.copy(logs / "ardupilot" / "test.BIN", ap / "test.BIN")
    shutil.copy(logs / "ardupilot" / "COPYING", ap / "COPYING")
    tx = HERE / "tyrex"
    tyrex_excerpt(tyrex / "datasets" / "android" / "Guillaume_Nexus5_NoDist_Texting",
                  tx / "android" / "Guillaume_Nexus5_NoDist_Texting_excerpt", 20.0, 5.0)
    tyrex_excerpt(tyrex / "datasets" / "ios" / "Guillaume_iPhone5_NoDist_Texting",
                  tx / "ios" / "Guillaume_iPhone5_NoDist_Texting_excerpt", 20.0, 5.0)
    shutil.copy(tyrex / "LICENCE", tx / "LICENCE")
    return 0


if __name__ == "__main__":
    sys.exit(main())
