import numpy as np

from rxcomm.model.limits import check_limits


def test_limit_ratios_find_the_worst_sample(rx130l):
    t = np.linspace(0, 3, 501)
    q = np.zeros((501, 6))
    qd = np.zeros((501, 6))
    qd[:, 2] = rx130l.v_max[2] * np.sin(np.pi * t / 3)  # peaks at the limit at t = 1.5
    qdd = np.gradient(qd, t, axis=0)
    tau = np.zeros((501, 6))
    tau[:, 0] = np.linspace(0, rx130l.tau_max[0] * 0.5, 501)
    rep = check_limits(rx130l, t, q, qd, qdd, tau)
    assert rep.max_by_limit()["velocity"] == 1.0
    name, joint, tw, ratio = rep.worst()
    assert (name, joint) == ("velocity", "joint_3") and abs(tw - 1.5) < 1e-9 and ratio == 1.0
    # Torque rises at 346/3 N·m/s: ratio vs 14000 N·m/s.
    np.testing.assert_allclose(rep.max_by_limit()["torque_rate"], 346 / 3 / 14000, rtol=1e-9)
    assert 0.0 < rep.active_fraction(0.98) < 0.2
