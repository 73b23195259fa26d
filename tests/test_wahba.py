"""Wahba solvers: exact recovery, agreement, scipy as an independent reference, degeneracy."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gnomon.estimators import wahba
from gnomon.rotation import error_angle, quat_conj, quat_normalize, quat_rotate

ALL = list(wahba.SOLVERS)
OPTIMAL = [s for s in ALL if s != "triad"]


def _problem(n, k, noise_rad, seed):
    rng = np.random.default_rng(seed)
    q = quat_normalize(rng.normal(size=(n, 4)))
    b = rng.normal(size=(n, k, 3))
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    r = quat_rotate(q[:, None, :], b)
    if noise_rad:
        b = b + rng.normal(0, noise_rad, b.shape)
    return q, r, b


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("k", [2, 3, 5])
def test_exact_recovery_from_noiseless_pairs(name, k):
    q, r, b = _problem(500, k, 0.0, seed=k)
    res = wahba.solve(name, r, b)
    ok = ~res.degenerate
    assert ok.mean() > 0.98
    assert np.max(error_angle(q[ok], res.q[ok])) < 1e-9
    assert np.max(res.loss[ok]) < 1e-18
    assert np.allclose(np.linalg.norm(res.q, axis=-1), 1.0)


def test_optimal_solvers_agree_and_match_scipy_on_noisy_pairs():
    noise = np.radians(0.5)
    q, r, b = _problem(300, 3, noise, seed=7)
    w = np.array([1.0, 2.0, 0.5])
    sols = {name: wahba.solve(name, r, b, w) for name in OPTIMAL}
    ref = sols["davenport"]
    for name, res in sols.items():
        assert np.max(np.degrees(error_angle(ref.q, res.q))) < 1e-6, name
        assert np.allclose(res.loss, ref.loss, atol=1e-14)
    # the loss at the optimum is 1 - λ_max of Davenport's K (weights normalised to 1)
    bn = b / np.linalg.norm(b, axis=-1, keepdims=True)
    B = np.einsum("k,nki,nkj->nij", w / w.sum(), r, bn)
    lam = np.linalg.eigvalsh(wahba._davenport_k(B))[:, -1]
    assert np.allclose(ref.loss, 1.0 - lam, atol=1e-12)
    # scipy's align_vectors solves the same problem independently (scalar-last quaternion)
    for i in range(0, 300, 37):
        rot, _ = Rotation.align_vectors(r[i], bn[i], weights=w)
        q_sp = rot.as_quat()[[3, 0, 1, 2]]
        assert np.degrees(error_angle(q_sp, ref.q[i])) < 1e-6
    # within the noise of the truth (three vectors, 0.5 deg each)
    err = np.degrees(error_angle(q, ref.q))
    assert np.sqrt(np.mean(err ** 2)) < 0.8
    tri = wahba.triad(r, b, w)
    assert np.sqrt(np.mean(np.degrees(error_angle(q, tri.q)) ** 2)) < 2.0


def test_quality_closed_form_for_two_vectors():
    th = np.radians([90.0, 60.0, 10.0, 1.0])
    r = np.stack([np.tile([1.0, 0, 0], (4, 1)),
                  np.stack([np.cos(th), np.sin(th), 0 * th], -1)], axis=1)
    qual = wahba.quality(r, r)
    assert np.allclose(qual, np.tan(th / 2) ** 2, rtol=1e-9)


@pytest.mark.parametrize("name", ALL)
def test_near_parallel_and_bad_vectors_are_flagged_never_silent(name):
    rng = np.random.default_rng(3)
    q = quat_normalize(rng.normal(size=4))
    v1 = np.array([0.3, -0.5, 0.8])
    cases = []
    for ang in (0.0, 0.05, 0.5):  # degrees between the two vectors
        a = np.radians(ang)
        v2 = v1 / np.linalg.norm(v1) * np.cos(a) + np.array([0.0, 0.848, 0.53]) * np.sin(a)
        cases.append(np.stack([v1, v2]))
    cases.append(np.stack([v1, np.zeros(3)]))  # zero vector
    cases.append(np.stack([v1, [np.nan, 0, 1]]))  # non-finite
    b = np.array(cases)
    r = quat_rotate(q, b.copy() if np.all(np.isfinite(b)) else np.nan_to_num(b))
    res = wahba.solve(name, r, b)
    assert np.all(res.degenerate), res.quality
    assert np.all(np.isfinite(res.q))
    # a well-posed pair (30 deg apart) is not flagged
    v2 = np.array([0.3, 0.1, 0.9])
    ok = wahba.solve(name, quat_rotate(q, np.stack([v1, v2])), np.stack([v1, v2]))
    assert not ok.degenerate
    assert np.degrees(error_angle(q, ok.q)) < 1e-9


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_quest_sequential_rotation_at_180_degrees(axis):
    q = np.zeros(4)
    q[1 + axis] = 1.0  # 180 deg about x, y or z: the Rodrigues parameters blow up
    b = np.array([[1.0, 0.2, 0.1], [0.0, 1.0, 0.3], [0.3, 0.1, 1.0]])
    res = wahba.quest(quat_rotate(q, b), b)
    assert np.degrees(error_angle(q, res.q)) < 1e-9


def test_gauss_newton_kernel_matches_python_sequence():
    from gnomon.estimators.qcf import gauss_newton_sequence_py, measured_quaternions

    rng = np.random.default_rng(11)
    n = 200
    q_true = quat_normalize(np.array([1.0, 0.1, -0.2, 0.05]) + 0.01 * np.cumsum(
        rng.normal(size=(n, 4)), 0))
    mag_o = rng.normal(size=(n, 3))
    sec_o = np.tile([0.0, -1.0, 0.0], (n, 1))
    pairs = {"dt": np.ones(n), "mag_o": mag_o, "sec_o": sec_o,
             "mag_b": quat_rotate(quat_conj(q_true), mag_o) + 0.01 * rng.normal(size=(n, 3)),
             "sec_b": quat_rotate(quat_conj(q_true), sec_o), "sec_valid": rng.random(n) > 0.1}
    pairs["mag_b"][5] = 0.0  # unusable sample
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    q_py, ok_py = gauss_newton_sequence_py(pairs, q0, iterations=2, k_mag=1.0, k_sun=3.0)
    q_nb, ok_nb = measured_quaternions(pairs, "gauss-newton", q0, 2, 1.0, 3.0)
    assert np.array_equal(ok_py, ok_nb)
    assert not ok_nb[5]
    assert np.max(np.abs(q_py - q_nb)) < 1e-12
    # and it converges to the Wahba optimum (SVD) where usable
    opt, ok_svd = measured_quaternions(pairs, "svd", q0, k_mag=1.0, k_sun=3.0)
    q_nb, ok_nb = measured_quaternions(pairs, "gauss-newton", q0, 5, 1.0, 3.0)
    use = ok_nb & ok_svd
    assert np.max(np.degrees(error_angle(opt[use], q_nb[use]))) < 1e-3


def test_unknown_solver_raises():
    from gnomon.errors import InputError

    with pytest.raises(InputError, match="solver"):
        wahba.solve("foo", np.ones((2, 3)), np.ones((2, 3)))
