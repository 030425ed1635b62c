"""`configs.yaml`: measurement poses for geometric calibration (kind `rxcomm/Configs`, paper §3.3).

`poses` is the list `run` drives to, in order, reading the tracker at each: the `fit` poses chosen by
the exchange algorithm, then `validation` poses (random feasible candidates not selected) that
`calibrate` holds out. `baseline_poses_rad` is the naive set (evenly spaced candidates in grid order,
the paper's "linear scan") of the same size, kept for comparison; `run` does not drive to it.

The observation index is computed on Θ̃ = W·Θ·S·T over the identifiable parameters (rows: position
m, orientation rad × σ_p/σ_o; columns: translations m, rotations rad × L, L =
`characteristic_length_m`, then whitened by the candidates' mean information), so Λ counts "average
candidate poses" and does not depend on the tracker frame or on units; see
`rxcomm.optim.pose_selection`. The summary's `expected_position_error_m` (and the baseline's) is the
rms position error over the candidates that calibrating from the set should leave, at the tracker
noise of `cell.yaml` (orientation likewise, rad).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field
from rxcomm.schemas.envelope import Artefact


class ConfigPose(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    q_rad: list[float] = Field(description="joint angles, rad, chain order")
    role: Literal["fit", "validation"] = "fit"
    tcp_position_m: tuple[float, float, float] | None = Field(
        None, description="nominal TCP position in the base frame (for people and plots)"
    )


class Configs(Artefact):
    KIND: ClassVar[str] = "rxcomm/Configs"
    SCHEMA_VERSION: ClassVar[int] = 1
    REQUIRED_SUMMARY_KEYS: ClassVar[tuple[str, ...]] = (
        "n_candidates",
        "n_selected",
        "observation_index",
        "baseline_observation_index",
        "improvement_ratio",
        "seconds",
    )

    robot: str
    joint_names: list[str]
    criterion: Literal["min-eig", "det-root", "cond"]
    measurement: Literal["pose", "position"]
    characteristic_length_m: float
    identifiable: list[str] = Field(description="the parameters the index is computed over")
    poses: list[ConfigPose]
    baseline_poses_rad: list[list[float]]
