"""The robot: an immutable Pinocchio model of a 6R arm plus its drives data (architecture §4).

`Robot` describes; scratch data comes from `robot.create_data()` (Pinocchio's Model/Data split).
A robot is loaded from a directory holding one URDF and `drives.yaml`; loading validates both and
raises `InputError` naming the file and the field at fault.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import pinocchio as pin
import yaml
from pydantic import ValidationError

from rxcomm.errors import InputError
from rxcomm.schemas.drives import Drives

TCP_FRAME = "tcp"


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def _per_joint(drives_field: str, doc: str | None = None) -> property:
    """A `Robot` property: `drives_field` of every joint in drives.yaml, as a read-only array."""
    return property(lambda robot: _readonly([getattr(j, drives_field) for j in robot.drives.joints]), doc=doc)


@dataclass(frozen=True, eq=False)
class Robot:
    """A fixed-base serial arm. Never mutated: a calibrated robot is a new `Robot` (see `with_model`).

    A 6R industrial arm: joint 2 is the shoulder, joint 3 the elbow, joint 5 the middle of the wrist,
    whose origin is the wrist centre (the ``*_joint_id`` attributes, Pinocchio's 1-based joint ids).
    """

    shoulder_joint_id: ClassVar[int] = 2
    elbow_joint_id: ClassVar[int] = 3
    wrist_joint_id: ClassVar[int] = 5

    name: str
    model: pin.Model
    drives: Drives
    urdf_path: Path
    drives_path: Path
    tcp_frame_id: int
    flange_frame_id: int
    q_min: np.ndarray = field(repr=False)
    q_max: np.ndarray = field(repr=False)
    v_max: np.ndarray = field(repr=False)

    @property
    def n(self) -> int:
        return self.model.nv

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.drives.joints)

    # Per joint, chain order, from drives.yaml (read-only arrays).
    tau_max = _per_joint("peak_torque_nm", "Peak joint torque, N·m.")
    tau_cont = _per_joint("continuous_torque_nm")
    tau_rate_max = _per_joint("torque_rate_max_nm_per_s")
    a_max = _per_joint("acceleration_max_rad_per_s2")
    gear_ratio = _per_joint("gear_ratio")
    rotor_inertia = _per_joint("rotor_inertia_kgm2", "Motor-side rotor inertia, kg·m².")
    torque_constant = _per_joint("torque_constant_nm_per_a")
    motor_sign = _per_joint("motor_sign")
    encoder_offset = _per_joint(
        "encoder_offset_rad", "Motor angle reported at the joint's calibrated zero, motor side, rad."
    )
    coulomb_prior = _per_joint("coulomb_friction_nm")
    viscous_prior = _per_joint("viscous_friction_nm_s_per_rad")

    @property
    def coupled_motors(self) -> tuple[int, ...]:
        """Motors whose angle depends on more than one joint (a row of C with off-diagonal entries)."""
        c = self.motor_coupling
        return tuple(i for i in range(self.n) if np.count_nonzero(np.delete(c[i], i)) > 0)

    @property
    def friction_mode(self) -> str:
        """Where the model puts friction: "joint", "motor" or "both" (drives.yaml `friction`; default
        both when a motor is coupled to several joints, else joint)."""
        mode = self.drives.friction
        if mode is None:
            mode = "both" if self.coupled_motors else "joint"
        return mode

    @property
    def has_motor_friction(self) -> bool:
        return self.friction_mode in ("motor", "both")

    def with_friction(self, mode: str) -> Robot:
        """The same robot with another friction model (e.g. to compare fits with and without motor
        friction)."""
        return replace(self, drives=self.drives.model_copy(update={"friction": mode}))

    @property
    def motor_coupling(self) -> np.ndarray:
        """Dimensionless C: motor angle = diag(gear_ratio)·C·q."""
        c = self.drives.motor_coupling
        return _readonly(np.eye(self.n) if c is None else c)

    @property
    def joint_to_motor(self) -> np.ndarray:
        """R = diag(gear_ratio)·C: motor angles θ_m = R·q, joint torques τ = Rᵀ·τ_m."""
        return _readonly(np.diag(self.gear_ratio) @ self.motor_coupling)

    @property
    def reflected_rotor_inertia(self) -> np.ndarray:
        """Joint-space rotor inertia Rᵀ·diag(J_m)·R (full when the wrist is coupled), kg·m²."""
        r = self.joint_to_motor
        return _readonly(r.T @ np.diag(self.rotor_inertia) @ r)

    @property
    def spring_joint_index(self) -> int | None:
        s = self.drives.spring
        return None if s is None else self.joint_names.index(s.joint)

    @property
    def reach_m(self) -> float:
        """Largest possible distance shoulder → TCP (m): the link offsets after the shoulder plus the
        TCP's, as if stretched in a line; an upper bound for any pose."""
        m = self.model
        links = sum(np.linalg.norm(m.jointPlacements[j].translation) for j in range(3, m.njoints))
        return float(links + np.linalg.norm(m.frames[self.tcp_frame_id].placement.translation))

    @property
    def reach_from_base_m(self) -> float:
        """Largest possible distance base origin → TCP (m): `reach_m` plus the offsets base → shoulder."""
        m = self.model
        return self.reach_m + sum(float(np.linalg.norm(m.jointPlacements[j].translation)) for j in (1, 2))

    @property
    def shoulder_height_m(self) -> float:
        """Height of the shoulder (joint 2's origin) above the base origin at q = 0 (m)."""
        data = self.create_data()
        pin.forwardKinematics(self.model, data, np.zeros(self.n))
        return float(data.oMi[self.shoulder_joint_id].translation[2])

    @functools.cached_property
    def forward_in_joint1(self) -> np.ndarray:
        """The unit direction, in joint 1's frame and across its axis, that the shoulder's front/back
        is read along: joint 1's x axis, unless it lies more than 60° off the direction the arm
        reaches at q = 0, and then that direction. A link frame turned about the axis (MuJoCo
        Menagerie's piper: x across the arm's plane) leaves the wrist centre never ahead of x nor
        behind it, and the label to round-off; an arm upright at q = 0 (the RX130L) reaches nowhere
        there and keeps x."""
        data = self.create_data()
        pin.forwardKinematics(self.model, data, np.zeros(self.n))
        j1 = data.oMi[1]
        axis = np.asarray(data.joints[1].S).reshape(6, -1)[3:, 0]
        across = lambda v: v - (v @ axis) * axis  # noqa: E731
        x = across(np.array([1.0, 0.0, 0.0]))
        reach = across(j1.rotation.T @ (data.oMi[self.wrist_joint_id].translation - j1.translation))
        if np.linalg.norm(reach) >= 0.01 * self.reach_m and abs(x @ reach) < 0.5 * np.linalg.norm(
            x
        ) * np.linalg.norm(reach):
            return _readonly(reach / np.linalg.norm(reach))
        return _readonly(x / np.linalg.norm(x))

    def create_data(self) -> pin.Data:
        return self.model.createData()

    def with_model(self, model: pin.Model) -> Robot:
        """The same drives on another kinematic/inertial model (e.g. a calibrated one)."""
        _check_chain(model, self.joint_names, self.urdf_path)
        return replace(
            self,
            model=model,
            tcp_frame_id=model.getFrameId(TCP_FRAME),
            flange_frame_id=link_frame_id(model, self.drives.tcp.parent_frame),
        )


def robot_files(robot_dir: str | Path) -> dict[str, Path]:
    """The files a robot is loaded from, by name, without loading it (for `check_outputs`, which runs
    before any input is read): drives.yaml and every URDF beside it."""
    robot_dir = Path(robot_dir)
    drives_path = robot_dir if robot_dir.is_file() else robot_dir / "drives.yaml"
    files = {"robot drives.yaml": drives_path}
    if drives_path.parent.is_dir():
        files |= {f"robot URDF {p.name}": p for p in sorted(drives_path.parent.glob("*.urdf"))}
    return files


def link_frame_id(model: pin.Model, name: str) -> int:
    """The frame of link `name`: a URDF may give a joint the name of a link (an MJCF's joints and
    bodies have their own namespaces), and Pinocchio then refuses the bare name as ambiguous."""
    if model.existFrame(name, pin.FrameType.BODY):
        return model.getFrameId(name, pin.FrameType.BODY)
    return model.getFrameId(name)


def load_robot(robot_dir: str | Path, urdf: str | Path | None = None) -> Robot:
    """Load `ROBOT_DIR/drives.yaml` and the URDF it names (or `urdf`, e.g. a calibrated one).

    `robot_dir` may also be the path of a drives YAML file.
    """
    robot_dir = Path(robot_dir)
    drives_path = robot_dir if robot_dir.is_file() else robot_dir / "drives.yaml"
    if not drives_path.exists():
        raise InputError("no drives.yaml here (a robot is a URDF + drives.yaml)", file=drives_path)
    drives = _load_drives(drives_path)
    urdf_path = Path(urdf) if urdf is not None else drives_path.parent / drives.urdf
    if not urdf_path.exists():
        raise InputError(f"URDF {urdf_path} not found", file=drives_path, field="urdf")
    names = [j.name for j in drives.joints]
    limits = _validate_urdf(urdf_path, names, drives_path)
    try:
        model = pin.buildModelFromUrdf(str(urdf_path))
    except (RuntimeError, ValueError) as e:
        raise InputError(f"Pinocchio cannot load it: {e}", file=urdf_path) from e
    _check_chain(model, tuple(names), urdf_path)
    tcp = drives.tcp
    if not model.existFrame(tcp.parent_frame):
        raise InputError(
            f"frame {tcp.parent_frame!r} is not in the URDF", file=drives_path, field="tcp.parent_frame"
        )
    parent_frame = link_frame_id(model, tcp.parent_frame)
    f = model.frames[parent_frame]
    placement = f.placement * pin.SE3(pin.rpy.rpyToMatrix(np.array(tcp.rpy_rad)), np.array(tcp.xyz_m))
    tcp_id = model.addFrame(
        pin.Frame(TCP_FRAME, f.parentJoint, parent_frame, placement, pin.FrameType.OP_FRAME)
    )
    lo, hi, vel = (np.array(v) for v in zip(*limits, strict=True))
    return Robot(
        name=model.name,
        model=model,
        drives=drives,
        urdf_path=urdf_path,
        drives_path=drives_path,
        tcp_frame_id=tcp_id,
        flange_frame_id=parent_frame,
        q_min=_readonly(lo),
        q_max=_readonly(hi),
        v_max=_readonly(vel),
    )


def _load_drives(path: Path) -> Drives:
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise InputError(f"not valid YAML: {e}", file=path) from e
    if not isinstance(raw, dict):
        raise InputError("expected a mapping at the top level", file=path)
    try:
        return Drives.model_validate(raw)
    except ValidationError as e:
        err = e.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        if len(err["loc"]) > 1 and err["loc"][0] == "joints":
            idx = err["loc"][1]
            if isinstance(idx, int) and idx < len(raw.get("joints", [])):
                name = raw["joints"][idx].get("name", idx) if isinstance(raw["joints"][idx], dict) else idx
                loc = loc.replace(f"joints.{idx}", f"joints[{name}]", 1)
        more = f" (and {len(e.errors()) - 1} more)" if len(e.errors()) > 1 else ""
        raise InputError(f"{err['msg']}{more}", file=path, field=loc or None) from e


def _validate_urdf(path: Path, joint_names: list[str], drives_path: Path) -> list[tuple[float, float, float]]:
    """Check what Pinocchio does not: limits present, inertias physical, joints matching drives.yaml."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise InputError(f"not valid XML: {e}", file=path) from e
    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        where = f"link[{link.get('name')}].inertial"
        mass_el, inertia_el = inertial.find("mass"), inertial.find("inertia")
        if mass_el is None or inertia_el is None:
            raise InputError("needs <mass> and <inertia>", file=path, field=where)
        try:
            mass = float(mass_el.get("value", "nan"))
            i = {k: float(inertia_el.get(k, "0")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        except ValueError as e:
            raise InputError(f"not a number: {e}", file=path, field=where) from e
        if not mass >= 0:
            raise InputError(f"mass must not be negative, got {mass}", file=path, field=f"{where}.mass")
        tensor = np.array(
            [[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]], [i["ixz"], i["iyz"], i["izz"]]]
        )
        # Positive semi-definite and the triangle inequality: a point mass (zero inertia) or a thin rod
        # is a legitimate prior; an indefinite tensor is not a body.
        ev = np.linalg.eigvalsh(tensor)
        tol = 1e-9 * max(abs(ev).max(), 1e-12)
        if ev[0] < -tol or ev[2] > ev[0] + ev[1] + tol:
            raise InputError(
                f"inertia tensor is not physical (eigenvalues {np.round(ev, 6).tolist()}: must be "
                "non-negative and satisfy the triangle inequality)",
                file=path,
                field=f"{where}.inertia",
            )
    moving = [j for j in root.iter("joint") if j.get("type") not in ("fixed",)]
    urdf_names = [j.get("name") for j in moving]
    if sorted(urdf_names) != sorted(joint_names):
        unknown = [n for n in joint_names if n not in urdf_names]
        field = f"joints[{unknown[0]}].name" if unknown else "joints"
        raise InputError(
            f"the URDF {path.name} has joints {urdf_names}; drives.yaml lists {joint_names}",
            file=drives_path,
            field=field,
        )
    limits = {}
    for j in moving:
        name = j.get("name")
        if j.get("type") != "revolute":
            raise InputError(
                f"only revolute joints are supported, got {j.get('type')!r}",
                file=path,
                field=f"joint[{name}].type",
            )
        lim = j.find("limit")
        if lim is None:
            raise InputError("missing <limit>", file=path, field=f"joint[{name}].limit")
        vals = []
        for attr in ("lower", "upper", "velocity"):
            if lim.get(attr) is None:
                raise InputError(f"missing {attr!r}", file=path, field=f"joint[{name}].limit.{attr}")
            vals.append(float(lim.get(attr)))
        if not vals[0] < vals[1]:
            raise InputError(f"lower {vals[0]} ≥ upper {vals[1]}", file=path, field=f"joint[{name}].limit")
        if not vals[2] > 0:
            raise InputError(
                "velocity limit must be positive", file=path, field=f"joint[{name}].limit.velocity"
            )
        limits[name] = tuple(vals)
    return [limits[n] for n in joint_names]


def _check_chain(model: pin.Model, joint_names: tuple[str, ...], path: Path) -> None:
    names = tuple(model.names[1:])
    if names != tuple(joint_names):
        raise InputError(
            f"joint order {list(names)} does not match drives.yaml {list(joint_names)}",
            file=path,
            field="joint",
        )
    if model.nq != model.nv or any(model.joints[i].nq != 1 for i in range(1, model.njoints)):
        raise InputError("every joint must be a single-DOF revolute joint", file=path, field="joint")
