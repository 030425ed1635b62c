"""`mdh.yaml`: the calibrated kinematics as a controller takes them (kind `rxcomm/Kinematics`).

Written by `calibrate --mdh-out` beside a CSV of the same table. Modified Denavit–Hartenberg
parameters in Craig's convention, frame i−1 → frame i = Rx(α_{i−1})·Ry(β_{i−1})·Tx(a_{i−1})·
Rz(q_i + θ_offset_i)·Tz(d_i), with β = 0 in plain MDH (Hayati's β only on the joint after a
parallel pair); TCP in the robot's base frame = base · Π_i (…) · tool. Two fits of the same
calibrated model are given: `mdh` (plain, β = 0) and `mdh_beta` (β free where MDH needs it); each
states the residual it leaves against the calibrated model's FK over sampled poses (what that form
cannot express). `zero_offsets`: per joint, the calibrated θ_offset minus the nominal one — the
encoder zero correction; J1's and the last joint's are the base's and the tool's rotation about
that axis, which no measurement tells apart from a zero offset. Compliance (if calibrated) is not
in these tables: it is a joint deflection c·τ, in calibration.yaml.
"""

from __future__ import annotations

from pydantic import Field

from rxcomm.schemas.cell import Placement
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict


class MdhJoint(Strict):
    joint: str
    alpha_rad: float = Field(description="α_{i−1}: twist of axis i about X_{i−1}, rad")
    a_m: float = Field(description="a_{i−1}: common-normal length along X_{i−1}, m")
    theta_offset_rad: float = Field(description="θ_offset_i: θ_i = q_i + θ_offset_i, rad")
    d_m: float = Field(description="d_i: offset along Z_i, m")
    beta_rad: float = Field(0.0, description="Hayati β_{i−1} about Y after α (0 in plain MDH), rad")


class MdhForm(Strict):
    base: Placement = Field(description="robot base frame → MDH frame 0")
    joints: list[MdhJoint]
    tool: Placement = Field(description="MDH frame n → TCP")
    max_position_residual_m: float = Field(
        description="max TCP position error vs the calibrated FK (0: exact, within round-off)"
    )
    max_orientation_residual_rad: float = Field(
        description="max TCP orientation error vs the calibrated FK (0: exact, within round-off)"
    )


class ZeroOffset(Strict):
    joint: str
    offset_rad: float = Field(description="calibrated − nominal θ_offset (encoder zero correction), rad")
    offset_deg: float
    note: str | None = None


class KinematicsSettings(Strict):
    """How the MDH forms were fitted and checked."""

    fit_poses: int
    check_poses: int
    seed: int
    length_m: float = Field(description="characteristic length weighing orientation against position, m")


class KinematicsSummary(Strict):
    """What a rxcomm/Kinematics summary holds (units in the names; None: not measured)."""

    mdh_max_position_residual_m: float | None = Field(description="required; None: not measured")
    mdh_max_orientation_residual_rad: float | None = None
    mdh_beta_max_position_residual_m: float | None = Field(description="required; None: not measured")
    mdh_beta_max_orientation_residual_rad: float | None = None
    n_sample_poses: int


class Kinematics(Artefact[KinematicsSettings, KinematicsSummary], kind="rxcomm/Kinematics", schema_version=1):
    robot: str
    joint_names: list[str]
    convention: str = Field(description="the row transform, spelled out")
    parallel_pairs: list[tuple[str, str]] = Field(description="consecutive axes treated as parallel (d = 0)")
    mdh: MdhForm
    mdh_beta: MdhForm
    nominal: MdhForm = Field(description="the nominal robot's MDH (exact: residual at round-off)")
    zero_offsets: list[ZeroOffset]
    notes: list[str] = []
