"""Coverage: how much of the sphere of directions the samples visit.

The unit sphere is cut into ``COVERAGE_CELLS = 100`` cells of equal area by Leopardi's
recursive zonal equal-area partition (ETNA 25, 2006: two polar caps and 8 collars, every
cell 4π/100 sr, about 20°x20°; :func:`coverage_cells`); the coverage of a set of vectors
(N, 3), any length and any frame, is the fraction of cells that hold the direction of at
least one of them (:func:`sphere_coverage`). The calibration reports it of the corrected
directions ``h/|h|`` in the sensor's axes, and its fit weighs each sample by the samples
in its cell (:mod:`gnomon.calibration.fit`, step 3).
"""

from __future__ import annotations

import math

import numpy as np

from gnomon.errors import InputError

__all__ = ["coverage_cells", "sphere_coverage", "COVERAGE_CELLS"]

#: number of equal-area cells of the coverage measure
COVERAGE_CELLS = 100


def coverage_cells(n: int = COVERAGE_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """Leopardi's recursive zonal equal-area partition of the unit sphere into ``n``
    cells: ``(colatitude edges (K+1,) rad, cells per zone (K,))``, zones from the north
    pole (a cap of one cell) to the south pole (a cap of one cell); every cell has the
    area ``4π/n``. Zone ``k`` spans ``edges[k] <= colatitude < edges[k+1]`` and is split
    into ``counts[k]`` equal sectors of longitude."""
    if n < 2:
        raise InputError(f"expected at least 2 cells, got {n}", field="cells")
    if n == 2:
        return np.array([0.0, math.pi / 2, math.pi]), np.array([1, 1])
    area = 4 * math.pi / n
    polar = 2 * math.asin(math.sqrt(1.0 / n))  # a cap of one cell's area
    n_collars = max(1, round((math.pi - 2 * polar) / math.sqrt(area)))
    step = (math.pi - 2 * polar) / n_collars
    counts, carry = [1], 0.0
    for i in range(n_collars):
        a, b = polar + i * step, polar + (i + 1) * step
        ideal = n * (math.cos(a) - math.cos(b)) / 2
        k = round(ideal + carry)
        carry += ideal - k
        counts.append(int(k))
    counts.append(1)
    cum = np.cumsum(counts)
    edges = np.concatenate([[0.0], np.arccos(np.clip(1 - 2 * cum / n, -1, 1))])
    edges[-1] = math.pi
    return edges, np.asarray(counts)


def _cell_index(directions: np.ndarray, n: int = COVERAGE_CELLS) -> np.ndarray:
    """The cell (0..n-1) of each unit vector (N, 3)."""
    edges, counts = coverage_cells(n)
    d = np.asarray(directions, dtype=float)
    colat = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    zone = np.clip(np.searchsorted(edges, colat, side="right") - 1, 0, counts.size - 1)
    lon = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * math.pi)
    k = counts[zone]
    sector = np.minimum((lon / (2 * math.pi) * k).astype(np.int64), k - 1)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return start[zone] + sector


def sphere_coverage(vectors, n: int = COVERAGE_CELLS) -> float:
    """Fraction (0..1) of the ``n`` equal-area cells (:func:`coverage_cells`) holding the
    direction of at least one of ``vectors`` (N, 3), any length (zero vectors ignored)."""
    v = np.asarray(vectors, dtype=float)
    norm = np.linalg.norm(v, axis=1)
    v = v[norm > 0] / norm[norm > 0, None]
    if not v.size:
        return 0.0
    return float(np.unique(_cell_index(v, n)).size / n)
