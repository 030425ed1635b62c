"""`truth.yaml`: the simulated cell's hidden truth (architecture §6).

Only `rxcomm.cell` (the simulator) and tests that score recovery read this. Stages never do.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rxcomm.schemas.payload import PayloadMount
from rxcomm.schemas.strict import Strict


class Placement(Strict):
    xyz_m: tuple[float, float, float]
    rpy_rad: tuple[float, float, float]


class GeometryTruth(Strict):
    """Real kinematics: error parameters of `rxcomm.model.geometric_errors` (name → value, SI), tracker.

    Joint/base/tool errors are small twists applied on the right of the nominal placements:
    `{joint}.tx|ty|tz` in m, `{joint}.rx|ry|rz` in rad, likewise `base.*` and `tool.*`.
    `base.*` perturbs the robot base in the tracker frame on top of `tracker_to_base`.
    """

    tracker_to_base: Placement = Field(description="pose of the robot base in the tracker frame (nominal)")
    error_parameters: dict[str, float]
    joint_stiffness_nm_per_rad: dict[str, float] = Field(
        default_factory=dict,
        description="joint name → torsional stiffness of its transmission (N·m/rad); a joint not listed "
        "is rigid. The link deflects by τ/k under the static holding torque τ (gravity and balancer "
        "spring of the true dynamics) while the motor encoder stays put: the tracker sees the deflection",
    )


class LinkInertial(Strict):
    """Pinocchio order: m, m·c (3), inertia about the link frame origin Ixx Ixy Iyy Ixz Iyz Izz."""

    link: str = Field(description="the body moved by this joint, named by its joint")
    mass_kg: float = Field(gt=0)
    first_moment_kgm: tuple[float, float, float]
    inertia_origin_kgm2: tuple[float, float, float, float, float, float]


class DynamicsTruth(Strict):
    links: list[LinkInertial]
    rotor_inertia_kgm2: list[float] = Field(description="motor side, per axis")
    coulomb_friction_nm: list[float]
    viscous_friction_nm_s_per_rad: list[float]
    torque_offset_nm: list[float] = Field(description="constant torque offset per joint (sensor bias)")
    spring_stiffness_n_per_m: float | None = None
    spring_free_length_m: float | None = None
    motor_coulomb_friction_nm: list[float] | None = Field(
        None, description="Coulomb friction of each motor, motor side, N·m (absent: none)"
    )
    motor_viscous_friction_nm_s_per_rad: list[float] | None = Field(
        None, description="viscous friction of each motor, motor side, N·m·s/rad (absent: none)"
    )


class NoiseTruth(Strict):
    encoder_lsb_rad: float = Field(gt=0, description="encoder quantisation, joint side, rad")
    torque_noise_nm: list[float] = Field(description="std of motor torque measurement, joint side, N·m")
    tracker_position_sigma_m: float = Field(ge=0)
    tracker_orientation_sigma_rad: float = Field(ge=0)
    tracker_latency_s: float = Field(
        0.0, ge=0, le=1.0, description="the tracker stamps a sample this late (its clock vs the cell's), s"
    )


class CellTruth(Strict):
    kind: Literal["rxcomm/CellTruth"]
    schema_version: Literal[1]
    robot: str = Field(description="robot directory, relative to this file")
    seed: int
    geometry: GeometryTruth
    dynamics: DynamicsTruth
    noise: NoiseTruth
    payload: PayloadMount | None = Field(
        None, description="the load mounted on the flange (absent: none); `run --truth-payload` swaps it"
    )
