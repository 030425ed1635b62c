"""`configs.yaml`: measurement poses for geometric calibration (kind `rxcomm/Configs`, paper §3.3).

`poses` is the list `run` drives to, in order, reading the tracker at each: the `fit` poses chosen by
the exchange algorithm, then `validation` poses (random feasible candidates not selected) that
`calibrate` holds out, then — with `select-configs --measure-baseline` — the naive set as `baseline`
poses, which `calibrate` fits on its own to report the held-out error it would have left.
`baseline_poses_rad` is that naive set, always written: the paper's "linear scan" of the joint grid
(from `baseline_centre_rad`, one joint swept at a time; `rxcomm.calibration.baselines.linear_scan`).
`evenly_spaced_poses_rad` is a second reference of the same size, evenly spaced candidates in grid
order (as diverse as a random draw of the candidates).

The observation index is computed on Θ̃ = W·Θ·S·T over the identifiable parameters (rows: position
m, orientation rad × σ_p/σ_o; columns: translations m, rotations rad × L, L =
`characteristic_length_m`, then whitened by the candidates' mean information), so Λ counts "average
candidate poses" and does not depend on the tracker frame or on units; see
`rxcomm.calibration.pose_selection`. The summary's `expected_position_error_m` (and the baseline's) is the
rms position error over the candidates that calibrating from the set should leave, at the tracker
noise of `cell.yaml` (orientation likewise, rad). Version 2: the baseline became the linear scan
(version 1's `baseline_poses_rad` were evenly spaced candidates).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict


class ConfigPose(Strict):
    q_rad: list[float] = Field(description="joint angles, rad, chain order")
    role: Literal["fit", "validation", "baseline"] = "fit"
    tcp_position_m: tuple[float, float, float] | None = Field(
        None, description="nominal TCP position in the base frame (for people and plots)"
    )


class ConfigsSettings(Strict):
    """Options of `select-configs` (recorded as used)."""

    n: int = Field(description="poses selected")
    intervals: int = Field(description="grid intervals per joint of the candidate grid")
    max_candidates: int = Field(description="candidates kept from the grid (0: all)")
    criterion: Literal["min-eig", "det-root", "cond"]
    restarts: int
    n_validation: int = Field(description="held-out validation poses added")
    seed: int
    measure_baseline: bool = Field(description="the linear-scan baseline poses are measured too")


class ConfigsSummary(Strict):
    """What a rxcomm/Configs summary holds (units in the names; None: not measured)."""

    n_candidates: int
    n_selected: int
    observation_index: float | None = Field(description="required; None: not measured")
    baseline_observation_index: float | None = Field(description="required; None: not measured")
    improvement_ratio: float | None = Field(description="required; None: not measured")
    min_eig_improvement_ratio: float | None = None
    expected_position_error_m: float | None = None
    baseline_expected_position_error_m: float | None = None
    evenly_spaced_expected_position_error_m: float | None = None
    expected_orientation_error_rad: float | None = None
    baseline_expected_orientation_error_rad: float | None = None
    evenly_spaced_expected_orientation_error_rad: float | None = None
    evenly_spaced_observation_index: float | None = None
    evenly_spaced_improvement_ratio: float | None = None
    seconds: float | None = Field(description="required; None: not measured")
    n_baseline: int | None = None
    n_validation: int | None = None
    n_grid: int | None = None
    n_feasible: int | None = None
    n_identifiable: int | None = None
    restart_indices: list[float | None] | None = None
    grid_seconds: float | None = None
    selection_seconds: float | None = None
    rejected_workspace: int | None = None
    rejected_self_collision: int | None = None
    rejected_tracker_range: int | None = None
    rejected_tracker_cone: int | None = None
    rejected_probe_facing: int | None = None
    rejected_joint_limits: int | None = None


class Configs(Artefact[ConfigsSettings, ConfigsSummary], kind="rxcomm/Configs", schema_version=2):
    robot: str
    joint_names: list[str]
    criterion: Literal["min-eig", "det-root", "cond"]
    measurement: Literal["pose", "position"]
    characteristic_length_m: float
    identifiable: list[str] = Field(description="the parameters the index is computed over")
    poses: list[ConfigPose]
    baseline_poses_rad: list[list[float]] = Field(description="the naive set: a linear scan of the grid")
    baseline_centre_rad: list[float] = Field(description="the configuration the linear scan sweeps from")
    evenly_spaced_poses_rad: list[list[float]] = Field(
        description="as many evenly spaced candidates in grid order (a second reference)"
    )
