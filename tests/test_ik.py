"""The one IK (`rxcomm.model.ik`), tested directly: every branch of a pose, seeds, singular poses, a
calibrated model, and an arm without a closed form (the multi-start fallback)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from rxcomm.model.geometric_errors import ErrorModel
from rxcomm.model.ik import analytic_solutions, ik_solutions, solve_ik, spherical_wrist
from rxcomm.model.kinematics import BranchSelector, inverse_kinematics, solve_branch_ik, tcp_placement
from rxcomm.model.robot import load_robot
from rxcomm.schemas.path import Branch

from .conftest import SAMPLES


def _pose_error(robot, q, target) -> float:
    return float(np.linalg.norm(pin.log6(tcp_placement(robot, q).actInv(target)).vector))


def _same_angles(a, b, tol=1e-7) -> bool:
    return bool(np.all(np.abs((np.asarray(a) - b + np.pi) % (2 * np.pi) - np.pi) < tol))


def _random_q(robot, rng):
    q = rng.uniform(np.maximum(robot.q_min, -3.0), np.minimum(robot.q_max, 3.0))
    q[4] = np.copysign(max(abs(q[4]), 0.2), q[4])  # off the wrist singularity
    return q


def test_the_closed_form_gives_every_branch_exactly(robot):
    """On both sample arms (the m900 with its shoulder offset): 8 closed-form solutions of a generic
    pose (4 where the other shoulder is out of reach), each exact to 1e-12, the pose's own q among
    them, the branches all different."""
    assert spherical_wrist(robot) is not None
    rng = np.random.default_rng(11)
    data = robot.create_data()
    selector = BranchSelector(robot, None)
    counts = []
    for _ in range(30):
        q = _random_q(robot, rng)
        target = tcp_placement(robot, q)
        sols = analytic_solutions(robot, target, data)
        counts.append(len(sols))
        assert len(sols) in (4, 8)
        assert max(_pose_error(robot, s, target) for s in sols) < 1e-12
        assert any(_same_angles(s, q) for s in sols)
        labels = {tuple(selector.labels(data, s).values()) for s in sols}
        assert len(labels) == len(sols), labels
    assert counts.count(8) >= 10


def test_all_solutions_are_within_limits_and_refined(robot):
    rng = np.random.default_rng(12)
    for _ in range(20):
        q = _random_q(robot, rng)
        target = tcp_placement(robot, q)
        sols = ik_solutions(robot, target)
        assert 1 <= len(sols) <= 8
        assert any(np.allclose(s, q, atol=1e-7) for s in sols)  # q itself, at its own turn
        for s in sols:
            assert np.all(s >= robot.q_min - 1e-9) and np.all(s <= robot.q_max + 1e-9)
            assert _pose_error(robot, s, target) < 1e-9


def test_a_seed_selects_its_branch(rx130l):
    """From a seed 0.05 rad off any branch's solution, the IK returns that solution; `near` picks the
    nearest branch; `solve_branch_ik` honours a branch selector."""
    rng = np.random.default_rng(13)
    data = rx130l.create_data()
    q = np.array([0.3, 0.4, 1.2, 0.5, 0.8, -0.4])
    target = tcp_placement(rx130l, q)
    sols = ik_solutions(rx130l, target, data)
    assert len(sols) >= 4
    for s in sols:
        seed = s + rng.normal(0, 0.05, 6)
        got = solve_ik(rx130l, target, data, seed=seed)
        assert got is not None and np.allclose(got, s, atol=1e-7)
        near = solve_ik(rx130l, target, data, near=s + 0.01)
        assert near is not None and np.allclose(near, s, atol=1e-7)
    for s in sols:
        branch = Branch(**BranchSelector(rx130l, None).labels(data, s))
        got = solve_branch_ik(rx130l, data, target, BranchSelector(rx130l, branch))
        assert got is not None and BranchSelector(rx130l, branch).matches(data, got)
        assert _pose_error(rx130l, got, target) < 1e-9
    # a seed on the far side of the workspace still gives a solution (the closed form, not Newton)
    far = solve_ik(rx130l, target, data, seed=-q)
    assert far is not None and _pose_error(rx130l, far, target) < 1e-9


def test_singular_poses(robot):
    """Wrist singular (q5 = 0: only q4 + q6 is fixed) and shoulder singular (wrist centre on axis 1):
    a solution exactly on the pose, the free joint kept at the reference's value."""
    data = robot.create_data()
    q = np.array([0.2, 0.5, 0.9, 0.7, 0.0, -0.3])
    target = tcp_placement(robot, q)
    ref = np.array([0.2, 0.5, 0.9, 0.4, 0.1, 0.0])
    got = solve_ik(robot, target, data, near=ref)
    assert got is not None and _pose_error(robot, got, target) < 1e-9
    assert got[3] == pytest.approx(0.4) and got[4] == pytest.approx(0.0, abs=1e-9)
    assert got[3] + got[5] == pytest.approx(q[3] + q[5])
    # shoulder: the wrist centre on axis 1 (both sample arms have no lateral offset, b = 0)
    sw = spherical_wrist(robot)
    assert sw is not None and abs(sw.b) < 1e-12
    tx0, ty0 = (sw.o1 - sw.o2) @ sw.e0, (sw.o1 - sw.o2) @ sw.w1  # a wrist centre on axis 1 in reach
    reach = 0.7 * (np.hypot(*sw.l1) + np.hypot(*sw.l2))
    centre = sw.o1 + (np.sqrt(reach**2 - tx0**2) - ty0) * sw.w1
    rot = pin.utils.rotate("y", 0.4) @ pin.utils.rotate("x", 0.3)
    t = pin.SE3(rot, centre - rot @ sw.centre_in_tcp)
    for q1 in (0.25, -0.6):
        got = solve_ik(robot, t, data, near=np.array([q1, 0, 0, 0, 0, 0]))
        assert got is not None and _pose_error(robot, got, t) < 1e-9
        assert got[0] == pytest.approx(q1)  # q1 is free there: the reference's is kept


def test_the_calibrated_model_is_solved_exactly(robot):
    """The closed form is read from the calibrated model (its wrist then only nearly spherical) and
    Newton closes the rest: every solution exact on the calibrated kinematics."""
    name = "rx130l" if robot.name == "rx130l" else "m900"
    truth = yaml.safe_load((SAMPLES / name / "truth.yaml").read_text())
    calibrated = ErrorModel.from_mapping(robot, truth["geometry"]["error_parameters"]).apply(robot)
    assert spherical_wrist(calibrated) is not None
    rng = np.random.default_rng(14)
    for _ in range(10):
        q = _random_q(calibrated, rng)
        target = tcp_placement(calibrated, q)
        sols = ik_solutions(calibrated, target)
        assert any(np.allclose(s, q, atol=1e-7) for s in sols)
        assert max(_pose_error(calibrated, s, target) for s in sols) < 1e-9
        res = inverse_kinematics(calibrated, target, q + 0.05)
        assert res.converged and np.allclose(res.q, q, atol=1e-7)


@pytest.fixture(scope="module")
def offset_wrist(tmp_path_factory):
    """The RX130L with axis 6 moved 5 cm off axis 4: no closed form."""
    d = tmp_path_factory.mktemp("offset-wrist")
    for f in (SAMPLES / "rx130l").iterdir():
        if f.is_file():
            shutil.copy(f, d / f.name)
    urdf = (d / "rx130l.urdf").read_text()
    i = urdf.index('<joint name="joint_6"')
    j = urdf.index('<origin xyz="0 0 0.11"', i)
    urdf = urdf[:j] + '<origin xyz="0.05 0 0.11"' + urdf[j + len('<origin xyz="0 0 0.11"') :]
    (d / "rx130l.urdf").write_text(urdf)
    return load_robot(Path(d))


def test_an_arm_without_a_closed_form_falls_back_to_the_multi_start(offset_wrist):
    assert spherical_wrist(offset_wrist) is None
    assert analytic_solutions(offset_wrist, tcp_placement(offset_wrist, np.zeros(6))) == []
    q = np.array([0.3, 0.4, 1.2, 0.5, 0.8, -0.4])
    target = tcp_placement(offset_wrist, q)
    sols = ik_solutions(offset_wrist, target, n_starts=64)
    assert sols and max(_pose_error(offset_wrist, s, target) for s in sols) < 1e-9
    got = solve_ik(offset_wrist, target, seed=q + 0.05)
    assert got is not None and np.allclose(got, q, atol=1e-7)


def test_an_unreachable_pose_has_no_solution(robot):
    far = pin.SE3(np.eye(3), np.array([5.0, 0.0, 1.0]))
    assert analytic_solutions(robot, far) == []
    assert ik_solutions(robot, far) == []
    assert solve_ik(robot, far, seed=np.zeros(6)) is None
