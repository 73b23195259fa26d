"""Observability of a linear(ised) system ``(F, D)``: rank and conditioning of
``M_o = [D; D F; D F²; …; D F^(n-1)]``.

Seed 002 (Bilous & Nesterenko) proves that the AHRS error state (attitude
error and gyro bias, n = 6) stays observable with the reduced 3-component
measurement: with ``F = [F₁ F₂; 0 0]``, ``F₁ = -[ω×]``, ``F₂ = -½I`` and
``D = [D₁ 0]`` the first two blocks ``[D₁ 0; D₁F₁ -½D₁]`` are already of
rank 6 whenever ``D₁`` is non-singular. ``observability`` checks any pair
numerically; the degenerate cases (gravity only with no rotation: rank 4; the
magnetic pole where ``tan I → ∞``: ``det D₁`` stays 8 but one singular value
grows like ``tan I`` and another shrinks like ``1/tan I``, so the condition
number grows like ``tan² I`` and the numerical rank drops) are in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Observability", "observability", "observability_matrix"]


@dataclass(frozen=True)
class Observability:
    """Result of ``observability``.

    ``rank``: number of singular values of ``M_o`` above ``tol · σ_max``;
    ``n``: state dimension (observable iff ``rank == n``); ``condition``:
    ``σ_max / σ_n`` (the n-th largest singular value; ``inf`` when it is 0);
    ``singular_values``: the n largest, descending; ``tol``: the relative
    tolerance used.
    """

    rank: int
    n: int
    condition: float
    singular_values: np.ndarray
    tol: float

    @property
    def observable(self) -> bool:
        return self.rank == self.n


def observability_matrix(F, D) -> np.ndarray:
    """``[D; D F; …; D F^(n-1)]``, shape ``(n·r, n)`` for ``F`` (n, n) and ``D`` (r, n)."""
    F = np.asarray(F, float)
    D = np.asarray(D, float)
    n = F.shape[0]
    if F.shape != (n, n) or D.ndim != 2 or D.shape[1] != n:
        raise ValueError(f"F must be (n, n) and D (r, n); got {F.shape} and {D.shape}")
    blocks = [D]
    for _ in range(n - 1):
        blocks.append(blocks[-1] @ F)
    return np.vstack(blocks)


def observability(F, D, tol: float = 1e-9) -> Observability:
    """Rank (relative tolerance ``tol``) and condition number of the observability matrix.

    A singular value counts towards the rank when it exceeds ``tol · σ_max``;
    the default 1e-9 is far above double-precision rounding of ``M_o``
    (~1e-15 relative) and far below the smallest singular value of any
    physically observable AHRS configuration (rates and fields of order 1 in SI
    units). Scale ``F`` and ``D`` to comparable units before calling.
    """
    Mo = observability_matrix(F, D)
    n = Mo.shape[1]
    s = np.linalg.svd(Mo, compute_uv=False)
    s = np.concatenate([s, np.zeros(max(0, n - s.size))])[:n]
    smax = s[0] if s.size else 0.0
    rank = int(np.sum(s > tol * smax)) if smax > 0 else 0
    cond = float(smax / s[-1]) if s[-1] > 0 else float("inf")
    return Observability(rank=rank, n=n, condition=cond, singular_values=s, tol=tol)
