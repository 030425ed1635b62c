"""Synthetic artefacts the tests hand to stages in place of a chain's output."""

from __future__ import annotations

from rxcomm.schemas.calibration import (
    Calibration,
    CalibrationSummary,
    ComplianceEstimate,
    ModelSelection,
    ParameterEstimate,
    TrackerNoise,
)
from rxcomm.schemas.cell import Placement


def _zero_summary() -> dict:
    """The calibration summary's required figures, zero (the model: "full")."""
    fields = CalibrationSummary.model_fields
    return {n: 0 for n, f in fields.items() if f.is_required()} | {"model": "full"}


def synthetic_calibration(
    robot,
    errors: dict[str, float],
    *,
    names: list[str] | None = None,
    compliance: dict[str, float] | None = None,
    summary: dict | None = None,
) -> Calibration:
    """A calibration of `robot` whose chosen model found the geometric `errors` (name → value; with
    `names`, every one of them listed, the others zero and not estimated) and, given, the joint
    `compliance` (joint → rad/(N·m)); summary figures zero but for `summary`."""
    listed = names if names is not None else list(errors)
    chosen = "full+compliance" if compliance else "full"
    return Calibration(
        **Calibration.envelope({}, {}, _zero_summary() | (summary or {})),
        robot=robot.name,
        joint_names=list(robot.joint_names),
        measurement="pose",
        tracker_to_base=Placement(),
        tracker_to_base_source="cell",
        parameters=[
            ParameterEstimate(name=n, value=errors.get(n, 0.0), std=None, estimated=n in errors)
            for n in listed
        ],
        dropped=[],
        frames_only_parameters=[],
        error_tables=[],
        fit_poses=[],
        heldout_poses=[],
        outlier_poses=[],
        tracker_noise=TrackerNoise(position_sigma_m=5e-5, orientation_sigma_rad=1e-4, source="cell"),
        model_selection=ModelSelection(folds=5, rule=f"given: {chosen}", chosen=chosen, candidates=[]),
        compliance=[
            ComplianceEstimate(joint=j, compliance_rad_per_nm=c, std=c / 20, stiffness_nm_per_rad=1 / c)
            for j, c in (compliance or {}).items()
        ],
    )
