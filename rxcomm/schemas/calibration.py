"""`calibration.yaml`: identified geometric errors (kind `rxcomm/Calibration`, paper §3.1–3.2).

`parameters` holds all 48 error parameters of `rxcomm.model.geometric_errors` (names `base.*`, `{joint}.*`,
`tool.*`; m and rad) with their standard deviations; parameters that the measurements cannot
identify are fixed at 0 (`estimated: false`) and listed in `dropped` with the reason. The errors are
relative to `tracker_to_base`, the nominal pose of the robot base in the tracker frame that was used.
`rxcomm.calibration.loading.load_calibration` returns (ErrorModel, tracker_to_base) from this file.

`error_tables` is the paper's Table 2: per pose set (fit, held out) and model (nominal, calibrated,
base + tool frames only) the max |e| and peak-to-peak of e for x, y, z (m: measured − predicted TCP
position in the tracker frame) and α, β, γ (rad: Cardan x-y-z angles of R_meas·R_predᵀ).

`tracker_noise` is the noise the fit weighed the residuals with (given, or estimated from them);
`model_selection` the candidate error models (base + tool frames; + joint offsets; the full
identifiable set; + joint compliance) with their cross-validated held-out errors and the one chosen
(the simplest within one standard error of the best); `compliance` the joint compliances of the
chosen model (rad per N·m of the prior model's holding torque; reported, not folded into the URDF);
`undetermined` the parameters whose σ says the data cannot determine them; `notes` what the user
should act on (a base guess replaced, a tool offset folded in, position-only measurements).

When the measurements hold `baseline` poses (a naive set, `select-configs --measure-baseline`),
`baseline_fit` is the same calibration fitted to those instead, and the held-out table of model
`baseline_poses` shows what it would have left on the same held-out poses.
"""

from __future__ import annotations

from typing import Literal

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
    model: Literal["nominal", "calibrated", "frames_only", "baseline_poses", "rigid"] = Field(
        description="rigid: the full rigid model, shown when the chosen one has joint compliance"
    )
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


class TrackerNoise(Strict):
    position_sigma_m: float = Field(gt=0, description="1σ per axis used to weigh position residuals")
    orientation_sigma_rad: float | None = Field(
        description="1σ per axis used to weigh orientation residuals; None: position-only measurements"
    )
    source: Literal["option", "cell", "measurements", "estimated"] = Field(
        description="estimated: variance components from the fit's residuals (no σ given)"
    )


class CandidateModel(Strict):
    name: Literal["frames", "offsets", "full", "full+compliance"]
    n_parameters: int
    parameters: list[str] = Field(description="the geometric parameters, then `{joint}.compliance`")
    cv_weighted_misfit: float | None = Field(
        description="mean over fit poses of the squared weighted residual when the pose was held out"
    )
    cv_standard_error: float | None = Field(description="paired standard error against the best candidate")
    cv_rms_position_error_m: float | None
    cv_rms_orientation_error_rad: float | None
    chosen: bool
    note: str | None = None


class ModelSelection(Strict):
    folds: int
    rule: str
    chosen: str
    candidates: list[CandidateModel]


class ComplianceEstimate(Strict):
    joint: str
    compliance_rad_per_nm: float
    std: float
    stiffness_nm_per_rad: float | None = Field(description="1 / compliance; None when not positive")


class Calibration(Artefact):
    KIND = "rxcomm/Calibration"
    SCHEMA_VERSION = 2
    REQUIRED_SUMMARY_KEYS = (
        "n_identifiable",
        "fit_max_position_error_m",
        "heldout_max_position_error_m",
        "heldout_max_orientation_error_rad",
        "nominal_heldout_max_position_error_m",
        "frames_only_heldout_max_position_error_m",
        "tracker_position_sigma_m",
        "model",
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
    tracker_noise: TrackerNoise
    model_selection: ModelSelection
    compliance: list[ComplianceEstimate] = Field([], description="of the chosen model; empty when rigid")
    undetermined: list[str] = Field([], description="parameters with σ above the threshold (see settings)")
    notes: list[str] = Field([], description="what the user should act on")
    calibrated_urdf: str | None = None
