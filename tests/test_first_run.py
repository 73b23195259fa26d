"""The first run on a new machine: what compiles, and what is said about it (issue 35).

``gnomon --help`` and ``gnomon filters`` compile nothing (checked on an empty numba cache:
no file appears in it); a real compilation is announced once on stderr with its
measured seconds, a load from memory or the cache says nothing. The first ``gnomon
estimate`` with a C compiler at hand builds the default filter's C export (about a
second) and compiles no numba kernel; without one it runs the numba kernels."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys

import pytest
from numba import njit

from gnomon.kernels.compile_notice import compile_notice


def _gnomon(args, cache_dir, **env_vars):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), **env_vars)
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


@pytest.mark.slow(reason="20-30 s (2 cores): three new processes, one compiles robust-ahrs "
                         "on an empty numba cache")
@pytest.mark.skipif(shutil.which("cc") is None or shutil.which("make") is None,
                    reason="no C compiler (cc) or make: the C backend NOT tested")
def test_the_first_estimate_builds_the_c_and_compiles_no_kernel(tmp_path):
    from gnomon.datasets import bundled

    trial = str(sorted(bundled("broad").glob("*.hdf5"))[0])
    numba_cache, data = tmp_path / "numba", tmp_path / "data"
    r = _gnomon(["estimate", trial, "--json"], numba_cache, GNOMON_DATA_DIR=str(data))
    assert r.returncode == 0, r.stderr
    c = json.loads(r.stdout)
    assert c["filter"] == "robust-ahrs" and c["backend"] == "c (double)"
    assert "built robust-ahrs's C" in r.stderr and "compiling" not in r.stderr, r.stderr
    assert list(numba_cache.rglob("*.nbi")) == []
    assert list(data.rglob("libgnomon_robust_ahrs_run.so"))

    again = _gnomon(["estimate", trial, "--json"], numba_cache, GNOMON_DATA_DIR=str(data))
    assert again.returncode == 0 and "built" not in again.stderr, again.stderr

    # no compiler: the numba kernels, the same numbers
    py = _gnomon(["estimate", trial, "--json"], numba_cache, GNOMON_DATA_DIR=str(data),
                 CC=str(tmp_path / "no-such-cc"))
    assert py.returncode == 0, py.stderr
    p = json.loads(py.stdout)
    assert p["backend"] == "python" and "no C compiler" in p["backend_because"]
    assert list(numba_cache.rglob("*.nbi"))
    for key in ("total_deg", "heading_deg", "inclination_deg", "max_deg"):
        assert abs(p["errors"][key] - c["errors"][key]) < 1e-9, key
    assert p["warnings"] == c["warnings"]
