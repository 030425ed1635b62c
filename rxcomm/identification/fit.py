"""Dynamic parameter identification from joint logs (paper §4.1, §4.3; architecture §7 identify).

`identify` chains the steps, each in its own module:

- `logs`: a `JointLog` (t, q, τ at the joint side) from a run log MCAP or a robot CSV, checked and put
  on a clean time base (`check_log`), the torque aligned with the position it acted at;
- `processing`: zero-phase low-pass, differentiation, trimming, decimation (`preprocess`) and the
  regressor rows with parallel-filtered Coulomb columns (`regressor`);
- `estimation`: OLS then per-joint WLS on the base parameters, covariance, excitation check;
- `consistency`: pseudo-inertia eigenvalues and the nearest physically consistent estimate;
- `validation`: the plain prediction error per joint on moving rows, standstill apart, a joint that
  did not move "not scored"; the interleaved hold-out when no validation log is given;
- `cross_validation`: blocked k-fold cross-validation in time (the held-out error beside the fit's,
  every identification), and the cut-off chosen by it (`cutoff_hz` "auto");
- `export`: the base parameters ± σ and the validation torques as CSV.

`score` checks an identified model on a new log with the same processing and figures.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.identification.consistency import (
    PhysicalFit,
    drive_violations,
    link_min_eigenvalues,
    physical_fit,
)
from rxcomm.identification.cross_validation import (
    CrossValidation,
    CutoffChoice,
    choose_cutoff,
    cross_validate,
)
from rxcomm.identification.estimation import Estimate, estimate
from rxcomm.identification.logs import JointLog, check_log
from rxcomm.identification.processing import preprocess, regressor
from rxcomm.identification.settings import IdentifySettings
from rxcomm.identification.validation import Validation, holdout_mask, nan_list, validate
from rxcomm.model.base_parameters import (
    BaseParameterSet,
    base_parameters,
    parameters_from_base,
)
from rxcomm.model.dynamics import (
    DynamicParameters,
    parameter_names,
    prior_parameters,
)
from rxcomm.model.robot import Robot

# A joint whose cross-validated held-out error exceeds its fit error by more than this is flagged.
CV_TO_FIT_LIMIT = 3.0
# The cut-off used when `auto` cannot choose (the option's long-standing default).
FALLBACK_CUTOFF_HZ = 10.0


@dataclass(frozen=True, eq=False)
class Identification:
    """What `identify` returns: the base set, the estimate, the parameters to write (`params`, with
    `p_b` = K·params; consistent when `physical`), the consistency figures, the validation."""

    bset: BaseParameterSet
    estimate: Estimate
    p_b: np.ndarray
    params: DynamicParameters
    physical: bool
    method: str
    physical_fit: PhysicalFit
    link_min_eig_kgm2: np.ndarray
    drive_violations: list[str]
    validation: Validation
    n_samples: int
    sample_hz: float
    source_hz: float
    seconds: float
    robot: Robot | None = None
    cutoff_hz: float = math.nan
    timings: dict[str, float] = field(default_factory=dict)
    cross_validation: CrossValidation | None = None
    cutoff_choice: CutoffChoice | None = None
    cutoff_note: str | None = None  # why `auto` could not choose (and the cut-off used instead)

    @property
    def friction_mode(self) -> str:
        return "joint" if self.robot is None else self.robot.friction_mode

    @property
    def rows_per_parameter(self) -> float:
        return self.estimate.n_rows / self.bset.n_base

    def inconsistent_links(self) -> list[str]:
        """Links whose pseudo-inertia (closest full vector to the prior) is not positive definite, with
        the smallest eigenvalue: no body has that mass distribution."""
        names = self.params.joint_names
        return [f"{names[i]} ({v:.3g} kg·m²)" for i, v in enumerate(self.link_min_eig_kgm2) if v <= 0]

    def consistency_note(self) -> str:
        """How far the nearest physically consistent estimate is, against the noise's √n_base σ."""
        dist, bound = self.physical_fit.mahalanobis, float(np.sqrt(self.bset.n_base))
        written = (
            f"written: the consistent body closest to the prior among those within one σ more "
            f"({self.physical_fit.params_mahalanobis:.3g} σ away)"
        )
        return (
            f"the nearest consistent estimate is {dist:.3g} σ away, "
            f"{'within' if dist <= bound else 'beyond'} the noise (√n_base = {bound:.3g}); "
            + (written if self.physical else "--physical writes it")
        )

    def warnings(self, settings: IdentifySettings | None = None) -> list[str]:
        """What a user should act on: too few rows per parameter, parameters the data barely see."""
        settings = settings or IdentifySettings()
        out = []
        rpp = self.rows_per_parameter
        if rpp < settings.min_rows_per_parameter:
            factor = settings.min_rows_per_parameter / rpp
            fc = min(self.cutoff_hz * factor, 0.4 * self.source_hz)
            out.append(
                f"{self.estimate.n_rows} fit rows for {self.bset.n_base} base parameters "
                f"({rpp:.1f} per parameter, fewer than {settings.min_rows_per_parameter:g}): the standard "
                f"deviations are large; a higher cut-off and sample rate keep more rows, e.g. --cutoff-hz "
                f"{fc:.0f} --decimate-hz {2 * fc:.0f} (or --cutoff-hz auto: the cut-off the held-out folds "
                "prefer), or record a longer log"
            )
        cv = self.cross_validation
        if cv is not None and cv.folds_scored:
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = cv.rms_nm / cv.fit_rms_nm
            over = [j for j in range(len(ratio)) if ratio[j] > CV_TO_FIT_LIMIT]
            if over:
                names = self.params.joint_names
                figs = ", ".join(
                    f"{names[j]} {cv.rms_nm[j]:.3g} vs {cv.fit_rms_nm[j]:.3g} N·m ({ratio[j]:.0f}×)"
                    for j in over
                )
                out.append(
                    f"held-out folds miss by more than {CV_TO_FIT_LIMIT:g}× the fit error ({figs}): the fit "
                    "follows noise or one part of the log on these joints (too few rows, too little "
                    "motion, or a model term that changes over the log); do not trust their "
                    "parameters without more or longer data"
                )
        if self.cutoff_note:
            out.append(self.cutoff_note)
        big = [self.bset.names[i] for i in np.flatnonzero(self.estimate.relative_std > 1.0)]
        if big:
            more = f" and {len(big) - 5} more" if len(big) > 5 else ""
            out.append(
                f"{len(big)} base parameters have a relative standard deviation above 100 % "
                f"({', '.join(big[:5])}{more}): small, or the log hardly excites them"
            )
        return out

    def summary(self) -> dict[str, object]:
        """The flat summary of dynamics.yaml (architecture §9 keys first). Per-joint validation figures
        are null for a joint that did not move on the validation data (not scored)."""
        est, val = self.estimate, self.validation
        return {
            "n_base_params": self.bset.n_base,
            "validation_nrmse": nan_list(val.nrmse),
            "validation_rms_nm": nan_list(val.rms_nm),
            "seconds": self.seconds,
            **validation_summary(val, self.params.joint_names),
            "friction": self.friction_mode,
            "cutoff_hz": self.cutoff_hz,
            "rows_per_parameter": self.rows_per_parameter,
            "cond": est.cond,
            "cond_raw": est.cond_raw,
            "method": self.method + (" + physical consistency" if self.physical else ""),
            "n_samples": self.n_samples,
            "n_rows": est.n_rows,
            "n_rows_rejected": est.n_rejected,
            "sample_hz": self.sample_hz,
            "source_hz": self.source_hz,
            "fit_rms_nm": est.residual_rms_nm.tolist(),
            "noise_sigma_nm": est.sigma_joint_nm.tolist(),
            "max_relative_std": float(np.max(est.relative_std)),
            "median_relative_std": float(np.median(est.relative_std)),
            "link_pseudo_inertia_min_eig_kgm2": self.link_min_eig_kgm2.tolist(),
            "n_inconsistent_links": int(np.sum(self.link_min_eig_kgm2 <= 0)),
            "inconsistent_links": ", ".join(self.inconsistent_links()),
            "negative_drive_parameters": ", ".join(self.drive_violations),
            "consistency_distance_sigma": self.physical_fit.mahalanobis,
            "consistency_written_sigma": self.physical_fit.params_mahalanobis if self.physical else None,
            **(self.cross_validation.summary() if self.cross_validation else {"cv_folds": 0}),
            **(
                self.cutoff_choice.summary()
                if self.cutoff_choice
                else {"cutoff_choice": self.cutoff_note or "given (--cutoff-hz)"}
            ),
        }


def validation_summary(val: Validation, joint_names: tuple[str, ...] | list[str]) -> dict[str, object]:
    """The validation's keys of the summary: per joint on moving rows, every row and standstill (in
    the friction band), and over all joints; null where not scored (never 0)."""

    def finite(v: float) -> float | None:
        return float(v) if math.isfinite(v) else None

    return {
        "validation_nrmse": nan_list(val.nrmse),
        "validation_rms_nm": nan_list(val.rms_nm),
        "validation": val.source,
        "validation_r2": nan_list(val.r2),
        "validation_scored_on": "rows where the joint moves (|qd| >= min_speed_rad_s); plain prediction",
        "validation_nrmse_normalisation": "rms error / (max - min) of the measured torque (moving rows)",
        "validation_joints_not_scored": ", ".join(
            j for j, ok in zip(joint_names, val.scored, strict=True) if not ok
        ),
        "validation_rms_all_rows_nm": val.rms_all_nm.tolist(),
        "validation_total_rms_moving_nm": finite(val.total_rms_moving_nm),
        "validation_total_rms_every_row_nm": finite(val.total_rms_every_row_nm),
        "validation_standstill_fraction": val.standstill_fraction.tolist(),
        "validation_standstill_rows": [int(k) for k in val.standstill_rows],
        "validation_standstill_rms_nm": nan_list(val.standstill_rms_nm),
        "validation_standstill_in_band_fraction": nan_list(val.standstill_in_band_fraction),
        "validation_stiction_band_nm": val.stiction_band_nm.tolist(),
        "validation_stiction_band_below_noise": [bool(b) for b in val.band_below_noise],
    }


def identify(
    robot: Robot,
    log: JointLog,
    settings: IdentifySettings | None = None,
    *,
    validation_log: JointLog | None = None,
    bset: BaseParameterSet | None = None,
    prior: DynamicParameters | None = None,
) -> Identification:
    """Identify the base parameters from `log` and validate them (module docstring)."""
    t0 = time.perf_counter()
    settings = settings or IdentifySettings()
    if settings.friction is not None and settings.friction != robot.friction_mode:
        robot = robot.with_friction(settings.friction)
    prior = prior_parameters(robot) if prior is None else prior.conform(robot)
    timings: dict[str, float] = {}
    bset = base_parameters(robot) if bset is None else bset
    if tuple(bset.full_names) != parameter_names(
        robot.joint_names, robot.drives.spring is not None, robot.has_motor_friction
    ):
        raise ValueError(f"the base set is not over robot {robot.name!r}'s parameters (friction model?)")
    timings["base_set"] = time.perf_counter() - t0
    tick = time.perf_counter()
    clean = check_log(log, robot, settings)
    choice, note = None, None
    if settings.cutoff_hz == "auto":
        try:
            choice = choose_cutoff(robot, bset, clean, settings)
            settings, data = settings.with_cutoff(choice.cutoff_hz), choice.data
        except InputError as e:
            note = f"{e.reason}: cut-off {FALLBACK_CUTOFF_HZ:g} Hz used"
            settings = settings.with_cutoff(FALLBACK_CUTOFF_HZ)
            data = preprocess(clean, settings, robot)
        timings["choose_cutoff"] = time.perf_counter() - tick
        tick = time.perf_counter()
    else:
        data = preprocess(clean, settings, robot)
    w_all = bset.base_regressor(regressor(robot, data))  # once: the fit, the folds and the hold-out
    fit_rows = np.ones(len(data.t), dtype=bool)
    if validation_log is None:
        held = holdout_mask(data.t, settings.holdout_fraction, settings.holdout_blocks)
        fit_rows = ~held
        fit_data, val_data = data.select(~held), data.select(held)
        pct = 100 * settings.holdout_fraction
        if settings.holdout_blocks == 1:
            val_source = f"held out: last {pct:.0f} % of the log (t >= {val_data.t[0]:.3f} s)"
        else:
            val_source = (
                f"held out: last {pct:.0f} % of each of {settings.holdout_blocks} blocks of the log "
                "(interleaved)"
            )
    else:
        fit_data = data
        val_data = preprocess(check_log(validation_log, robot, settings), settings, robot)
        val_source = f"log: {Path(validation_log.source).name or 'given'}"
    timings["preprocess"] = time.perf_counter() - tick
    tick = time.perf_counter()
    w_fit = w_all[np.repeat(fit_rows, robot.n)]
    est = estimate(robot, bset, fit_data, settings, source=log.source or None, w=w_fit)
    timings["estimate"] = time.perf_counter() - tick
    tick = time.perf_counter()
    cv = cross_validate(robot, bset, data, settings, w=w_all) if settings.folds >= 2 else None
    timings["cross_validation"] = time.perf_counter() - tick
    tick = time.perf_counter()
    closest = parameters_from_base(robot, bset, est.p_b, prior)
    phys = physical_fit(robot, bset, est, prior)
    timings["physical"] = time.perf_counter() - tick
    physical = settings.physical
    if physical is None:  # auto: no body has that mass distribution, and the data cannot tell
        inconsistent = bool(np.any(link_min_eigenvalues(closest) <= 0) or drive_violations(closest))
        # (consistent by construction, solved or not: links projected positive definite, drives ≥ 0)
        physical = inconsistent and phys.mahalanobis <= np.sqrt(len(est.p_b))
    if physical:
        params, p_b = phys.params, phys.p_b
    else:
        params, p_b = closest, est.p_b
    tick = time.perf_counter()
    val = validate(robot, params, val_data, val_source, settings.min_speed_rad_s, est.sigma_joint_nm)
    timings["validate"] = time.perf_counter() - tick
    return Identification(
        bset=bset,
        estimate=est,
        p_b=p_b,
        params=params,
        physical=physical,
        method=settings.method,
        physical_fit=phys,
        link_min_eig_kgm2=link_min_eigenvalues(closest),
        drive_violations=drive_violations(closest),
        validation=val,
        n_samples=len(fit_data.t),
        sample_hz=data.sample_hz,
        source_hz=data.source_hz,
        seconds=time.perf_counter() - t0,
        robot=robot,
        cutoff_hz=settings.cutoff,
        timings=timings,
        cross_validation=cv,
        cutoff_choice=choice,
        cutoff_note=note,
    )


def score(
    robot: Robot,
    params: DynamicParameters,
    log: JointLog,
    settings: IdentifySettings | None = None,
    noise_nm: np.ndarray | None = None,
) -> Validation:
    """An identified model checked on another log without refitting (e.g. last month's model against
    today's recording): the same processing and figures as `identify`'s validation; `noise_nm`: the
    model's own fit noise per joint (its summary's), for the stiction band."""
    settings = settings or IdentifySettings()
    if settings.cutoff_hz == "auto":
        raise InputError(
            "a model is scored at its own cut-off (dynamics.yaml summary.cutoff_hz): give a number, not auto",
            field="cutoff_hz",
        )
    if settings.friction is not None and settings.friction != robot.friction_mode:
        robot = robot.with_friction(settings.friction)
    data = preprocess(check_log(log, robot, settings), settings, robot)
    source = f"log: {Path(log.source).name or 'given'}"
    return validate(robot, params, data, source, settings.min_speed_rad_s, noise_nm)
