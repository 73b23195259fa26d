"""``gnomon datasets [fetch NAME]``: the real data sets, where they are, and fetching one."""

from __future__ import annotations

from gnomon.cli.common import print_json, progress_wanted
from gnomon.errors import InputError


def add_parser(sub) -> None:
    s = sub.add_parser("datasets", help="the real data sets: source, licence, bundled or "
                                        "fetched; `gnomon datasets fetch NAME` downloads one")
    s.add_argument("action", nargs="?", choices=["list", "fetch"], default="list")
    s.add_argument("name", nargs="?", help="data set to fetch (broad, tyrex, logs, images)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.datasets.describe`` for every data set, or ``gnomon.datasets.fetch(NAME)``."""
    from gnomon import datasets

    if args.action == "fetch":
        if not args.name:
            raise InputError(f"gnomon datasets fetch needs a NAME: {', '.join(datasets.CATALOGUE)}",
                             field="NAME")
        folder = datasets.fetch(args.name, progress=progress_wanted(args))
        if args.json:
            print_json(datasets.describe(args.name))
        else:
            print(f"{args.name}: complete in {folder}")
        return 0
    rows = [datasets.describe(name) for name in datasets.CATALOGUE]
    if args.json:
        print_json({"cache": str(datasets.cache_dir()), "datasets": rows})
        return 0
    print(f"cache folder: {datasets.cache_dir()} (setting GNOMON_DATA_DIR)")
    for r in rows:
        where = {"local": f"local copy in {r['local']}",
                 "cached": f"fetched into {r['cache']}",
                 "partly fetched": f"{r['cached_files']} of {r['files']} files fetched into "
                                   f"{r['cache']}: gnomon datasets fetch {r['name']}",
                 "not fetched": f"not fetched ({r['bytes'] / 1e6:.1f} MB): "
                                f"gnomon datasets fetch {r['name']}"}[r["state"]]
        print(f"\n{r['name']}: {r['title']}")
        print(f"  licence: {r['licence']}; credit: {r['citation']}")
        print(f"  source:  {r['source']} ({r['scope']})")
        print(f"  bundled: {'excerpt in ' + r['bundled'] if r['bundled'] else 'no'}")
        print(f"  full:    {where}")
    return 0
