"""A calibration artefact back as an error model or a calibrated robot (IK, planners)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.model.artefact_checks import check_same_robot
from rxcomm.model.geometric_errors import COMPONENTS, ErrorModel, placement_to_se3
from rxcomm.model.robot import Robot
from rxcomm.schemas.calibration import Calibration


def load_calibration(path: str | Path) -> tuple[ErrorModel, pin.SE3]:
    """(ErrorModel, nominal tracker_to_base) from a `rxcomm/Calibration` artefact.

    `errors.apply(robot)` gives the calibrated robot (TCP in the cell's nominal base frame);
    `inverse_kinematics(robot, target, seed, errors=errors)` honours it.
    """
    art = read_yaml_artefact(path, Calibration)
    names = tuple(p.name for p in art.parameters)
    expected = {f"{g}.{c}" for g in ("base", "tool", *art.joint_names) for c in COMPONENTS}
    if set(names) != expected or len(names) != len(expected):
        raise InputError(
            "parameters must list the 48 error parameters exactly once", file=path, field="parameters"
        )
    order = parameter_names_from(art.joint_names)
    by_name = {p.name: p.value for p in art.parameters}
    t2b = placement_to_se3(art.tracker_to_base.xyz_m, art.tracker_to_base.rpy_rad)
    return ErrorModel(order, np.array([by_name[n] for n in order])), t2b


def parameter_names_from(joint_names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """`parameter_names` from joint names alone (no robot needed)."""
    return tuple(f"{g}.{c}" for g in ("base", *joint_names, "tool") for c in COMPONENTS)


def read_calibration(path: str | Path, robot: Robot) -> Calibration:
    """calibration.yaml, refused (InputError naming the file) when made for other joints than `robot`'s."""
    art = read_yaml_artefact(path, Calibration)
    if tuple(art.joint_names) != robot.joint_names:
        raise InputError(
            f"calibration is for joints {art.joint_names}, the robot has {list(robot.joint_names)}",
            file=path,
            field="joint_names",
        )
    return art


def calibration_errors(robot: Robot, path: str | Path) -> ErrorModel:
    """A calibration artefact's geometric errors on `robot` (nominal); exit 2 unless it is this robot's."""
    art = read_calibration(path, robot)
    check_same_robot(robot, art.inputs, path)
    return ErrorModel.from_mapping(robot, {p.name: p.value for p in art.parameters}, file=str(path))


def load_calibrated_robot(robot: Robot, path: str | Path) -> Robot:
    """`robot` with a calibration artefact's geometric errors applied: its kinematics and IK honour
    the calibration (planners take it with `--calibration`). A torque model is evaluated on the
    kinematics it was fitted on instead (`model.base_parameters.load_dynamics`), whatever this is."""
    return calibration_errors(robot, path).apply(robot)
