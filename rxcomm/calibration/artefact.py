"""The `rxcomm/Calibration` artefact from a calibration result: parameters ± σ, the model
comparison, compliance as stiffness ± σ, Table 2 per pose set and model, and the summary figures
the chain and the report read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rxcomm.calibration.fit import CalibrationResult
from rxcomm.calibration.lm import FitResult
from rxcomm.model.geometric_errors import parameter_names, se3_to_xyz_rpy
from rxcomm.model.robot import Robot
from rxcomm.schemas.calibration import (
    BaselineFit,
    Calibration,
    CandidateModel,
    ComplianceEstimate,
    DroppedParameter,
    ErrorRow,
    ErrorTable,
    ModelSelection,
    ParameterEstimate,
    TrackerNoise,
)
from rxcomm.schemas.cell import Placement

QUANTITIES = (("x", "m"), ("y", "m"), ("z", "m"), ("alpha", "rad"), ("beta", "rad"), ("gamma", "rad"))


def _estimates(robot: Robot, fit: FitResult, only: set[str] | None = None) -> list[ParameterEstimate]:
    out = []
    for i, name in enumerate(parameter_names(robot)):
        if only is not None and name not in only:
            continue
        est = bool(fit.estimated[i])
        out.append(
            ParameterEstimate(
                name=name,
                value=float(fit.errors.values[i]),
                std=float(fit.std[i]) if est else None,
                estimated=est,
            )
        )
    return out


def _model_selection(robot: Robot, res: CalibrationResult) -> ModelSelection:
    names = parameter_names(robot)
    cands = [
        CandidateModel(
            name=c.name,
            n_parameters=c.n_parameters,
            parameters=[names[i] for i in c.idx] + [f"{robot.joint_names[j]}.compliance" for j in c.comp],
            cv_weighted_misfit=c.cv_misfit,
            cv_standard_error=c.cv_se,
            cv_rms_position_error_m=c.cv_rms_position_m,
            cv_rms_orientation_error_rad=c.cv_rms_orientation_rad,
            chosen=c.name == res.model,
            note=c.note,
        )
        for c in res.candidates
    ]
    return ModelSelection(
        folds=min(res.settings.cv_folds, int(res.fit_idx.size)),
        rule="auto: the simplest candidate within one paired standard error of the best cross-validated "
        "misfit"
        if res.settings.model == "auto"
        else f"given: {res.settings.model}",
        chosen=res.model,
        candidates=cands,
    )


def compliance_estimates(robot: Robot, fit: FitResult) -> list[ComplianceEstimate]:
    if fit.compliance is None:
        return []
    return [
        ComplianceEstimate(
            joint=robot.joint_names[j],
            compliance_rad_per_nm=float(fit.compliance[j]),
            std=float(fit.compliance_std[j]),
            stiffness_nm_per_rad=float(1.0 / fit.compliance[j]) if fit.compliance[j] > 0 else None,
        )
        for j in np.flatnonzero(np.isfinite(fit.compliance_std))
    ]


def _error_tables(res: CalibrationResult) -> list[ErrorTable]:
    tables = []
    for (pose_set, model), st in res.tables.items():
        rows = [
            ErrorRow(
                quantity=q,
                unit=unit,
                max_abs=float(st.max_abs[k]),
                peak_to_peak=float(st.peak_to_peak[k]),
                rms=float(st.rms[k]),
            )
            for k, (q, unit) in enumerate(QUANTITIES)
            if unit != "rad" or st.max_orientation_error_rad is not None
        ]
        tables.append(
            ErrorTable(
                pose_set=pose_set,
                model=model,
                n_poses=st.n_poses,
                max_position_error_m=st.max_position_error_m,
                rms_position_error_m=st.rms_position_error_m,
                max_orientation_error_rad=st.max_orientation_error_rad,
                rows=rows,
            )
        )
    return tables


def _summary(robot: Robot, res: CalibrationResult, torque_model: str, source: str) -> dict[str, object]:
    """The artefact's summary: the figures make commission and the report read."""

    def stat(pose_set: str, model: str, attr: str):
        st = res.tables.get((pose_set, model))
        return None if st is None else getattr(st, attr)

    summary = {
        "n_identifiable": len(res.identifiable),
        "fit_max_position_error_m": stat("fit", "calibrated", "max_position_error_m"),
        "fit_max_orientation_error_rad": stat("fit", "calibrated", "max_orientation_error_rad"),
        "heldout_max_position_error_m": stat("heldout", "calibrated", "max_position_error_m"),
        "heldout_max_orientation_error_rad": stat("heldout", "calibrated", "max_orientation_error_rad"),
        "nominal_heldout_max_position_error_m": stat("heldout", "nominal", "max_position_error_m"),
        "nominal_heldout_max_orientation_error_rad": stat("heldout", "nominal", "max_orientation_error_rad"),
        "frames_only_heldout_max_position_error_m": stat("heldout", "frames_only", "max_position_error_m"),
        "frames_only_heldout_max_orientation_error_rad": stat(
            "heldout", "frames_only", "max_orientation_error_rad"
        ),
        "nominal_fit_max_position_error_m": stat("fit", "nominal", "max_position_error_m"),
        "rigid_heldout_max_position_error_m": stat("heldout", "rigid", "max_position_error_m"),
        "model": res.model,
        "tracker_position_sigma_m": res.noise.position_sigma_m,
        "tracker_orientation_sigma_rad": res.noise.orientation_sigma_rad,
        "tracker_sigma_source": source,
        "prior_scale": res.prior_scale if res.settings.regularise else None,
        "n_undetermined": len(res.undetermined),
        "compliance_torque_model": torque_model,
        "heldout_rms_position_error_m": stat("heldout", "calibrated", "rms_position_error_m"),
        "n_fit": int(res.fit_idx.size),
        "n_heldout": int(res.heldout_idx.size),
        "n_outliers": int(res.outlier_idx.size),
        **detectable_blunder_figures(res),
        "n_unread_fit_poses": res.unread["fit"],
        "n_unread_validation_poses": res.unread["validation"],
        "n_unread_baseline_poses": res.unread["baseline"],
        "residual_scale": res.fit.residual_scale,
        "jacobian_cond": res.fit.cond,
        "function_evaluations": res.fit.iterations,
        "seconds": res.seconds,
    }
    for c in res.candidates:
        summary[f"cv_rms_position_error_{c.name.replace('+', '_')}_m"] = c.cv_rms_position_m
    estimates = compliance_estimates(robot, res.fit)
    summary["stiffness_nm_per_rad"] = {est.joint: est.stiffness_nm_per_rad for est in estimates}
    summary["stiffness_std_nm_per_rad"] = {
        est.joint: None if est.stiffness_nm_per_rad is None else est.std * est.stiffness_nm_per_rad**2
        for est in estimates
    }
    base = res.baseline
    if base is not None:
        ids = list(res.identifiable.indices)
        summary |= {
            "n_baseline_poses": base.n_poses,
            "baseline_poses_heldout_max_position_error_m": stat(
                "heldout", "baseline_poses", "max_position_error_m"
            ),
            "baseline_poses_heldout_max_orientation_error_rad": stat(
                "heldout", "baseline_poses", "max_orientation_error_rad"
            ),
            "baseline_poses_heldout_rms_position_error_m": stat(
                "heldout", "baseline_poses", "rms_position_error_m"
            ),
            "baseline_poses_worse_p_value": base.worse_p_value,
            # How much less certain each identifiable parameter is from the baseline poses.
            "baseline_poses_median_std_ratio": None
            if base.fit is None
            else float(np.median(base.fit.std[ids] / res.fit.std[ids])),
        }
    return summary


def _baseline_fit(robot: Robot, res: CalibrationResult) -> BaselineFit | None:
    base = res.baseline
    if base is None:
        return None
    return BaselineFit(
        n_poses=base.n_poses,
        parameters=[] if base.fit is None else _estimates(robot, base.fit),
        fit_poses=base.fit_idx.tolist(),
        outlier_poses=base.outlier_idx.tolist(),
        worse_p_value=base.worse_p_value,
        note=base.note,
    )


def calibration_artefact(
    robot: Robot,
    res: CalibrationResult,
    inputs: dict[str, Path],
    urdf_out: Path | None,
    noise_source: str | None = None,
) -> Calibration:
    """`noise_source`: where a given σ came from (option, cell); None: the result's own source."""
    source = res.noise.source if res.noise.source != "settings" else (noise_source or "option")
    torque_model = "identified" if "dynamics" in inputs else "prior"
    summary = _summary(robot, res, torque_model, source)
    xyz, rpy = se3_to_xyz_rpy(res.tracker_to_base)
    frames = {n for n in parameter_names(robot) if n.startswith(("base.", "tool."))}
    return Calibration(
        **Calibration.envelope(inputs, res.settings, summary),
        robot=robot.name,
        joint_names=list(robot.joint_names),
        measurement=res.measurement,
        tracker_to_base=Placement(xyz_m=tuple(xyz), rpy_rad=tuple(rpy)),
        tracker_to_base_source=res.tracker_to_base_source,
        parameters=_estimates(robot, res.fit),
        dropped=[DroppedParameter(name=n, reason=r) for n, r in res.identifiable.dropped],
        frames_only_parameters=_estimates(robot, res.frames_only, frames),
        error_tables=_error_tables(res),
        fit_poses=res.fit_idx.tolist(),
        heldout_poses=res.heldout_idx.tolist(),
        outlier_poses=res.outlier_idx.tolist(),
        baseline_fit=_baseline_fit(robot, res),
        calibrated_urdf=None if urdf_out is None else str(urdf_out),
        tracker_noise=TrackerNoise(
            position_sigma_m=res.noise.position_sigma_m,
            orientation_sigma_rad=res.noise.orientation_sigma_rad,
            source=source,
        ),
        model_selection=_model_selection(robot, res),
        compliance=compliance_estimates(robot, res.fit),
        undetermined=list(res.undetermined),
        notes=list(res.notes),
    )


def detectable_blunder_figures(res: CalibrationResult) -> dict[str, float | int | None]:
    """The pose set's check on blunders (`Fitter.detectable_blunders_m`): the largest and the median
    minimal detectable blunder over the fit poses' position components, and the pose of the largest."""
    mdb = res.detectable_blunder_m
    if mdb is None or mdb.size == 0:
        return {}
    k = int(np.argmax(mdb)) // mdb.shape[1]
    return {
        "minimal_detectable_blunder_m": float(mdb.max()),
        "minimal_detectable_blunder_pose": int(res.fit_idx[k]),
        "median_minimal_detectable_blunder_m": float(np.median(mdb)),
    }
