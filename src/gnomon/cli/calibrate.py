"""``gnomon calibrate SENSOR``: sensor calibration from a recording or log (``mag``: hard and
soft iron; ``mag --orbit``: TWOSTEP; ``imu``: the gyro's and accelerometer's noise from
the Allan deviation of a static log)."""

from __future__ import annotations

from gnomon.cli.common import (
    add_csv_options,
    add_format_option,
    add_log_options,
    add_phone_mag_option,
    print_json,
    raw_phone_mag,
    read_input,
)
from gnomon.errors import InputError


def add_parser(sub) -> None:
    s = sub.add_parser("calibrate", help="sensor calibration from a recording or log "
                                         "(mag: hard and soft iron; imu: noise from a "
                                         "static log)")
    csub = s.add_subparsers(dest="sensor", metavar="SENSOR")
    c = csub.add_parser(
        "mag", help="magnetometer hard/soft iron by a constrained ellipsoid fit, with a "
                    "quality report; exit status 1 when refused",
        description="Fit offset (hard iron) and a symmetric soft-iron matrix to the log's "
                    "magnetometer: h = S (m - o), |h| = B. Move the device through as many "
                    "directions as you can (docs/calibration.md). Spacecraft: --orbit "
                    "estimates the bias alone by TWOSTEP against the recording's field "
                    "model, whatever the attitude.")
    _add_io_options(c, "recording file or folder (any format gnomon reads)",
                    out="write the calibration as JSON (for gnomon estimate "
                        "--mag-calibration)",
                    plot="write a figure of raw and corrected samples, e.g. cal.png")
    c.add_argument("--field-uT", type=float, dest="field_uT",
                   help="the local field magnitude B in uT (default: from --location/--date, "
                        "else the data's own scale)")
    c.add_argument("--location", metavar="LAT,LON[,ALT_M]",
                   help="where the log was taken (deg, deg, m): B from IGRF-14")
    c.add_argument("--date", help="when (YYYY-MM-DD), with --location")
    c.add_argument("--model", default="auto", choices=["auto", "full", "scale", "offset"],
                   help="auto (default): the richest model the directions visited determine")
    add_phone_mag_option(c)
    c.add_argument("--no-gyro", action="store_true",
                   help="do not use the gyro (start, gate and fallback for the offset)")
    c.add_argument("--orbit", action="store_true",
                   help="spacecraft: the bias alone by TWOSTEP against the recording's field "
                        "model (extra.b_o_model_nT or b_o_nT), attitude-independent "
                        "(docs/calibration.md, 'On orbit: TWOSTEP')")
    c.add_argument("--noise-nT", type=float, dest="noise_nT",
                   help="with --orbit: the magnetometer's noise sigma per axis in nT "
                        "(default: estimated from the data)")
    add_csv_options(c)
    c.set_defaults(func=run_mag)
    _add_imu_parser(csub)



def _add_io_options(c, input_help: str, *, out: str, plot: str) -> None:
    """What every ``calibrate`` subcommand takes: the input, its format and log options,
    ``--out``, ``--plot`` and ``--json``."""
    c.add_argument("input", help=input_help)
    add_format_option(c)
    add_log_options(c)
    c.add_argument("--out", help=out)
    c.add_argument("--plot", help=plot)
    c.add_argument("--json", action="store_true", help="print the report as JSON")

def _add_imu_parser(csub) -> None:
    c = csub.add_parser(
        "imu", help="gyro and accelerometer noise (Allan deviation: angle random walk, bias "
                    "instability, rate random walk) and rest biases from a static log; "
                    "--out for gnomon estimate --noise",
        description="The overlapping Allan deviation of each gyro and accelerometer axis of "
                    "a log recorded at rest (hours on a steady table, after warm-up), the "
                    "IEEE Std 952 noise terms read off it and the rest biases "
                    "(docs/calibration.md, 'IMU noise'). Refused when the log is not "
                    "static.")
    _add_io_options(c, "static recording file or folder (any format gnomon reads)",
                    out="write the noise report as JSON (for gnomon estimate --noise)",
                    plot="write the Allan deviation figure, e.g. allan.png")
    c.add_argument("--gravity-m-s2", type=float, dest="gravity_m_s2",
                   help="local gravity for the accelerometer's bias along gravity (default "
                        "standard gravity 9.80665 m/s^2)")
    add_csv_options(c)
    c.set_defaults(func=run_imu)


def run_imu(args) -> int:
    """``gnomon.calibration.imu_noise.imu_noise(gnomon.io.read(path))``, ``--out``
    ``save_imu_noise``, ``--plot`` ``plot_allan``. ``--json`` prints the report (keys:
    ``gyro``, ``accel``, ``duration_s``, ``static``, ``notes``, ``method``, ``input``)."""
    from gnomon.calibration.imu_noise import imu_noise, save_imu_noise

    rec = read_input(args)
    report, curves = imu_noise(rec, gravity_m_s2=args.gravity_m_s2)
    report = {**report, "input": str(args.input)}
    if args.out:
        save_imu_noise(args.out, report)
        report["out"] = str(args.out)
    if args.plot:
        from gnomon.calibration.allan_plot import plot_allan

        plot_allan(report, curves, args.plot, title=str(args.input))
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
        return 0
    g, a = report["gyro"], report["accel"]
    print(f"IMU noise of {args.input}: {report['duration_s']:.1f} s at rest, gyro "
          f"{g['rate_hz']:.4g} Hz" + (f", accelerometer {a['rate_hz']:.4g} Hz" if a else ""))
    rows = [("gyro", "white noise N (angle random walk)", g["noise_density_rad_s_sqrt_hz"],
             "rad/s/sqrt(Hz)", g["angle_random_walk_deg_sqrt_h"], "deg/sqrt(h)"),
            ("gyro", "bias instability B", g["bias_instability_rad_s"], "rad/s",
             g["bias_instability_deg_h"], "deg/h"),
            ("gyro", "rate random walk K", g["rate_random_walk_rad_s2_sqrt_hz"],
             "rad/s^2/sqrt(Hz)", None, ""),
            ("gyro", "mean rate (bias + Earth rate)", g["bias_rad_s"], "rad/s", None, "")]
    if a:
        rows += [("accel", "white noise N (velocity random walk)",
                  a["noise_density_m_s2_sqrt_hz"], "m/s^2/sqrt(Hz)",
                  a["velocity_random_walk_m_s_sqrt_h"], "m/s/sqrt(h)"),
                 ("accel", "bias instability B", a["bias_instability_m_s2"], "m/s^2", None, ""),
                 ("accel", "random walk K", a["random_walk_m_s3_sqrt_hz"], "m/s^3/sqrt(Hz)",
                  None, "")]
    for sensor, what, v, unit, alt, alt_unit in rows:
        line = f"  {sensor:5s} {what}: [{_fmt(v)}] {unit}"
        if alt is not None:
            line += f" = [{_fmt(alt)}] {alt_unit}"
        print(line)
    if a:
        print(f"  accel bias along gravity |mean| - g: {a['bias_along_gravity_m_s2']:.4g} m/s^2 "
              f"(g = {a['gravity_m_s2']:.5g} m/s^2, {a['gravity_source']}); {a['bias_note']}")
    for note in report["notes"]:
        print(f"  note: {note}")
    for key in ("out", "plot"):
        if key in report:
            print(f"  wrote {report[key]}")
    return 0


def _fmt(values) -> str:
    return ", ".join("-" if v is None else f"{v:.3g}" for v in values)


def run_mag(args) -> int:
    """``gnomon.calibration.calibrate_mag(gnomon.io.read(path), field_uT=, location=,
    model=)``, ``save_mag_calibration(out, cal)``, ``plot_mag_calibration(...)``. Exit
    status 1 when the calibration is refused (the report says why). ``--orbit``:
    :func:`_run_mag_orbit` (TWOSTEP against the recording's field model)."""
    from gnomon.calibration import (
        calibrate_mag,
        mag_uT_of,
        plot_mag_calibration,
        save_mag_calibration,
    )

    raw_phone_mag(args, "calibrating")
    rec = read_input(args)
    if args.orbit:
        return _run_mag_orbit(args, rec)
    if args.noise_nT is not None:
        raise InputError("--noise-nT goes with --orbit", field="--noise-nT")
    location = None
    if args.location:
        parts = args.location.split(",")
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise InputError(f"expected LAT,LON[,ALT_M] in degrees and m, got "
                             f"{args.location!r}", field="--location") from None
        if len(values) not in (2, 3):
            raise InputError(f"expected LAT,LON[,ALT_M], got {args.location!r}",
                             field="--location")
        if not args.date:
            raise InputError("--location needs --date YYYY-MM-DD (the field changes with "
                             "time)", field="--date")
        location = {"latitude_deg": values[0], "longitude_deg": values[1],
                    "altitude_m": values[2] if len(values) == 3 else 0.0, "date": args.date}
    elif args.date:
        raise InputError("--date goes with --location", field="--date")
    cal = calibrate_mag(rec, field_uT=args.field_uT, location=location, model=args.model,
                        gyro=not args.no_gyro)
    report = {**cal.to_dict(), "input": str(args.input)}
    if args.out:
        save_mag_calibration(args.out, cal)
        report["out"] = str(args.out)
    if args.plot:
        plot_mag_calibration(mag_uT_of(rec), cal, args.plot, title=str(args.input))
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
    else:
        o = ", ".join(f"{v:.2f}" for v in cal.offset_uT)
        print(f"magnetometer calibration of {args.input}: {cal.n_samples} samples, "
              f"{cal.model} model, {'ok' if cal.ok else 'REFUSED'}")
        if not cal.ok:
            print(f"  reason: {cal.reason}")
        print(f"  offset_uT [{o}]")
        print("  soft_iron " + "\n            ".join(
            "[" + ", ".join(f"{v:8.5f}" for v in row) + "]" for row in cal.soft_iron))
        print(f"  field {cal.field_uT:.2f} uT ({cal.field_source}); residual "
              f"{cal.residual_uT:.2f} uT (raw spread {cal.raw_residual_uT:.2f} uT); coverage "
              f"{cal.coverage:.2f}; condition {cal.condition:.3g}")
        for key in ("out", "plot"):
            if key in report:
                print(f"  wrote {report[key]}")
    return 0 if cal.ok else 1


def _run_mag_orbit(args, rec) -> int:
    """``gnomon calibrate mag REC --orbit``: ``gnomon.twostep.calibrate_mag_orbit(rec,
    noise_nT)`` (TWOSTEP against the recording's field model). ``--json`` prints
    ``TwostepResult.to_dict()`` (``bias_nT``, ``std_nT``, ``cov_nT2``, ``centred_bias_nT``,
    ``centred_std_nT``, ``iterations``, ``converged``, ``residual_nT``,
    ``raw_residual_nT``, ``noise_nT``, ``noise_source``, ``condition``, ``n_samples``,
    ``mean_field_nT``, ``coverage``, ``field_source``, ``source``) plus ``input``,
    ``mag_unit``, ``bias_in_mag_unit``, ``std_in_mag_unit`` and ``out``. ``--out`` writes
    the bias as a calibration JSON (``gnomon estimate --mag-calibration``). Exit status 1
    when Gauss-Newton did not converge."""
    from gnomon.calibration import save_mag_calibration
    from gnomon.recording import MAG_UNITS_TO_TESLA
    from gnomon.twostep import calibrate_mag_orbit

    for opt in ("field_uT", "location", "date", "plot"):
        if getattr(args, opt, None):
            raise InputError(f"--orbit uses the recording's field model; "
                             f"--{opt.replace('_', '-')} does not apply",
                             field=f"--{opt.replace('_', '-')}")
    if args.model != "auto":
        raise InputError("--orbit estimates the bias alone; --model does not apply",
                         field="--model")
    res = calibrate_mag_orbit(rec, noise_nT=args.noise_nT)
    per_unit = 1e-9 / MAG_UNITS_TO_TESLA[rec.mag_unit]
    report = {**res.to_dict(), "input": str(args.input), "mag_unit": rec.mag_unit,
              "bias_in_mag_unit": [float(v) * per_unit for v in res.bias_nT],
              "std_in_mag_unit": [float(v) * per_unit for v in res.std_nT]}
    if args.out:
        save_mag_calibration(args.out, res.calibration())
        report["out"] = str(args.out)
    if args.json:
        print_json(report)
    else:
        print(f"TWOSTEP magnetometer bias of {args.input}: {res.n_samples} samples against "
              f"{res.field_source}, {res.iterations} iterations, "
              f"{'converged' if res.converged else 'NOT CONVERGED'}")
        print("  bias_nT [" + ", ".join(f"{v:.1f}" for v in res.bias_nT) + "] +- ["
              + ", ".join(f"{v:.1f}" for v in res.std_nT) + "] (1 sigma)")
        if rec.mag_unit != "nT":
            print(f"  bias_{rec.mag_unit} [" + ", ".join(
                f"{v:.6g}" for v in report["bias_in_mag_unit"]) + "]")
        print(f"  residual ||B - b| - |H|| {res.residual_nT:.1f} nT RMS (raw "
              f"{res.raw_residual_nT:.1f} nT); noise {res.noise_nT:.1f} nT "
              f"({res.noise_source}); condition {res.condition:.3g}")
        if "out" in report:
            print(f"  wrote {report['out']}")
    return 0 if res.converged else 1
