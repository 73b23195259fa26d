"""Compiled-kernel caches are dropped when any kernel source changes (numba alone
would miss a change in an inlined helper from another module)."""

from gnomon.kernels import drop_stale_caches


def test_caches_dropped_when_any_source_changes(tmp_path):
    (tmp_path / "quat.py").write_text("A = 1\n")
    (tmp_path / "mahony.py").write_text("B = 2\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "mahony.kernel-1.py311.nbi").write_text("index")
    assert drop_stale_caches(tmp_path)  # no digest yet: caches of unknown sources go
    assert not (cache / "mahony.kernel-1.py311.nbi").exists()
    (cache / "mahony.kernel-1.py311.nbi").write_text("index")
    (cache / "mahony.kernel-1.py311.1.nbc").write_text("code")
    assert not drop_stale_caches(tmp_path)  # same sources: kept
    assert (cache / "mahony.kernel-1.py311.1.nbc").exists()
    (tmp_path / "quat.py").write_text("A = 3\n")  # a helper changes, mahony.py does not
    assert drop_stale_caches(tmp_path)
    assert not list(cache.glob("*.nb?"))
