"""Reproductions of the seed papers: ``pNNN.run(out_dir=None, quick=False, progress=False) -> dict``."""
