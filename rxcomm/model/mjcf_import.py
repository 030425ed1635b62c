"""A robot directory from a MuJoCo model (MJCF or URDF): what `rxcomm import-robot` writes.

MuJoCo compiles the model (default classes, body quaternions or Euler angles, inertias given with a
rotation or as `fullinertia`, meshes present or absent) and this module reads the COMPILED model, so
whatever MJCF spelling was used, the numbers are MuJoCo's own:

- kinematics at q = 0 (MuJoCo's joint zero, not `ref`): each hinge's link frame is its body frame moved
  to the joint anchor (`jnt_pos`), the URDF joint origin is the parent link → child link transform and
  the axis is `jnt_axis` (same rotation as the body); jointless bodies become fixed links;
- inertials: `body_mass`, `body_ipos`, `body_iquat`·diag(`body_inertia`) rotated into the link frame;
- drives: `armature` → rotor inertia (armature / N², N the gear ratio), `damping` → viscous prior,
  `frictionloss` → Coulomb prior, `actuatorfrcrange` (or the force range of an actuator on the joint,
  × its gear) → peak torque, `range` → position limits.

What a MuJoCo model cannot know is written with the stated default of `ASSUMED` and listed in
`ImportedRobot.assumed` (the stage prints it). What rxcomm's model cannot hold is said in
`ImportedRobot.notes`: a joint `stiffness` (a spring the MuJoCo plant keeps); a body's `gravcomp`
(MuJoCo's gravity compensation: left out here and on the MuJoCo plant, the arm has its weight).
Anything but a serial chain of six hinges is refused, naming the joint or body that breaks it (exit
2); joints below the sixth link (a gripper's) are named as such, to be deleted so the bodies import
as a rigid tool.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from rxcomm.errors import InputError

N_JOINTS = 6
ROOT_LINK = "mujoco_world"
# Stated defaults for what a MuJoCo model does not hold (drives.yaml fields, per joint unless noted).
ASSUMED = {
    "gear_ratio": 100.0,
    "torque_constant_nm_per_a": 0.5,
    "winding_resistance_ohm": 1.0,  # the energy objective's copper losses (the samples: 0.9–1.4 Ω)
    "velocity_limit_rad_s": 3.0,
    "viscous_share": 0.5,  # … lowered where viscous friction alone would need this × peak torque
    "acceleration_max_rad_per_s2": 10.0,
    "torque_rate_per_s": 20.0,  # torque rate limit = this × peak torque, N·m/s
    "continuous_fraction": 0.5,  # continuous torque = this × peak torque
    "peak_over_gravity": 2.5,  # peak torque ≥ this × the largest holding torque (gravity, springs)
    # … and ≥ the holding torque plus the assumed acceleration on the joint's inertia (a vertical axis
    # holds nothing: 2.5 × 0 left an industrial arm's J1 at the 5 N·m floor)
    "peak_min_nm": 5.0,
    "range_rad": float(np.pi),  # an unlimited hinge: ±this
    "cycle_s": 0.0004,
}


@dataclass
class ImportedRobot:
    """The files of a robot directory, as text, and what was assumed."""

    name: str
    urdf: str
    drives: dict
    assumed: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def compile_model(path: Path) -> tuple[mujoco.MjModel, list[str]]:
    """MuJoCo's compiled model of `path`; mesh files that are absent drop their geoms (a note says so)."""
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as e:
        raise InputError(f"MuJoCo cannot read it: {e}", file=path) from e
    model, dropped = compile_without_absent_meshes(spec, path)
    notes = (
        ["mesh files absent: their geoms dropped; inertias from the bodies' <inertial>"] if dropped else []
    )
    if compensated := gravity_compensated_bodies(model):
        notes.append(gravity_compensation_note(compensated))
        model.body_gravcomp[:] = 0.0  # the holding torques below are the arm's own weight
    return model, notes


def gravity_compensated_bodies(model: mujoco.MjModel) -> list[str]:
    """The bodies MuJoCo's `gravcomp` lifts (a simulation's stand-in for a controller's gravity
    feed-forward: with it the arm has no weight at its joints)."""
    return [
        _name(model, mujoco.mjtObj.mjOBJ_BODY, b, "body")
        for b in range(model.nbody)
        if model.body_gravcomp[b] != 0.0
    ]


def gravity_compensation_note(bodies: list[str]) -> str:
    return (
        f"gravcomp on {', '.join(bodies)}: MuJoCo's gravity compensation, a simulation's stand-in for a "
        "controller's, left out: the arm has its weight at its joints (in the holding torques here and "
        "on the MuJoCo plant) and rxcomm's feed-forward holds it"
    )


def compile_without_absent_meshes(spec: mujoco.MjSpec, path: Path) -> tuple[mujoco.MjModel, bool]:
    """`spec` compiled; where a mesh file is absent (a model shipped without its assets), with every
    mesh geom and mesh dropped (the second value True). InputError (`path` named) otherwise."""
    try:
        return spec.compile(), False
    except ValueError as e:
        if "mesh" not in str(e).lower() and "file" not in str(e).lower():
            raise _compile_error(e, path, "MuJoCo cannot compile it") from e
    for geom in [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH]:
        spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    try:
        return spec.compile(), True
    except ValueError as e:
        raise _compile_error(e, path, "MuJoCo cannot compile it without its meshes") from e


def _compile_error(e: ValueError, path: Path, what: str) -> InputError:
    """MuJoCo's compile error as an InputError; a massless moving link (a kinematics-only URDF, as
    ROS-Industrial's are) said in the commissioning's terms, the link named."""
    text = str(e)
    link = re.search(r"Element name '([^']*)'", text)
    if "mass and inertia of moving bodies" in text and link:
        return InputError(
            "a moving link without mass and inertia (no <inertial>, and no mesh to infer one "
            "from): the prior dynamics every plan is limited by need them; add an <inertial> to each "
            "moving link (the maker's data or a CAD estimate; kinematics-only URDFs carry none)",
            file=path,
            field=link.group(1),
        )
    return InputError(f"{what}: {text}", file=path)


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int, prefix: str) -> str:
    return mujoco.mj_id2name(model, obj, i) or f"{prefix}{i}"


def serial_hinges(model: mujoco.MjModel, path: Path) -> list[int]:
    """The six hinge ids in chain order, or InputError naming the joint or body that breaks the chain."""
    jname = lambda j: _name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint")  # noqa: E731
    bname = lambda b: _name(model, mujoco.mjtObj.mjOBJ_BODY, b, "body")  # noqa: E731
    tool = [j for j in range(model.njnt) if _hinges_above(model, j) >= N_JOINTS]
    hint = (
        f": {[jname(j) for j in tool]} hang off the arm's sixth link (a gripper or a tool?); delete "
        "those joints (their bodies stay on as a rigid tool) and import again"
        if tool
        else ""
    )
    for j in range(model.njnt):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            kind = mujoco.mjtJoint(model.jnt_type[j]).name.removeprefix("mjJNT_").lower()
            raise InputError(
                f"joint {jname(j)!r} is a {kind} joint: a serial 6R arm has hinges only{hint}", file=path
            )
    if model.njnt != N_JOINTS:
        raise InputError(
            f"{model.njnt} hinges ({[jname(j) for j in range(model.njnt)]}): a 6R arm has 6{hint}",
            file=path,
        )
    bodies = [int(model.jnt_bodyid[j]) for j in range(N_JOINTS)]
    for b in set(bodies):
        if bodies.count(b) > 1:
            raise InputError(f"body {bname(b)!r} has {bodies.count(b)} joints: one per link", file=path)
    order = sorted(range(N_JOINTS), key=lambda j: _depth(model, bodies[j]))
    for k, j in enumerate(order):
        b = int(model.body_parentid[bodies[j]])
        while b != 0 and model.body_jntnum[b] == 0:
            b = int(model.body_parentid[b])
        want = 0 if k == 0 else bodies[order[k - 1]]
        if b != want:
            raise InputError(
                f"joint {jname(j)!r} (body {bname(bodies[j])!r}) hangs off {bname(b)!r}, "
                f"not off the previous joint's body {bname(want)!r}: not a serial chain",
                file=path,
            )
    return order


def _hinges_above(model: mujoco.MjModel, j: int) -> int:
    """How many hinges sit on the bodies above joint j's body (its ancestors, world excluded)."""
    n, b = 0, int(model.body_parentid[model.jnt_bodyid[j]])
    while b != 0:
        adr, num = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        n += sum(model.jnt_type[k] == mujoco.mjtJoint.mjJNT_HINGE for k in range(adr, adr + num))
        b = int(model.body_parentid[b])
    return n


def _depth(model: mujoco.MjModel, b: int) -> int:
    d = 0
    while b != 0:
        b, d = int(model.body_parentid[b]), d + 1
    return d


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw of R = Rz(y)·Ry(p)·Rx(r)."""
    pitch = float(np.arcsin(-np.clip(r[2, 0], -1.0, 1.0)))
    if abs(r[2, 0]) < 1 - 1e-12:
        return float(np.arctan2(r[2, 1], r[2, 2])), pitch, float(np.arctan2(r[1, 0], r[0, 0]))
    return 0.0, pitch, float(np.arctan2(-r[0, 1], r[1, 1]))


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in v)


def _frames(model: mujoco.MjModel) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """World pose (R, p) of every body's link frame at q = 0 (hinge bodies at their anchor)."""
    data = mujoco.MjData(model)
    data.qpos[:] = 0.0
    mujoco.mj_kinematics(model, data)
    frames = {}
    for b in range(1, model.nbody):
        r = data.xmat[b].reshape(3, 3).copy()
        p = data.xpos[b].copy()
        if model.body_jntnum[b]:
            p = p + r @ model.jnt_pos[model.body_jntadr[b]]
        frames[b] = (r, p)
    frames[0] = (np.eye(3), np.zeros(3))
    return frames


def _urdf(model: mujoco.MjModel, name: str, limits: list[tuple[float, float, float, float]]) -> str:
    frames = _frames(model)
    bname = lambda b: ROOT_LINK if b == 0 else _name(model, mujoco.mjtObj.mjOBJ_BODY, b, "body")  # noqa: E731
    robot = ET.Element("robot", name=name)
    ET.SubElement(robot, "link", name=ROOT_LINK)
    for b in range(1, model.nbody):
        link = ET.SubElement(robot, "link", name=bname(b))
        if model.body_mass[b] > 0:
            anchor = model.jnt_pos[model.body_jntadr[b]] if model.body_jntnum[b] else np.zeros(3)
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.body_iquat[b])
            rot = rot.reshape(3, 3)
            tensor = rot @ np.diag(model.body_inertia[b]) @ rot.T
            inertial = ET.SubElement(link, "inertial")
            ET.SubElement(inertial, "origin", xyz=_fmt(model.body_ipos[b] - anchor), rpy="0 0 0")
            ET.SubElement(inertial, "mass", value=f"{model.body_mass[b]:.12g}")
            ET.SubElement(
                inertial,
                "inertia",
                **{k: f"{tensor[i, j]:.12g}" for k, (i, j) in _TENSOR.items()},
            )
    for b in range(1, model.nbody):
        parent = int(model.body_parentid[b])
        rp, pp = frames[parent]
        rc, pc = frames[b]
        hinge = model.body_jntnum[b] > 0
        jid = int(model.body_jntadr[b]) if hinge else -1
        jn = _name(model, mujoco.mjtObj.mjOBJ_JOINT, jid, "joint") if hinge else f"{bname(b)}_fixed"
        joint = ET.SubElement(robot, "joint", name=jn, type="revolute" if hinge else "fixed")
        ET.SubElement(joint, "parent", link=bname(parent))
        ET.SubElement(joint, "child", link=bname(b))
        rel = rp.T @ rc
        ET.SubElement(joint, "origin", xyz=_fmt(rp.T @ (pc - pp)), rpy=_fmt(_rpy(rel)))
        if hinge:
            ET.SubElement(joint, "axis", xyz=_fmt(model.jnt_axis[jid]))
            lo, hi, vel, effort = limits[jid]
            ET.SubElement(
                joint,
                "limit",
                lower=f"{lo:.12g}",
                upper=f"{hi:.12g}",
                velocity=f"{vel:.12g}",
                effort=f"{effort:.6g}",
            )
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _urdf_velocity_limits(path: Path) -> dict[str, float]:
    """Joint name → `<limit velocity>` (rad/s) of a URDF, those > 0; {} for an MJCF (it has none)."""
    if path.suffix.lower() != ".urdf":
        return {}
    limits = {}
    for joint in ET.parse(path).getroot().iter("joint"):
        limit = joint.find("limit")
        try:
            velocity = float(limit.get("velocity", "0")) if limit is not None else 0.0
        except ValueError:
            continue
        if velocity > 0 and joint.get("name"):
            limits[joint.get("name")] = velocity
    return limits


_TENSOR = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}


def _peak_torques(model: mujoco.MjModel, order: list[int], assumed: list[str]) -> np.ndarray:
    """actuatorfrcrange, an actuator's forcerange × gear, else the stated default (module docstring)."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    held = np.zeros(model.nv)
    moving = np.zeros(model.nv)  # holding torque + inertia (armature in) × the assumed acceleration
    unit, column, diagonal = np.zeros(model.nv), np.zeros(model.nv), np.zeros(model.nv)
    for _ in range(200):  # over random poses within the limits
        for j in range(model.njnt):
            lo, hi = model.jnt_range[j] if model.jnt_limited[j] else (-np.pi, np.pi)
            data.qpos[model.jnt_qposadr[j]] = rng.uniform(lo, hi)
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        hold = np.abs(data.qfrc_bias - data.qfrc_passive)  # gravity and any spring
        for i in range(model.nv):  # M's columns (mj_mulM: the one signature MuJoCo 3 and 4 share)
            unit[:] = 0.0
            unit[i] = 1.0
            mujoco.mj_mulM(model, data, column, unit)
            diagonal[i] = column[i]
        held = np.maximum(held, hold)
        moving = np.maximum(moving, hold + diagonal * ASSUMED["acceleration_max_rad_per_s2"])
    peaks = np.zeros(len(order))
    for k, j in enumerate(order):
        if model.jnt_actfrclimited[j]:
            peaks[k] = float(np.max(np.abs(model.jnt_actfrcrange[j])))
            continue
        acts = [
            a
            for a in range(model.nu)
            if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
            and model.actuator_trnid[a, 0] == j
            and model.actuator_forcelimited[a]
        ]
        if acts:
            a = acts[0]
            peaks[k] = float(np.max(np.abs(model.actuator_forcerange[a])) * abs(model.actuator_gear[a, 0]))
            continue
        dof = model.jnt_dofadr[j]
        peaks[k] = max(ASSUMED["peak_over_gravity"] * held[dof], moving[dof], ASSUMED["peak_min_nm"])
        assumed.append(
            f"{_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, 'joint')}.peak_torque_nm = {peaks[k]:.4g} (the "
            f"larger of {ASSUMED['peak_over_gravity']} × its largest holding torque and holding plus "
            f"{ASSUMED['acceleration_max_rad_per_s2']:g} rad/s² on its inertia, ≥ {ASSUMED['peak_min_nm']})"
        )
    return peaks


def import_model(path: str | Path) -> ImportedRobot:
    """The robot directory's contents from a MuJoCo model file (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such model file", file=path)
    model, notes = compile_model(path)
    order = serial_hinges(model, path)
    assumed: list[str] = []
    a = ASSUMED
    peaks = _peak_torques(model, order, assumed)
    urdf_velocity = _urdf_velocity_limits(path)  # MuJoCo keeps a URDF's effort, not its velocity
    limits: dict[int, tuple[float, float, float, float]] = {}
    joints = []
    for k, j in enumerate(order):
        jn = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint")
        if model.jnt_limited[j]:
            lo, hi = (float(v) for v in model.jnt_range[j])
        else:
            lo, hi = -a["range_rad"], a["range_rad"]
            assumed.append(f"{jn}: unlimited hinge, limits ±{a['range_rad']:.4g} rad")
        dof = model.jnt_dofadr[j]
        velocity = urdf_velocity.get(jn) or a["velocity_limit_rad_s"]
        damping = float(model.dof_damping[dof])
        if damping * velocity > a["viscous_share"] * peaks[k]:
            # a `damping` that stabilises a simulation (the UR5e's 200 N·m·s/rad on 150 N·m) stops the
            # joint at peak/damping: no speed above it can be commanded, nor held without feed-forward
            velocity = a["viscous_share"] * peaks[k] / damping
            assumed.append(
                f"{jn}: velocity limit {velocity:.4g} rad/s, where its damping ({damping:g} N·m·s/rad) "
                f"needs {a['viscous_share']:g} × its peak torque"
            )
        limits[j] = (lo, hi, velocity, peaks[k])
        if stiffness := float(model.jnt_stiffness[j]):
            rest = float(model.qpos_spring[model.jnt_qposadr[j]])
            notes.append(
                f"{jn}: a spring of {stiffness:g} N·m/rad to {rest:g} rad (MuJoCo `stiffness`), kept by the "
                f"MuJoCo plant; rxcomm's model has no joint spring: up to "
                f"{stiffness * max(abs(lo - rest), abs(hi - rest)):.3g} N·m it cannot explain"
            )
        n = a["gear_ratio"]
        joints.append(
            {
                "name": jn,
                "gear_ratio": n,
                "rotor_inertia_kgm2": float(model.dof_armature[dof]) / n**2,
                "torque_constant_nm_per_a": a["torque_constant_nm_per_a"],
                "winding_resistance_ohm": a["winding_resistance_ohm"],
                "peak_torque_nm": float(peaks[k]),
                "continuous_torque_nm": float(a["continuous_fraction"] * peaks[k]),
                "torque_rate_max_nm_per_s": float(a["torque_rate_per_s"] * peaks[k]),
                "acceleration_max_rad_per_s2": a["acceleration_max_rad_per_s2"],
                "coulomb_friction_nm": float(model.dof_frictionloss[dof]),
                "viscous_friction_nm_s_per_rad": float(model.dof_damping[dof]),
            }
        )
    assumed += [
        f"gear_ratio = {a['gear_ratio']:g} on every joint (rotor inertia = armature / N²)",
        f"torque_constant_nm_per_a = {a['torque_constant_nm_per_a']:g}, "
        f"winding_resistance_ohm = {a['winding_resistance_ohm']:g}",
        (
            "velocity limits from the URDF (lower where listed), "
            if all(joint["name"] in urdf_velocity for joint in joints)
            else f"velocity limit {a['velocity_limit_rad_s']:g} rad/s where the model gives none "
            "(lower where listed), "
        )
        + f"acceleration limit {a['acceleration_max_rad_per_s2']:g} rad/s², torque rate "
        f"{a['torque_rate_per_s']:g} × peak /s",
        f"continuous torque = {a['continuous_fraction']:g} × peak; drive cycle {a['cycle_s'] * 1e6:.0f} µs",
    ]
    last = _name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.jnt_bodyid[order[-1]]), "body")
    assumed.append(f"TCP = the last link's frame ({last}), no tool offset")
    name = Path(path).stem
    drives = {
        "kind": "rxcomm/Drives",
        "schema_version": 1,
        "urdf": f"{name}.urdf",
        "cycle_s": a["cycle_s"],
        "tcp": {"parent_frame": last, "xyz_m": [0.0, 0.0, 0.0], "rpy_rad": [0.0, 0.0, 0.0]},
        "joints": joints,
    }
    return ImportedRobot(
        name=name, urdf=_urdf(model, name, limits), drives=drives, assumed=assumed, notes=notes
    )
