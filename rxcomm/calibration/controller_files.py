"""A calibration as the files a controller or driver loads, each written with its parity figure.

Formats (`FORMATS`), all from a `rxcomm/Calibration` on the robot it was made for (geometric errors;
joint compliance is in none of them, it stays in calibration.yaml):

- ``urdf``: the calibrated URDF (`rxcomm.calibration.urdf`) with its TCP link;
- ``joint-origins``: per moving joint its origin in the previous joint's frame (xyz m, rpy rad) and
  axis, as the calibrated URDF's joint origins with fixed joints folded in, and the TCP in the last
  joint's frame: the shape of a driver's calibration file; when the joints are a UR arm's (names
  and z axes) the UR ROS 2 driver's ``kinematics.yaml`` layout (x y z roll pitch yaw per joint);
- ``mdh``: Craig's modified DH, plain (β = 0): it cannot follow a calibrated tilt between parallel
  axes, so it states its residual and names ``mdh-hayati`` / ``urdf``;
- ``mdh-hayati``: the same with Hayati's β on the joint after a parallel pair.

Angles: rpy = (roll, pitch, yaw) about the fixed X, Y, Z axes, R = Rz(yaw)·Ry(pitch)·Rx(roll) (the
URDF's); MDH rows θ_i = q_i + θ_offset_i. Every file carries, and `write_controller_file` returns,
the parity of the file as read back (`rxcomm.calibration.parity`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from rxcomm.calibration.exports import CONVENTION, FIT_POSES
from rxcomm.calibration.parity import (
    HOLD_M,
    Parity,
    compare,
    mdh_fk,
    origins_fk,
    parity_poses,
    urdf_fk,
)
from rxcomm.calibration.urdf import calibrated_urdf_text
from rxcomm.io.files import atomic_write_text
from rxcomm.model.geometric_errors import (
    ErrorModel,
    characteristic_length_m,
    random_poses,
    se3_to_xyz_rpy,
)
from rxcomm.model.mdh import FIELDS, fit_mdh
from rxcomm.model.robot import TCP_FRAME, Robot

RPY = "rpy_rad = [roll, pitch, yaw] about the fixed X, Y, Z axes: R = Rz(yaw)·Ry(pitch)·Rx(roll) (URDF)"
UR_JOINTS = (
    ("shoulder_pan_joint", "shoulder"),
    ("shoulder_lift_joint", "upper_arm"),
    ("elbow_joint", "forearm"),
    ("wrist_1_joint", "wrist_1"),
    ("wrist_2_joint", "wrist_2"),
    ("wrist_3_joint", "wrist_3"),
)
# format -> (what it is, default suffix)
FORMATS: dict[str, tuple[str, str]] = {
    "urdf": ("calibrated URDF (TCP link)", ".urdf"),
    "joint-origins": ("per-joint origin table (xyz/rpy, driver calibration layout)", ".joint-origins.yaml"),
    "mdh": ("modified DH table (plain)", ".mdh.yaml"),
    "mdh-hayati": ("modified DH table with Hayati's beta", ".mdh-hayati.yaml"),
}


def _placement(m: pin.SE3) -> dict[str, list[float]]:
    xyz, rpy = se3_to_xyz_rpy(m)
    return {"xyz_m": xyz, "rpy_rad": rpy}


def _yaml(comments: Sequence[str], doc: dict[str, Any]) -> str:
    head = "".join(f"# {c}\n" for c in comments)
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120, allow_unicode=True)


def _urdf(
    robot: Robot, calibrated: Robot, errors: ErrorModel, qs: np.ndarray, src: str
) -> tuple[str, Parity]:
    text = calibrated_urdf_text(robot, errors)
    tip = f"{TCP_FRAME}_calibrated" if f'<link name="{TCP_FRAME}_calibrated"' in text else TCP_FRAME
    t = urdf_fk(text, list(robot.joint_names), tip, qs)
    parity = compare("urdf_parser_py (urdfdom-py) + the URDF chain formula", robot, calibrated, qs, t)
    note = f"<!-- rxcomm export of {src}: TCP link {tip!r}; parity with rxcomm's FK: {parity.text()} -->"
    head, _, body = text.partition("\n")
    return f"{head}\n{note}\n{body}", parity


def _axis(model: pin.Model, k: int) -> list[float]:
    short = model.joints[k].shortname()
    if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return [float(short[-1] == c) for c in "XYZ"]
    if short == "JointModelRevoluteUnaligned":
        return [float(v) for v in model.joints[k].extract().axis]
    raise ValueError(f"joint {model.names[k]}: {short} is not a revolute joint")


def _origins(
    robot: Robot, calibrated: Robot, errors: ErrorModel, qs: np.ndarray, src: str
) -> tuple[str, Parity]:
    model = calibrated.model
    joints = [
        {"joint": name, **_placement(model.jointPlacements[k]), "axis": _axis(model, k)}
        for k, name in enumerate(robot.joint_names, start=1)
    ]
    tool = _placement(model.frames[robot.tcp_frame_id].placement)
    table = {"joints": joints, "tool": tool}
    parity = compare("the URDF chain formula on the table", robot, calibrated, qs, origins_fk(table, qs))
    doc: dict[str, Any] = {
        "robot": robot.name,
        "convention": "T_tcp = Π_i origin_i · R(axis_i, q_i) · tool; origin_i in joint i−1's frame "
        "(joint 1's in the robot's base frame), fixed joints folded in; " + RPY,
        "parity": parity.as_dict(),
        **table,
    }
    ur = dict(UR_JOINTS)
    if tuple(robot.joint_names) == tuple(ur) and all(j["axis"] == [0.0, 0.0, 1.0] for j in joints):
        doc["kinematics"] = {
            ur[j["joint"]]: dict(
                zip(("x", "y", "z", "roll", "pitch", "yaw"), j["xyz_m"] + j["rpy_rad"], strict=True)
            )
            for j in joints
        }
        doc["kinematics"]["hash"] = "calib_" + hashlib.sha256(repr(joints).encode()).hexdigest()[:16]
    return _yaml([f"rxcomm joint-origin table of {src}"], doc), parity


def _mdh(beta: bool) -> Callable[[Robot, Robot, ErrorModel, np.ndarray, str], tuple[str, Parity]]:
    def write(
        robot: Robot, calibrated: Robot, errors: ErrorModel, qs: np.ndarray, src: str
    ) -> tuple[str, Parity]:
        fit_q = random_poses(robot, FIT_POSES, np.random.default_rng(0))
        mdh = fit_mdh(robot, calibrated, fit_q, characteristic_length_m(robot), beta=beta)
        rows = [
            {"joint": name, **{f: float(getattr(r, f)) for f in FIELDS}}
            for name, r in zip(robot.joint_names, mdh.rows, strict=True)
        ]
        table = {"base": _placement(mdh.base), "joints": rows, "tool": _placement(mdh.tool)}
        name = "Hayati-modified DH" if beta else "modified DH (plain)"
        parity = compare("Craig's MDH formula on the table", robot, calibrated, qs, mdh_fk(table, qs))
        doc: dict[str, Any] = {
            "robot": robot.name,
            "form": "mdh-hayati" if beta else "mdh",
            "convention": CONVENTION,
            "parity": parity.as_dict(),
        }
        if not parity.holds:
            doc["note"] = (
                f"{name} cannot hold this calibration to {HOLD_M * 1e6:g} µm: it leaves "
                f"{parity.max_position_m * 1e3:.3g} mm; mdh-hayati or urdf hold it"
            )
        return _yaml([f"rxcomm {name} table of {src}"], {**doc, **table}), parity

    return write


WRITERS = {"urdf": _urdf, "joint-origins": _origins, "mdh": _mdh(False), "mdh-hayati": _mdh(True)}


def write_controller_file(
    fmt: str, robot: Robot, errors: ErrorModel, out: str | Path, source: str = "a calibration"
) -> Parity:
    """Write ``fmt`` of ``robot`` with ``errors`` to ``out`` (atomic); return its parity."""
    calibrated = errors.apply(robot)
    text, parity = WRITERS[fmt](robot, calibrated, errors, parity_poses(robot), source)
    atomic_write_text(out, text)
    return parity
