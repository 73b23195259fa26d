"""Rotation kernels against scipy's Rotation (scalar-last, converted explicitly here)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gnomon import rotation as rot

N = 10_000


def to_scipy(q_wxyz):
    """gnomon [w, x, y, z] -> scipy Rotation (scipy stores [x, y, z, w])."""
    return Rotation.from_quat(np.roll(q_wxyz, -1, axis=-1))


def from_scipy(r):
    return np.roll(r.as_quat(), 1, axis=-1)


def same_rotation(q1, q2, atol=1e-12):
    """q and -q are the same rotation: compare |<q1, q2>| to 1."""
    d = np.abs(np.sum(q1 * q2, axis=-1))
    return np.all(np.abs(d - 1.0) < atol)


@pytest.fixture(scope="module")
def quats():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(N, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_product_matches_scipy_composition(quats):
    rng = np.random.default_rng(2)
    p = quats
    q = rng.permutation(quats)
    pq = rot.quat_mul(p, q)
    ref = from_scipy(to_scipy(p) * to_scipy(q))
    assert same_rotation(pq, ref)
    # matrix terms: R(p ⊗ q) = R(p) @ R(q)
    np.testing.assert_allclose(
        rot.dcm_from_quat(pq), rot.dcm_from_quat(p) @ rot.dcm_from_quat(q), atol=1e-12
    )


def test_rotate_matches_scipy_and_dcm(quats):
    rng = np.random.default_rng(3)
    v = rng.normal(size=(N, 3))
    np.testing.assert_allclose(rot.quat_rotate(quats, v), to_scipy(quats).apply(v), atol=1e-12)
    np.testing.assert_allclose(
        rot.dcm_from_quat(quats), to_scipy(quats).as_matrix(), atol=1e-12
    )


def test_dcm_roundtrip_including_near_180deg(quats):
    assert same_rotation(rot.quat_from_dcm(rot.dcm_from_quat(quats)), quats)
    rng = np.random.default_rng(4)
    axes = rng.normal(size=(1000, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for angle in (np.pi, np.pi - 1e-9, 1e-10, 0.0):
        q = rot.quat_from_rotvec(axes * angle)
        back = rot.quat_from_dcm(rot.dcm_from_quat(q))
        assert same_rotation(back, q, atol=1e-12), angle
        ref = from_scipy(Rotation.from_matrix(rot.dcm_from_quat(q)))
        assert same_rotation(back, ref, atol=1e-12)


def test_euler_zyx_matches_scipy(quats):
    rpy = rot.euler_from_quat(quats)
    ypr_ref = to_scipy(quats).as_euler("ZYX")  # intrinsic z-y'-x'': [yaw, pitch, roll]
    np.testing.assert_allclose(rpy[:, ::-1], ypr_ref, atol=1e-9)
    assert same_rotation(rot.quat_from_euler(rpy), quats, atol=1e-12)
    assert same_rotation(
        rot.quat_from_euler(rpy), from_scipy(Rotation.from_euler("ZYX", rpy[:, ::-1]))
    )


def test_euler_gimbal_lock_roundtrip():
    rpy = np.array([[0.3, np.pi / 2, -0.4], [0.1, -np.pi / 2, 1.0]])
    q = rot.quat_from_euler(rpy)
    back = rot.euler_from_quat(q)
    assert np.all(back[:, 0] == 0.0)
    assert same_rotation(rot.quat_from_euler(back), q, atol=1e-9)


def test_rotvec_exp_log_match_scipy(quats):
    rv = rot.rotvec_from_quat(quats)
    np.testing.assert_allclose(rv, to_scipy(quats).as_rotvec(), atol=1e-10)
    assert same_rotation(rot.quat_from_rotvec(rv), quats)
    # near the identity: small-angle branches
    small = np.random.default_rng(5).normal(size=(1000, 3)) * 1e-7
    np.testing.assert_allclose(rot.rotvec_from_quat(rot.quat_from_rotvec(small)), small,
                               rtol=1e-12, atol=1e-22)
    np.testing.assert_allclose(rot.quat_from_rotvec(small),
                               from_scipy(Rotation.from_rotvec(small)), atol=1e-15)


def test_slerp_matches_scipy():
    from scipy.spatial.transform import Slerp

    rng = np.random.default_rng(6)
    q0, q1 = rng.normal(size=(2, 4))
    q0 /= np.linalg.norm(q0)
    q1 /= np.linalg.norm(q1)
    t = np.linspace(0, 1, 11)
    ref = Slerp([0, 1], to_scipy(np.stack([q0, q1])))(t)
    got = rot.quat_slerp(q0, q1, t)
    assert same_rotation(got, from_scipy(ref), atol=1e-12)


def test_error_angle_closed_form_and_sign_safe():
    q = rot.quat_from_rotvec([0.0, 0.0, 0.3])
    assert rot.error_angle([1, 0, 0, 0], q) == pytest.approx(0.3, abs=1e-15)
    assert rot.error_angle([1, 0, 0, 0], -q) == pytest.approx(0.3, abs=1e-15)
    tiny = rot.quat_from_rotvec([1e-9, 0, 0])
    assert rot.error_angle([1, 0, 0, 0], tiny) == pytest.approx(1e-9, rel=1e-9)


def test_shape_contract():
    q = np.array([1.0, 0, 0, 0])
    assert rot.quat_mul(q, q).shape == (4,)
    assert rot.quat_rotate(q, [1.0, 2, 3]).shape == (3,)
    assert rot.dcm_from_quat(q).shape == (3, 3)
    assert rot.quat_from_dcm(np.eye(3)).shape == (4,)
    assert rot.euler_from_quat(q).shape == (3,)
    assert rot.quat_mul(np.tile(q, (5, 2, 1)), q).shape == (5, 2, 4)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: rot.quat_mul([1, 0, 0], [1, 0, 0, 0]), "p"),
        (lambda: rot.quat_rotate([1, 0, 0, 0], [1, 2]), "v_b"),
        (lambda: rot.quat_rotate([np.nan, 0, 0, 0], [1, 2, 3]), "q_ab"),
        (lambda: rot.quat_normalize([0.0, 0, 0, 0]), "zero-norm"),
        (lambda: rot.quat_from_dcm(np.eye(4)), "R_ab"),
    ],
)
def test_malformed_input_names_argument(call, name):
    with pytest.raises(ValueError, match=name):
        call()
