"""Shared test fixtures: a synthetic IMU whose truth is known in closed form."""

import numpy as np
import pytest

from gnomon.kernels import drop_stale_caches
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate


def pytest_configure(config):
    # kernels compiled from sources that have changed since (an inlined helper) are dropped
    drop_stale_caches()


def pytest_collection_modifyitems(config, items):
    """A slow test says why (``@pytest.mark.slow(reason="...")``): the quick tier,
    ``pytest -m "not slow"``, leaves it out, and its reason says what it costs."""
    for item in items:
        for mark in item.iter_markers("slow"):
            if not mark.kwargs.get("reason"):
                raise pytest.UsageError(f"{item.nodeid}: @pytest.mark.slow needs a reason=")


G = 9.81
FIELD_ENU_UT = np.array([0.0, 20.0, -45.0])  # north and down, inclination ~66 deg


def synthetic_imu(q0_nb, w_b, n=2000, fs=100.0, gyro_bias=(0, 0, 0), noise=0.0, seed=0):
    """Body rotating at constant rate ``w_b`` (rad/s, body frame) from ``q0_nb`` (ENU from body).

    Exact truth: q(t) = q0 ⊗ exp(w_b t). Sensors: gyro = w_b + bias (+ noise), accel =
    R_nbᵀ [0, 0, g], mag = R_nbᵀ FIELD_ENU_UT (+ noise).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    w_b = np.asarray(w_b, float)
    q = quat_mul(np.asarray(q0_nb, float), quat_from_rotvec(t[:, None] * w_b))
    q_bn = quat_conj(q)
    acc = quat_rotate(q_bn, np.array([0.0, 0.0, G]))
    mag = quat_rotate(q_bn, FIELD_ENU_UT)
    gyro = np.tile(w_b + np.asarray(gyro_bias, float), (n, 1))
    if noise:
        gyro = gyro + rng.normal(0, noise, gyro.shape)
        acc = acc + rng.normal(0, noise * 10, acc.shape)
        mag = mag + rng.normal(0, noise * 20, mag.shape)
    return Recording(t=t, gyro=gyro, accel=acc, mag=mag, mag_unit="uT", q_true=q,
                     source="synthetic")


@pytest.fixture
def imu_factory():
    return synthetic_imu


def _full_dataset(name: str, what: str):
    """The full data set ``name``'s folder (``gnomon.datasets.dataset_dir``), or a skip
    naming its setting and how to fetch it."""
    from gnomon.datasets import dataset, dataset_dir

    d = dataset_dir(name)
    if d is None:
        pytest.skip(f"{what} not found: set {dataset(name).env} (default "
                    f"../shared/data/{name} beside the repository), or run "
                    f"`gnomon datasets fetch {name}`")
    return d


@pytest.fixture(scope="session")
def full_broad():
    """The full BROAD data directory, or a clear skip (setting: GNOMON_BROAD_DIR)."""
    return _full_dataset("broad", "full BROAD data")


@pytest.fixture(scope="session")
def full_tyrex():
    """The tyrex smartphone data set's root, or a clear skip (setting: GNOMON_TYREX_DIR)."""
    return _full_dataset("tyrex", "tyrex data set")
