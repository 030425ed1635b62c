"""Kinematics: Cardan angles, IK round trips (with and without an error model), branch keeping,
unreachable targets as a returned status, singularity measures."""

import numpy as np
import pinocchio as pin
import pytest
import yaml

from rxcomm.errors import InfeasibleError, SolveStatus
from rxcomm.model.geometric_errors import ErrorModel, random_poses
from rxcomm.model.kinematics import (
    BranchSelector,
    cardan_xyz,
    cardan_xyz_matrix,
    ik_along,
    inverse_kinematics,
    tcp_placement,
    tcp_pose,
    tcp_sigma_min,
    wrist_singularity,
)
from rxcomm.model.robot import load_robot

from .conftest import SAMPLES


def _truth_errors(robot):
    name = "rx130l" if robot.name == "rx130l" else "m900"
    truth = yaml.safe_load((SAMPLES / name / "truth.yaml").read_text())
    return ErrorModel.from_mapping(robot, truth["geometry"]["error_parameters"])


def _rx(a):
    return pin.utils.rotate("x", a)


def test_cardan_xyz_is_rx_ry_rz_and_inverts():
    a, b, g = 0.3, -0.5, 1.2
    r = _rx(a) @ pin.utils.rotate("y", b) @ pin.utils.rotate("z", g)
    np.testing.assert_allclose(cardan_xyz(r), [a, b, g], atol=1e-14)
    np.testing.assert_allclose(cardan_xyz_matrix([a, b, g]), r, atol=1e-14)
    rng = np.random.default_rng(0)
    angles = rng.uniform([-np.pi, -np.pi / 2 + 0.01, -np.pi], [np.pi, np.pi / 2 - 0.01, np.pi], (50, 3))
    np.testing.assert_allclose(cardan_xyz(cardan_xyz_matrix(angles)), angles, atol=1e-12)
    # Gimbal lock: still a valid decomposition of the same rotation.
    locked = cardan_xyz_matrix([0.4, np.pi / 2, 0.1])
    np.testing.assert_allclose(cardan_xyz_matrix(cardan_xyz(locked)), locked, atol=1e-12)


def test_tcp_pose_matches_nominal_geometry(rx130l):
    p, r = tcp_pose(rx130l, np.zeros(6))
    # Upright arm: 0.55 + 0.625 + 0.4 + 0.525 + 0.11 flange + 0.15 TCP along z.
    np.testing.assert_allclose(p, [0, 0, 2.36], atol=1e-12)
    np.testing.assert_allclose(r, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("with_errors", [False, True])
def test_ik_round_trip_below_1e_9_m(robot, with_errors):
    errors = _truth_errors(robot) if with_errors else None
    rr = errors.apply(robot) if errors is not None else robot
    rng = np.random.default_rng(3)
    worst_p, worst_o, n_ok = 0.0, 0.0, 0
    for _ in range(40):
        q = random_poses(robot, 1, rng)[0]
        q[4] = np.copysign(max(abs(q[4]), 0.3), q[4])  # away from the wrist singularity
        q[2] = np.copysign(max(abs(q[2]), 0.3), q[2])  # … and the elbow one
        q = np.clip(q, robot.q_min + 0.05, robot.q_max - 0.05)
        target = tcp_placement(rr, q)
        seed = q + rng.normal(0, 0.1, robot.n)
        res = inverse_kinematics(robot, target, seed, errors=errors)
        assert res.converged, res
        got = tcp_placement(rr, res.q)
        worst_p = max(worst_p, np.linalg.norm(got.translation - target.translation))
        worst_o = max(worst_o, np.linalg.norm(pin.log3(got.rotation @ target.rotation.T)))
        # Same branch as the seed: the solution is the pose we started from.
        np.testing.assert_allclose(res.q, q, atol=1e-7)
        n_ok += 1
    assert worst_p <= 1e-9 and worst_o <= 1e-9
    assert n_ok == 40


def test_ik_keeps_the_seed_branch(rx130l):
    # Elbow up and elbow down reach the same TCP pose; each seed keeps its own branch.
    q_up = np.array([0.2, 0.5, 1.2, 0.3, 0.9, 0.1])
    target = tcp_placement(rx130l, q_up)
    res = inverse_kinematics(rx130l, target, q_up + 0.15)
    np.testing.assert_allclose(res.q, q_up, atol=1e-8)
    # A seed near the other elbow branch (q3 negative) converges there, with a different q3 sign.
    res_dn = inverse_kinematics(rx130l, target, np.array([0.2, 1.6, -1.2, 0.3, 0.9, 0.1]))
    assert res_dn.converged and res_dn.q[2] < 0
    got = tcp_placement(rx130l, res_dn.q)
    assert np.linalg.norm(got.translation - target.translation) < 1e-9


def test_unreachable_target_is_a_status_not_an_exception(rx130l):
    far = pin.SE3(np.eye(3), np.array([5.0, 0.0, 1.0]))
    res = inverse_kinematics(rx130l, far, np.array([0.0, 0.5, 0.5, 0.0, 0.5, 0.0]))
    assert not res.converged and res.status is SolveStatus.INFEASIBLE
    assert res.position_error_m > 2.5  # reach is ≈ 1.8 m from the shoulder
    assert np.all(res.q >= rx130l.q_min) and np.all(res.q <= rx130l.q_max)
    with pytest.raises(InfeasibleError, match="unreachable"):
        res.raise_if_failed()


def test_ik_along_a_line_is_continuous(rx130l):
    q0 = np.array([-0.5, 0.4, 1.3, 0.2, 0.8, 0.0])
    start = tcp_placement(rx130l, q0)
    poses = [
        pin.SE3(start.rotation, start.translation + np.array([0.0, s, 0.0])) for s in np.linspace(0, 0.6, 61)
    ]
    res = ik_along(rx130l, poses, q0).raise_if_failed()
    assert res.ok and res.max_jump_rad < 0.1
    assert np.max(res.position_error_m) < 1e-9


def test_singularity_measures(rx130l):
    q = np.array([0.1, 0.3, 1.0, 0.4, 0.0, 0.2])
    assert wrist_singularity(q) == 0.0
    assert tcp_sigma_min(rx130l, q) < 1e-9
    q[4] = 0.8
    assert wrist_singularity(q) == pytest.approx(np.sin(0.8))
    assert tcp_sigma_min(rx130l, q) > 1e-2
    # Elbow stretched (q3 = 0): J2, J3, J5 in a plane, another singularity.
    q_el = np.array([0.1, 0.3, 0.0, 0.4, 0.8, 0.2])
    assert tcp_sigma_min(rx130l, q_el) < 1e-9


def test_shoulder_label_holds_when_link_1_is_turned_about_its_axis(tmp_path, m900):
    """The same arm with link 1's frame turned 90° about joint 1 (and joint 2 placed back where it
    was), as MuJoCo Menagerie's piper is modelled: the shoulder's front/back is read along the way
    the arm reaches at q = 0, not along link 1's x, which now lies across the arm's plane (the wrist
    centre was never ahead of it nor behind: its label was round-off, and a calibration flipped it)."""
    import shutil

    turned = tmp_path / "m900"
    shutil.copytree(SAMPLES / "m900", turned)
    urdf = turned / "m900.urdf"
    text = urdf.read_text()
    j1 = '<origin xyz="0 0 0.35" rpy="0 0 0"/>'
    j2 = '<origin xyz="0.075 0 0" rpy="0 0 0"/>'
    assert text.count(j1) == 1 and text.count(j2) == 1
    quarter = 1.5707963267948966
    text = text.replace(j1, f'<origin xyz="0 0 0.35" rpy="0 0 {quarter}"/>')
    urdf.write_text(text.replace(j2, f'<origin xyz="0 -0.075 0" rpy="0 0 {-quarter}"/>'))
    other = load_robot(turned)
    assert np.allclose(other.forward_in_joint1, [0, -1, 0], atol=1e-9)
    assert np.allclose(m900.forward_in_joint1, [1, 0, 0])
    data, other_data = m900.create_data(), other.create_data()
    a, b = BranchSelector(m900, None), BranchSelector(other, None)
    for q in random_poses(m900, 40, np.random.default_rng(4)):
        assert np.allclose(tcp_placement(m900, q).homogeneous, tcp_placement(other, q).homogeneous)
        assert a.labels(data, q) == b.labels(other_data, q)
