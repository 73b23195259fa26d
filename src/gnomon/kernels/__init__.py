"""Numba-compiled hot loops, imported lazily by the estimators' ``run``.

Each kernel has a readable twin (the estimator's per-sample ``update``) and a
test comparing the two sample by sample. Kernels take every argument
explicitly (an omitted default costs ~37 µs per call in numba) and write into
preallocated output arrays; ``cache=True`` keeps the compiled code on disk.
"""
