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


class CalibrateSettings(Strict):
    """Options of `calibrate` (the stage's settings, recorded in the artefact)."""

    holdout_fraction: float | None = Field(
        None,
        ge=0.0,
        lt=1.0,
        description="fraction of the fit-role poses held out (seeded); default 0 if the file has "
        "validation poses, else 0.25",
    )
    seed: int = 0
    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = Field(
        "linear", description="robust loss on the weighted residuals (scale 3σ); linear = plain LM"
    )
    outlier_sigma: float = Field(
        5.0, gt=0, description="flag a pose with a residual beyond this many robust σ"
    )
    drop_outliers: bool = True
    position_sigma_m: float | None = Field(
        None, gt=0, description="tracker position noise (1σ, m); default the file's, else estimated"
    )
    orientation_sigma_rad: float | None = Field(
        None, gt=0, description="tracker orientation noise (1σ, rad); default the file's, else estimated"
    )
    point_in_tcp_m: tuple[float, float, float] | None = Field(
        None, description="measured point in the TCP frame (position-only probes); default the TCP origin"
    )
    max_iterations: int = Field(100, ge=1)
    cv_folds: int = Field(5, ge=2, description="folds of the cross-validation that chooses the model")
    model: Literal["auto", "frames", "offsets", "full", "full+compliance"] = Field(
        "auto", description="error model; auto: the richest model offered, regularised by the priors"
    )
    regularise: bool = Field(
        True,
        description="priors from manufacturing tolerances on the joint errors (calibration.priors): "
        "few noisy poses shrink toward the frames-only answer",
    )
    compliance: bool = Field(True, description="offer joint-compliance candidates to the model selection")
    undetermined_std_ratio: float = Field(
        5.0,
        gt=0,
        description="name a parameter whose σ at the TCP (m; rad × reach) exceeds this many position σ",
    )


class CalibrationSummary(Strict):
    """What a rxcomm/Calibration summary holds (units in the names; None: not measured)."""

    n_identifiable: int
    fit_max_position_error_m: float | None = Field(description="required; None: not measured")
    fit_max_orientation_error_rad: float | None = None
    heldout_max_position_error_m: float | None = Field(description="required; None: not measured")
    heldout_max_orientation_error_rad: float | None = Field(description="required; None: not measured")
    nominal_heldout_max_position_error_m: float | None = Field(description="required; None: not measured")
    nominal_heldout_max_orientation_error_rad: float | None = None
    frames_only_heldout_max_position_error_m: float | None = Field(description="required; None: not measured")
    frames_only_heldout_max_orientation_error_rad: float | None = None
    nominal_fit_max_position_error_m: float | None = None
    rigid_heldout_max_position_error_m: float | None = None
    model: str
    tracker_position_sigma_m: float | None = Field(description="required; None: not measured")
    tracker_orientation_sigma_rad: float | None = None
    tracker_sigma_source: str | None = None
    prior_scale: float | None = Field(
        None,
        description="factor on the manufacturing classes' prior σ the data asked for (0.01–30; 1: the "
        "classes hold, below 1 the arm is better than them); None: not regularised",
    )
    n_undetermined: int | None = None
    compliance_torque_model: str | None = None
    heldout_rms_position_error_m: float | None = None
    n_fit: int | None = None
    n_heldout: int | None = None
    n_outliers: int | None = None
    minimal_detectable_blunder_m: float | None = Field(
        None,
        description="the largest, over the fit poses' position components, of the blunder the outlier "
        "test flags 4 times in 5 (Baarda's minimal detectable blunder: (outlier_sigma + 0.84)·σ_p/√(1 − h)); "
        "a larger one there is likely caught, a smaller one may hide",
    )
    minimal_detectable_blunder_pose: int | None = Field(
        None, description="the pose of minimal_detectable_blunder_m (the one the fit leans on most)"
    )
    median_minimal_detectable_blunder_m: float | None = Field(
        None, description="the median of the same over all fit poses' position components"
    )
    n_unread_fit_poses: int | None = Field(
        None, description="fit poses in the measurements without a tracker reading (valid: false), left out"
    )
    n_unread_validation_poses: int | None = Field(None, description="the same for the validation poses")
    n_unread_baseline_poses: int | None = Field(None, description="the same for the naive (baseline) poses")
    residual_scale: float | None = None
    jacobian_cond: float | None = None
    function_evaluations: int | None = None
    seconds: float | None = Field(description="required; None: not measured")
    cv_rms_position_error_frames_m: float | None = None
    cv_rms_position_error_offsets_m: float | None = None
    cv_rms_position_error_full_m: float | None = None
    cv_rms_position_error_full_compliance_m: float | None = None
    n_baseline_poses: int | None = None
    baseline_poses_heldout_max_position_error_m: float | None = None
    baseline_poses_heldout_max_orientation_error_rad: float | None = None
    baseline_poses_heldout_rms_position_error_m: float | None = None
    baseline_poses_worse_p_value: float | None = None
    baseline_poses_median_std_ratio: float | None = None
    mdh_max_position_residual_m: float | None = None
    mdh_max_orientation_residual_rad: float | None = None
    mdh_beta_max_position_residual_m: float | None = None
    mdh_beta_max_orientation_residual_rad: float | None = None
    stiffness_nm_per_rad: dict[str, float | None] = Field(
        {}, description="joint name -> fitted stiffness, N·m/rad (None: not positive)"
    )
    stiffness_std_nm_per_rad: dict[str, float | None] = Field({}, description="joint name -> its 1σ, N·m/rad")


class Calibration(
    Artefact[CalibrateSettings, CalibrationSummary], kind="rxcomm/Calibration", schema_version=2
):
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
