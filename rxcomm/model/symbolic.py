"""The inverse dynamics of `rxcomm.model.dynamics` and the TCP forward kinematics, in CasADi.

The PyPI Pinocchio has no `pinocchio.casadi`, so the recursive Newton–Euler algorithm is written here
once from the Pinocchio model's joint placements and axes. Link inertias enter as the 10 dynamic
parameters (m, m·c, I about the joint origin), which the spatial inertia is linear in, so a parameter
vector may be numeric (a `DynamicParameters`, e.g. identified: planners) or symbolic (an input `p`:
the regressor is then ∂τ/∂p, exactly, since τ is linear in p).

Functions name their inputs and outputs: `q`, `qd`, `qdd` (and `p`) → `tau`; `q` → `p`, `R`.
Coulomb friction: exact sign by default; pass `coulomb_eps_rad_s` (e.g.
`rxcomm.model.dynamics.COULOMB_EPS_NLP_RAD_S`) for the smooth tanh(q̇/ε) NLPs need.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from rxcomm.errors import InputError
from rxcomm.model.dynamics import DynamicParameters, n_parameters
from rxcomm.model.robot import Robot

_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}


def joint_axes(robot: Robot) -> list[np.ndarray]:
    """Unit rotation axis of each joint in its own frame."""
    axes = []
    for i in range(1, robot.model.njoints):
        j = robot.model.joints[i]
        name = j.shortname()
        if name in _AXES:
            axes.append(np.array(_AXES[name]))
        elif name == "JointModelRevoluteUnaligned":
            axes.append(np.asarray(j.extract().axis, dtype=float))
        else:
            raise InputError(f"joint {robot.model.names[i]!r} of type {name} is not a revolute joint")
    return axes


def _rotation(axis: np.ndarray, q):
    """Rotation by angle q about a unit axis (Rodrigues), with the zeros of a principal axis kept exact."""
    c, s = ca.cos(q), ca.sin(q)
    x, y, z = (float(v) for v in axis)
    k = ca.DM([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return ca.DM.eye(3) + s * k + (1.0 - c) * ca.DM(np.outer(axis, axis) - np.eye(3))


def _spatial_inertia_times(pi, v, w):
    """(f, n) = I·(v, ω) for dynamic parameters pi = (m, h, Ixx, Ixy, Iyy, Ixz, Iyz, Izz) about the origin."""
    m = pi[0]
    h = ca.vertcat(pi[1], pi[2], pi[3])
    i_o = ca.vertcat(
        ca.horzcat(pi[4], pi[5], pi[7]),
        ca.horzcat(pi[5], pi[6], pi[8]),
        ca.horzcat(pi[7], pi[8], pi[9]),
    )
    return m * v - ca.cross(h, w), ca.cross(h, v) + ca.mtimes(i_o, w)


def rnea_expr(robot: Robot, q, qd, qdd, inertial):
    """Rigid-body joint torques (links only) as a CasADi expression. `inertial` indexes as
    inertial[link][k] (numeric n × 10 array, or a symbolic vector reshaped by the caller)."""
    model = robot.model
    axes = joint_axes(robot)
    n = robot.n
    g = np.asarray(model.gravity.linear, dtype=float)
    v_par, w_par = ca.DM.zeros(3), ca.DM.zeros(3)
    a_par, al_par = ca.DM(-g), ca.DM.zeros(3)  # base acceleration: −gravity (linear part)
    rot, trans, forces = [], [], []
    for i in range(n):
        pl = model.jointPlacements[i + 1]
        if model.parents[i + 1] != i:
            raise InputError("only serial chains are supported", field="joint")
        r = ca.mtimes(ca.DM(pl.rotation), _rotation(axes[i], q[i]))
        t = ca.DM(pl.translation)
        ax = ca.DM(axes[i])
        rt = r.T
        w = ca.mtimes(rt, w_par) + ax * qd[i]
        v = ca.mtimes(rt, v_par + ca.cross(w_par, t))
        al = ca.mtimes(rt, al_par) + ax * qdd[i] + ca.cross(w, ax * qd[i])
        # Pinocchio's spatial (not classical) acceleration: a_i = X·a_par + S·q̈ + v_i × S·q̇;
        # the linear part of v_i × S·q̇ is v × (axis·q̇).
        a = ca.mtimes(rt, a_par + ca.cross(al_par, t)) + ca.cross(v, ax * qd[i])
        f_i, n_i = _spatial_inertia_times(inertial[i], a, al)
        fv, nv = _spatial_inertia_times(inertial[i], v, w)
        f_i = f_i + ca.cross(w, fv)
        n_i = n_i + ca.cross(w, nv) + ca.cross(v, fv)
        rot.append(r)
        trans.append(t)
        forces.append([f_i, n_i])
        v_par, w_par, a_par, al_par = v, w, a, al
    tau = [None] * n
    for i in reversed(range(n)):
        f_i, n_i = forces[i]
        tau[i] = ca.dot(ca.DM(axes[i]), n_i)
        if i > 0:
            f_p = ca.mtimes(rot[i], f_i)
            forces[i - 1][0] = forces[i - 1][0] + f_p
            forces[i - 1][1] = forces[i - 1][1] + ca.mtimes(rot[i], n_i) + ca.cross(trans[i], f_p)
    return ca.vertcat(*tau)


def _coulomb(qd, eps):
    if eps is None:
        return ca.sign(qd)
    if not eps > 0:
        raise ValueError("coulomb_eps_rad_s must be positive (or None for the exact sign)")
    return ca.tanh(qd / eps)


def inverse_dynamics_expr(robot: Robot, q, qd, qdd, p, coulomb_eps_rad_s: float | None = None):
    """τ(q, q̇, q̈; p), p the flat vector of `DynamicParameters.vector()` (numeric or symbolic)."""
    n = robot.n
    if isinstance(p, DynamicParameters):
        p = p.conform(robot)
        p.check_robot(robot)
        p = p.vector()
    if p.shape[0] != n_parameters(robot):
        raise ValueError(f"parameter vector must have {n_parameters(robot)} entries, got {p.shape[0]}")
    inertial = [[p[10 * i + k] for k in range(10)] for i in range(n)]
    tau = rnea_expr(robot, q, qd, qdd, inertial)
    r = ca.DM(robot.joint_to_motor)
    j_m = ca.vertcat(*[p[10 * n + i] for i in range(n)])
    tau = tau + ca.mtimes(r.T, j_m * ca.mtimes(r, qdd))
    block = [ca.vertcat(*[p[10 * n + k * n + i] for i in range(n)]) for k in range(1, 4)]
    tau = tau + _joint_coulomb(robot, qd, p, coulomb_eps_rad_s) + block[1] * qd + block[2]
    spring = robot.drives.spring
    if spring is not None:
        k = robot.spring_joint_index
        a, b = spring.fixed_pivot_m, spring.moving_pivot_m
        theta = q[k] + spring.angle_offset_rad
        length = ca.sqrt(a * a + b * b - 2.0 * a * b * ca.cos(theta))
        ab_sin = a * b * ca.sin(theta)
        tau_s = ab_sin * p[14 * n] - ab_sin / length * p[14 * n + 1]
        tau = tau + ca.vertcat(*[tau_s if i == k else 0.0 for i in range(n)])
    if robot.has_motor_friction:  # Rᵀ·(Fc_m·sgn(R·q̇) + Fv_m·R·q̇)
        fv_m = ca.vertcat(*[p[_motor_friction_offset(robot) + n + i] for i in range(n)])
        vm = ca.mtimes(r, qd)
        tau = tau + ca.mtimes(r.T, _motor_coulomb(robot, vm, p, coulomb_eps_rad_s) + fv_m * vm)
    return tau


def _motor_friction_offset(robot: Robot) -> int:
    return 14 * robot.n + (2 if robot.drives.spring is not None else 0)


def _joint_coulomb(robot: Robot, qd, p, eps):
    return ca.vertcat(*[p[11 * robot.n + i] for i in range(robot.n)]) * _coulomb(qd, eps)


def _motor_coulomb(robot: Robot, vm, p, eps):
    """Fc_m·sgn(v_m) at the motor speeds v_m = R·q̇ (ε on the axis's joint scale)."""
    fc_m = ca.vertcat(*[p[_motor_friction_offset(robot) + i] for i in range(robot.n)])
    return fc_m * _coulomb(vm / ca.DM(np.abs(np.diag(robot.joint_to_motor))), eps)


def coulomb_torque_expr(robot: Robot, qd, p, coulomb_eps_rad_s: float | None = None):
    """The Coulomb-friction part of `inverse_dynamics_expr`: Fc·sgn(q̇), plus Rᵀ·Fc_m·sgn(R·q̇) with
    motor friction; p the flat parameter vector (numeric or symbolic), sgn smoothed as there."""
    p = p.conform(robot).vector() if isinstance(p, DynamicParameters) else p
    tau = _joint_coulomb(robot, qd, p, coulomb_eps_rad_s)
    if robot.has_motor_friction:
        r = ca.DM(robot.joint_to_motor)
        tau = tau + ca.mtimes(r.T, _motor_coulomb(robot, ca.mtimes(r, qd), p, coulomb_eps_rad_s))
    return tau


def _states(n: int):
    return ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)


def inverse_dynamics_function(
    robot: Robot, params: DynamicParameters, coulomb_eps_rad_s: float | None = None
) -> ca.Function:
    """CasADi Function `inverse_dynamics(q, qd, qdd) -> tau` for fixed (e.g. identified) parameters."""
    q, qd, qdd = _states(robot.n)
    tau = inverse_dynamics_expr(robot, q, qd, qdd, params, coulomb_eps_rad_s)
    return ca.Function("inverse_dynamics", [q, qd, qdd], [tau], ["q", "qd", "qdd"], ["tau"])


def parametric_inverse_dynamics_function(robot: Robot, coulomb_eps_rad_s: float | None = None) -> ca.Function:
    """`inverse_dynamics_p(q, qd, qdd, p) -> tau` with the parameter vector as an input."""
    q, qd, qdd = _states(robot.n)
    p = ca.SX.sym("p", n_parameters(robot))
    tau = inverse_dynamics_expr(robot, q, qd, qdd, p, coulomb_eps_rad_s)
    return ca.Function("inverse_dynamics_p", [q, qd, qdd, p], [tau], ["q", "qd", "qdd", "p"], ["tau"])


def regressor_function(robot: Robot, coulomb_eps_rad_s: float | None = None) -> ca.Function:
    """`regressor(q, qd, qdd) -> Y` (n × P) with τ = Y·p, the same columns as
    `rxcomm.model.dynamics.joint_torque_regressor` (e.g. for the excitation NLP)."""
    q, qd, qdd = _states(robot.n)
    p = ca.SX.sym("p", n_parameters(robot))
    tau = inverse_dynamics_expr(robot, q, qd, qdd, p, coulomb_eps_rad_s)
    y = ca.substitute(ca.jacobian(tau, p), p, ca.DM.zeros(p.shape[0]))  # τ is linear in p
    return ca.Function("regressor", [q, qd, qdd], [y], ["q", "qd", "qdd"], ["Y"])


def frame_placement_expr(robot: Robot, q, frame_id: int | None = None):
    """(position (3), rotation (3 × 3)) of a frame (default: the TCP) in the base frame."""
    model = robot.model
    frame_id = robot.tcp_frame_id if frame_id is None else frame_id
    axes = joint_axes(robot)
    frame = model.frames[frame_id]
    rot, pos = ca.DM.eye(3), ca.DM.zeros(3)
    for i in range(frame.parentJoint):
        pl = model.jointPlacements[i + 1]
        pos = pos + ca.mtimes(rot, ca.DM(pl.translation))
        rot = ca.mtimes(rot, ca.mtimes(ca.DM(pl.rotation), _rotation(axes[i], q[i])))
    pos = pos + ca.mtimes(rot, ca.DM(frame.placement.translation))
    rot = ca.mtimes(rot, ca.DM(frame.placement.rotation))
    return pos, rot


def forward_kinematics_function(robot: Robot, frame_id: int | None = None) -> ca.Function:
    """CasADi Function `fk(q) -> (p, R)`: position (m) and rotation of a frame (default the TCP)."""
    q = ca.SX.sym("q", robot.n)
    pos, rot = frame_placement_expr(robot, q, frame_id)
    return ca.Function("fk", [q], [pos, rot], ["q"], ["p", "R"])
