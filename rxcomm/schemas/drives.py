"""`drives.yaml`: what a URDF lacks to commission a robot (architecture §4).

Joint-side quantities unless the name says motor. Position and velocity limits come from the URDF
(`<limit lower upper velocity>`); torque limits come from here (the URDF `effort` is ignored).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from rxcomm.schemas.strict import Strict


class JointDrive(Strict):
    """One axis: gearbox, motor and the limits the drive enforces."""

    name: str = Field(description="URDF joint name")
    gear_ratio: float = Field(
        description="motor turns per joint turn (dimensionless, positive: a reversed axis is motor_sign -1)"
    )
    rotor_inertia_kgm2: float = Field(ge=0, description="motor rotor inertia, motor side, kg·m²")
    torque_constant_nm_per_a: float = Field(gt=0, description="motor torque constant, N·m/A (motor side)")
    motor_sign: Literal[-1, 1] = Field(1, description="sign of motor position/torque w.r.t. the joint")
    encoder_offset_rad: float = Field(
        0.0,
        description="motor angle the drive reports at the joint's calibrated zero, motor side, rad "
        "(subtracted from a CSV's motor{i}_rad before conversion)",
    )
    peak_torque_nm: float = Field(gt=0, description="peak joint torque, N·m")
    continuous_torque_nm: float = Field(gt=0, description="continuous (RMS) joint torque, N·m")
    torque_rate_max_nm_per_s: float = Field(gt=0, description="joint torque rate limit, N·m/s")
    acceleration_max_rad_per_s2: float = Field(gt=0, description="joint acceleration limit, rad/s²")
    coulomb_friction_nm: float = Field(ge=0, description="prior Coulomb friction, N·m")
    viscous_friction_nm_s_per_rad: float = Field(ge=0, description="prior viscous friction, N·m·s/rad")
    winding_resistance_ohm: float | None = Field(
        None,
        ge=0,
        description="motor winding resistance of the DC-equivalent motor, Ω (copper loss R·I² with "
        "I = τ_m / k_t); absent: a run's electrical energy is not measured",
    )

    @field_validator("gear_ratio")
    @classmethod
    def _positive_ratio(cls, v: float) -> float:
        if v < 0:
            raise ValueError(
                f"gear_ratio {v} is negative: give its magnitude ({-v:g}) and motor_sign: -1 "
                "for an axis whose motor turns the other way"
            )
        if not v > 0:
            raise ValueError("gear_ratio must be positive")
        return v

    @model_validator(mode="after")
    def _continuous_below_peak(self) -> JointDrive:
        if self.continuous_torque_nm > self.peak_torque_nm:
            raise ValueError("continuous_torque_nm exceeds peak_torque_nm")
        return self


class BalancerSpring(Strict):
    """A gravity balancer stretched between a pivot fixed to the parent link and one on the child link.

    Both pivots lie on the spring joint's plane at distances `fixed_pivot_m` and `moving_pivot_m` from
    the joint axis; at q = -angle_offset_rad they are aligned (shortest spring). The spring length is
    L(q) = sqrt(a² + b² − 2ab·cos(q + offset)); its holding torque k·(L − L0)·dL/dq is linear in
    (k, k·L0) with a shape that is not collinear with link gravity, so identification can see it.
    """

    joint: str
    fixed_pivot_m: float = Field(gt=0)
    moving_pivot_m: float = Field(gt=0)
    angle_offset_rad: float = 0.0
    stiffness_n_per_m: float = Field(ge=0, description="prior stiffness k, N/m")
    free_length_m: float = Field(ge=0, description="prior free length L0, m")


class ToolFrame(Strict):
    """The tool centre point, fixed to `parent_frame`."""

    parent_frame: str = "tool0"
    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)


class RatedPayload(Strict):
    """The payload a maker rates the arm for: a point mass at the flange (the catalogue limits hold
    with it at every pose)."""

    mass_kg: float = Field(gt=0, description="rated payload mass, kg")
    com_m: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="its centre of mass in the TCP's parent frame (the flange), m"
    )


class ServoLoops(Strict):
    """The drives' position/velocity loops as their maker states them (all axes alike): what a generic
    controller without torque feed-forward can follow (`rxcomm.model.servo`). The simulated cell's
    drives are tuned with the same defaults (`rxcomm.cell.drives.DriveTuning`)."""

    velocity_bandwidth_rad_s: float = Field(
        60.0, gt=0, description="velocity loop bandwidth ω_v (K_p = J_nominal·ω_v), rad/s"
    )
    position_gain_ratio: float = Field(4.0, gt=1, description="γ: position gain K_v = ω_v/γ, 1/s")
    integral_time_ratio: float = Field(4.0, gt=0, description="β: velocity integral time T_i = β/ω_v")
    following_error_limit_rad: float = Field(
        0.035, gt=0, description="the following-error window: |demand − actual| above it trips (0x8611), rad"
    )


class Drives(Strict):
    kind: Literal["rxcomm/Drives"]
    schema_version: Literal[1]
    urdf: str = Field(description="URDF file name, relative to drives.yaml")
    cycle_s: float = Field(gt=0, le=0.01, description="drive cycle, s (RX130L: 0.0004)")
    tcp: ToolFrame
    joints: list[JointDrive] = Field(min_length=1)
    spring: BalancerSpring | None = None
    motor_coupling: list[list[float]] | None = Field(
        None,
        description="dimensionless C with motor angle = diag(gear_ratio)·C·q (e.g. a J5–J6 wrist coupling); "
        "identity when absent",
    )
    rated_payload: RatedPayload | None = Field(
        None, description="the maker's rated payload (catalogue limits); absent: none (0 kg)"
    )
    friction: Literal["joint", "motor", "both"] | None = Field(
        None,
        description="where friction acts in the model: per joint (joint side), per motor (motor side, "
        "mapped to the joints by Rᵀ: a coupled motor loads every joint it turns with), or both; "
        "default both when motor_coupling couples axes, else joint",
    )
    servo: ServoLoops = Field(
        default_factory=ServoLoops, description="the drives' loops and following-error window"
    )
    regenerative_supply: bool = Field(
        False,
        description="the DC bus returns braking power to the mains (true) or burns what the other axes do "
        "not draw in a brake resistor (false, the default): the electrical energy and the planners' "
        "energy objective count only the positive part of the bus power then",
    )

    @model_validator(mode="after")
    def _shapes(self) -> Drives:
        n = len(self.joints)
        names = [j.name for j in self.joints]
        if len(set(names)) != n:
            raise ValueError(f"duplicate joint names in joints: {names}")
        if self.motor_coupling is not None:
            c = self.motor_coupling
            if len(c) != n or any(len(row) != n for row in c):
                raise ValueError(f"motor_coupling must be {n}×{n}")
            if any(abs(c[i][i]) < 1e-9 for i in range(n)):
                raise ValueError("motor_coupling has a zero on its diagonal")
        if self.spring is not None and self.spring.joint not in names:
            raise ValueError(f"spring.joint {self.spring.joint!r} is not one of {names}")
        return self
