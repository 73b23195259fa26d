"""Paper reproductions: ``pNNN.run(out_dir=None, quick=False, progress=False) -> dict``."""
