"""What the commands share: JSON printing, ``KEY=VALUE`` options, the input options
(``--format`` with ``--strict``, log and CSV options, ``--phone-mag``), reading the input,
progress.

Nothing here knows a command; each command module in :mod:`gnomon.cli` uses these.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from gnomon.errors import InputError


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def clean_json(o):
    """NaN/inf -> None so the output is strict JSON."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: clean_json(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [clean_json(v) for v in o]
    return o


def print_json(obj) -> None:
    print(json.dumps(clean_json(json.loads(json.dumps(obj, default=_json_default))), indent=2))


def parse_pairs(pairs: list[str], option: str = "--param", typed: bool = False) -> dict:
    """``KEY=VALUE`` strings to a dict; ``typed`` parses values as YAML scalars (1.5, true)."""
    out = {}
    for p in pairs or []:
        if "=" not in p:
            raise InputError(f"expected KEY=VALUE, got {p!r}", field=option)
        k, v = p.split("=", 1)
        if typed:
            import yaml

            v = yaml.safe_load(v)
        out[k.strip()] = v.strip() if isinstance(v, str) else v
    return out


#: phone exports with an OS-calibrated and a raw magnetometer (``mag=`` of their reader)
PHONE_FORMATS = ("tyrex", "sensorlogger")


def raw_phone_mag(args, why: str) -> None:
    """``--phone-mag raw`` when not given and the input is a phone export: a magnetometer
    calibration is fitted to (and corrects) the raw magnetometer, never the one the OS
    already corrected. Says so on stderr."""
    from gnomon.io import detect_format

    if getattr(args, "phone_mag", None) is not None:
        return
    try:
        fmt = getattr(args, "format", "auto")
        fmt = detect_format(args.input) if fmt == "auto" else fmt
    except InputError:
        return  # the reader will say what is wrong with the input
    if fmt in PHONE_FORMATS:
        args.phone_mag = "raw"
        print(f"note: {why}: the phone's raw magnetometer (--phone-mag raw; "
              f"--phone-mag calibrated for the OS-calibrated one)", file=sys.stderr)


def read_input(args):
    from gnomon.io import read

    if getattr(args, "map", None):  # a table of another layout, read with a map
        return read(args.input, map=args.map, **_no_csv_options(args))
    csv_opts = {}
    if args.columns:
        csv_opts["columns"] = parse_pairs(args.columns.split(","), option="--columns")
    for opt in ("gyro_unit", "accel_unit", "mag_unit", "time_unit"):
        if getattr(args, opt, None):
            csv_opts[opt] = getattr(args, opt)
    if getattr(args, "phone_mag", None):  # phone exports: which magnetometer file
        csv_opts["mag"] = args.phone_mag
    return read(args.input, format=args.format, **csv_opts, **log_options(args))


def _no_csv_options(args) -> dict:
    """With ``--map``: the CSV options are the map's (an error naming one given too);
    ``--strict`` still applies."""
    for opt in ("columns", "gyro_unit", "accel_unit", "mag_unit", "time_unit", "topic",
                "mag_topic", "instance"):
        if getattr(args, opt, None) is not None:
            raise InputError("the map names the columns and units: give them there",
                             field="--" + opt.replace("_", "-"))
    if getattr(args, "format", "auto") != "auto":
        raise InputError("the map names the kind of file", field="--format")
    return {"strict": True} if getattr(args, "strict", False) else {}


def add_map_option(s) -> None:
    """``--map MAP.yaml``: read a table of another layout (CSV/TSV, .mat, .npz, Parquet) with
    a map (``gnomon inspect FILE --write-map MAP.yaml``; :mod:`gnomon.io.mapping`)."""
    s.add_argument("--map", metavar="MAP.yaml",
                   help="read the input with a map (columns or arrays, units, axes, truth "
                        "order), as `gnomon inspect FILE --write-map MAP.yaml` proposes")


def log_options(args) -> dict:
    """``--topic``/``--instance`` (and ``--mag-topic``) as reader options, when given, and
    ``--strict`` as ``gnomon.io.read``'s ``strict``."""
    out = {}
    for opt in ("topic", "mag_topic", "instance"):
        if getattr(args, opt, None) is not None:
            out[opt] = getattr(args, opt)
    if getattr(args, "strict", False):
        out["strict"] = True
    return out


def add_format_option(s) -> None:
    """``--format``: the input's format, found from its content by default; and
    ``--strict`` (:func:`add_strict_option`)."""
    from gnomon.io import FORMATS

    s.add_argument("--format", default="auto", choices=list(FORMATS))
    add_strict_option(s)


def add_strict_option(s) -> None:
    """``--strict``: refuse a sample with a non-finite value instead of dropping it from
    its sensor (and counting it)."""
    s.add_argument("--strict", action="store_true",
                   help="refuse a NaN/inf sample (naming the field and the row) instead of "
                        "dropping it from its own sensor and counting it")


def add_log_options(s) -> None:
    g = s.add_argument_group("log options (ULog, DataFlash, ROS bags)")
    g.add_argument("--topic", help="IMU topic (ROS: /imu/data; ULog: sensor_combined, "
                                   "vehicle_imu, sensor_gyro)")
    g.add_argument("--mag-topic", help="magnetometer topic, or none")
    g.add_argument("--instance", type=int, help="IMU instance (ULog, DataFlash; default 0)")


def add_csv_options(s) -> None:
    g = s.add_argument_group("CSV options")
    g.add_argument("--columns", help="column map NAME=COLUMN,... (names: t, gyr_x, ..., mag_z)")
    g.add_argument("--gyro-unit", help="rad/s (default) or deg/s")
    g.add_argument("--accel-unit", help="m/s^2 (default) or g")
    g.add_argument("--mag-unit", help="uT (default), nT, mT, T or gauss")
    g.add_argument("--time-unit", help="s (default), ms, us or ns")
    add_map_option(g)


def add_quiet_option(s) -> None:
    s.add_argument("--quiet", action="store_true",
                   help="no progress bar (there is none in CI, nor when stderr is not a "
                        "terminal)")


def progress_wanted(args) -> bool:
    """Whether to show progress: ``gnomon.progress.wanted`` (a terminal, not CI), and
    neither ``--quiet`` nor ``--json``."""
    from gnomon.progress import wanted

    return wanted(quiet=getattr(args, "json", False) or getattr(args, "quiet", False))


def add_phone_mag_option(s) -> None:
    s.add_argument("--phone-mag", choices=["calibrated", "raw"],
                   help="phone exports (tyrex, Sensor Logger): the OS-calibrated magnetometer "
                        "(the reader's default) or the raw one (the default of calibrate mag "
                        "and of estimate --mag-calibration: a calibration corrects the raw "
                        "one)")


def add_backend_option(s, which: str) -> None:
    """``--backend auto|python|c`` of ``estimate`` and ``live``; ``which``: the filters
    whose export ``auto`` runs on the C in that command."""
    s.add_argument("--backend", default="auto", choices=["auto", "python", "c"],
                   help="c: the filter's exported C flight code (gnomon export c), built "
                        "once into the user cache (about a second); python: gnomon's numba "
                        "kernels (compiled once per machine: robust-ahrs 12-16 s on 2 "
                        f"cores); auto (default): c for {which} when a C compiler is found, "
                        "else python. Both give the same estimates")


def _c_failure(err: Exception) -> str | None:
    """What an error of the C path ``err`` means, or None for an error of the command's own:
    ``make`` failed or the cache is unwritable (an ``OSError``): the build; the export
    refuses a parameter (``--param``: tilt-cf's speed compensation, which the C does not
    do): the parameters."""
    if isinstance(err, OSError) or isinstance(err, InputError) and err.field == "make":
        return "the C build failed"
    if isinstance(err, InputError) and err.field == "--param":
        return "the C export does not take these parameters"
    return None


def fall_back_from_c(requested: str, err: Exception) -> str | None:
    """Why an error of the C path ``err`` (the build, or a parameter the export refuses)
    leaves the command to the numba kernels, said on stderr; only under ``--backend auto``
    (``requested``). None: any other error, the caller's to raise."""
    what = _c_failure(err)
    if requested != "auto" or what is None:
        return None
    print(f"gnomon: {what}, running the numba kernels instead "
          f"(--backend python skips the C): {err}", file=sys.stderr)
    return what
