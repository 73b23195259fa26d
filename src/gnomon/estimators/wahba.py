"""Wahba's problem: the attitude that best maps body vectors onto reference vectors.

Given unit reference directions ``r_i`` (frame r, e.g. the orbital frame from a
field model and a sun model), the same directions measured in the body ``b_i``
and weights ``a_i >= 0``, find the rotation ``R_rb`` minimising

    L(R) = ½ Σ a_i |r_i − R_rb b_i|²                       (Wahba 1965)

Every solver here has ONE signature::

    solver(r, b, w=None, **options) -> WahbaResult

with ``r``, ``b`` of shape (..., k, 3) (any units: rows are normalised),
``w`` (..., k) (default ones) and leading axes vectorised (e.g. one problem per
time sample). The result holds ``q`` = ``q_rb`` ``[w, x, y, z]`` (Hamilton,
reference from body), the loss ``L`` of the normalised problem, a quality
figure and a ``degenerate`` flag.

Quality: with ``B = Σ a_i r_i b_iᵀ / Σ a_i`` and its singular values
``s1 >= s2 >= s3``, ``quality = s2 / s1`` (for two unit vectors at angle θ
with equal weights it is ``tan²(θ/2)``; ``0`` means the rotation about the
common direction is unobservable). ``degenerate`` is set when ``quality <
min_quality`` (default ``1e-4``, about 1.1° between two vectors), when fewer
than two usable vectors remain (zero-norm or non-finite rows get weight zero),
or when the weights sum to zero. A degenerate result still carries the
solver's best guess in ``q`` (finite, normalised), but it must not be used as
a measurement: the filters skip such samples and flag them.

Solvers (all return the same optimum up to rounding on well-posed problems,
except TRIAD which uses only the first two usable vectors, trusting the first
exactly):

* ``triad``: Black (1964); Shuster & Oh (1981).
* ``davenport``: Davenport's q-method, the eigenvector of the largest eigenvalue
  of the 4x4 K matrix (Keat 1977).
* ``quest``: Shuster & Oh (1981), the largest eigenvalue by Newton iteration on
  the characteristic polynomial, Rodrigues parameters, with Shuster's method of
  sequential rotations for rotations near 180°.
* ``svd``: Markley (1988), ``R = U diag(1, 1, det U det V) Vᵀ``.
* ``gauss_newton``: the "recursive least squares" of seed 000 (the paper on
  microsatellite complementary filtering): minimise ``J(q) = |y° − R(q) y^b|²``
  over the 4 *unnormalised* quaternion components by Gauss-Newton,
  ``q ← q + (AᵀWA)⁻¹ AᵀW e``, ``A = ∂(R(q) y^b)/∂q`` (3k x 4), renormalising
  after each step, starting from ``q0`` (the previous estimate in a filter).

``solve(name, r, b, w)`` dispatches by name (``SOLVERS``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.rotation import dcm_from_quat, quat_conj, quat_from_dcm, quat_mul, skew

__all__ = ["WahbaResult", "triad", "davenport", "quest", "svd", "gauss_newton", "solve",
           "SOLVERS", "wahba_loss", "quality"]

DEFAULT_MIN_QUALITY = 1e-4


@dataclass
class WahbaResult:
    """Solution of Wahba's problem (leading shape ``S`` of the input problems).

    ``q`` (S..., 4) ``q_rb`` [w, x, y, z], finite and normalised; ``loss`` (S...)
    the Wahba loss of the normalised problem (weights scaled to sum 1, vectors
    unit); ``quality`` (S...) in [0, 1] (``s2/s1`` of the attitude profile
    matrix); ``degenerate`` (S...) bool: do not use ``q`` as a measurement;
    ``method``: solver name.
    """

    q: np.ndarray
    loss: np.ndarray
    quality: np.ndarray
    degenerate: np.ndarray
    method: str


# ------------------------------------------------------------------ helpers
def _prepare(r, b, w):
    """Unit rows, usable-row weights normalised to sum 1 (or all zero), per problem."""
    r = np.asarray(r, dtype=float)
    b = np.asarray(b, dtype=float)
    if r.ndim < 2 or r.shape[-1] != 3:
        raise InputError(f"expected shape (..., k, 3), got {r.shape}", field="r")
    if b.shape != r.shape:
        raise InputError(f"expected the shape of r {r.shape}, got {b.shape}", field="b")
    w = np.ones(r.shape[:-1]) if w is None else np.asarray(w, dtype=float)
    w = np.broadcast_to(w, r.shape[:-1]).astype(float)
    with np.errstate(invalid="ignore", over="ignore"):
        nr = np.linalg.norm(r, axis=-1)
        nb = np.linalg.norm(b, axis=-1)
    ok = (np.isfinite(nr) & np.isfinite(nb) & (nr > 0) & (nb > 0) & np.isfinite(w) & (w > 0))
    safe_r = np.where(ok[..., None], r / np.where(ok, nr, 1.0)[..., None], 0.0)
    safe_b = np.where(ok[..., None], b / np.where(ok, nb, 1.0)[..., None], 0.0)
    w = np.where(ok, w, 0.0)
    total = w.sum(axis=-1)
    w = w / np.where(total > 0, total, 1.0)[..., None]
    n_ok = ok.sum(axis=-1)
    return safe_r, safe_b, w, n_ok


def _profile(r, b, w):
    """Attitude profile matrix ``B = Σ w r bᵀ`` (..., 3, 3): ``R_rb`` maximises tr(R Bᵀ)."""
    return np.einsum("...k,...ki,...kj->...ij", w, r, b)


def quality(r, b, w=None) -> np.ndarray:
    """The quality figure ``s2/s1`` of the attitude profile matrix (see module docstring)."""
    r, b, w, _ = _prepare(r, b, w)
    return _quality_from_profile(_profile(r, b, w))


def _quality_from_profile(B):
    s = np.linalg.svd(B, compute_uv=False)
    return np.where(s[..., 0] > 0, s[..., 1] / np.where(s[..., 0] > 0, s[..., 0], 1.0), 0.0)


def wahba_loss(q_rb, r, b, w=None) -> np.ndarray:
    """Loss ``½ Σ w |r − R(q) b|²`` of the normalised problem (weights summing to 1)."""
    r, b, w, _ = _prepare(r, b, w)
    R = dcm_from_quat(np.asarray(q_rb, float))
    d = r - np.einsum("...ij,...kj->...ki", R, b)
    return 0.5 * np.einsum("...k,...k->...", w, np.einsum("...ki,...ki->...k", d, d))


def _finish(q, r, b, w, n_ok, min_quality, method, B=None):
    q = np.asarray(q, float)
    nq = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~np.all(np.isfinite(q), axis=-1) | (nq[..., 0] < 1e-12)
    q = np.where(bad[..., None], np.array([1.0, 0.0, 0.0, 0.0]), q / np.where(bad, 1.0,
                                                                            nq[..., 0])[..., None])
    if B is None:
        B = _profile(r, b, w)
    qual = _quality_from_profile(B)
    R = dcm_from_quat(q)
    d = r - np.einsum("...ij,...kj->...ki", R, b)
    loss = 0.5 * np.einsum("...k,...k->...", w, np.einsum("...ki,...ki->...k", d, d))
    degenerate = bad | (n_ok < 2) | (qual < min_quality)
    return WahbaResult(q=q, loss=loss, quality=qual, degenerate=degenerate, method=method)


# ------------------------------------------------------------------ solvers
def triad(r, b, w=None, min_quality: float = DEFAULT_MIN_QUALITY) -> WahbaResult:
    """TRIAD from the first two usable vectors (the first is matched exactly).

    Black (1964): triads ``t1 = v1, t2 = v1×v2/|v1×v2|, t3 = t1×t2`` in both
    frames, ``R_rb = [t_r] [t_b]ᵀ``. Weights only select usable rows.
    """
    r, b, w, n_ok = _prepare(r, b, w)
    # index of the first two usable rows per problem
    usable = w > 0
    order = np.argsort(~usable, axis=-1, kind="stable")
    i1 = order[..., 0:1, None]
    i2 = order[..., 1:2, None] if r.shape[-2] > 1 else order[..., 0:1, None]
    r1 = np.take_along_axis(r, i1, axis=-2)[..., 0, :]
    r2 = np.take_along_axis(r, i2, axis=-2)[..., 0, :]
    b1 = np.take_along_axis(b, i1, axis=-2)[..., 0, :]
    b2 = np.take_along_axis(b, i2, axis=-2)[..., 0, :]

    def frame(v1, v2):
        c = np.cross(v1, v2)
        nc = np.linalg.norm(c, axis=-1, keepdims=True)
        # any perpendicular if parallel (flagged degenerate below)
        alt = np.cross(v1, np.where(np.abs(v1[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0]))
        alt = alt / np.maximum(np.linalg.norm(alt, axis=-1, keepdims=True), 1e-300)
        t2 = np.where(nc > 1e-12, c / np.maximum(nc, 1e-300), alt)
        t3 = np.cross(v1, t2)
        return np.stack([v1, t2, t3], axis=-1)  # columns

    R = frame(r1, r2) @ np.swapaxes(frame(b1, b2), -1, -2)
    q = quat_from_dcm(_orthonormalise(R))
    # TRIAD's own observability: the two vectors it uses
    pair_w = np.zeros(r.shape[:-1])
    np.put_along_axis(pair_w, i1[..., 0], 0.5, axis=-1)
    np.put_along_axis(pair_w, i2[..., 0], 0.5, axis=-1)
    res = _finish(q, r, b, w, n_ok, min_quality, "triad", B=_profile(r, b, pair_w))
    return res


def _orthonormalise(R):
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def _davenport_k(B):
    """Davenport's K (..., 4, 4) in Hamilton order [w, x, y, z] for ``q_rb``.

    With ``B = Σ w r bᵀ``: ``tr(R_rb Bᵀ) = qᵀ K q``, ``K = [[σ, zᵀ], [z, S − σI]]``,
    ``σ = tr B``, ``S = B + Bᵀ``, ``z = Σ w b × r`` ... expressed through B's entries.
    """
    sigma = np.trace(B, axis1=-2, axis2=-1)
    S = B + np.swapaxes(B, -1, -2)
    # z = Σ w (b × r) for q_rb: components from the antisymmetric part of B
    z = np.stack([B[..., 2, 1] - B[..., 1, 2], B[..., 0, 2] - B[..., 2, 0],
                  B[..., 1, 0] - B[..., 0, 1]], axis=-1)
    K = np.zeros(B.shape[:-2] + (4, 4))
    K[..., 0, 0] = sigma
    K[..., 0, 1:] = z
    K[..., 1:, 0] = z
    K[..., 1:, 1:] = S - sigma[..., None, None] * np.eye(3)
    return K


def davenport(r, b, w=None, min_quality: float = DEFAULT_MIN_QUALITY) -> WahbaResult:
    """Davenport's q-method: eigenvector of the largest eigenvalue of K."""
    r, b, w, n_ok = _prepare(r, b, w)
    B = _profile(r, b, w)
    _, vec = np.linalg.eigh(_davenport_k(B))
    return _finish(vec[..., :, -1], r, b, w, n_ok, min_quality, "davenport", B=B)


def svd(r, b, w=None, min_quality: float = DEFAULT_MIN_QUALITY) -> WahbaResult:
    """Markley's SVD method: ``R_rb = U diag(1, 1, det U det V) Vᵀ`` from ``B = U S Vᵀ``."""
    r, b, w, n_ok = _prepare(r, b, w)
    B = _profile(r, b, w)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return _finish(quat_from_dcm(U @ Vt), r, b, w, n_ok, min_quality, "svd", B=B)


def _quest_core(B, newton_iterations):
    """QUEST on profile B: (q_rb unnormalised, |γ|-like conditioning) per problem."""
    K = _davenport_k(B)
    sigma = K[..., 0, 0]
    z = K[..., 1:, 0]
    S = K[..., 1:, 1:] + sigma[..., None, None] * np.eye(3)
    kappa = np.trace(_adj3(S), axis1=-2, axis2=-1)
    delta = np.linalg.det(S)
    a = sigma ** 2 - kappa
    bq = sigma ** 2 + np.einsum("...i,...i->...", z, z)
    Sz = np.einsum("...ij,...j->...i", S, z)
    c = delta + np.einsum("...i,...i->...", z, Sz)
    d = np.einsum("...i,...i->...", z, np.einsum("...ij,...j->...i", S, Sz))
    lam = np.ones_like(sigma)  # weights sum to 1: λ_max ≤ 1, start there (Shuster)
    for _ in range(newton_iterations):
        f = lam ** 4 - (a + bq) * lam ** 2 - c * lam + (a * bq + c * sigma - d)
        fp = 4 * lam ** 3 - 2 * (a + bq) * lam - c
        lam = lam - f / np.where(np.abs(fp) > 1e-300, fp, 1e-300)
    alpha = lam ** 2 - sigma ** 2 + kappa
    beta = lam - sigma
    gamma = (lam + sigma) * alpha - delta
    X = (alpha[..., None] * z + beta[..., None] * Sz
         + np.einsum("...ij,...j->...i", S, Sz))
    q = np.concatenate([gamma[..., None], X], axis=-1)
    return q


def _adj3(M):
    """Adjugate of (..., 3, 3)."""
    c = np.empty_like(M)
    c[..., 0, 0] = M[..., 1, 1] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 1]
    c[..., 0, 1] = M[..., 0, 2] * M[..., 2, 1] - M[..., 0, 1] * M[..., 2, 2]
    c[..., 0, 2] = M[..., 0, 1] * M[..., 1, 2] - M[..., 0, 2] * M[..., 1, 1]
    c[..., 1, 0] = M[..., 1, 2] * M[..., 2, 0] - M[..., 1, 0] * M[..., 2, 2]
    c[..., 1, 1] = M[..., 0, 0] * M[..., 2, 2] - M[..., 0, 2] * M[..., 2, 0]
    c[..., 1, 2] = M[..., 0, 2] * M[..., 1, 0] - M[..., 0, 0] * M[..., 1, 2]
    c[..., 2, 0] = M[..., 1, 0] * M[..., 2, 1] - M[..., 1, 1] * M[..., 2, 0]
    c[..., 2, 1] = M[..., 0, 1] * M[..., 2, 0] - M[..., 0, 0] * M[..., 2, 1]
    c[..., 2, 2] = M[..., 0, 0] * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]
    return c


_FLIPS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                   [0.0, 0.0, 0.0, 1.0]])  # q_rr' for rotations by 0 or 180° about x, y, z


def quest(r, b, w=None, min_quality: float = DEFAULT_MIN_QUALITY,
          newton_iterations: int = 6) -> WahbaResult:
    """QUEST (Shuster & Oh 1981) with sequential rotations near 180°.

    The reference frame is also rotated by 180° about x, y and z, and the
    candidate with the largest Rodrigues denominator |γ| is kept when the
    unrotated one is poorly conditioned; the rotation is composed back:
    ``q_rb = q_rr' ⊗ q_r'b``.
    """
    r, b, w, n_ok = _prepare(r, b, w)
    B = _profile(r, b, w)
    best = None
    best_g = None
    for flip in _FLIPS:
        # r' = R_r'r r with q_r'r = conj(flip); B' = R_r'r B
        R_fr = dcm_from_quat(quat_conj(flip))
        qp = _quest_core(R_fr @ B, newton_iterations)
        g = np.abs(qp[..., 0])  # |γ|: the Rodrigues denominator, larger is better conditioned
        n = np.linalg.norm(qp, axis=-1, keepdims=True)
        q = quat_mul(flip, qp / np.where(n > 0, n, 1.0))
        if best is None:
            best, best_g = q, g
        else:
            take = (best_g < 0.3 * (n[..., 0] + 1e-300)) & (g > best_g)
            best = np.where(take[..., None], q, best)
            best_g = np.where(take, g, best_g)
    return _finish(best, r, b, w, n_ok, min_quality, "quest", B=B)


def _gn_jacobian(q, v):
    """∂(R(q) v)/∂q (..., 3, 4) for the unnormalised quadratic form R(q) of ``q = [w, u]``.

    ``R(q) v = (w² − |u|²) v + 2 (u·v) u + 2 w (u × v)``.
    """
    w0 = q[..., 0:1]
    u = q[..., 1:]
    dw = 2 * w0 * v + 2 * np.cross(u, v)
    uv = np.einsum("...i,...i->...", u, v)[..., None, None]
    du = (-2 * v[..., :, None] * u[..., None, :] + 2 * u[..., :, None] * v[..., None, :]
          + 2 * uv * np.eye(3) - 2 * w0[..., None] * skew(v))
    return np.concatenate([dw[..., :, None], du], axis=-1)


def _rotate_unnorm(q, v):
    w0 = q[..., 0:1]
    u = q[..., 1:]
    uu = np.einsum("...i,...i->...", u, u)[..., None]
    uv = np.einsum("...i,...i->...", u, v)[..., None]
    return (w0 ** 2 - uu) * v + 2 * uv * u + 2 * w0 * np.cross(u, v)


def gauss_newton(r, b, w=None, min_quality: float = DEFAULT_MIN_QUALITY, q0=None,
                 iterations: int = 5) -> WahbaResult:
    """The paper's Gauss-Newton ("recursive least squares") solution of J(q) = |y° − R(q)y^b|².

    ``q0`` (..., 4): start (default: the TRIAD solution). Each iteration solves
    ``(AᵀWA) δ = AᵀW e`` with ``e = y° − R(q) y^b`` (stacked over the k pairs),
    ``q ← (q + δ)/|q + δ|``. From a start within tens of degrees it converges in
    3-4 iterations to the same optimum as the other solvers.
    """
    r, b, w, n_ok = _prepare(r, b, w)
    if q0 is None:
        q = triad(r, b, w).q
    else:
        q = np.broadcast_to(np.asarray(q0, float), r.shape[:-2] + (4,)).copy()
        nq = np.linalg.norm(q, axis=-1, keepdims=True)
        q = np.where(nq > 0, q / np.where(nq > 0, nq, 1.0), [1.0, 0.0, 0.0, 0.0])
    for _ in range(iterations):
        A = _gn_jacobian(q[..., None, :], b)  # (..., k, 3, 4)
        e = r - _rotate_unnorm(q[..., None, :], b)  # (..., k, 3)
        N = np.einsum("...k,...kia,...kib->...ab", w, A, A)
        g = np.einsum("...k,...kia,...ki->...a", w, A, e)
        ok = np.abs(np.linalg.det(N)) > 1e-14
        N = np.where(ok[..., None, None], N, np.eye(4))
        delta = np.linalg.solve(N, g[..., None])[..., 0]
        q = q + np.where(ok[..., None], delta, 0.0)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return _finish(q, r, b, w, n_ok, min_quality, "gauss-newton")


SOLVERS = {"triad": triad, "davenport": davenport, "quest": quest, "svd": svd,
           "gauss-newton": gauss_newton}


def solve(method: str, r, b, w=None, **options) -> WahbaResult:
    """Dispatch to the solver named ``method`` (a key of ``SOLVERS``)."""
    try:
        fn = SOLVERS[method]
    except KeyError:
        raise InputError(f"unknown Wahba solver {method!r}; known: {', '.join(SOLVERS)}",
                         field="solver") from None
    return fn(r, b, w, **options)
