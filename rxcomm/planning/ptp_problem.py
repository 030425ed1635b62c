"""The point-to-point problem (paper §5.4): its options, limits, dynamics, node guesses and solution.

Shared by the OCP transcription (`ptp_ocp`), the planner that samples and checks it (`ptp`) and the
forward-dynamics shooting peer (`ptp_shooting`), so none of them imports another for its inputs.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S, DynamicParameters, prior_parameters
from rxcomm.model.energy import BusPowerModel
from rxcomm.model.limits import (
    AccelerationLimit,
    PositionLimit,
    TorqueLimit,
    TorqueRateLimit,
    VelocityLimit,
)
from rxcomm.model.robot import Robot
from rxcomm.model.symbolic import coulomb_torque_expr, forward_kinematics_function, inverse_dynamics_function
from rxcomm.planning.warm_start import KinematicProfile

Vec3 = tuple[float, float, float]


PTP_COULOMB_EPS_RAD_S = 0.1  # friction smoothing of the PtP model (module doc)


class PtpOptions(BaseModel):
    """Settings of the PtP OCP (units in the names)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_intervals: int = Field(50, ge=4, le=2000, description="N, jerk intervals of the normalised time")
    k1: float = Field(1.0, ge=0, description="weight of time in ∫(k1 + k2·τᵀτ)dt (dimensionless)")
    k2_per_nm2: float = Field(0.0, ge=0, description="weight of τᵀτ in ∫(k1 + k2·τᵀτ)dt, 1/(N·m)²")
    margin: float = Field(
        0.01,
        ge=0,
        lt=0.5,
        description="the NLP uses (1 − margin)·limit so the dense check passes between nodes",
    )
    acceleration_limits: bool = Field(
        False, description="also limit |q̈| ≤ a_max (the paper's PtP limits torque, not acceleration)"
    )
    tcp_box_m: tuple[Vec3, Vec3] | None = Field(
        None, description="(min, max) corners of a box in the base frame the TCP must stay in, m"
    )
    max_iter: int = Field(3000, ge=1, description="IPOPT iteration cap")
    max_wall_s: float | None = Field(None, gt=0, description="IPOPT wall-time cap, s")
    tol: float = Field(1e-6, gt=0, description="IPOPT relative tolerance")
    compile: bool | None = Field(
        None,
        description="the node functions as C (rxcomm.casadi_build, cached per content): None (default) "
        "compiled unoptimised (-O0, ~1 s once; derivatives ~5× faster than CasADi's virtual machine), "
        "True optimised (-O1, ~1 min once, ~2× faster again), False never; without a C compiler the "
        "virtual machine, with a warning",
    )
    hessian: Literal["exact", "limited-memory"] = Field(
        "exact", description="IPOPT's Hessian: exact (assembled from the nodes) or its L-BFGS approximation"
    )
    objective: Literal["torque", "energy"] = Field(
        "torque",
        description="torque: ∫(k1 + k2·τᵀτ)dt; energy: the electrical energy drawn from the bus (`bus`) "
        "at the fixed duration_s",
    )
    bus: BusPowerModel | None = Field(None, description="the bus power of the energy objective")
    duration_s: float | None = Field(None, gt=0, description="fixed duration, s (energy objective)")

    @model_validator(mode="after")
    def _objective(self) -> PtpOptions:
        if self.objective == "energy" and (self.bus is None or self.duration_s is None):
            raise ValueError("the energy objective needs the bus power model and a duration")
        if self.duration_s is not None and self.objective != "energy":
            raise ValueError("a fixed duration is for the energy objective")
        if self.k1 == 0 and self.k2_per_nm2 == 0 and self.objective != "energy":
            raise ValueError("k1 and k2_per_nm2 are both 0: nothing to minimise")
        if self.tcp_box_m is not None and not all(a < b for a, b in zip(*self.tcp_box_m, strict=True)):
            raise ValueError("tcp_box_m: every min must be below its max")
        return self


@dataclass(frozen=True, eq=False)
class PtpLimits:
    """The joint-space limits a PtP motion obeys (joint side, SI units)."""

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    tau_max: np.ndarray
    tau_rate_max: np.ndarray
    a_max: np.ndarray | None = None

    @classmethod
    def from_robot(cls, robot: Robot, acceleration: bool = False) -> PtpLimits:
        return cls(
            robot.q_min, robot.q_max, robot.v_max, robot.tau_max, robot.tau_rate_max,
            robot.a_max if acceleration else None,
        )  # fmt: skip

    def dense_checks(self) -> list:
        """The limit objects of `rxcomm.model.limits` for the dense check (the same set the NLP obeys)."""
        lims = [PositionLimit(self.q_min, self.q_max), VelocityLimit(self.v_max)]
        if self.a_max is not None:
            lims.append(AccelerationLimit(self.a_max))
        return [*lims, TorqueLimit(self.tau_max), TorqueRateLimit(self.tau_rate_max)]

    def key(self) -> str:
        h = hashlib.sha256()
        for a in (self.q_min, self.q_max, self.v_max, self.tau_max, self.tau_rate_max, self.a_max):
            h.update(b"-" if a is None else np.ascontiguousarray(a, dtype=float).tobytes())
        return h.hexdigest()


@dataclass(frozen=True, eq=False)
class PtpDynamics:
    """What the OCP needs of the robot's dynamics, as CasADi Functions with named inputs.

    `inv_dyn` (q, qd, qdd) → tau: the NLP's joint torque (torque limit, objective), Coulomb friction
    smoothed wide (`PTP_COULOMB_EPS_RAD_S`, `ptp_ocp` module doc).
    `coulomb` (qd) → tau: its Coulomb-friction part, left out of the NLP's torque-rate rows.
    `tcp_fk` (q) → (p, R): the TCP placement, needed only for a TCP box.
    `output` (q, qd, qdd) → tau: the torque of the sampled plan, Coulomb friction smoothed as `run`
    computes its feed-forward and checks it (`COULOMB_EPS_NLP_RAD_S`); `output_coulomb` (qd) → tau its
    Coulomb part. Without them the sampled torque is `inv_dyn`'s.
    `output_shift` (qd) → tau: `output` − `inv_dyn` (the two Coulomb smoothings' difference, joint and
    motor friction), so the energy objective prices the torque the plan is judged on (`ptp_ocp`).
    """

    inv_dyn: ca.Function
    coulomb: ca.Function | None = None
    tcp_fk: ca.Function | None = None
    output: ca.Function | None = None
    output_coulomb: ca.Function | None = None
    output_shift: ca.Function | None = None

    @classmethod
    def from_parameters(
        cls,
        robot: Robot,
        params: DynamicParameters | None = None,
        coulomb_eps_rad_s: float = PTP_COULOMB_EPS_RAD_S,
        *,
        kinematics: Robot | None = None,
    ) -> PtpDynamics:
        """From `rxcomm.model.symbolic` with `params` (default: the robot's priors): the NLP's model with
        Coulomb friction smoothed as tanh(q̇/ε), ε = `coulomb_eps_rad_s` (`ptp_ocp` module doc: why wider
        than the output's), and the output's with `run`'s ε = `COULOMB_EPS_NLP_RAD_S`. The TCP
        kinematics are those of `kinematics` (a calibrated robot) when given, else `robot`'s."""
        params = prior_parameters(robot) if params is None else params
        qd = ca.SX.sym("qd", robot.n)

        def coulomb(eps: float) -> ca.Function:
            return ca.Function(
                "coulomb", [qd], [ca.DM(params.coulomb_nm) * ca.tanh(qd / eps)], ["qd"], ["tau"]
            )

        shift = coulomb_torque_expr(robot, qd, params, COULOMB_EPS_NLP_RAD_S) - coulomb_torque_expr(
            robot, qd, params, coulomb_eps_rad_s
        )
        return cls(
            inverse_dynamics_function(robot, params, coulomb_eps_rad_s),
            coulomb(coulomb_eps_rad_s),
            forward_kinematics_function(kinematics or robot),
            inverse_dynamics_function(robot, params, COULOMB_EPS_NLP_RAD_S),
            coulomb(COULOMB_EPS_NLP_RAD_S),
            ca.Function("output_shift", [qd], [shift], ["qd"], ["tau"]),
        )

    @property
    def dof(self) -> int:
        return int(self.inv_dyn.size1_in(0))

    def key(self) -> str:
        h = hashlib.sha256()
        for f in (self.inv_dyn, self.coulomb, self.tcp_fk, self.output_shift):
            h.update(b"-" if f is None else f.serialize().encode())
        return h.hexdigest()

    def torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """The NLP's τ [n, dof] at many samples (one mapped call)."""
        return _mapped(self.inv_dyn, q, qd, qdd)

    def output_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """The sampled plan's τ [n, dof] (`output`, else the NLP's)."""
        return _mapped(self.output or self.inv_dyn, q, qd, qdd)

    def rate_torque(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The torque whose rate the NLP limits: the NLP's τ minus its Coulomb part."""
        return tau if self.coulomb is None else tau - _mapped(self.coulomb, qd)

    def output_coulomb_torque(self, qd: np.ndarray) -> np.ndarray:
        """The Coulomb part of `output_torque` [n, dof] (zeros without `output_coulomb`)."""
        return np.zeros_like(qd) if self.output_coulomb is None else _mapped(self.output_coulomb, qd)


def _mapped(f: ca.Function, *args: np.ndarray) -> np.ndarray:
    """`f` at many samples: each argument [n, dof], the result [n, dof] (one mapped call)."""
    return np.asarray(f.map(args[0].shape[0])(*(a.T for a in args))).T.reshape(args[0].shape)


def energy_quadrature(n_intervals: int) -> tuple[np.ndarray, np.ndarray]:
    """The energy objective's quadrature on the normalised time s ∈ [0, 1]: composite Simpson on the
    N + 1 nodes and the N interval midpoints, points s [2N + 1] and weights w [2N + 1] (1, 4, 2, 4, …, 4,
    1 over 6N; ∫₀ᵀ P dt ≈ T·Σ w·P(s·T)). The nodes alone (the trapezoid) do not see the motion between
    them, and the optimum used that (`ptp_ocp` module doc)."""
    w = np.full(2 * n_intervals + 1, 2.0)
    w[1::2] = 4.0
    w[[0, -1]] = 1.0
    return np.linspace(0.0, 1.0, 2 * n_intervals + 1), w / (6 * n_intervals)


@dataclass(frozen=True, eq=False)
class NodeGuess:
    """Values on the OCP grid: T, q/q̇/q̈ at the N + 1 nodes [N+1, dof], jerk on the N intervals [N, dof]."""

    duration_s: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    jerk: np.ndarray

    @classmethod
    def from_profile(cls, profile: KinematicProfile, n_intervals: int) -> NodeGuess:
        """Sample a kinematic profile at the nodes; the jerk makes q̈ match at every node."""
        T = max(profile.duration_s, 1e-3)
        t = np.linspace(0.0, T, n_intervals + 1)
        q, qd, qdd = profile.at(t)
        return cls(T, q, qd, qdd, np.diff(qdd, axis=0) / (T / n_intervals))

    def stretched(self, duration_s: float) -> NodeGuess:
        """The same motion slowed (or sped up) uniformly to `duration_s`."""
        k = self.duration_s / duration_s
        return NodeGuess(duration_s, self.q, self.qd * k, self.qdd * k**2, self.jerk * k**3)


def ipopt_options(options: PtpOptions, hessian: str) -> dict:
    """IPOPT's options for the PtP NLPs (`ptp_ocp` and its shooting peer): the options' caps and
    tolerance, `hessian` "exact" or "limited-memory"."""
    ipopt = {
        "max_iter": options.max_iter,
        "tol": options.tol,
        # the time converges to ~1e-5 long before IPOPT's default tolerances: stop there
        "acceptable_tol": 1e-4,
        "acceptable_iter": 5,
        "acceptable_obj_change_tol": 1e-6,
        "print_level": 0,
        "sb": "yes",
        "mu_strategy": "adaptive",
        "hessian_approximation": hessian,
    }
    if options.max_wall_s is not None:
        ipopt["max_wall_time"] = float(options.max_wall_s)
    return ipopt


@dataclass(frozen=True, eq=False)
class IpoptOutcome:
    """How IPOPT got to a PtP NLP's answer (the fields both solutions share)."""

    objective: float
    status: str
    success: bool
    iterations: int
    solve_seconds: float


def run_ipopt(solver: ca.Function, x0, lbx, ubx, lbg, ubg) -> tuple[np.ndarray, dict]:
    """Solve from `x0` (clipped into the bounds); the solution vector and the `IpoptOutcome` fields.
    Never raises on non-convergence: see `success`, `status`."""
    t0 = time.perf_counter()
    res = solver(x0=np.clip(x0, lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    seconds = time.perf_counter() - t0
    stats = solver.stats()
    return np.asarray(res["x"]).ravel(), {
        "objective": float(res["f"]),
        "status": str(stats.get("return_status", "unknown")),
        "success": bool(stats.get("success", False)),
        "iterations": int(stats.get("iter_count", -1)),
        "solve_seconds": seconds,
    }


@dataclass(frozen=True, eq=False)
class PtpSolution(IpoptOutcome):
    """The OCP's answer on its grid, and how IPOPT got there."""

    duration_s: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    jerk: np.ndarray
    tau: np.ndarray

    @property
    def n_intervals(self) -> int:
        return self.jerk.shape[0]

    @property
    def tau_squared_integral(self) -> float:
        """∫τᵀτ dt by the trapezoid rule over the nodes, (N·m)²·s."""
        s = np.sum(self.tau**2, axis=1)
        return float(self.duration_s / self.n_intervals * (s.sum() - 0.5 * (s[0] + s[-1])))
