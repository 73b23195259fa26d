"""``gnomon filters``: every registered filter with its parameters, defaults and units."""

from __future__ import annotations

from gnomon.cli.common import print_json


def add_parser(sub) -> None:
    s = sub.add_parser("filters", help="list filters with their parameters, defaults and units")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.describe_filters()``: names, parameters, defaults, units."""
    from gnomon.estimators import registry

    table = registry.describe()
    if args.json:
        print_json(table)
        return 0
    for f in table:
        print(f"{f['name']}: {f['summary']}  (needs {', '.join(f['needs'])})")
        for p in f["params"]:
            unit = f" [{p['unit']}]" if p["unit"] else ""
            print(f"    {p['name']} = {p['default']!r}{unit}  {p['doc']}")
    return 0
