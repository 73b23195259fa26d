"""The ``gnomon`` command line: parse, call the library, print. No logic of its own.

Every command is one library call a user could make from Python (named in each
command's ``run`` docstring). Bad input ends with one line ``gnomon: error: ...`` naming
the file, field and row, and exit status 2 — never a traceback.

One module per command or command group, each with ``add_parser(sub)`` (its sub-parser)
and ``run...(args) -> int`` (what it does); :mod:`gnomon.cli.common` holds what they
share (JSON printing, the input options, reading the input). :data:`COMMANDS` lists them
in the order ``gnomon --help`` shows them. A new command is a module here and one entry
in :data:`COMMANDS`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from gnomon import __version__
from gnomon.errors import InputError

#: the command modules, in the order of ``gnomon --help``
COMMANDS = ("filters", "estimate", "live", "export", "calibrate", "inspect", "benchmark",
            "bench", "compile", "simulate", "campaign", "datasets", "reproduce")

__all__ = ["COMMANDS", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``gnomon`` parser: every command module's ``add_parser`` in :data:`COMMANDS`
    order. Building it compiles nothing (no filter is imported)."""
    p = argparse.ArgumentParser(
        prog="gnomon",
        description="Attitude determination and estimation: filters, benchmarks, reproductions. "
                    "Quaternions are Hamilton, scalar-first [w, x, y, z]; q_ab maps b to a.")
    p.add_argument("--version", action="version", version=f"gnomon {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"gnomon.cli.{name}").add_parser(sub)
    return p


def main(argv=None) -> int:
    """``gnomon ARGS``: the exit status (0 done, 1 a result refused, 2 bad input, 130
    interrupted)."""
    from gnomon import kernels

    if kernels.in_source_checkout():  # kernel sources may have changed under their caches
        kernels.drop_stale_caches()
    parser = build_parser()
    args = parser.parse_args(None if argv is None else [str(a) for a in argv])
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from gnomon.kernels.compile_notice import compile_notice

    try:
        with compile_notice():
            return args.func(args)
    except InputError as e:
        print(f"gnomon: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gnomon: interrupted", file=sys.stderr)
        return 130
