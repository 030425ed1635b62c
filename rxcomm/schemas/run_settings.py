"""What `run` records as the settings of its artefacts: a run log (`rxcomm/RunLog`) and a measurement
campaign's `rxcomm/Measurements`.

The stage's own models (`rxcomm.execution.session.RunSettings`, `StreamSettings`,
`rxcomm.execution.campaign.CampaignSettings`) carry its defaults and bounds; these are how an artefact
states what was used, plus the cell and model the run had. Every field is optional: None where a
field was not recorded (a file from before it existed, or a test's hand-made artefact) or does not
apply — a reader says "not recorded", never fills in a default. tests/test_schemas.py holds the
fields here equal to the stage models'.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rxcomm.schemas.strict import Strict


class StreamRecord(Strict):
    """How setpoints were fed to the gateway (`StreamSettings`)."""

    interpolation_ratio: int | None = Field(
        None,
        description="drive cycles per setpoint as asked (None: chosen from the round trip, the "
        "summary's interpolation_ratio, or not recorded)",
    )
    lead_s: float | None = Field(None, description="buffered setpoints kept ahead of execution, s")
    prefill_s: float | None = Field(None, description="buffered before the stream started, s")
    min_lead_s: float | None = Field(None, description="the lead the run promised to keep, s")
    watchdog_ms: int | None = Field(None, description="the cell's watchdog, ms")
    round_trip_probes: int | None = Field(None, description="empty blocks timed to choose the ratio")
    stop_timeout_s: float | None = Field(None, description="wait for the stop ramp before disabling, s")


class RunRecord(Strict):
    """What both kinds of `run` record: the model, the cell, the stream."""

    feedforward: bool | None = Field(None, description="τ_ff of the model streamed (False: zeros)")
    limit_tolerance: float | None = Field(None, description="limit ratios up to 1 + this passed")
    fault_reset: bool | None = Field(None, description="drive faults and latched stops were reset first")
    stream: StreamRecord | None = None
    model: Literal["identified", "prior"] | None = Field(
        None, description="the model of τ_ff and the torque checks: --dynamics (identified) or the prior"
    )
    embedded_cell: bool | None = Field(None, description="a simulated cell started by `run` itself")
    handover: bool | None = Field(
        None,
        description="without feed-forward, the model's static torque was first handed over to the "
        "drives' integrators (drives just powered on)",
    )
    plant: str | None = Field(
        None, description="the embedded cell's plant (own, mujoco); None: a gateway, or not recorded"
    )


class RunLogSettings(RunRecord):
    """A trajectory run (`RunSettings`, and the cell's pacing)."""

    approach: bool | None = Field(None, description="a move to the plan's start was allowed")
    approach_speed_fraction: float | None = Field(None, description="of velocity and acceleration limits")
    start_tolerance_rad: float | None = Field(None, description="per joint: 'at the start' within this")
    realtime: bool | None = Field(None, description="the embedded cell ran on the wall clock")
    trip_is_result: bool | None = Field(
        None, description="a drive trip ended the run as its result (the log written whole, exit 0)"
    )


class MeasurementsSettings(RunRecord):
    """A measurement campaign (`CampaignSettings`)."""

    speed_fraction: float | None = Field(None, description="moves: of velocity and acceleration limits")
    settle_s: float | None = Field(None, description="demand held at each pose before the tracker read, s")
    tracker_attempts: int | None = Field(None, description="tracker reads per pose before giving up")
    tracker_retry_s: float | None = Field(None, description="pause between tracker reads, s")
