"""Reproductions of the seed papers.

Each ``pNNN`` module has ``run(out_dir=None, quick=False, progress=False) -> dict``.
"""
