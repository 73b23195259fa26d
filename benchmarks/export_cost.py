"""The cost of every C export, measured: ``gnomon export c`` for each filter and precision
into a temporary folder, its ``cost.json`` collected into one Markdown table.

    python benchmarks/export_cost.py [--json FILE]

State and code bytes, ns per update on this machine (``gnomon_run --bench``: the fastest
pass over the bundled BROAD excerpt, or 600 s of the star-tracker scenario for mekf),
operations per update (``gnomon_count``) and, where arm-none-eabi-gcc is installed, the
code bytes for a Cortex-M4F. The numbers of docs/flight-code.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path


def main(argv=None) -> int:
    from gnomon.export import SPECS, export_c

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="also write the costs to this file")
    ap.add_argument("--filters", help="comma-separated (default: every export)")
    args = ap.parse_args(argv)
    names = args.filters.split(",") if args.filters else sorted(SPECS)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for precision in ("double", "float"):
                out = Path(tmp) / f"{name}-{precision}"
                cost = export_c(name, out, precision, build=True)["cost"]
                rows.append({"filter": name, "precision": precision, **cost})
    print("| filter | precision | state (bytes) | code x86-64 (bytes) | code Cortex-M4F (bytes) "
          "| ns per update (this machine) | operations per update |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        ops = r.get("ops_per_update") or {}
        m4 = r.get("code_bytes_cortex_m4f")
        print(f"| {r['filter']} | {r['precision']} | {r['state_bytes']} | {r['code_bytes']} | "
              f"{m4 if m4 is not None else 'n/a'} | {r['ns_per_update']:.0f} | "
              f"{ops.get('total', float('nan')):.0f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
