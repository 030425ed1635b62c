"""Commanding through the calibrated joint compliance (rxcomm.calibration.compliance)."""

import numpy as np
import pytest

from rxcomm.calibration.compensation import encoder_angles
from rxcomm.calibration.compliance import holding_torques


def test_encoder_angles_put_the_links_at_the_pose(rx130l):
    c = np.zeros(6)
    c[1], c[2] = 1.0e-6, 1.8e-6  # J2/J3 as the chain's calibration finds them, rad/(N·m)
    q_link = np.array([0.3, 0.9, 0.6, 0.2, 0.8, -0.4])  # arm reaching forward: J2/J3 loaded
    q = encoder_angles(rx130l, q_link, c)
    # the calibration's model of the link angle: q − c·τ(q) with the prior holding torque at q
    back = q - c * holding_torques(rx130l, q)[0]
    np.testing.assert_allclose(back, q_link, atol=1e-12)
    tau = holding_torques(rx130l, q_link)[0]
    assert abs(tau[1]) > 50 and q[1] - q_link[1] == pytest.approx(c[1] * tau[1], rel=1e-3)
    np.testing.assert_array_equal(q[[0, 3, 4, 5]], q_link[[0, 3, 4, 5]])  # rigid joints as solved
    np.testing.assert_array_equal(encoder_angles(rx130l, q_link, np.zeros(6)), q_link)
