"""The calibrated URDF: the geometric errors folded into the joint origins (base error into the
first joint's origin, so the URDF root stays the nominal base frame of the cell; tool error into the
fixed joint carrying the TCP's parent frame — a new one when that frame is a moving link such as
`wrist_3_link` — so drives.yaml's TCP stays valid), and the TCP as a
named fixed frame (link `tcp`, joint `tcp_joint` on drives.yaml's tcp), so that any URDF tool
(RViz, Foxglove, MoveIt) reaches the calibrated TCP by FK without drives.yaml. Joint compliance is
not in a URDF: it stays in calibration.yaml."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_text
from rxcomm.model.geometric_errors import ErrorModel, placement_to_se3, se3_to_xyz_rpy
from rxcomm.model.robot import TCP_FRAME, Robot


def _origin(joint: ET.Element) -> pin.SE3:
    o = joint.find("origin")
    xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
    rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
    return placement_to_se3(xyz, rpy)


def _set_origin(joint: ET.Element, m: pin.SE3) -> None:
    o = joint.find("origin")
    if o is None:
        o = ET.SubElement(joint, "origin")
    xyz, rpy = se3_to_xyz_rpy(m)
    o.set("xyz", " ".join(repr(v) for v in xyz))
    o.set("rpy", " ".join(repr(v) for v in rpy))


def calibrated_urdf_text(robot: Robot, errors: ErrorModel) -> str:
    """The robot's URDF with `errors` folded into the joint origins (see the module docstring)."""
    root = ET.parse(robot.urdf_path).getroot()
    joints = {j.get("name"): j for j in root.iter("joint")}
    model = robot.model
    for k, name in enumerate(robot.joint_names, start=1):
        el = joints[name]
        o = _origin(el)
        new = o * pin.exp6(errors.twist(name))
        if model.parents[k] == 0:
            # Pinocchio's placement = C·O (C: fixed joints above); exp(δb)·C·O = C·(C⁻¹·exp(δb)·C)·O.
            c = model.jointPlacements[k] * o.inverse()
            new = c.inverse() * pin.exp6(errors.twist("base")) * c * new
        _set_origin(el, new)
    tool = errors.twist("tool")
    if np.any(tool != 0):
        parent = robot.drives.tcp.parent_frame
        carrier = [
            j
            for j in root.iter("joint")
            if j.get("type") == "fixed" and j.find("child").get("link") == parent
        ]
        el = carrier[0] if carrier else _split_link(root, parent, robot)
        f = placement_to_se3(robot.drives.tcp.xyz_m, robot.drives.tcp.rpy_rad)
        _set_origin(el, _origin(el) * f * pin.exp6(tool) * f.inverse())
    tcp_name = _add_tcp_frame(root, robot)
    root.insert(
        0,
        ET.Comment(
            " calibrated by rxcomm: geometric errors folded into the joint origins; link "
            f"{tcp_name!r} is the TCP "
        ),
    )
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def _split_link(root: ET.Element, parent: str, robot: Robot) -> ET.Element:
    """A fixed carrier for the tool error when the TCP's parent frame is a moving link (e.g.
    `wrist_3_link`, the child of the last revolute joint): that joint's child becomes a new empty
    link `{parent}_uncalibrated`, joined to `parent` by a new fixed joint (identity origin, returned)
    that takes the tool error; everything on `parent` (meshes, inertia, child frames) moves with it."""
    movers = [j for j in root.iter("joint") if j.find("child").get("link") == parent]
    if not movers:
        raise InputError(
            f"the tool error cannot be folded into the URDF: TCP parent frame {parent!r} is no link's "
            "child in it",
            file=robot.urdf_path,
            field="tcp.parent_frame",
        )
    links = {el.get("name") for el in root.iter("link")}
    name = f"{parent}_uncalibrated"
    while name in links:
        name += "_"
    movers[0].find("child").set("link", name)
    ET.SubElement(root, "link", name=name)
    joint = ET.SubElement(root, "joint", name=f"{parent}_tool_error", type="fixed")
    ET.SubElement(joint, "parent", link=name)
    ET.SubElement(joint, "child", link=parent)
    return joint


def _add_tcp_frame(root: ET.Element, robot: Robot) -> str:
    """A fixed link at drives.yaml's TCP on its parent frame (whose carrier joint holds the tool
    error); named `tcp`, unless the URDF already has a link of that name. Returns the name."""
    links = {el.get("name") for el in root.iter("link")}
    name = TCP_FRAME if TCP_FRAME not in links else f"{TCP_FRAME}_calibrated"
    tcp = robot.drives.tcp
    ET.SubElement(root, "link", name=name)
    joint = ET.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
    ET.SubElement(joint, "parent", link=tcp.parent_frame)
    ET.SubElement(joint, "child", link=name)
    _set_origin(joint, placement_to_se3(tcp.xyz_m, tcp.rpy_rad))
    return name


def write_calibrated_urdf(robot: Robot, errors: ErrorModel, path: str | Path) -> Path:
    """Write the calibrated URDF atomically. Load it with `load_robot(ROBOT_DIR, urdf=path)`."""
    return atomic_write_text(path, calibrated_urdf_text(robot, errors))
