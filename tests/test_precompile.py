"""``gnomon compile``: kernels compiled ahead of their first use, in parallel processes,
into the cache a later process loads from (issue 35)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.precompile import precompile, targets


def _gnomon(args, cache_dir):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    return subprocess.run([sys.executable, "-c", "import sys; from gnomon.cli import main; "
                           "sys.exit(main(sys.argv[1:]))", *args],
                          capture_output=True, text=True, env=env, timeout=600)


def test_targets_are_the_filters_then_simulation_and_scoring():
    from gnomon.estimators import registry

    assert targets() == [*registry.names(), "simulation", "scoring"]


def test_unknown_targets_and_workers_are_refused():
    with pytest.raises(InputError, match="unknown target 'vqf'.*robust-ahrs"):
        precompile(["vqf"])
    with pytest.raises(InputError, match="at least 1 worker, got 0"):
        precompile(["tilt-cf"], workers=0)


@pytest.mark.slow(reason="two processes compile on an empty cache, then a third loads "
                         "from it: 20-40 s")
def test_compiled_in_two_processes_then_loaded_by_an_estimate(tmp_path):
    cache = tmp_path / "numba"
    r = _gnomon(["compile", "tilt-cf", "scoring", "--workers", "2", "--json"], cache)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert set(res) >= {"targets", "workers", "wall_s"} and res["workers"] == 2
    assert list(res["targets"]) == ["tilt-cf", "scoring"]
    for name, t in res["targets"].items():
        assert t["error"] == "" and t["seconds"] > 0.0, name
    stems = {p.name.split(".")[0] for p in cache.rglob("*.nbi")}
    assert {"tilt_cf", "scores"} <= stems, stems
    # a later process running the filter on a real log loads it: nothing is compiled
    log = next(bundled("broad").glob("*.hdf5"))
    r = _gnomon(["estimate", str(log), "--filter", "tilt-cf"], cache)
    assert r.returncode == 0, r.stderr
    assert "compiling" not in r.stderr, r.stderr

    r = _gnomon(["compile", "no-such-filter"], cache)
    assert r.returncode == 2 and "unknown target 'no-such-filter'" in r.stderr
