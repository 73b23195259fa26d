"""``python -m gnomon.kernels``: drop compiled-kernel caches whose sources changed."""

from gnomon.kernels import PACKAGE_DIR, drop_stale_caches

if __name__ == "__main__":
    dropped = drop_stale_caches()
    where = PACKAGE_DIR / "__pycache__"
    if dropped:
        print(f"dropped the compiled caches of {', '.join(dropped)} in {where}")
    else:
        print(f"kept the compiled caches in {where}")
