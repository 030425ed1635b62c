"""Geometric error model: names match the truth files, the perturbed model is a new model, the batched
kinematics equals Pinocchio, the analytic identification Jacobian equals central finite differences,
and the identifiable counts are 30 (full pose) and 27 (position of an off-axis point) on both robots."""

import numpy as np
import pinocchio as pin
import pytest
import yaml

from rxcomm.errors import InputError
from rxcomm.model.geometric_errors import (
    ErrorModel,
    identifiable_parameters,
    identification_jacobians,
    measured_pose,
    parameter_names,
    predict_poses,
    random_poses,
)
from rxcomm.model.kinematics import tcp_placement

from .conftest import SAMPLES

OFF_AXIS_POINT = np.array([0.05, 0.03, 0.10])  # a probe point off the flange axis, in the TCP frame


def _truth(robot):
    name = "rx130l" if robot.name == "rx130l" else "m900"
    return yaml.safe_load((SAMPLES / name / "truth.yaml").read_text())["geometry"]


def _errors_and_t2b(robot):
    g = _truth(robot)
    t2b = pin.SE3(
        pin.rpy.rpyToMatrix(np.array(g["tracker_to_base"]["rpy_rad"])),
        np.array(g["tracker_to_base"]["xyz_m"]),
    )
    return ErrorModel.from_mapping(robot, g["error_parameters"]), t2b


def test_names_are_the_truth_files_names(robot):
    names = parameter_names(robot)
    assert len(names) == 48 and set(names) == set(_truth(robot)["error_parameters"])


def test_unknown_parameter_name_is_input_error(rx130l):
    with pytest.raises(InputError, match="unknown error parameter"):
        ErrorModel.from_mapping(rx130l, {"joint_9.tx": 1e-3})


def test_apply_builds_a_new_model_and_leaves_the_shared_one(robot):
    errors, _ = _errors_and_t2b(robot)
    before = [robot.model.jointPlacements[j].homogeneous.copy() for j in range(1, 7)]
    tcp_before = robot.model.frames[robot.tcp_frame_id].placement.homogeneous.copy()
    perturbed = errors.apply(robot)
    assert perturbed.model is not robot.model
    for j in range(1, 7):
        np.testing.assert_array_equal(robot.model.jointPlacements[j].homogeneous, before[j - 1])
    np.testing.assert_array_equal(robot.model.frames[robot.tcp_frame_id].placement.homogeneous, tcp_before)
    q = np.array([0.3, -0.4, 0.9, 1.1, -0.7, 0.5])
    moved = np.linalg.norm(tcp_placement(perturbed, q).translation - tcp_placement(robot, q).translation)
    assert 1e-3 < moved < 2e-2  # mm-level errors move the TCP by millimetres


def test_single_joint_offset_is_a_joint_angle_shift(rx130l):
    # joint_2 turns about y: its ry error is exactly an encoder offset.
    q = np.array([0.3, -0.4, 0.9, 1.1, -0.7, 0.5])
    e = ErrorModel.from_mapping(rx130l, {"joint_2.ry": 0.01})
    q_shift = q.copy()
    q_shift[1] += 0.01
    np.testing.assert_allclose(
        tcp_placement(rx130l, q, e).homogeneous, tcp_placement(rx130l, q_shift).homogeneous, atol=1e-14
    )


def test_batched_kinematics_equals_pinocchio(robot):
    errors, t2b = _errors_and_t2b(robot)
    qs = random_poses(robot, 20, np.random.default_rng(1))
    p, r = predict_poses(robot, qs, errors, t2b)
    for k, q in enumerate(qs):
        m = measured_pose(robot, q, errors, t2b)
        np.testing.assert_allclose(p[k], m.translation, atol=1e-12)
        np.testing.assert_allclose(r[k], m.rotation, atol=1e-12)
        # measured pose = tracker_to_base · TCP in the nominal base frame (base error folded into joint 1).
        np.testing.assert_allclose(
            (t2b * tcp_placement(robot, q, errors)).homogeneous, m.homogeneous, atol=1e-12
        )


def _fd_jacobian(robot, q, errors, t2b, position_only, point, h=1e-6):
    cols = []
    for i in range(48):
        vp, vm = errors.values.copy(), errors.values.copy()
        vp[i] += h
        vm[i] -= h
        pp, rp = predict_poses(robot, q[None], errors.with_values(vp), t2b, point)
        pm, rm = predict_poses(robot, q[None], errors.with_values(vm), t2b, point)
        col = [(pp[0] - pm[0]) / (2 * h)]
        if not position_only:
            col.append(pin.log3(rp[0] @ rm[0].T) / (2 * h))
        cols.append(np.concatenate(col))
    return np.array(cols).T


@pytest.mark.parametrize(("position_only", "point"), [(False, None), (True, OFF_AXIS_POINT)])
def test_identification_jacobian_equals_central_differences(robot, position_only, point):
    errors, t2b = _errors_and_t2b(robot)  # at the (non-zero) truth: exercises the exp6 right Jacobian
    rng = np.random.default_rng(2)
    for q in random_poses(robot, 3, rng):
        jac = identification_jacobians(robot, q[None], errors, t2b, position_only, point)[0]
        fd = _fd_jacobian(robot, q, errors, t2b, position_only, point)
        assert jac.shape == (3 if position_only else 6, 48)
        rel = np.max(np.abs(jac - fd)) / np.max(np.abs(jac))
        assert rel <= 1e-6, rel


def test_identifiable_counts(robot):
    poses = random_poses(robot, 60, np.random.default_rng(4))
    full = identifiable_parameters(robot, poses)
    assert len(full) == 30 and full.rank == 30
    # A clear numerical gap: structural dependencies are at round-off, the weakest kept column is not.
    assert full.largest_dropped_ratio < 1e-12 and full.smallest_kept_ratio > 1e-3
    pos = identifiable_parameters(robot, poses, position_only=True, point=OFF_AXIS_POINT)
    assert len(pos) == 27
    # The base absorbs joint 1 entirely: all six of its errors are dropped, each explained.
    dropped = dict(full.dropped)
    j1 = robot.joint_names[0]
    assert all(f"{j1}.{c}" in dropped for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
    assert "base" in dropped[f"{j1}.tz"]
    assert all(n.startswith("base.") for n in full.names[:6])


def test_on_axis_tcp_position_only_loses_the_tool_rotations(rx130l):
    # The RX130L TCP lies on the flange axis: its position alone cannot see rotations about the TCP.
    poses = random_poses(rx130l, 60, np.random.default_rng(5))
    s = identifiable_parameters(rx130l, poses, position_only=True)
    assert len(s) == 25
    assert "does not affect" in dict(s.dropped)["tool.rx"]


def test_too_few_poses_show_rank_deficiency(rx130l):
    poses = random_poses(rx130l, 3, np.random.default_rng(6))  # 18 rows < 30 parameters
    assert len(identifiable_parameters(rx130l, poses)) < 30
