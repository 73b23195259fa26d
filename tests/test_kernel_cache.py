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


def test_importing_the_kernels_package_touches_no_file(tmp_path):
    import subprocess
    import sys

    from gnomon import kernels

    stamp = kernels.PACKAGE_DIR / "__pycache__" / "gnomon-kernels.sources"
    before = stamp.stat().st_mtime_ns if stamp.exists() else None
    (kernels.PACKAGE_DIR / "__pycache__").mkdir(exist_ok=True)
    marker = kernels.PACKAGE_DIR / "__pycache__" / "zz-test-marker.nbi"
    marker.write_text("x")
    try:
        subprocess.run([sys.executable, "-c", "import gnomon.kernels, gnomon.kernels.quat"],
                       check=True)
        assert marker.exists()  # a stale-looking cache file survives a plain import
        after = stamp.stat().st_mtime_ns if stamp.exists() else None
        assert after == before
    finally:
        marker.unlink(missing_ok=True)
