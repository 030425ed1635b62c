"""The one IK (`rxcomm.model.ik`, its closed form `rxcomm.model.opw`), tested directly: every branch
of a pose, seeds, singular poses, a calibrated model, arms the project does not ship (other OPW arms,
other URDF conventions), and arms without a closed form (the multi-start fallback); one result
convention (`IkResult`, a `SolveStatus`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml

from rxcomm.errors import InfeasibleError, SolveOutcome, SolveStatus
from rxcomm.model.geometric_errors import ErrorModel
from rxcomm.model.ik import ACCEPT_TOL, IkResult, ik_solutions, solve_ik
from rxcomm.model.kinematics import (
    BranchSelector,
    inverse_kinematics,
    pose_branches,
    solve_branch_ik,
    tcp_placement,
)
from rxcomm.model.opw import analytic_solutions, spherical_wrist
from rxcomm.model.robot import load_robot
from rxcomm.schemas.path import Branch

from .arm_urdfs import KUKA_LIKE, UR_LIKE, lateral_offset, read_joints, reframed, write_arm
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


# OPW parameters of the samples, read off their URDFs by hand (m): a1 shoulder offset, c1 height of
# axis 2, c2 upper arm, c3 forearm to the wrist centre, a2 its step off the forearm, b lateral offset.
OPW = {
    "rx130l": {"a1": 0.0, "c1": 0.55, "c2": 0.625, "c3": 0.4 + 0.525, "a2": 0.0, "b": 0.0},
    "m900": {"a1": 0.075, "c1": 0.35, "c2": 0.36, "c3": 0.15 + 0.23, "a2": 0.02, "b": 0.0},
}


def test_both_sample_urdfs_are_of_the_class(robot):
    """Axes 2 ∥ 3 ⟂ 1 and the three wrist axes through one point (to 1e-12), and the closed form's
    constants are the OPW parameters of the URDF."""
    sw = spherical_wrist(robot)
    assert sw is not None and sw.exact
    assert abs(sw.w1 @ sw.w2) < 1e-12 and sw.s3 == 1.0
    opw = OPW[robot.name]
    shoulder = sw.o2 - sw.o1
    assert np.linalg.norm(shoulder - (shoulder @ sw.w1) * sw.w1) == pytest.approx(opw["a1"], abs=1e-12)
    assert sw.o2 @ sw.w1 == pytest.approx(opw["c1"], abs=1e-12)
    assert np.hypot(*sw.l1) == pytest.approx(opw["c2"], abs=1e-12)
    along = np.array(sw.l1) / np.hypot(*sw.l1)
    assert np.array(sw.l2) @ along == pytest.approx(opw["c3"], abs=1e-12)
    assert abs(along[0] * sw.l2[1] - along[1] * sw.l2[0]) == pytest.approx(opw["a2"], abs=1e-12)
    assert sw.b == pytest.approx(opw["b"], abs=1e-12)


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
        assert got.ok and np.allclose(got.q, s, atol=1e-7)
        assert got.position_error_m < 1e-9 and got.orientation_error_rad < 1e-9
        near = solve_ik(rx130l, target, data, near=s + 0.01)
        assert near.ok and np.allclose(near.q, s, atol=1e-7)
    for s in sols:
        branch = Branch(**BranchSelector(rx130l, None).labels(data, s))
        got = solve_branch_ik(rx130l, data, target, BranchSelector(rx130l, branch))
        assert got.ok and BranchSelector(rx130l, branch).matches(data, got.q)
        assert _pose_error(rx130l, got.q, target) < 1e-9
    # a seed on the far side of the workspace still gives a solution (the closed form, not Newton)
    far = solve_ik(rx130l, target, data, seed=-q)
    assert far.ok and _pose_error(rx130l, far.q, target) < 1e-9


def test_singular_poses(robot):
    """Stated behaviour. Wrist singular (q5 = 0: only q4 + q6 is fixed): an exact solution, q4 kept at
    the reference's value (`near`), or from a seed the seed's neighbourhood on the pose; near it
    (q5 = 1e-6) the solutions stay exact and the seed's is returned. Shoulder singular (wrist centre
    on axis 1, q1 free): an exact solution with q1 at the reference's value."""
    data = robot.create_data()
    q = np.array([0.2, 0.5, 0.9, 0.7, 0.0, -0.3])
    target = tcp_placement(robot, q)
    ref = np.array([0.2, 0.5, 0.9, 0.4, 0.1, 0.0])
    got = solve_ik(robot, target, data, near=ref)
    assert got.ok and _pose_error(robot, got.q, target) < 1e-9
    assert got.q[3] == pytest.approx(0.4) and got.q[4] == pytest.approx(0.0, abs=1e-9)
    assert got.q[3] + got.q[5] == pytest.approx(q[3] + q[5])
    seeded = solve_ik(robot, target, data, seed=q + 0.01)
    assert seeded.ok and _pose_error(robot, seeded.q, target) < 1e-9
    assert abs(seeded.q[4]) < 1e-6 and seeded.q[3] + seeded.q[5] == pytest.approx(q[3] + q[5], abs=1e-6)
    assert np.max(np.abs(seeded.q - q)) < 0.1  # stays by the seed
    near_singular = q.copy()
    near_singular[4] = 1e-6
    t_near = tcp_placement(robot, near_singular)
    exact = analytic_solutions(robot, t_near, data)
    assert len(exact) >= 4 and max(_pose_error(robot, s, t_near) for s in exact) < 1e-9
    got = solve_ik(robot, t_near, data, seed=near_singular + 0.01)
    assert got.ok and np.allclose(got.q, near_singular, atol=1e-6)
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
        assert got.ok and _pose_error(robot, got.q, t) < 1e-9
        assert got.q[0] == pytest.approx(q1)  # q1 is free there: the reference's is kept


def test_the_calibrated_model_is_solved_to_the_tolerance(robot):
    """The closed form read from the calibrated model is approximate (its wrist only nearly spherical,
    axes 2 and 3 only nearly parallel): its starts miss by millimetres (mrad), and
    Newton on the calibrated model closes the rest to the solver's tolerance, every branch."""
    name = "rx130l" if robot.name == "rx130l" else "m900"
    truth = yaml.safe_load((SAMPLES / name / "truth.yaml").read_text())
    calibrated = ErrorModel.from_mapping(robot, truth["geometry"]["error_parameters"]).apply(robot)
    sw = spherical_wrist(calibrated)
    assert sw is not None and not sw.exact and spherical_wrist(robot).exact
    rng = np.random.default_rng(14)
    start_miss = []
    for _ in range(10):
        q = _random_q(calibrated, rng)
        target = tcp_placement(calibrated, q)
        start_miss += [_pose_error(calibrated, s, target) for s in analytic_solutions(calibrated, target)]
        sols = ik_solutions(calibrated, target)
        assert any(np.allclose(s, q, atol=1e-7) for s in sols)
        assert max(_pose_error(calibrated, s, target) for s in sols) <= ACCEPT_TOL
        res = inverse_kinematics(calibrated, target, q + 0.05)
        assert res.ok and np.allclose(res.q, q, atol=1e-7) and res.position_error_m <= ACCEPT_TOL
    assert 1e-9 < max(start_miss) < 1e-2  # the closed form alone is not the answer here


def _sample_joints(name: str):
    return read_joints(next((SAMPLES / name).glob("*.urdf")).read_text())


OTHER_ARMS = {
    "kuka-like": lambda name, rng: KUKA_LIKE,
    "lateral-offset": lambda name, rng: lateral_offset(_sample_joints(name), 0.05),
    "reframed": lambda name, rng: reframed(_sample_joints(name), rng),
}


@pytest.mark.parametrize("kind", sorted(OTHER_ARMS))
@pytest.mark.parametrize("name", ["rx130l", "m900"])
def test_arms_the_project_does_not_ship(tmp_path, name, kind):
    """OPW arms in other URDF conventions (axis 1 down, arm along x, rotated joint frames, negative
    axes, a lateral offset b): the class is read from the kinematics, every branch exact."""
    rng = np.random.default_rng(15)
    robot = load_robot(write_arm(SAMPLES / name, tmp_path / kind, OTHER_ARMS[kind](name, rng)))
    sw = spherical_wrist(robot)
    assert sw is not None and sw.exact
    data = robot.create_data()
    counts = []
    for _ in range(15):
        q = _random_q(robot, rng)
        target = tcp_placement(robot, q)
        sols = analytic_solutions(robot, target, data)
        counts.append(len(sols))
        assert sols and max(_pose_error(robot, s, target) for s in sols) < 1e-9
        assert any(_same_angles(s, q) for s in sols)
        branches = pose_branches(robot, target, data)
        assert any(np.allclose(b[1], q, atol=1e-7) for b in branches)
    assert counts.count(8) >= 8, counts


@pytest.fixture(scope="module")
def offset_wrist(tmp_path_factory):
    """The RX130L with axis 6 moved 5 cm off axis 4: no closed form."""
    joints = _sample_joints("rx130l")
    xyz, rot, axis = joints[5]
    joints[5] = (xyz + np.array([0.05, 0.0, 0.0]), rot, axis)
    return load_robot(write_arm(SAMPLES / "rx130l", tmp_path_factory.mktemp("offset-wrist"), joints))


@pytest.fixture(scope="module")
def ur_like(tmp_path_factory):
    return load_robot(write_arm(SAMPLES / "rx130l", tmp_path_factory.mktemp("ur-like"), UR_LIKE))


@pytest.mark.parametrize("arm", ["offset_wrist", "ur_like"])
def test_an_arm_without_a_closed_form_falls_back_to_the_multi_start(request, arm):
    robot = request.getfixturevalue(arm)
    assert spherical_wrist(robot) is None
    assert analytic_solutions(robot, tcp_placement(robot, np.zeros(6))) == []
    q = np.array([0.3, 0.4, 1.2, 0.5, 0.8, -0.4])
    target = tcp_placement(robot, q)
    sols = ik_solutions(robot, target, n_starts=64)
    assert sols and max(_pose_error(robot, s, target) for s in sols) < 1e-9
    assert any(np.allclose(s, q, atol=1e-7) for s in sols)
    got = solve_ik(robot, target, seed=q + 0.05)
    assert got.ok and np.allclose(got.q, q, atol=1e-7)
    far = solve_ik(robot, pin.SE3(np.eye(3), np.array([5.0, 0.0, 1.0])), n_starts=8)
    assert far.status is SolveStatus.NOT_CONVERGED and "8-start Newton" in far.message


def test_an_unreachable_pose_is_a_status_with_a_message(robot):
    """One result convention: every front end returns an `IkResult`, whose `outcome` is the solvers'
    `SolveOutcome`; the closed form proves a pose out of reach (INFEASIBLE), the seed's error is kept."""
    far = pin.SE3(np.eye(3), np.array([5.0, 0.0, 1.0]))
    assert analytic_solutions(robot, far) == []
    assert ik_solutions(robot, far) == []
    seed = np.zeros(6)
    results = [
        solve_ik(robot, far, seed=seed),
        inverse_kinematics(robot, far, seed),
        solve_branch_ik(robot, robot.create_data(), far, BranchSelector(robot, None), seed=seed),
    ]
    for res in results:
        assert isinstance(res, IkResult) and not res.ok
        assert res.outcome == SolveOutcome(SolveStatus.INFEASIBLE, res.message)
        assert "no closed-form solution" in res.message and np.array_equal(res.q, seed)
        assert res.position_error_m == pytest.approx(
            np.linalg.norm(far.translation - tcp_placement(robot, seed).translation)
        )
        with pytest.raises(InfeasibleError, match="unreachable"):
            res.raise_if_failed()


def test_a_branch_beyond_the_limits_is_infeasible(rx130l):
    """The RX130L reaches this pose on 4 of its 8 branches within its limits: asking for another is
    INFEASIBLE, saying so; the pose's own branch is solved."""
    q = np.array([0.3, 0.4, 1.2, 0.5, 0.8, -0.4])
    target = tcp_placement(rx130l, q)
    data = rx130l.create_data()
    labels = {b for b, _ in pose_branches(rx130l, target, data)}
    every = [
        Branch(shoulder=s, elbow=e, wrist=w)
        for s in ("front", "back")
        for e in ("up", "down")
        for w in ("positive", "negative")
    ]
    assert len(labels) == 4
    for branch in every:
        res = solve_branch_ik(rx130l, data, target, BranchSelector(rx130l, branch))
        if branch in labels:
            assert res.ok and BranchSelector(rx130l, branch).matches(data, res.q)
        else:
            assert res.status is SolveStatus.INFEASIBLE and "on the selected branch" in res.message


def test_pose_branches_labels_each_solution(robot):
    """Every branch of a generic pose with the project's `Branch` labels, one label per solution, each
    solution on its label."""
    rng = np.random.default_rng(16)
    data = robot.create_data()
    for _ in range(10):
        q = _random_q(robot, rng)
        target = tcp_placement(robot, q)
        branches = pose_branches(robot, target, data)
        assert len({b for b, _ in branches}) == len(branches) >= 1
        for b, s in branches:
            assert BranchSelector(robot, b).matches(data, s) and _pose_error(robot, s, target) < 1e-9
