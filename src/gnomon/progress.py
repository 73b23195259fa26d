"""Progress bars for long loops: campaigns, reproductions, benchmarks and ``gnomon bench``.

One helper for all of them. A bar (tqdm, on stderr: done / total, rate, elapsed and
time left) is drawn only where a person watches: stderr is a terminal, the ``CI``
environment variable is unset or empty, and the caller did not ask for quiet
(``--quiet``, ``--json``). Everywhere else :class:`Progress` is a no-op with the same
methods, so a loop never tests whether it has a bar.
"""

from __future__ import annotations

import os
import sys

__all__ = ["Progress", "wanted"]


def wanted(quiet: bool = False, stream=None) -> bool:
    """Whether a progress bar should be drawn: not ``quiet``, ``stream`` (default
    ``sys.stderr``) is a terminal and ``CI`` is not set in the environment."""
    if quiet or os.environ.get("CI"):
        return False
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


class Progress:
    """A progress bar over ``total`` steps of ``unit`` (e.g. "run"), labelled ``desc``.

    ``enabled``: the caller's wish (``progress=`` of a library call); the bar is drawn
    only if also :func:`wanted`. ``update(n, **postfix)`` advances by ``n`` steps and shows
    ``postfix`` (e.g. ``failed=2``); ``note(text)`` shows what runs now; ``close()`` ends
    the bar (also as a context manager).
    """

    def __init__(self, total: int, desc: str, unit: str = "run", enabled: bool = True,
                 leave: bool = True):
        self.bar = None
        if enabled and wanted():
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True,
                            leave=leave, file=sys.stderr)

    def update(self, n: int = 1, **postfix) -> None:
        if self.bar is not None:
            if postfix:
                self.bar.set_postfix(refresh=False, **postfix)
            self.bar.update(n)

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(text, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
