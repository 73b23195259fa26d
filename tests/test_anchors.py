"""Adapters to the reference libraries: frames and units converted to gnomon's (ENU from sensor).

Each library, fed a synthetic IMU whose attitude is known exactly, must converge
to that attitude in gnomon's convention; a wrong frame (NWU vs ENU: 90 deg of
heading) or a wrong unit would show as a large error.
"""

import numpy as np
import pytest

from gnomon import anchors
from gnomon.metrics import broad_errors_rad
from gnomon.rotation import quat_from_euler


@pytest.mark.parametrize("name", ["vqf", "imufusion", "ahrs-madgwick"])
def test_anchor_converges_to_truth_in_gnomon_frames(name, imu_factory):
    pytest.importorskip({"vqf": "vqf", "imufusion": "imufusion", "ahrs-madgwick": "ahrs"}[name])
    rec = imu_factory(quat_from_euler([0.3, -0.2, 2.2]), [0.0, 0.0, 0.05], n=6000, fs=100)
    q = anchors.run_anchor(name, rec)
    e = broad_errors_rad(rec.q_true[-500:], q[-500:])
    assert np.degrees(e["inclination"]).max() < 0.5
    assert np.degrees(e["heading"]).max() < 2.0


def test_q_enu_nwu_maps_north():
    from gnomon.rotation import quat_rotate

    # NWU x axis is north, which is ENU's y axis; NWU y (west) is ENU -x
    np.testing.assert_allclose(quat_rotate(anchors.Q_ENU_NWU, [1.0, 0, 0]), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(quat_rotate(anchors.Q_ENU_NWU, [0, 1.0, 0]), [-1, 0, 0],
                               atol=1e-15)


def test_unknown_anchor():
    with pytest.raises(ValueError, match="unknown anchor"):
        anchors.run_anchor("kalman9000", None)
