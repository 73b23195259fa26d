"""The first run on a new machine: what compiles, and what is said about it (issue 35).

``gnomon --help`` and ``gnomon filters`` compile nothing (checked on an empty numba cache:
no file appears in it); a real compilation is announced once on stderr with its
measured seconds, a load from memory or the cache says nothing."""

from __future__ import annotations

import io
import os
import subprocess
import sys

from numba import njit

from gnomon.kernels.compile_notice import compile_notice


def _gnomon(args, cache_dir):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    return subprocess.run([sys.executable, "-c", "import sys; from gnomon.cli import main; "
                           "sys.exit(main(sys.argv[1:]))", *args],
                          capture_output=True, text=True, env=env, timeout=300)


def test_help_and_filters_compile_nothing(tmp_path):
    for args in (["--help"], ["filters"]):
        r = _gnomon(args, tmp_path)
        assert r.returncode == 0, r.stderr
        assert "compiling" not in r.stderr
        assert list(tmp_path.rglob("*.nbi")) == [], args


def test_a_compilation_is_announced_once_with_its_seconds():
    @njit
    def twice(x):
        return 2.0 * x

    out = io.StringIO()
    with compile_notice(out) as notice:
        assert twice(1.5) == 3.0
        assert twice(2.5) == 5.0  # same types: no second compilation
    lines = out.getvalue().splitlines()
    assert len(lines) == 2, lines
    assert "compiling test_first_run.test_a_compilation_is_announced_once_with_its_seconds" \
           ".<locals>.twice" in lines[0]
    assert lines[1] == f"gnomon: compiled in {notice.seconds:.1f} s"
    assert notice.seconds > 0.0

    again = io.StringIO()
    with compile_notice(again) as notice:
        twice(4.0)  # compiled already: nothing to say
    assert again.getvalue() == "" and notice.first is None and notice.seconds == 0.0
