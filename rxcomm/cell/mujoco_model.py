"""The MuJoCo model of a truth file: the robot's URDF read by MuJoCo's own parser, the truth put on it.

A second, independent plant (architecture §6.1): nothing here goes through rxcomm's kinematics or
dynamics. MuJoCo parses the robot's model — the MJCF `import-robot` kept beside it (NAME.mujoco.xml)
if there is one, else the URDF — (`mujoco.MjSpec.from_file`, static links kept as bodies, actuators
dropped) and this module edits the spec; a hinge's frame is its body frame moved to the joint
anchor (zero for a URDF):

- geometric errors (truth `geometry.error_parameters`): each joint's body placement in its parent
  becomes placement·exp6(δ_j) — the two rotations off the axis tilt the joint axis, the one about it
  moves the joint's zero, the translations move the body; the base error places the root body,
  exp6(δ_base); the tool error places the TCP site, tcp·exp6(δ_tool). Exact for the truth's model,
  not a first-order approximation. The world frame is the robot's nominal base frame (gravity −z);
  the tracker frame is `tracker_to_base` applied to the site's world pose outside MuJoCo.
- inertials (truth `dynamics.links`: m, m·c, inertia about the joint frame origin) become each joint
  body's mass, centre of mass and full inertia about it (`fullinertia`); bodies fixed to a joint body
  lose theirs (the truth's link already holds them, as Pinocchio merges fixed links).
- friction: joint Coulomb → `frictionloss` (MuJoCo's dry-friction constraint), viscous → `damping`.
- rotor inertia: an uncoupled motor i turning joint j at r_ij·q̇_j → `armature` r_ij²·J_i on joint j;
  a coupled motor (RX130L: motor 6 at 40·(q̇6 + 0.4·q̇5)) → a fixed tendon Σ r_ij·q_j with
  `armature` J_i, so its inertia couples the joints it turns (Rᵀ·J·R exactly), and its own friction
  (truth `motor_*_friction`) → that tendon's `frictionloss` / `damping` (motor side, N·m); an
  uncoupled motor's friction adds |r_ij|·Fc_m, r_ij²·Fv_m to its joint's.
- the axis-2 balancing spring → a spatial tendon between a site on the parent body (distance a from
  the joint axis, in the plane of the joint origin) and one on the child (distance b, turned by the
  spring's angle offset), `stiffness` k and `springlength` L0: MuJoCo computes its length and lever
  from the two sites, L(θ) = √(a² + b² − 2ab·cos θ) is not coded anywhere here.
- joint compliance (truth `joint_stiffness_nm_per_rad`) → a second hinge on the same body and axis
  after the motor hinge, `stiffness` k: the motor hinge carries the encoder, armature, friction and
  the drive torque; the link turns by both, so it deflects under the dynamic torque too.
- the TCP → a site `tcp` on the flange body: the tracker reads it.

No faithful MuJoCo form (the plant says so at start-up, `MujocoPlantModel.notes`):
- the torque offset τ_0 is a constant generalised force on the motor hinge (`qfrc_applied`);
- a compliant joint's transmission damping is not in the truth; an undamped hinge would ring for
  ever, so it gets ζ = `COMPLIANCE_DAMPING_RATIO` (at the link inertia of the initial pose);
- MuJoCo's friction is a soft constraint: it slides at exactly F_c but sticks with a creep, not the
  own plant's exact stiction (`FRICTION_SOLREF_CYCLES`, `FRICTION_SOLIMP` make it stiff);
- a brake is a joint-equality lock to the braked angle (the own plant: friction + 2·peak torque).

Left out: a body's `gravcomp` (MuJoCo's gravity compensation, a simulation's stand-in for a
controller's): the truth's arm has its weight at its joints, as import-robot sized its drives.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from rxcomm.cell.truth import SimTruth
from rxcomm.errors import InputError
from rxcomm.model.geometric_errors import ErrorModel, placement_to_se3
from rxcomm.model.mjcf_import import (
    compile_without_absent_meshes,
    gravity_compensated_bodies,
    gravity_compensation_note,
)

COMPLIANCE_DAMPING_RATIO = 0.05  # assumed: the truth gives no transmission damping
FRICTION_SOLREF_CYCLES = 2.0  # friction constraint time constant, in integration steps (MuJoCo's minimum)
FRICTION_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
TCP_SITE = "tcp"
COMPLIANCE_SUFFIX = "__link"
BRAKE_SUFFIX = "__brake"


@dataclass(frozen=True, eq=False)
class MujocoPlantModel:
    """The compiled model and where rxcomm's joints live in it."""

    model: mujoco.MjModel
    spec: mujoco.MjSpec
    joint_names: tuple[str, ...]
    motor_qpos: np.ndarray  # (n,) qpos address of each motor hinge (the encoder side)
    motor_dof: np.ndarray  # (n,) dof address of each motor hinge
    compliance_qpos: np.ndarray  # (n,) qpos address of the link hinge, −1 for a rigid joint
    compliance_dof: np.ndarray  # (n,) dof address of the link hinge, −1 for a rigid joint
    tcp_site: int
    brake_eq: np.ndarray  # (n,) equality id of each joint's brake lock
    tracker_to_base: pin.SE3
    notes: tuple[str, ...]

    def xml(self) -> str:
        """The model as MJCF (what MuJoCo compiled; for inspection and the robot directory)."""
        return self.spec.to_xml()


def _se3(body) -> pin.SE3:
    rot = np.zeros(9)
    quat = np.array(body.quat, dtype=float)
    mujoco.mju_quat2Mat(rot, quat / np.linalg.norm(quat))
    return pin.SE3(rot.reshape(3, 3), np.array(body.pos, dtype=float))


def _shift(a: np.ndarray) -> pin.SE3:
    return pin.SE3(np.eye(3), np.asarray(a, dtype=float))


MJCF_SOURCE_SUFFIX = ".mujoco.xml"


def model_source(robot_dir: Path, urdf: Path) -> Path:
    """The file MuJoCo parses: the MJCF `import-robot` kept beside the robot (NAME.mujoco.xml), else
    the URDF."""
    kept = sorted(Path(robot_dir).glob(f"*{MJCF_SOURCE_SUFFIX}"))
    return kept[0] if kept else Path(urdf)


def _load_spec(source: Path) -> tuple[mujoco.MjSpec, list[str]]:
    """MuJoCo's spec of `source`, static links kept, its actuators, keyframes and sensors dropped,
    every body's placement the compiled one as a quaternion (an MJCF's Euler angles, axis-angles or
    degrees resolved by MuJoCo's compiler), and no body's gravity compensated (the names of those that
    were: `gravity_compensated_bodies`)."""
    try:
        spec = mujoco.MjSpec.from_file(str(source))
        spec.compiler.fusestatic = False
        spec.compiler.discardvisual = True
        # The drives act here: the model's own actuators go, and with them what refers to them
        # (keyframes hold a ctrl per actuator, sensors may read one); the cell sets its own state.
        for element in [*spec.actuators, *spec.keys, *spec.sensors]:
            spec.delete(element)
    except ValueError as e:
        raise InputError(f"MuJoCo cannot load it: {e}", file=source) from e
    # as import-robot read it: a model kept without its mesh files loses those geoms (no contacts here)
    compiled, _ = compile_without_absent_meshes(spec, source)
    compensated = gravity_compensated_bodies(compiled)
    for body in spec.bodies:  # as import-robot read it: the arm has its weight (gravcomp left out)
        body.gravcomp = 0.0
    for i, body in enumerate(spec.bodies):  # the spec's body order is the compiled model's
        if i > 0:
            body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
            body.pos, body.quat = compiled.body_pos[i].copy(), compiled.body_quat[i].copy()
    return spec, compensated


def _set_placement(element, m: pin.SE3) -> None:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(m.rotation).reshape(-1))
    element.pos = m.translation.copy()
    element.quat = quat


def _inertial(body, pi: np.ndarray, anchor: np.ndarray) -> None:
    """Pinocchio's (m, m·c, I about the frame origin: xx xy yy xz yz zz) as MuJoCo's mass, ipos and
    full inertia about the centre of mass (xx yy zz xy xz yz)."""
    m, mc = float(pi[0]), np.asarray(pi[1:4], dtype=float)
    xx, xy, yy, xz, yz, zz = (float(v) for v in pi[4:10])
    c = mc / m
    i_o = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    i_c = i_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    body.explicitinertial = True
    body.mass = m
    body.ipos = c + anchor  # the truth's link frame sits at the joint anchor
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.inertia = [0.0, 0.0, 0.0]  # a source MJCF's diaginertia: the full one below replaces it
    body.fullinertia = [i_c[0, 0], i_c[1, 1], i_c[2, 2], i_c[0, 1], i_c[0, 2], i_c[1, 2]]


def _joint_bodies(spec: mujoco.MjSpec, names: tuple[str, ...]) -> list:
    bodies = []
    for name in names:
        joint = spec.joint(name)
        if joint is None:
            raise InputError(f"MuJoCo's URDF import has no joint {name!r}", field="joints")
        bodies.append(joint.parent)
    return bodies


def _root_body(spec: mujoco.MjSpec):
    roots = [b for b in spec.bodies if b.parent is not None and b.parent.name == "world"]
    if len(roots) != 1:
        raise InputError(f"expected one root link, MuJoCo found {[b.name for b in roots]}", field="urdf")
    return roots[0]


def build_mujoco_model(
    truth: SimTruth,
    *,
    timestep_s: float | None = None,
    errors: bool = True,
    compliance: bool = True,
    q0_rad: np.ndarray | None = None,
) -> MujocoPlantModel:
    """Compile the MuJoCo model of `truth` (see the module docstring). `errors=False` leaves the
    nominal kinematics; `compliance=False` the joints rigid (both for the checks against rxcomm's
    own dynamics). `q0_rad` is where the compliance damping is sized (default all zero)."""
    robot, params = truth.robot, truth.params
    source = model_source(robot.drives_path.parent, robot.urdf_path)
    spec, compensated = _load_spec(source)
    h = robot.drives.cycle_s if timestep_s is None else timestep_s
    spec.option.timestep = h
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    spec.option.gravity = [0.0, 0.0, -9.81]
    names = robot.joint_names
    bodies = _joint_bodies(spec, names)
    joint_bodies = {b.name for b in bodies}
    root = _root_body(spec)
    for b in spec.bodies:  # fixed links: their inertia is in the truth's link already
        if b.name not in joint_bodies and b.name != "world" and b is not root:
            b.explicitinertial = True
            b.mass, b.ipos, b.fullinertia = 0.0, [0.0, 0.0, 0.0], [float("nan")] * 6
            b.inertia = [0.0, 0.0, 0.0]
    anchors = [np.array(spec.joint(n).pos, dtype=float) for n in names]
    for body, pi, a in zip(bodies, params.inertial, anchors, strict=True):
        _inertial(body, pi, a)
    g = truth.truth.geometry
    err = ErrorModel.from_mapping(
        robot, g.error_parameters if errors else {}, field="geometry.error_parameters"
    )
    if errors:
        _set_placement(root, pin.exp6(err.twist("base")) * _se3(root))
        for body, name, a in zip(bodies, names, anchors, strict=True):  # exp6 at the joint frame
            _set_placement(body, _se3(body) * _shift(a) * pin.exp6(err.twist(name)) * _shift(-a))
    tcp = robot.drives.tcp
    flange = spec.body(tcp.parent_frame)
    if flange is None:
        raise InputError(f"no body {tcp.parent_frame!r} in MuJoCo's model", field="tcp.parent_frame")
    site = flange.add_site(name=TCP_SITE)
    at = _shift(anchors[bodies.index(flange)]) if flange in bodies else pin.SE3.Identity()
    _set_placement(site, at * placement_to_se3(tcp.xyz_m, tcp.rpy_rad) * pin.exp6(err.twist("tool")))
    notes = [f"model source: {source.name} (MuJoCo's parser)"] if source != robot.urdf_path else []
    if compensated:
        notes.append(gravity_compensation_note(compensated))
    notes += ["torque offset τ_0: no MuJoCo element, a constant generalised force on each motor hinge"]
    notes.append("brakes: a joint-equality lock at the braked angle (own plant: friction + 2·peak torque)")
    notes.append(
        "Coulomb friction: MuJoCo's soft constraint slides at F_c, sticks with a slow creep (own: exact)"
    )
    _drives(spec, robot, params, h, notes)
    if robot.drives.spring is not None and params.spring is not None:
        _spring(spec, robot, params, bodies, anchors)
    stiff = dict(g.joint_stiffness_nm_per_rad) if compliance else {}
    for name, k in stiff.items():
        if name not in names or not k > 0:
            raise InputError(
                f"{name!r}: needs a joint of {list(names)} and k > 0",
                field="geometry.joint_stiffness_nm_per_rad",
            )
        motor = spec.joint(name)
        bodies[names.index(name)].add_joint(
            name=name + COMPLIANCE_SUFFIX,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=list(motor.axis),
            pos=list(motor.pos),
            stiffness=_coef(k),
        )
    model = spec.compile()
    if stiff:
        notes.append(
            f"joint compliance: transmission damping not in the truth; ζ = {COMPLIANCE_DAMPING_RATIO} assumed"
        )
        _compliance_damping(spec, model, names, stiff, q0_rad)
        model = spec.compile()
    return _mapped(model, spec, robot, stiff, g, notes)


def _drives(spec, robot, params, h: float, notes: list[str]) -> None:
    names = robot.joint_names
    r = robot.joint_to_motor
    armature = np.zeros(robot.n)
    fc = np.array(params.coulomb_nm, dtype=float)
    fv = np.array(params.viscous_nm_s_per_rad, dtype=float)
    mfc = np.zeros(robot.n) if params.motor_coulomb_nm is None else np.array(params.motor_coulomb_nm)
    mfv = (
        np.zeros(robot.n)
        if params.motor_viscous_nm_s_per_rad is None
        else np.array(params.motor_viscous_nm_s_per_rad)
    )
    solref = [FRICTION_SOLREF_CYCLES * h, 1.0]
    for i in range(robot.n):
        turns = np.flatnonzero(r[i])
        if len(turns) == 1:
            j = int(turns[0])
            armature[j] += r[i, j] ** 2 * params.rotor_inertia_kgm2[i]
            fc[j] += abs(r[i, j]) * mfc[i]
            fv[j] += r[i, j] ** 2 * mfv[i]
            continue
        tendon = spec.add_tendon(name=f"motor_{i + 1}")
        for j in turns:
            tendon.wrap_joint(names[j], float(r[i, j]))
        tendon.armature = float(params.rotor_inertia_kgm2[i])
        tendon.frictionloss = float(mfc[i])
        tendon.damping = _coef(mfv[i])
        tendon.solref_friction = solref
        tendon.solimp_friction = list(FRICTION_SOLIMP)
    for j, name in enumerate(names):
        joint = spec.joint(name)
        joint.armature = float(armature[j])
        joint.frictionloss = float(fc[j])
        joint.damping = _coef(fv[j])
        joint.stiffness = _coef(0.0)  # a source MJCF's own joint springs are not the truth's
        joint.solref_friction = solref
        joint.solimp_friction = list(FRICTION_SOLIMP)
        joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE  # the drives keep the limits, as on our plant
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        brake = spec.add_equality(name=name + BRAKE_SUFFIX, type=mujoco.mjtEq.mjEQ_JOINT, name1=name)
        brake.objtype = mujoco.mjtObj.mjOBJ_JOINT
        brake.active = False  # the plant engages it (the braked angle in its polycoef) on disable
        brake.solref = [FRICTION_SOLREF_CYCLES * h, 1.0]
        brake.solimp = list(FRICTION_SOLIMP)


def _coef(value: float) -> list[float]:
    """A linear stiffness or damping as MuJoCo ≥ 4's spec takes it (linear term, two higher ones 0)."""
    return [float(value), 0.0, 0.0]


def _perpendicular(axis: np.ndarray) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - (helper @ a) * a
    return u / np.linalg.norm(u)


def _spring(spec, robot, params, bodies, anchors) -> None:
    """The balancer as a spatial tendon between its pivots (module docstring)."""
    s = robot.drives.spring
    k = robot.spring_joint_index
    child = bodies[k]
    joint = spec.joint(robot.joint_names[k])
    axis = np.array(joint.axis, dtype=float)
    axis /= np.linalg.norm(axis)
    u = _perpendicular(axis)
    moving = anchors[k] + pin.AngleAxis(s.angle_offset_rad, axis).matrix() @ (s.moving_pivot_m * u)
    placement = _se3(child) * _shift(anchors[k])  # the joint frame in the parent (errors included)
    fixed = placement.act(s.fixed_pivot_m * u)
    child.parent.add_site(name="spring_fixed_pivot", pos=fixed.tolist())
    child.add_site(name="spring_moving_pivot", pos=moving.tolist())
    tendon = spec.add_tendon(name="balancer_spring")
    tendon.wrap_site("spring_fixed_pivot")
    tendon.wrap_site("spring_moving_pivot")
    stiffness, k_l0 = float(params.spring[0]), float(params.spring[1])
    tendon.stiffness = _coef(stiffness)
    tendon.springlength = [k_l0 / stiffness, k_l0 / stiffness]


def _compliance_damping(spec, model, names, stiff: dict[str, float], q0_rad) -> None:
    data = mujoco.MjData(model)
    if q0_rad is not None:
        for name, q in zip(names, q0_rad, strict=True):
            data.qpos[model.joint(name).qposadr[0]] = q
    mujoco.mj_forward(model, data)
    for name, k in stiff.items():
        dof = model.joint(name + COMPLIANCE_SUFFIX).dofadr[0]
        unit, column = np.zeros(model.nv), np.zeros(model.nv)
        unit[dof] = 1.0
        mujoco.mj_mulM(model, data, column, unit)  # the link's inertia about its axis: M[dof, dof]
        spec.joint(name + COMPLIANCE_SUFFIX).damping = _coef(
            2.0 * COMPLIANCE_DAMPING_RATIO * np.sqrt(k * column[dof])
        )


def _mapped(model, spec, robot, stiff, g, notes) -> MujocoPlantModel:
    names = robot.joint_names
    motor_qpos = np.array([model.joint(n).qposadr[0] for n in names])
    motor_dof = np.array([model.joint(n).dofadr[0] for n in names])
    cq = np.full(robot.n, -1)
    cd = np.full(robot.n, -1)
    for name in stiff:
        j = names.index(name)
        cq[j] = model.joint(name + COMPLIANCE_SUFFIX).qposadr[0]
        cd[j] = model.joint(name + COMPLIANCE_SUFFIX).dofadr[0]
    return MujocoPlantModel(
        model=model,
        spec=spec,
        joint_names=names,
        motor_qpos=motor_qpos,
        motor_dof=motor_dof,
        compliance_qpos=cq,
        compliance_dof=cd,
        tcp_site=model.site(TCP_SITE).id,
        brake_eq=np.array([model.equality(n + BRAKE_SUFFIX).id for n in names]),
        tracker_to_base=placement_to_se3(g.tracker_to_base.xyz_m, g.tracker_to_base.rpy_rad),
        notes=tuple(notes),
    )
