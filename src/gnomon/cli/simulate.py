"""``gnomon scenarios`` (the presets) and ``gnomon simulate`` (a scenario into a recording)."""

from __future__ import annotations

from gnomon.cli.common import parse_pairs, print_json


def add_parser(sub) -> None:
    s = sub.add_parser("scenarios", help="list the scenario presets")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run_scenarios)

    s = sub.add_parser("simulate", help="simulate a scenario into a gnomon HDF5 recording")
    s.add_argument("scenario", help="preset name (see `gnomon scenarios`) or a YAML file")
    s.add_argument("--out", required=True, help="recording file to write (.h5)")
    s.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario value by its dotted key")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run_simulate)


def run_scenarios(args) -> int:
    """``gnomon.scenarios.list_presets()`` and each preset's description."""
    from gnomon.scenarios import list_presets, load_scenario

    rows = [{"name": n, "description": load_scenario(n).config.get("description", "")}
            for n in list_presets()]
    if args.json:
        print_json(rows)
    else:
        for r in rows:
            print(f"{r['name']}: {' '.join(str(r['description']).split())}")
    return 0


def run_simulate(args) -> int:
    """``gnomon.io.write(out, gnomon.scenarios.simulate(load_scenario(name), rng_seed))``."""
    from gnomon.io import write
    from gnomon.scenarios import load_scenario, simulate

    scenario = load_scenario(args.scenario)
    if args.set:
        scenario = scenario.replace(parse_pairs(args.set, option="--set", typed=True))
    rec = simulate(scenario, rng_seed=args.seed)
    write(args.out, rec)
    summary = {"scenario": args.scenario, "out": str(args.out), "samples": len(rec),
               "duration_s": float(rec.t[-1] - rec.t[0]), "frames": rec.frames}
    if args.json:
        print_json(summary)
    else:
        print(f"simulated {args.scenario}: {len(rec)} samples over "
              f"{summary['duration_s']:.0f} s; wrote {args.out}")
    return 0
