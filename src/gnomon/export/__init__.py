"""Flight code: gnomon's filters as self-contained C99 libraries a microcontroller or a
flight computer runs, equal to the Python (``gnomon export c``).

Each exported filter is a **hand-written C twin** of its compiled kernel
(``gnomon.kernels.<filter>``), kept in this package (``gnomon/export/c/``) and held to the
kernel by the tests: every twin is compiled with ``cc -std=c99 -O2 -Wall -Wextra -Werror
-pedantic`` and run on real and simulated recordings, within 1e-6 rad of the compiled
Python at every sample in double precision (``tests/test_export.py``). Hand-written rather
than generated: the kernels are numba code on records and tuples; a translator from that
to C would be a compiler of its own, while a twin of ~200 lines per filter reads like the
kernel it follows, phase by phase, and the tests fail at the first sample it drifts. The
one generated part is the ESKF's straight-line Kalman gain and Joseph update
(``c/eskf_unrolled.h``), written by ``tools/codegen_eskf.py`` from the same trace as the
Python's ``kernels/eskf_unrolled.py`` and checked up to date by the tests.

``export_c(name, out_dir, precision, params)`` writes into ``out_dir``:

* the library: ``<filter>.h`` (the state struct with the named fields of the kernel's
  ``STATE``, the parameter struct, ``init``, one update per sensor, the getters) and
  ``<filter>.c``; ``gnomon_real.h`` (``real_t``: double or float), ``gnomon_quat.h``;
  only ``<math.h>``, ``<stdint.h>``, ``<stdbool.h>``; no heap, no globals, no I/O;
* ``<filter>_params.h``: the chosen parameter values, baked in;
* ``runner.c`` + ``runner_adapter.h``: ``gnomon_run`` (a gnomon CSV on stdin, ``t,q_w,
  q_x,q_y,q_z`` on stdout; ``--bench``), ``gnomon_count.hpp`` (operation counts);
* ``Makefile`` (``make``, ``make count``, ``make size``, ``make m4``) and ``README.md``.

``build(out_dir)`` runs ``make`` and writes ``cost.json`` (:mod:`gnomon.export.cost`).
"""

from __future__ import annotations

import dataclasses
import math
from importlib import resources
from pathlib import Path

from gnomon import __version__
from gnomon.errors import InputError
from gnomon.export.spec import FilterSpec

__all__ = ["export_c", "SPECS", "FilterSpec", "PRECISIONS"]

PRECISIONS = ("double", "float")


def _spec_table() -> dict[str, FilterSpec]:
    """Every ``SPECS`` of the modules in ``gnomon.export.filters``."""
    import importlib
    import pkgutil

    from gnomon.export import filters

    table = {}
    for mod in sorted(m.name for m in pkgutil.iter_modules(filters.__path__)):
        for spec in importlib.import_module(f"gnomon.export.filters.{mod}").SPECS:
            table[spec.filter] = spec
    return table


#: filter name -> its C twin
SPECS: dict[str, FilterSpec] = _spec_table()

_COMMON = ("gnomon_real.h", "gnomon_quat.h", "gnomon_count.hpp")


def _c_value(v) -> str:
    """A Python parameter value as a C initialiser."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "INFINITY" if v > 0 else "-INFINITY"
        return repr(v) if ("e" in repr(v) or "." in repr(v)) else repr(v) + ".0"
    if isinstance(v, tuple | list):
        return "{" + ", ".join(_c_value(x) for x in v) + "}"
    raise InputError(f"no C value for {v!r}", field="--param")


def _source(name: str) -> str:
    return resources.files("gnomon.export").joinpath("c", name).read_text()


def export_c(name: str, out_dir, precision: str = "double", params: dict | None = None,
             *, build: bool = False) -> dict:
    """Write filter ``name``'s C twin into ``out_dir`` (module docstring) with the
    parameters ``params`` (a mapping of the filter's ``Params``; defaults otherwise) in
    ``precision`` (``"double"`` or ``"float"``). With ``build``, also run ``make`` and
    write ``cost.json``. Returns a summary (files, parameter values, cost)."""
    from gnomon.estimators import registry

    if name not in SPECS:
        raise InputError(f"no C export of {name!r}; exported filters: "
                         f"{', '.join(sorted(SPECS))}", field="--filter")
    if precision not in PRECISIONS:
        raise InputError(f"expected one of {', '.join(PRECISIONS)}, got {precision!r}",
                         field="--precision")
    spec = SPECS[name]
    cls = registry.get(name)
    p = cls.Params.from_dict(params or {})
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    values = dict(p.as_dict())
    if spec.values is not None:
        values.update(spec.values(p))
    written = []

    def write(fname: str, text: str) -> None:
        (out / fname).write_text(text)
        written.append(fname)

    for fname in _COMMON + spec.headers + spec.sources:
        write(fname, _source(fname))
    write("runner.c", _source(spec.runner))
    write("runner_adapter.h", _source(spec.adapter))
    config = ["/* gnomon_config.h: written by gnomon export c */",
              "#ifndef GNOMON_CONFIG_H", "#define GNOMON_CONFIG_H",
              f'#define GNOMON_FILTER "{name}"', f'#define GNOMON_VERSION "{__version__}"']
    if precision == "float":
        config.append("#define GNOMON_FLOAT 1")
    config += list(spec.defines) + ["#endif", ""]
    write("gnomon_config.h", "\n".join(config))
    baked = {field: values[field] for field in spec.params}
    upper = spec.prefix.upper()
    header = "\n".join([
        f"/* {spec.prefix}_params.h: the parameters baked in by gnomon export c "
        f"(gnomon {__version__}). */",
        f"#ifndef GNOMON_{upper}_PARAMS_H", f"#define GNOMON_{upper}_PARAMS_H",
        f'#include "{spec.headers[0]}"',
        *(f"/* {k} = {v!r} */" for k, v in baked.items()),
        f"static const gnomon_{spec.prefix}_params GNOMON_{upper}_PARAMS = {{",
        ",\n".join(f"    {_c_value(v)}" for v in baked.values()),
        "};", "#endif", ""])
    write(f"{spec.prefix}_params.h", header)
    make = (_source("Makefile.in").replace("@FILTER@", name).replace("@PREFIX@", spec.prefix)
            .replace("@PRECISION@", precision).replace("@VERSION@", __version__)
            .replace("@SOURCES@", " ".join(spec.sources)))
    write("Makefile", make)
    write("README.md", _readme(spec, precision, baked))
    summary = {"filter": name, "precision": precision, "out": str(out), "files": written,
               "params": baked}
    if build:
        from gnomon.export.cost import build_and_measure

        summary["cost"] = build_and_measure(out, spec)
    return summary


#: the README's paragraph on gnomon_run's input, by ``FilterSpec.kind``
_CSV_HELP = {
    "imu": """The recording CSV for gnomon_run: `gnomon convert LOG rec.csv`, or a header
`t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z` in s, rad/s, m/s² and µT (an empty
magnetometer cell: no sample).""",
    "spacecraft": """The recording CSV for gnomon_run: `gnomon convert rec.h5 rec.csv` of a
spacecraft recording; columns read by name (the comment at the top of `runner.c` lists them): `t`,
`gyr_x..z` (rad/s) and what the recording has of `mag_x..z` (µT) with `b_o_nT_x..z`,
`sun_x..z` with `sun_valid` and `s_o_x..z`, `st_q_ib_0..3` with `st_valid`,
`st_boresight_b_x..z` and `q_io_0..3`, `w_io_o_x..z` (an empty cell: no value).""",
}


def _readme(spec: FilterSpec, precision: str, baked: dict) -> str:
    from gnomon.estimators import registry

    cls = registry.get(spec.filter)
    doc = {f.name: (f.metadata.get("unit", ""), f.metadata.get("doc", ""))
           for f in dataclasses.fields(cls.Params)}
    rows = "\n".join(f"| `{k}` | `{v!r}` | {doc.get(k, ('', ''))[0]} | {doc.get(k, ('', ''))[1]} |"
                     for k, v in baked.items())
    usage = _source(spec.headers[0]).split("*/", 1)[0].lstrip("/* ").rstrip()
    return f"""# {spec.filter}: gnomon flight code ({precision} precision)

Exported by `gnomon export c --filter {spec.filter}` (gnomon {__version__}): the C twin of
gnomon's compiled `{spec.filter}` kernel, tested against it sample by sample.

```
{usage}
```

## Build

    make              # lib{'gnomon_' + spec.prefix}.a and gnomon_run (cc -std=c99 -O2, strict)
    ./gnomon_run < recording.csv > q.csv     # t,q_w,q_x,q_y,q_z, as gnomon estimate --out
    ./gnomon_run --bench < recording.csv     # ns per update on this machine
    make count && ./gnomon_count < recording.csv   # operations per update
    make m4           # objects for a Cortex-M4F (arm-none-eabi-gcc) and their size

The library is `{spec.sources[0]}` and the headers; it uses only `<math.h>`, `<stdint.h>`
and `<stdbool.h>`, no heap, no globals and no I/O. Precision: `real_t` is
`{'float' if precision == 'float' else 'double'}` (`gnomon_config.h`); re-export with
`--precision {'double' if precision == 'float' else 'float'}` for the other.
{_CSV_HELP.get(spec.kind, _CSV_HELP["imu"])}

## Parameters baked in (`{spec.prefix}_params.h`)

| parameter | value | unit | meaning |
| --- | --- | --- | --- |
{rows}

## Frames and units

Quaternions are Hamilton, scalar first `[w, x, y, z]`; `q_ab` maps b-coordinates to
a-coordinates. SI units: s, rad, rad/s, m/s²; see gnomon's docs/conventions.md.
"""
