"""`dynamics.yaml`: identified dynamics of one robot (kind `rxcomm/Dynamics`, architecture §7 identify).

What planners and `run` need is τ(q, q̇, q̈); the base parameters determine it completely. Each base
parameter stores its definition as a combination of named full parameters (p_b = Σ c_i·p_i, the
paper's regrouping), so a reader rebuilds a full parameter vector reproducing exactly these torques
(`rxcomm.model.base_parameters.load_dynamics`) without recomputing the QR. `full_parameters`, when present
(e.g. a physically consistent estimate), takes precedence.

Units: SI; parameter names as in `rxcomm.model.dynamics.parameter_names` (`joint_2.mcx` in kg·m,
`joint_3.Ixx` in kg·m² about the joint frame origin, `joint_4.rotor_inertia` motor side kg·m²,
`joint_1.fc` N·m, `joint_1.fv` N·m·s/rad, `joint_1.offset` N·m, `spring.k` N/m, `spring.kL0` N).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict


class BaseParameterEstimate(Strict):
    name: str = Field(description="e.g. joint_2.mcz_R (suffix _R: other parameters are regrouped onto it)")
    label: str = Field(description="human-readable definition, e.g. 'joint_2.mcz + 0.625·joint_3.m + …'")
    independent: str = Field(description="the full parameter kept for it (coefficient 1 in `combination`)")
    combination: dict[str, float] = Field(description="full parameter name → coefficient")
    value: float = Field(description="estimate, SI units of the independent parameter")
    relative_std: float | None = Field(
        None,
        description="standard deviation / |value| from the least-squares covariance; None if not estimated",
    )
    std: float | None = Field(
        None,
        description="standard deviation (units of value) from the least-squares covariance; None if not "
        "estimated (older artefacts: |value| · relative_std, which a value of 0 cannot carry)",
    )

    @model_validator(mode="after")
    def _independent_in_combination(self) -> BaseParameterEstimate:
        if abs(self.combination.get(self.independent, 0.0) - 1.0) > 1e-12:
            raise ValueError(f"combination must contain {self.independent!r} with coefficient 1")
        return self


class BaseSetInfo(Strict):
    """How the base set was found (numerical QR on random states, `rxcomm.model.base_parameters`)."""

    n_full: int = Field(description="number of full parameters (regressor columns)")
    n_base: int
    rank_tolerance: float = Field(description="relative tolerance on the unit-column QR diagonal")
    r_min_kept: float = Field(description="smallest kept |R_ii| / |R_00| (unit columns)")
    r_max_dropped: float = Field(description="largest dropped |R_ii| / |R_00| (unit columns)")
    cond: float = Field(description="condition number of the unit-column base regressor on the random states")
    n_samples: int
    seed: int
    unidentifiable: list[str] = Field(description="parameters with no effect on the joint torques")


class JointFriction(Strict):
    joint: str
    coulomb_nm: float
    viscous_nm_s_per_rad: float
    offset_nm: float = Field(description="constant torque offset (sensor bias), N·m")
    motor_coulomb_nm: float | None = Field(
        None, description="Coulomb friction of this axis's motor, motor side, N·m (motor friction models)"
    )
    motor_viscous_nm_s_per_rad: float | None = Field(
        None, description="viscous friction of this axis's motor, motor side, N·m·s/rad"
    )


class SpringEstimate(Strict):
    """The balancer: τ_s = k·ab·sinθ − k·L0·ab·sinθ/L. The first term has the shape of link gravity and
    regroups with the spring link's first moment, so only k·L0 is identifiable on its own."""

    joint: str
    k_l0_n: float = Field(description="k·L0, N (identified)")
    k_l0_relative_std: float | None = None
    stiffness_n_per_m: float = Field(
        description="k, N/m: the prior when not identifiable alone (`stiffness_identified` false)"
    )
    stiffness_identified: bool = False


class IdentifySettings(Strict):
    """Options of `rxcomm identify` (units in the names)."""

    cutoff_hz: Annotated[float, Field(gt=0)] | Literal["auto"] = Field(
        10.0,
        description="low-pass cut-off of positions and torques, Hz; auto: the grid value with the least "
        "cross-validated held-out error (`rxcomm.identification.cross_validation.choose_cutoff`)",
    )
    cutoff_grid_hz: tuple[Annotated[float, Field(gt=0)], ...] = Field(
        (5.0, 10.0, 20.0, 40.0), min_length=2, description="cut-offs tried by cutoff_hz auto, Hz"
    )
    filter_order: int = Field(4, ge=1, le=8, description="Butterworth order (doubled by the zero-phase pass)")
    decimate_hz: float | None = Field(
        None,
        gt=0,
        description="sample rate after filtering and differentiation, Hz; None: 2 × cutoff_hz (rows "
        "uncorrelated)",
    )
    folds: int = Field(
        5,
        ge=0,
        description="blocked cross-validation: the log cut into this many contiguous folds in time, each "
        "predicted by a fit on the others (0: none)",
    )
    min_speed_rad_s: float = Field(
        0.05, ge=0, description="rows of a joint slower than this are rejected (friction sign uncertain)"
    )
    standstill_speed_rad_s: float = Field(
        0.005,
        ge=0,
        description="the prediction takes a joint slower than this as standing (zero velocity: no "
        "Coulomb term), never the sign of the noise in q̇, except until q̇ first reaches zero and from "
        "where it last leaves zero (a reversal, a dip, a creep to a stop slide the way they move); "
        "above the filtered q̇'s noise (≈1e-4 rad/s for 2e-5 rad encoder noise at 10 Hz)",
    )
    method: Literal["wls", "ols"] = Field("wls", description="weighted (per-joint noise) or ordinary LS")
    physical: bool | None = Field(
        None,
        description="write the physically consistent estimate: always (True), never (False), or (None) "
        "where the unconstrained one is inconsistent and the consistent one within √n_base σ of it",
    )
    holdout_fraction: float = Field(
        0.2, gt=0, lt=0.9, description="part of the log held out for validation without --validate"
    )
    holdout_blocks: int = Field(
        5,
        ge=1,
        description="without --validate the log is cut into this many blocks and the last holdout_fraction "
        "of each is held out (interleaved: a log that ends at standstill still validates on motion; "
        "1 = the last part of the log)",
    )
    friction: Literal["joint", "motor", "both"] | None = Field(
        None, description="friction model; None: drives.yaml's (`Robot.friction_mode`)"
    )
    min_rows_per_parameter: float = Field(
        10.0, gt=0, description="fewer fit rows per base parameter than this gets a warning and a suggestion"
    )
    max_cond: float = Field(
        1e4, gt=1, description="refuse a log whose unit-column base regressor is worse conditioned"
    )
    max_gap_s: float = Field(0.01, ge=0, description="longer gaps (or lost-record runs) are an error")
    torque_lag_s: float | None = Field(
        None,
        description="the torque paired with a position sample is logged this much later; "
        "None: the log's own (one drive cycle for a run log, 0 for a CSV)",
    )
    stick_guard_s: float | None = Field(
        None, ge=0, description="rows this close to a joint's slow sample are rejected; default 1/cutoff_hz"
    )
    saturation_fraction: float = Field(
        0.995, gt=0, le=1, description="|τ| at or above this fraction of peak torque counts as saturated"
    )
    trim_s: float | None = Field(None, ge=0, description="trimmed at each end; default 2/cutoff_hz")

    @property
    def cutoff(self) -> float:
        """The cut-off in Hz (a resolved `auto`: see `with_cutoff`)."""
        if self.cutoff_hz == "auto":
            raise ValueError("cutoff_hz auto is resolved by choose_cutoff before processing")
        return float(self.cutoff_hz)

    @property
    def decimate(self) -> float:
        """The decimated sample rate, Hz (2 × the cut-off unless set)."""
        return 2.0 * self.cutoff if self.decimate_hz is None else float(self.decimate_hz)

    def with_cutoff(self, cutoff_hz: float) -> IdentifySettings:
        """These settings at a given cut-off (the decimation follows it unless set)."""
        return self.model_copy(update={"cutoff_hz": float(cutoff_hz)})


class DynamicsSummary(Strict):
    """What a rxcomm/Dynamics summary holds (units in the names; None: not measured)."""

    n_base_params: int
    kinematics: str | None = Field(
        None, description="nominal, or calibrated (identify --calibration): the kinematics of the fit"
    )
    kinematics_regrouped: str | None = Field(
        None,
        description="calibrated kinematics: link first moments the axis tilt separates, fitted regrouped "
        "because the log could not condition them all beside J1's friction offset and did not determine "
        "these; '' none; None nominal kinematics",
    )
    validation_nrmse: list[float | None] | None = Field(description="required; None: not measured")
    validation_rms_nm: list[float | None] | None = Field(description="required; None: not measured")
    seconds: float | None = Field(description="required; None: not measured")
    validation: str | None = None
    validation_r2: list[float | None] | None = None
    validation_scored_on: str | None = None
    validation_nrmse_normalisation: str | None = None
    validation_joints_not_scored: str | None = None
    validation_rms_all_rows_nm: list[float | None] | None = None
    validation_total_rms_moving_nm: float | None = None
    validation_total_rms_every_row_nm: float | None = None
    validation_standstill_fraction: list[float | None] | None = None
    validation_standstill_rows: list[int] | None = Field(
        None, description="per joint, how many validation rows it stood still on (the in-band share's base)"
    )
    validation_standstill_rms_nm: list[float | None] | None = None
    validation_standstill_in_band_fraction: list[float | None] | None = Field(
        None,
        description="per joint, the share of standstill rows inside the stiction band; null: no "
        "standstill, or the band is narrower than the torque noise (validation_stiction_band_below_noise)",
    )
    validation_stiction_band_nm: list[float | None] | None = Field(
        None, description="per joint, the static friction band ±Fc (joint side) scored against"
    )
    validation_stiction_band_below_noise: list[bool] | None = Field(
        None,
        description="per joint, the band is narrower than the fit's torque noise (noise_sigma_nm): its "
        "standstill rows are not scored against it",
    )
    friction: str | None = None
    cutoff_hz: float | None = None
    rows_per_parameter: float | None = None
    cond: float | None = None
    cond_raw: float | None = None
    method: str | None = None
    n_samples: int | None = None
    n_rows: int | None = None
    n_rows_rejected: int | None = None
    sample_hz: float | None = None
    source_hz: float | None = None
    fit_rms_nm: list[float | None] | None = None
    noise_sigma_nm: list[float | None] | None = None
    max_relative_std: float | None = None
    median_relative_std: float | None = None
    link_pseudo_inertia_min_eig_kgm2: list[float | None] | None = None
    n_inconsistent_links: int | None = None
    inconsistent_links: str | None = None
    negative_drive_parameters: str | None = None
    consistency_distance_sigma: float | None = None
    consistency_written_sigma: float | None = None
    cv_folds: int | None = None
    cv_folds_scored: int | None = None
    cv_rms_nm: list[float | None] | None = None
    cv_nrmse: list[float | None] | None = None
    cv_r2: list[float | None] | None = None
    cv_fit_rms_nm: list[float | None] | None = None
    cv_gap_s: float | None = None
    cv_scored_on: str | None = None
    cutoff_choice: str | None = None
    cutoff_grid_hz: list[float | None] | None = None
    cutoff_grid_cv_nrmse: list[float | None] | None = None


class Dynamics(Artefact[IdentifySettings, DynamicsSummary], kind="rxcomm/Dynamics", schema_version=1):
    robot: str = Field(description="robot name (URDF)")
    robot_joints: list[str]
    parameter_names: list[str] = Field(description="full parameter names, regressor column order")
    base_set: BaseSetInfo
    base_parameters: list[BaseParameterEstimate]
    full_parameters: dict[str, float] | None = Field(
        None, description="a full parameter estimate consistent with the base values (takes precedence)"
    )
    full_parameters_method: str | None = Field(None, description="how `full_parameters` was obtained")
    friction: list[JointFriction]
    spring: SpringEstimate | None = None
    kinematics_errors: dict[str, float] | None = Field(
        None,
        description="geometric errors (model.geometric_errors names; m, rad) of the kinematics of the fit "
        "(identify --calibration), where stages evaluate its torques; None: the nominal kinematics",
    )

    @model_validator(mode="after")
    def _consistent(self) -> Dynamics:
        names = set(self.parameter_names)
        if len(names) != len(self.parameter_names):
            raise ValueError("parameter_names has duplicates")
        base_names = [b.name for b in self.base_parameters]
        if len(set(base_names)) != len(base_names):
            raise ValueError("base parameter names must be unique")
        if len(base_names) != self.base_set.n_base:
            raise ValueError(
                f"base_set.n_base is {self.base_set.n_base}, {len(base_names)} base parameters given"
            )
        for b in self.base_parameters:
            if unknown := [n for n in b.combination if n not in names]:
                raise ValueError(f"base parameter {b.name!r} uses unknown parameters {unknown}")
        if self.full_parameters is not None and set(self.full_parameters) != names:
            raise ValueError("full_parameters must hold exactly the names of parameter_names")
        if [f.joint for f in self.friction] != self.robot_joints:
            raise ValueError("friction must list robot_joints in order")
        return self
