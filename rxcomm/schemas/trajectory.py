"""The summary YAML written beside a planned trajectory MCAP (``cp.mcap`` -> ``cp.yaml``)."""

from __future__ import annotations

from pydantic import Field

from rxcomm.schemas.envelope import McapSummary
from rxcomm.schemas.excitation import ExcitationSettings
from rxcomm.schemas.path import Branch
from rxcomm.schemas.strict import Strict

# The settings a planner records (plan-cp, plan-ptp, plan-poses, plan-cycles; excite records its
# ExcitationSettings). The stages' own models (`rxcomm.planning.cp.CpSettings`,
# `rxcomm.planning.ptp_problem.PtpOptions`) carry the defaults and bounds; these state what was used.
# Every field is optional: None where it was not recorded (an older file) or does not apply — a reader
# says "not recorded", never fills in a default. tests/test_schemas.py holds the option fields equal
# to the stage models'.


class CatalogueJoint(Strict):
    """One joint's catalogue limits and what bounds them (`rxcomm.model.catalogue`)."""

    name: str
    velocity_max_rad_s: float
    acceleration_max_rad_s2: float
    velocity_scale: float | None = None
    acceleration_scale: float | None = None
    velocity_bound_by: str | None = Field(None, description="the joint whose torque row binds, or drive")
    acceleration_bound_by: str | None = None
    acceleration_binding: str | None = Field(None, description="torque, following error or drive")
    following_error_peak_rad: float | None = None
    following_error_reversal_peak_rad: float | None = Field(
        None, description="the same after a reversal (the velocity integrator holding −F_c)"
    )
    velocity_worst_pose_rad: list[float] | None = Field(None, description="None: bound by the drive")
    acceleration_worst_pose_rad: list[float] | None = Field(
        None, description="None: bound by the drive or by the following error"
    )


class CatalogueLimits(Strict):
    """The maker's catalogue limits a factory-state plan was timed with, and how they were found."""

    method: str
    acceleration_reserve: float | None = None
    n_poses: int | None = None
    seed: int | None = None
    payload_kg: float | None = None
    following_error: str | None = None
    following_error_allowed_rad: float | None = None
    following_error_reversal_allowed_rad: float | None = None
    joints: list[CatalogueJoint]


class BusPowerRecord(Strict):
    """The energy objective's bus model (`rxcomm.model.energy.BusPowerModel`)."""

    copper_w_per_nm2: list[list[float]] = Field(description="Q, W/(N·m)²: copper losses τᵀQτ")
    regenerative: bool
    smoothing_w: float | None = Field(None, description="δ of the smoothed positive part, W")


class PtpOptionsRecord(Strict):
    """The PtP OCP's options as used (`PtpOptions`)."""

    n_intervals: int | None = None
    k1: float | None = None
    k2_per_nm2: float | None = None
    margin: float | None = None
    acceleration_limits: bool | None = None
    tcp_box_m: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    max_iter: int | None = None
    max_wall_s: float | None = None
    tol: float | None = None
    compile: bool | None = None
    hessian: str | None = None
    objective: str | None = None
    bus: BusPowerRecord | None = None
    duration_s: float | None = None


class PlanContext(Strict):
    """What every planner records besides its options: the model, the kinematics, the timing."""

    dynamics_model: str | None = Field(None, description="identified or prior, + payload when one was added")
    calibrated: bool | None = Field(None, description="planned on the calibrated kinematics")
    compliance_compensated_rad_per_nm: list[float] | None = Field(
        None, description="joint compliance the commanded angles compensate (None: none, or not recorded)"
    )
    branch: Branch | None = Field(None, description="the IK branch the joint path follows")
    timing: str | None = Field(None, description="optimal, catalogue, or catalogue (cycloidal moves)")
    catalogue: CatalogueLimits | None = Field(None, description="the catalogue limits of a catalogue timing")


class CpPlanSettings(PlanContext):
    """plan-cp (`CpSettings`)."""

    k1: float | None = None
    k2: float | None = Field(None, description="weight of τᵀτ, 1/(N·m)²")
    torque_rate: bool | None = None
    method: str | None = Field(None, description="nlp or toppra")
    intervals: int | None = None
    tcp_speed_max_m_s: float | None = None
    tcp_acceleration_max_m_s2: float | None = None
    coulomb_eps_rad_s: float | None = None
    sigma_min_margin: float | None = None
    target_ratio: float | None = None
    max_refinements: int | None = None
    objective: str | None = Field(None, description="torque or energy")
    duration_s: float | None = Field(None, description="the fixed duration, s (None: free)")
    regrid_below: float | None = None


class PtpPlanSettings(PlanContext):
    """plan-ptp: the states as given, how they were read, the OCP's options."""

    start: str | None = Field(None, description="--start as given (joint angles, rad, or a TCP pose)")
    goal: str | None = Field(None, description="--goal as given")
    start_kind: str | None = Field(None, description="joints or pose")
    goal_kind: str | None = None
    options: PtpOptionsRecord | None = None


class PosesPlanSettings(PlanContext):
    """plan-poses: the ISO 9283 pose cycle on the catalogue limits."""

    sample_s: float | None = Field(None, description="the plan's sample period, s")


class CyclesPlanSettings(Strict):
    """plan-cycles: a plan repeated, with the source plan's own settings."""

    cycles: int | None = None
    dwell_s: float | None = Field(None, description="held between cycles, s")
    duration_s: float | None = Field(None, description="each cycle time-scaled to this, s (None: as planned)")
    return_moves: str | None = None
    plan_settings: TrajectorySettings | None = Field(None, description="the repeated plan's settings")


# Tried in this order (each refuses another's keys; an empty mapping reads as a CP plan's, all None).
TrajectorySettings = (
    CpPlanSettings | PtpPlanSettings | PosesPlanSettings | CyclesPlanSettings | ExcitationSettings
)


class TrajectoryFigures(Strict):
    """What a rxcomm/Trajectory summary holds (units in the names; None: not measured)."""

    duration_s: float
    solve_seconds: float | None = Field(description="required; None: not measured")
    max_limit_ratio: float | None = Field(description="required; None: not measured")
    active_fraction: float | None = Field(description="required; None: not measured")
    q_start: list[float]
    q_goal: list[float]
    n_cycles: int | None = None
    cycle_duration_s: float | None = None
    time_scale: float | None = None
    seconds: float | None = None
    method: str | None = None
    path_length_m: float | None = None
    tau_squared_integral_nm2_s: float | None = None
    max_tcp_speed_m_s: float | None = None
    min_tcp_speed_mid_m_s: float | None = None
    singularity_margin: float | None = None
    singularity_margin_at_m: float | None = None
    max_path_deviation_m: float | None = None
    toppra_duration_s: float | None = None
    toppra_seconds: float | None = None
    ik_seconds: float | None = None
    refinements: int | None = None
    worst_limit: str | None = None
    nlp_seconds: float | None = None
    nlp_iterations: int | None = None
    nlp_status: str | None = None
    max_position_ratio: float | None = None
    max_velocity_ratio: float | None = None
    max_acceleration_ratio: float | None = None
    max_torque_ratio: float | None = None
    max_torque_rate_ratio: float | None = None
    cond: float | None = None
    catalogue_acceleration_bound: str | None = None
    max_filter_deviation_m: float | None = None
    max_tcp_speed_ratio: float | None = None
    max_tcp_acceleration_ratio: float | None = None
    max_tcp_box_ratio: float | None = None
    # plan-ptp: a limit's margin where its re-solves widened it beyond the option's (None: not widened)
    margin_position: float | None = None
    margin_velocity: float | None = None
    margin_acceleration: float | None = None
    margin_torque: float | None = None
    margin_torque_rate: float | None = None
    margin_tcp_box: float | None = None
    dwell_s: float | None = None
    order: str | None = None
    limits_checked: str | None = None
    fallback: bool | None = None
    build_seconds: float | None = None
    iterations: int | None = None
    solver_status: str | None = None
    objective: float | None = None
    warm_start_duration_s: float | None = None
    resolves: int | None = None
    planned_electrical_energy_j: float | None = Field(
        None, description="the plan's bus energy with its own torques (null: no winding resistances)"
    )
    energy_objective_j: float | None = Field(None, description="an energy-objective NLP's own value")


class TrajectorySummary(
    McapSummary[TrajectorySettings, TrajectoryFigures], kind="rxcomm/Trajectory", schema_version=1
):
    """Envelope + summary of a trajectory MCAP (cp, ptp), plus where its samples are.

    The MCAP carries the same envelope as its ``rxcomm/envelope`` metadata record.
    """

    settings: TrajectorySettings = Field(union_mode="left_to_right")

    topic: str = Field(description="MCAP topic of the samples")
    n_samples: int = Field(ge=1)
    fields: list[str] = Field(description="message fields: q, qd, qdd, tau_ff and any extras")
