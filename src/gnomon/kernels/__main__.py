"""``python -m gnomon.kernels``: drop compiled-kernel caches whose sources changed."""

from gnomon.kernels import PACKAGE_DIR, drop_stale_caches

if __name__ == "__main__":
    dropped = drop_stale_caches()
    what = "dropped" if dropped else "kept"
    print(f"{what} the compiled caches in {PACKAGE_DIR / '__pycache__'}")
