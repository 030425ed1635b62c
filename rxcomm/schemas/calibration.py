"""`calibration.yaml`: identified geometric errors (kind `rxcomm/Calibration`, paper §3.1–3.2).

`parameters` holds all 48 error parameters of `rxcomm.model.geometric_errors` (names `base.*`, `{joint}.*`,
`tool.*`; m and rad) with their standard deviations; parameters that the measurements cannot
identify are fixed at 0 (`estimated: false`) and listed in `dropped` with the reason. The errors are
relative to `tracker_to_base`, the nominal pose of the robot base in the tracker frame that was used.
`rxcomm.calibration.fit.load_calibration` returns (ErrorModel, tracker_to_base) from this file.

`error_tables` is the paper's Table 2: per pose set (fit, held out) and model (nominal, calibrated,
base + tool frames only) the max |e| and peak-to-peak of e for x, y, z (m: measured − predicted TCP
position in the tracker frame) and α, β, γ (rad: Cardan x-y-z angles of R_meas·R_predᵀ).

When the measurements hold `baseline` poses (a naive set, `select-configs --measure-baseline`),
`baseline_fit` is the same calibration fitted to those instead, and the held-out table of model
`baseline_poses` shows what it would have left on the same held-out poses.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from rxcomm.schemas.cell import Placement
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict


class ParameterEstimate(Strict):
    name: str
    value: float = Field(description="m for t*, rad for r*")
    std: float | None = Field(None, description="standard deviation from the covariance; None if fixed")
    estimated: bool


class DroppedParameter(Strict):
    name: str
    reason: str


class ErrorRow(Strict):
    quantity: Literal["x", "y", "z", "alpha", "beta", "gamma"]
    unit: Literal["m", "rad"]
    max_abs: float
    peak_to_peak: float
    rms: float


class ErrorTable(Strict):
    pose_set: Literal["fit", "heldout"]
    model: Literal["nominal", "calibrated", "frames_only", "baseline_poses"]
    n_poses: int
    max_position_error_m: float = Field(description="max over poses of |e_xyz|")
    rms_position_error_m: float | None = Field(None, description="rms over poses of |e_xyz|")
    max_orientation_error_rad: float | None = Field(description="max over poses of the rotation angle")
    rows: list[ErrorRow]


class BaselineFit(Strict):
    n_poses: int = Field(description="valid baseline poses measured")
    parameters: list[ParameterEstimate] = Field(description="empty when the poses cannot identify them")
    fit_poses: list[int] = Field(description="indices into the measurement file's poses")
    outlier_poses: list[int]
    worse_p_value: float | None = Field(
        description="one-sided Wilcoxon signed-rank test that this fit misses the held-out poses by "
        "more than the main fit, pose by pose, in the fit's weighted residual (position/σ_p, "
        "orientation/σ_o); small: measurably worse"
    )
    note: str | None = Field(None, description="why there is no fit")


class Calibration(Artefact):
    KIND: ClassVar[str] = "rxcomm/Calibration"
    SCHEMA_VERSION: ClassVar[int] = 1
    REQUIRED_SUMMARY_KEYS: ClassVar[tuple[str, ...]] = (
        "n_identifiable",
        "fit_max_position_error_m",
        "heldout_max_position_error_m",
        "heldout_max_orientation_error_rad",
        "nominal_heldout_max_position_error_m",
        "frames_only_heldout_max_position_error_m",
        "seconds",
    )

    robot: str
    joint_names: list[str]
    measurement: Literal["pose", "position"]
    tracker_to_base: Placement = Field(
        description="nominal base pose in the tracker frame the errors refer to"
    )
    tracker_to_base_source: Literal["measurements", "cell", "registration"]
    parameters: list[ParameterEstimate]
    dropped: list[DroppedParameter]
    frames_only_parameters: list[ParameterEstimate] = Field(description="the base + tool baseline fit")
    error_tables: list[ErrorTable]
    fit_poses: list[int] = Field(description="indices into the measurement file's poses")
    heldout_poses: list[int]
    outlier_poses: list[int] = Field(description="flagged poses (excluded from the final fit unless kept)")
    baseline_fit: BaselineFit | None = Field(None, description="the calibration from the baseline poses")
    calibrated_urdf: str | None = None
