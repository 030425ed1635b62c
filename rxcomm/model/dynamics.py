"""Rigid-body dynamics of the arm with its drives: rotor inertia, friction, torque offset, spring.

Joint torque (joint side, N·m) needed to move along (q, q̇, q̈):

    τ = RNEA(q, q̇, q̈; link inertias) + Rᵀ·diag(J_m)·R·q̈ + Fc·sgn(q̇) + Fv·q̇ + τ_0 + τ_s(q_spring)
        + Rᵀ·(Fc_m·sgn(R·q̇) + Fv_m·R·q̇)

with R = `robot.joint_to_motor` (gear ratios and the wrist coupling), J_m the motor-side rotor
inertias, Fc/Fv Coulomb and viscous friction at the joints, τ_0 a constant offset, τ_s the balancer
spring (`rxcomm.model.spring`) and Fc_m/Fv_m the friction of the motors (motor side, present when
drives.yaml's `friction` is motor or both: `Robot.friction_mode`). A coupled motor (the RX130L's motor
6 turns at 40·(q̇6 + 0.4·q̇5)) loads every joint it turns with, which joint friction cannot express;
an uncoupled motor's friction equals its joint's (scaled by N, N²), and the base-parameter QR
regroups the two. Everything is linear in the parameter vector p of `DynamicParameters`, so
τ = Y(q, q̇, q̈)·p with `joint_torque_regressor`; base parameters live in `rxcomm.model.base_parameters`.

Coulomb friction: `coulomb_eps_rad_s=None` (default) uses the exact sign (identification, simulation
with its own stiction handling); a positive ε uses tanh(q̇/ε), smooth for NLPs. At q̇ = ε it gives
76 % of Fc, at 2ε 96 %; `COULOMB_EPS_NLP_RAD_S` (0.02 rad/s, ≈ 1 °/s) is the value the planners use,
well below any commanded joint speed yet wide enough for IPOPT's derivatives.

Pinocchio conventions throughout: per link the 10 inertial parameters of
`pin.Inertia.toDynamicParameters()` (m, m·c, inertia about the joint frame origin Ixx Ixy Iyy Ixz Iyz
Izz); models evaluated with other parameters are new models (`model_with_inertials`), never a mutated
shared one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.model.robot import Robot
from rxcomm.model.spring import SPRING_PARAMETERS, spring_prior, spring_regressor
from rxcomm.schemas.truth import CellTruth

INERTIAL_PARAMETERS = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
DRIVE_PARAMETERS = ("rotor_inertia", "fc", "fv", "offset")
MOTOR_FRICTION_PARAMETERS = ("fc_motor", "fv_motor")  # motor side: N·m, N·m·s/rad
COULOMB_EPS_NLP_RAD_S = 0.02


def _ro(a, shape: tuple[int, ...] | None = None, what: str = "") -> np.ndarray:
    a = np.array(a, dtype=float)
    if shape is not None and a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    a.setflags(write=False)
    return a


def parameter_names(
    joint_names: tuple[str, ...] | list[str], has_spring: bool, motor_friction: bool = False
) -> tuple[str, ...]:
    """Names of the full parameter vector, in its order: per link the 10 inertials (link-major), then
    per joint rotor inertia, Coulomb, viscous, offset (each a block over joints), then the spring, then
    (with motor friction) per motor Coulomb and viscous friction, motor side (a motor is named by its
    axis: `joint_6.fc_motor`)."""
    names = [f"{j}.{p}" for j in joint_names for p in INERTIAL_PARAMETERS]
    names += [f"{j}.{p}" for p in DRIVE_PARAMETERS for j in joint_names]
    if has_spring:
        names += [f"spring.{p}" for p in SPRING_PARAMETERS]
    if motor_friction:
        names += [f"{j}.{p}" for p in MOTOR_FRICTION_PARAMETERS for j in joint_names]
    return tuple(names)


@dataclass(frozen=True, eq=False)
class DynamicParameters:
    """The full dynamic parameter set of one robot (SI units, joint side unless noted).

    `inertial[i]`: link i's 10 parameters (Pinocchio order, about joint i's frame); `rotor_inertia_kgm2`:
    motor side J_m per axis; `coulomb_nm`, `viscous_nm_s_per_rad`, `offset_nm` per joint; `spring`:
    (k in N/m, k·L0 in N) or None for a robot without balancer; `motor_coulomb_nm`,
    `motor_viscous_nm_s_per_rad` per motor (motor side) or None for a model without motor friction.
    Arrays are read-only copies.
    """

    joint_names: tuple[str, ...]
    inertial: np.ndarray
    rotor_inertia_kgm2: np.ndarray
    coulomb_nm: np.ndarray
    viscous_nm_s_per_rad: np.ndarray
    offset_nm: np.ndarray
    spring: np.ndarray | None = None
    motor_coulomb_nm: np.ndarray | None = None
    motor_viscous_nm_s_per_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "inertial", _ro(self.inertial, (n, 10), "inertial"))
        for f in ("rotor_inertia_kgm2", "coulomb_nm", "viscous_nm_s_per_rad", "offset_nm"):
            object.__setattr__(self, f, _ro(getattr(self, f), (n,), f))
        if self.spring is not None:
            object.__setattr__(self, "spring", _ro(self.spring, (2,), "spring"))
        if (self.motor_coulomb_nm is None) != (self.motor_viscous_nm_s_per_rad is None):
            raise ValueError("motor Coulomb and viscous friction come together (or neither)")
        for f in ("motor_coulomb_nm", "motor_viscous_nm_s_per_rad"):
            if getattr(self, f) is not None:
                object.__setattr__(self, f, _ro(getattr(self, f), (n,), f))

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def has_spring(self) -> bool:
        return self.spring is not None

    @property
    def has_motor_friction(self) -> bool:
        return self.motor_coulomb_nm is not None

    @property
    def names(self) -> tuple[str, ...]:
        return parameter_names(self.joint_names, self.has_spring, self.has_motor_friction)

    def conform(self, robot: Robot) -> DynamicParameters:
        """These parameters in `robot`'s friction model: motor friction added as zeros when the robot
        has it and they do not; refused (InputError) when they have motor friction the robot's model
        lacks (its regressor has no columns for it)."""
        if robot.has_motor_friction == self.has_motor_friction:
            return self
        if self.has_motor_friction:
            if not (np.any(self.motor_coulomb_nm) or np.any(self.motor_viscous_nm_s_per_rad)):
                return replace(self, motor_coulomb_nm=None, motor_viscous_nm_s_per_rad=None)
            raise InputError(
                f"the dynamic parameters have motor friction, robot {robot.name!r} models friction at "
                f"the joints only (drives.yaml friction: {robot.friction_mode})"
            )
        zero = np.zeros(self.n)
        return replace(self, motor_coulomb_nm=zero, motor_viscous_nm_s_per_rad=zero)

    def vector(self) -> np.ndarray:
        """The flat parameter vector p (order of `names`)."""
        parts = [
            self.inertial.ravel(),
            self.rotor_inertia_kgm2,
            self.coulomb_nm,
            self.viscous_nm_s_per_rad,
            self.offset_nm,
        ]
        if self.spring is not None:
            parts.append(self.spring)
        if self.has_motor_friction:
            parts += [self.motor_coulomb_nm, self.motor_viscous_nm_s_per_rad]
        return np.concatenate(parts)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.vector().tolist(), strict=True))

    @classmethod
    def from_vector(
        cls, joint_names: tuple[str, ...], p: np.ndarray, has_spring: bool, motor_friction: bool = False
    ) -> DynamicParameters:
        n = len(joint_names)
        p = np.asarray(p, dtype=float)
        ns = 2 if has_spring else 0
        expected = 14 * n + ns + (2 * n if motor_friction else 0)
        if p.shape != (expected,):
            raise ValueError(f"parameter vector must have shape ({expected},), got {p.shape}")
        blocks = [p[10 * n + k * n : 10 * n + (k + 1) * n] for k in range(4)]
        m0 = 14 * n + ns
        return cls(
            joint_names=joint_names,
            inertial=p[: 10 * n].reshape(n, 10),
            rotor_inertia_kgm2=blocks[0],
            coulomb_nm=blocks[1],
            viscous_nm_s_per_rad=blocks[2],
            offset_nm=blocks[3],
            spring=p[14 * n : 14 * n + 2] if has_spring else None,
            motor_coulomb_nm=p[m0 : m0 + n] if motor_friction else None,
            motor_viscous_nm_s_per_rad=p[m0 + n : m0 + 2 * n] if motor_friction else None,
        )

    @classmethod
    def from_dict(cls, robot: Robot, values: dict[str, float]) -> DynamicParameters:
        """From a name → value mapping holding exactly the robot's parameter names (motor friction
        missing from a model of a robot that has it reads as zero)."""
        names = parameter_names(robot.joint_names, robot.drives.spring is not None, robot.has_motor_friction)
        values = dict(values)
        for nm in names:
            if nm.endswith(MOTOR_FRICTION_PARAMETERS):
                values.setdefault(nm, 0.0)
        if missing := [n for n in names if n not in values]:
            raise InputError(f"missing dynamic parameters {missing[:5]}{'…' if len(missing) > 5 else ''}")
        if extra := [n for n in values if n not in names]:
            raise InputError(f"unknown dynamic parameters {extra[:5]} for robot {robot.name!r}")
        p = np.array([values[n] for n in names])
        return cls.from_vector(
            robot.joint_names, p, robot.drives.spring is not None, robot.has_motor_friction
        )

    def check_robot(self, robot: Robot, friction: bool = True) -> None:
        """Raise InputError unless these parameters describe `robot`'s joints, spring and (unless
        `friction` is False: the simulator takes the true friction whatever the model) friction model."""
        if self.joint_names != robot.joint_names:
            raise InputError(
                f"dynamic parameters are for joints {list(self.joint_names)}, the robot has "
                f"{list(robot.joint_names)}"
            )
        if self.has_spring != (robot.drives.spring is not None):
            raise InputError(
                "dynamic parameters and robot disagree on the balancer spring "
                f"(parameters: {'with' if self.has_spring else 'without'}, drives.yaml: "
                f"{'with' if robot.drives.spring is not None else 'without'})"
            )
        if friction and self.has_motor_friction != robot.has_motor_friction:
            raise InputError(
                "dynamic parameters and robot disagree on motor friction (parameters: "
                f"{'with' if self.has_motor_friction else 'without'}, drives.yaml friction: "
                f"{robot.friction_mode}); use DynamicParameters.conform"
            )


def n_parameters(robot: Robot) -> int:
    return (
        14 * robot.n
        + (2 if robot.drives.spring is not None else 0)
        + (2 * robot.n if robot.has_motor_friction else 0)
    )


def prior_parameters(robot: Robot) -> DynamicParameters:
    """The nominal parameters: URDF inertials, drives.yaml rotor inertias, friction priors and spring;
    torque offsets 0. drives.yaml's friction priors are joint side: with friction "motor" they are
    moved to the motors (Fc/N, Fv/N² per axis), with "both" the motors' own start at 0."""
    m = robot.model
    n = robot.n
    fc, fv = robot.coulomb_prior, robot.viscous_prior
    mfc = mfv = None
    if robot.friction_mode == "motor":
        mfc, mfv = fc / robot.gear_ratio, fv / robot.gear_ratio**2
        fc, fv = np.zeros(n), np.zeros(n)
    elif robot.friction_mode == "both":
        mfc, mfv = np.zeros(n), np.zeros(n)
    return DynamicParameters(
        joint_names=robot.joint_names,
        inertial=np.array([m.inertias[i].toDynamicParameters() for i in range(1, m.njoints)]),
        rotor_inertia_kgm2=robot.rotor_inertia,
        coulomb_nm=fc,
        viscous_nm_s_per_rad=fv,
        offset_nm=np.zeros(n),
        spring=None if robot.drives.spring is None else spring_prior(robot.drives.spring),
        motor_coulomb_nm=mfc,
        motor_viscous_nm_s_per_rad=mfv,
    )


def truth_parameters(robot: Robot, truth: CellTruth) -> DynamicParameters:
    """The simulated cell's true parameters (for the simulator and recovery-scoring tests only)."""
    d = truth.dynamics
    by_link = {link.link: link for link in d.links}
    if sorted(by_link) != sorted(robot.joint_names):
        raise InputError(
            f"truth links {sorted(by_link)} do not match the robot's joints {list(robot.joint_names)}",
            field="dynamics.links",
        )
    inertial = [
        [by_link[j].mass_kg, *by_link[j].first_moment_kgm, *by_link[j].inertia_origin_kgm2]
        for j in robot.joint_names
    ]
    spring = None
    if robot.drives.spring is not None:
        if d.spring_stiffness_n_per_m is None or d.spring_free_length_m is None:
            raise InputError(
                "the robot has a spring: truth needs its stiffness and free length", field="dynamics"
            )
        spring = np.array([d.spring_stiffness_n_per_m, d.spring_stiffness_n_per_m * d.spring_free_length_m])
    for f in (
        "rotor_inertia_kgm2",
        "coulomb_friction_nm",
        "viscous_friction_nm_s_per_rad",
        "torque_offset_nm",
    ):
        if len(getattr(d, f)) != robot.n:
            raise InputError(f"expected {robot.n} values", field=f"dynamics.{f}")
    mfc, mfv = d.motor_coulomb_friction_nm, d.motor_viscous_friction_nm_s_per_rad
    for f, v in (("motor_coulomb_friction_nm", mfc), ("motor_viscous_friction_nm_s_per_rad", mfv)):
        if v is not None and len(v) != robot.n:
            raise InputError(f"expected {robot.n} values (per motor)", field=f"dynamics.{f}")
    if mfc is not None or mfv is not None or robot.has_motor_friction:
        mfc = np.zeros(robot.n) if mfc is None else np.array(mfc)
        mfv = np.zeros(robot.n) if mfv is None else np.array(mfv)
    return DynamicParameters(
        joint_names=robot.joint_names,
        inertial=np.array(inertial),
        rotor_inertia_kgm2=d.rotor_inertia_kgm2,
        coulomb_nm=d.coulomb_friction_nm,
        viscous_nm_s_per_rad=d.viscous_friction_nm_s_per_rad,
        offset_nm=d.torque_offset_nm,
        spring=spring,
        motor_coulomb_nm=mfc,
        motor_viscous_nm_s_per_rad=mfv,
    )


def model_with_inertials(model: pin.Model, inertial: np.ndarray) -> pin.Model:
    """A new Pinocchio model equal to `model` but with link inertias from `inertial` (n × 10).

    Any real values are accepted (a base-parameter model need not be physically consistent), except a
    zero mass, which Pinocchio's (m, c, I_c) storage cannot represent.
    """
    inertial = np.asarray(inertial, dtype=float)
    if inertial.shape != (model.njoints - 1, 10):
        raise ValueError(f"inertial must be ({model.njoints - 1}, 10), got {inertial.shape}")
    if np.any(np.abs(inertial[:, 0]) < 1e-12):
        bad = [model.names[int(i) + 1] for i in np.flatnonzero(np.abs(inertial[:, 0]) < 1e-12)]
        raise InputError(f"link mass is zero for {bad}: cannot build a Pinocchio model")
    new = pin.Model(model)
    for i, pi in enumerate(inertial, start=1):
        new.inertias[i] = pin.Inertia.FromDynamicParameters(pi)
    return new


def coulomb_shape(qd: np.ndarray, eps_rad_s: float | None) -> np.ndarray:
    """sgn(q̇) (exact) or tanh(q̇/ε) (smooth)."""
    if eps_rad_s is None:
        return np.sign(qd)
    if not eps_rad_s > 0:
        raise ValueError("coulomb_eps_rad_s must be positive (or None for the exact sign)")
    return np.tanh(qd / eps_rad_s)


def _as_samples(n: int, *arrays: np.ndarray) -> tuple[tuple[int, ...], list[np.ndarray]]:
    arrs = [np.asarray(a, dtype=float) for a in arrays]
    shape = np.broadcast_shapes(*(a.shape for a in arrs))
    if not shape or shape[-1] != n:
        raise ValueError(f"joint arrays must end in dimension {n}, got shape {shape}")
    return shape[:-1], [np.broadcast_to(a, shape).reshape(-1, n) for a in arrs]


class RobotDynamics:
    """Pinocchio evaluation of one robot with one parameter set: builds the model once, keeps its data.

    Use it for repeated calls (planners, the plant); the free functions below build one per call.
    """

    def __init__(self, robot: Robot, params: DynamicParameters, coulomb_eps_rad_s: float | None = None):
        params.check_robot(robot, friction=False)
        self.robot = robot
        self.params = params
        self.coulomb_eps_rad_s = coulomb_eps_rad_s
        self.model = model_with_inertials(robot.model, params.inertial)
        self.data = self.model.createData()
        r = robot.joint_to_motor
        self.rotor_matrix = _ro(r.T @ np.diag(params.rotor_inertia_kgm2) @ r)
        self._spring_index = robot.spring_joint_index

    def _drive_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray | None) -> np.ndarray:
        """Rotor inertia + friction + offset + spring for (N, n) samples."""
        p = self.params
        tau = (
            p.coulomb_nm * coulomb_shape(qd, self.coulomb_eps_rad_s)
            + p.viscous_nm_s_per_rad * qd
            + p.offset_nm
        )
        if p.has_motor_friction:
            r = self.robot.joint_to_motor
            vm = qd @ r.T  # motor velocities
            # smoothing on the axis's joint scale (ε per joint rad/s), exact sign unchanged
            tau_m = p.motor_coulomb_nm * coulomb_shape(vm / np.abs(np.diag(r)), self.coulomb_eps_rad_s)
            tau = tau + (tau_m + p.motor_viscous_nm_s_per_rad * vm) @ r
        if qdd is not None:
            tau = tau + qdd @ self.rotor_matrix.T
        if self._spring_index is not None:
            k = self._spring_index
            tau[:, k] += spring_regressor(self.robot.drives.spring, q[:, k]) @ p.spring
        return tau

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torque τ (N·m), shape (..., n), for states of shape (..., n)."""
        lead, (q, qd, qdd) = _as_samples(self.robot.n, q, qd, qdd)
        m, d = self.model, self.data
        tau = np.array([pin.rnea(m, d, q[i], qd[i], qdd[i]) for i in range(len(q))]).reshape(-1, self.robot.n)
        tau += self._drive_torque(q, qd, qdd)
        return tau.reshape(*lead, self.robot.n)

    def mass_matrix(self, q) -> np.ndarray:
        """M(q) including the (coupled) rotor inertia, shape (..., n, n)."""
        lead, (q,) = _as_samples(self.robot.n, q)
        out = np.empty((len(q), self.robot.n, self.robot.n))
        for i, qi in enumerate(q):
            mm = pin.crba(self.model, self.data, qi)
            out[i] = np.triu(mm) + np.triu(mm, 1).T + self.rotor_matrix
        return out.reshape(*lead, self.robot.n, self.robot.n)

    def gravity_torque(self, q, include_spring: bool = True) -> np.ndarray:
        """Static holding torque of the links' weight, plus the spring's τ_s unless excluded (N·m)."""
        lead, (q,) = _as_samples(self.robot.n, q)
        tau = np.array([pin.computeGeneralizedGravity(self.model, self.data, qi) for qi in q])
        tau = tau.reshape(-1, self.robot.n)
        if include_spring and self._spring_index is not None:
            k = self._spring_index
            tau[:, k] += spring_regressor(self.robot.drives.spring, q[:, k]) @ self.params.spring
        return tau.reshape(*lead, self.robot.n)

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """q̈ solving M(q)·q̈ + h(q, q̇) = τ (CRBA + full rotor matrix + solve), shape (..., n)."""
        lead, (q, qd, tau) = _as_samples(self.robot.n, q, qd, tau)
        zero = np.zeros(self.robot.n)
        h = np.array([pin.rnea(self.model, self.data, q[i], qd[i], zero) for i in range(len(q))])
        h = h.reshape(-1, self.robot.n) + self._drive_torque(q, qd, None)
        mm = self.mass_matrix(q)
        qdd = np.linalg.solve(mm, (tau - h)[..., None])[..., 0]
        return qdd.reshape(*lead, self.robot.n)


def inverse_dynamics(
    robot: Robot, params: DynamicParameters, q, qd, qdd, coulomb_eps_rad_s=None
) -> np.ndarray:
    """τ(q, q̇, q̈) (N·m), vectorised over leading dimensions. See the module docstring."""
    return RobotDynamics(robot, params, coulomb_eps_rad_s).inverse_dynamics(q, qd, qdd)


def mass_matrix(robot: Robot, params: DynamicParameters, q) -> np.ndarray:
    return RobotDynamics(robot, params).mass_matrix(q)


def gravity_torque(robot: Robot, params: DynamicParameters, q, include_spring: bool = True) -> np.ndarray:
    return RobotDynamics(robot, params).gravity_torque(q, include_spring)


def forward_dynamics(
    robot: Robot, params: DynamicParameters, q, qd, tau, coulomb_eps_rad_s=None
) -> np.ndarray:
    return RobotDynamics(robot, params, coulomb_eps_rad_s).forward_dynamics(q, qd, tau)


def joint_torque_regressor(robot: Robot, q, qd, qdd, coulomb_eps_rad_s=None) -> np.ndarray:
    """Y with τ = Y·p (p = `DynamicParameters.vector()`): shape (N·n, P) for N samples (rows stacked
    sample by sample), or (n, P) for one sample.

    Columns: Pinocchio's joint-torque regressor (10 per link), rotor inertia (column j is
    R[j,:]ᵀ·(R[j,:]·q̈), so coupled motors load several joints), Coulomb, viscous, offset, spring,
    motor Coulomb R[j,:]ᵀ·sgn(R[j,:]·q̇) and viscous R[j,:]ᵀ·(R[j,:]·q̇). With friction "motor" the
    joint friction columns are zero (the base set lists them as unidentifiable).
    """
    n = robot.n
    lead, (q, qd, qdd) = _as_samples(n, q, qd, qdd)
    ns = len(q)
    y = np.zeros((ns, n, n_parameters(robot)))
    m, d = robot.model, robot.create_data()
    for i in range(ns):
        y[i, :, : 10 * n] = pin.computeJointTorqueRegressor(m, d, q[i], qd[i], qdd[i])
    r = robot.joint_to_motor
    # rotor column j: R[j, :]ᵀ · (R[j, :]·q̈)
    y[:, :, 10 * n : 11 * n] = r.T[None, :, :] * (qdd @ r.T)[:, None, :]
    idx = np.arange(n)
    y[:, idx, 11 * n + idx] = coulomb_shape(qd, coulomb_eps_rad_s)
    y[:, idx, 12 * n + idx] = qd
    y[:, idx, 13 * n + idx] = 1.0
    if robot.drives.spring is not None:
        k = robot.spring_joint_index
        y[:, k, 14 * n : 14 * n + 2] = spring_regressor(robot.drives.spring, q[:, k])
    if robot.has_motor_friction:
        m0 = 14 * n + (2 if robot.drives.spring is not None else 0)
        vm = qd @ r.T
        shape = coulomb_shape(vm / np.abs(np.diag(r)), coulomb_eps_rad_s)
        y[:, :, m0 : m0 + n] = r.T[None, :, :] * shape[:, None, :]
        y[:, :, m0 + n : m0 + 2 * n] = r.T[None, :, :] * vm[:, None, :]
        if robot.friction_mode == "motor":
            y[:, :, 11 * n : 13 * n] = 0.0
    return y.reshape(n, -1) if not lead else y.reshape(ns * n, -1)


def random_states(robot: Robot, n_samples: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform random (q, q̇, q̈) within the joint position, velocity and acceleration limits."""
    rng = np.random.default_rng(seed)
    shape = (n_samples, robot.n)
    q = rng.uniform(robot.q_min, robot.q_max, shape)
    qd = rng.uniform(-robot.v_max, robot.v_max, shape)
    qdd = rng.uniform(-robot.a_max, robot.a_max, shape)
    return q, qd, qdd
