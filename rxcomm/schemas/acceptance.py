"""Acceptance: the thresholds a customer accepts the commissioned robot by, and the verdict.

``samples/ROBOT/acceptance.yaml`` (kind `rxcomm/AcceptanceThresholds`, beside the cell) lists the
criteria; `rxcomm accept` compares the factory and the commissioned state of the robot, measured the
same way, and writes ``verdict.yaml`` (kind `rxcomm/Acceptance`): one row per criterion with factory,
commissioned, ratio (commissioned / factory), threshold and verdict (PASS, FAIL or not measured).

Criteria: the ISO 9283 ones of `rxcomm iso9283` (``rxcomm.schemas.iso9283``: AP_p, RP_l, AT_p, RT_p,
CO in m; AV, RV in 1) on a test pose or path (``target``; none: the worst over all of them) and at a
command speed, and the reference task's figures from its run logs: ``cycle_time`` (s, the sum of the
runs' durations), ``tau_squared_integral`` (N²·m²·s, ∫τᵀτ dt of the measured torques) and
``electrical_energy`` (J, drawn from the bus, `rxcomm.model.energy`), and
``electrical_energy_at_factory_time`` (J): the commissioned reference task slowed uniformly in time to
the factory's cycle time with the energy objective (`plan-cp/plan-ptp --objective energy --duration-s`),
run, against the factory's: energy at equal time; ``cycle_time_at_factory_energy`` (s): the cycle time
at which the commissioned time–energy curve (its measured points) reaches the factory's energy, against
the factory's cycle time: time at equal energy (issue 29).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict

TASK_CRITERIA: dict[str, str] = {
    "cycle_time": "s",
    "tau_squared_integral": "N2m2s",
    "electrical_energy": "J",
    "electrical_energy_at_factory_time": "J",
    "cycle_time_at_factory_energy": "s",
}
ISO_CRITERIA: dict[str, str] = {
    "AP_p": "m",
    "RP_l": "m",
    "AT_p": "m",
    "RT_p": "m",
    "CO": "m",
    "AV": "1",
    "RV": "1",
}
CRITERION_UNITS: dict[str, str] = {**ISO_CRITERIA, **TASK_CRITERIA}
CriterionName = Literal[
    "AP_p",
    "RP_l",
    "AT_p",
    "RT_p",
    "CO",
    "AV",
    "RV",
    "cycle_time",
    "tau_squared_integral",
    "electrical_energy",
    "electrical_energy_at_factory_time",
    "cycle_time_at_factory_energy",
]
Unit = Literal["m", "1", "s", "N2m2s", "J"]
Verdict = Literal["PASS", "FAIL", "not measured"]


class Threshold(Strict):
    """One acceptance criterion: the commissioned value (its magnitude) at most `max_commissioned`,
    and/or commissioned / factory at most `max_ratio`. Both given: both must hold."""

    criterion: CriterionName
    unit: Unit = Field(description="the criterion's unit, stated so the file reads alone (m, 1, s, N2m2s, J)")
    target: str | None = Field(
        None, description="ISO test pose P1..P5 or path (iso9283-line, ...); none: the worst of all"
    )
    command_speed_m_per_s: float | None = Field(
        None, gt=0, description="ISO path criteria at this command TCP speed (±5 %), m/s; none: any"
    )
    max_commissioned: float | None = Field(None, ge=0, description="bound on |commissioned|, in `unit`")
    max_ratio: float | None = Field(None, gt=0, description="bound on |commissioned| / |factory| (1)")

    @model_validator(mode="after")
    def _consistent(self) -> Threshold:
        if self.unit != CRITERION_UNITS[self.criterion]:
            raise ValueError(f"{self.criterion} is in {CRITERION_UNITS[self.criterion]}, not {self.unit}")
        if self.max_commissioned is None and self.max_ratio is None:
            raise ValueError("give max_commissioned, max_ratio or both")
        if self.criterion in TASK_CRITERIA and (self.target is not None or self.command_speed_m_per_s):
            raise ValueError(f"{self.criterion} is a reference-task figure: no target or command speed")
        return self


class AcceptanceThresholds(Strict):
    kind: Literal["rxcomm/AcceptanceThresholds"]
    schema_version: Literal[1]
    criteria: list[Threshold] = Field(min_length=1)


class VerdictRow(Strict):
    """One line of the verdict table."""

    criterion: str = Field(description="criterion name with its target and speed, as the table shows it")
    unit: Unit
    factory: float | None = Field(description="the factory state's value, in `unit`; null: not measured")
    commissioned: float | None = Field(description="the commissioned state's value; null: not measured")
    ratio: float | None = Field(description="|commissioned| / |factory|; null when either is missing")
    threshold: str = Field(description="the bound(s) as text, e.g. '≤ 0.0003 m', 'ratio ≤ 0.7'")
    max_commissioned: float | None = Field(description="the bound on |commissioned|, in `unit`")
    max_ratio: float | None = Field(description="the bound on the ratio")
    verdict: Verdict
    note: str = Field("", description="why not measured, or what the value rests on")


class AcceptanceSettings(Strict):
    """The run logs the verdict was taken from (file names)."""

    factory_logs: list[str] = []
    commissioned_logs: list[str] = []
    commissioned_equal_time_logs: list[str] = []
    commissioned_curve_logs: list[str] = []


class AcceptanceSummary(Strict):
    """What a rxcomm/Acceptance summary holds (units in the names; None: not measured)."""

    verdict: str
    accepted: bool | None = None
    verdict_line: str | None = None
    n_criteria: int | None = None
    n_pass: int
    n_fail: int
    n_not_measured: int


class Acceptance(Artefact[AcceptanceSettings, AcceptanceSummary], kind="rxcomm/Acceptance", schema_version=1):
    """Factory vs commissioned, criterion by criterion, with the verdict."""

    rows: list[VerdictRow]
