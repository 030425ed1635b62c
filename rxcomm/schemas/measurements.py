"""`measurements.yaml`: tracker measurements of the TCP at standstill (kind `rxcomm/Measurements`).

Written by `run` when it executes a pose list (`configs.yaml`) on a cell; read by `calibrate`.
Per pose: the joint angles from the encoders after settling (rad), the TCP position (m) and, with a
6D probe, its orientation as a unit quaternion **w, x, y, z** — both in the **tracker frame** — and
whether the tracker saw the probe (`valid`). `role` is copied from the pose list: `fit` poses are
used to estimate the parameters, `validation` poses only to check the result (held out), `baseline`
poses (a naive set measured for comparison) are fitted on their own so `calibrate` can show what
they would have left on the same held-out poses.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from rxcomm.schemas.cell import Placement
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.run_log import RunReport
from rxcomm.schemas.run_settings import MeasurementsSettings
from rxcomm.schemas.strict import Strict


class MeasuredPose(Strict):
    q_rad: list[float] = Field(description="joint angles from the encoders, rad, chain order")
    position_m: tuple[float, float, float] = Field(description="TCP position in the tracker frame, m")
    quaternion_wxyz: tuple[float, float, float, float] | None = Field(
        None,
        description="TCP orientation in the tracker frame (unit quaternion w, x, y, z); None: position only",
    )
    valid: bool = Field(True, description="the tracker saw the probe")
    role: Literal["fit", "validation", "baseline"] = "fit"

    @model_validator(mode="after")
    def _unit_quaternion(self) -> MeasuredPose:
        qt = self.quaternion_wxyz
        if qt is not None and all(math.isfinite(v) for v in qt) and abs(math.hypot(*qt) - 1.0) > 1e-6:
            raise ValueError(f"quaternion_wxyz must have unit norm, got norm {math.hypot(*qt):.6g}")
        return self


class MeasurementsSummary(RunReport):
    """What a rxcomm/Measurements summary holds (units in the names; None: not measured)."""

    n_poses: int
    n_valid: int
    n_planned: int | None = None
    max_move_lag_rad: float | None = None
    max_tracker_attempts: int | None = None
    seconds: float | None = None


class Measurements(
    Artefact[MeasurementsSettings, MeasurementsSummary], kind="rxcomm/Measurements", schema_version=1
):
    robot: str = Field(description="robot name (URDF)")
    joint_names: list[str]
    tracker_to_base: Placement | None = Field(
        None, description="nominal pose of the robot base in the tracker frame (from cell.yaml), if known"
    )
    position_sigma_m: float | None = Field(None, gt=0, description="tracker position noise spec (1σ), m")
    orientation_sigma_rad: float | None = Field(None, gt=0, description="tracker orientation noise spec, rad")
    poses: list[MeasuredPose]
