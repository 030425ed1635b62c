"""The summary YAML written beside a planned trajectory MCAP (``cp.mcap`` -> ``cp.yaml``)."""

from __future__ import annotations

from pydantic import Field

from rxcomm.schemas.envelope import McapSummary
from rxcomm.schemas.strict import Strict


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


class TrajectorySummary(McapSummary):
    """Envelope + summary of a trajectory MCAP (cp, ptp), plus where its samples are.

    The MCAP carries the same envelope as its ``rxcomm/envelope`` metadata record.
    """

    KIND = "rxcomm/Trajectory"
    SCHEMA_VERSION = 1
    SETTINGS_UNTYPED = True  # issue 28: stage settings plus nested models not yet in the schema layer
    summary: TrajectoryFigures

    topic: str = Field(description="MCAP topic of the samples")
    n_samples: int = Field(ge=1)
    fields: list[str] = Field(description="message fields: q, qd, qdd, tau_ff and any extras")
