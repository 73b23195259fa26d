"""Compiled-kernel caches are dropped when the sources they were compiled from change
(numba alone would miss a change in an inlined helper from another module), and only
those."""

from gnomon.kernels import drop_stale_caches


def _files(cache):
    return sorted(f.name for f in cache.glob("*.nb?"))


def test_caches_dropped_with_the_sources_they_were_compiled_from(tmp_path):
    """A module's caches go when its source or that of a kernel module it imports
    (directly or through another) changes; the others stay."""
    (tmp_path / "quat.py").write_text("A = 1\n")
    (tmp_path / "linalg.py").write_text("from gnomon.kernels.quat import A\n")
    (tmp_path / "mahony.py").write_text("from gnomon.kernels import linalg\nB = 2\n")
    (tmp_path / "tilt_cf.py").write_text("C = 3\n")
    (tmp_path / "scores.py").write_text("def f():\n    from . import quat\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()

    def compiled():
        for m in ("quat", "linalg", "mahony", "tilt_cf", "scores"):
            (cache / f"{m}.kernel-1.py311.nbi").write_text("index")
            (cache / f"{m}.kernel-1.py311.1.nbc").write_text("code")

    compiled()
    (cache / "gone.kernel-1.py311.nbi").write_text("index")  # no such module any more
    # no digest yet: caches of unknown sources go
    assert drop_stale_caches(tmp_path) == ["gone", "linalg", "mahony", "quat", "scores",
                                           "tilt_cf"]
    assert _files(cache) == []
    compiled()
    assert drop_stale_caches(tmp_path) == []  # same sources: kept
    assert len(_files(cache)) == 10
    (tmp_path / "tilt_cf.py").write_text("C = 4\n")  # a module alone
    assert drop_stale_caches(tmp_path) == ["tilt_cf"]
    compiled()
    (tmp_path / "quat.py").write_text("A = 3\n")  # a helper: every module that uses it
    assert drop_stale_caches(tmp_path) == ["linalg", "mahony", "quat", "scores"]
    assert _files(cache) == ["tilt_cf.kernel-1.py311.1.nbc", "tilt_cf.kernel-1.py311.nbi"]
    compiled()
    (cache / "gnomon-kernels.sources").write_text("an older stamp")  # unreadable: all go
    assert len(drop_stale_caches(tmp_path)) == 5


def test_the_real_kernels_depend_on_their_helpers():
    """The digests of the package's own modules follow its imports: robust-ahrs uses
    quat, linalg and its state module; the quaternion helpers depend on nothing."""
    from gnomon.kernels import PACKAGE_DIR, _kernel_imports

    names = {p.stem for p in PACKAGE_DIR.glob("*.py")} - {"__init__", "__main__"}
    src = (PACKAGE_DIR / "robust_ahrs.py").read_text()
    assert {"quat", "linalg", "robust_ahrs_state"} <= _kernel_imports(src, names)
    assert _kernel_imports((PACKAGE_DIR / "quat.py").read_text(), names) <= {"quat"}


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
