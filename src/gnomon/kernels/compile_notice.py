"""Saying on stderr, once per command, that a compiled kernel is being built for this
machine, and how long it took.

numba compiles a kernel the first time it is called with new argument types and keeps
the machine code on disk (``cache=True``: beside the package's sources, or under
``NUMBA_CACHE_DIR``); later processes load it in a fraction of a second. The first run
of a filter on a new machine, a new virtual environment or after an upgrade therefore
waits several seconds with nothing to show. :func:`compile_notice` listens to numba's
``numba:compile`` events (numba's public event API; they fire for a real compilation,
not for a load from the cache) and writes two lines to ``stream``: ``gnomon: compiling
robust_ahrs.robust_ahrs_batch for this machine, once (later runs load it from the
cache) ...`` when the first compilation starts, ``gnomon: compiled in 7.9 s`` at the end.

Nothing is written when everything came from the cache. The seconds are measured,
the names are the compiled functions' own.
"""

from __future__ import annotations

import contextlib
import sys
import time

from numba.core import event

__all__ = ["compile_notice"]


class _Notice(event.Listener):
    """A numba event listener that times the outermost compilations."""

    def __init__(self, stream):
        self.stream = stream
        self.depth = 0
        self.started = 0.0
        self.seconds = 0.0
        self.first: str | None = None

    def on_start(self, ev) -> None:
        if self.depth == 0:
            self.started = time.perf_counter()
            if self.first is None:
                self.first = _name(ev)
                print(f"gnomon: compiling {self.first} for this machine, once (later runs "
                      "load it from the cache) ...", file=self.stream, flush=True)
        self.depth += 1

    def on_end(self, ev) -> None:
        self.depth -= 1
        if self.depth == 0:
            self.seconds += time.perf_counter() - self.started


def _name(ev) -> str:
    """``module.function`` of the dispatcher an event is about (the module's last part)."""
    d = (ev.data or {}).get("dispatcher")
    f = getattr(d, "py_func", None)
    if f is None:
        return "a kernel"
    return f"{f.__module__.rsplit('.', 1)[-1]}.{f.__qualname__}"


@contextlib.contextmanager
def compile_notice(stream=None):
    """Within the block, announce the first numba compilation on ``stream`` (default
    stderr) and, at its end, the seconds all compilations took; yields the listener
    (``.seconds``, ``.first``: None when nothing compiled)."""
    listener = _Notice(sys.stderr if stream is None else stream)
    event.register("numba:compile", listener)
    try:
        yield listener
    finally:
        event.unregister("numba:compile", listener)
        if listener.first is not None:
            print(f"gnomon: compiled in {listener.seconds:.1f} s", file=listener.stream,
                  flush=True)
