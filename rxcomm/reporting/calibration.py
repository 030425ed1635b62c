"""The report's sections for pose selection and geometric calibration (paper §3.1–3.4, Table 2):
headline figures, held-out errors per axis, parameters ± σ, the joint stiffness.

Pure functions over the summaries of configs.yaml and calibration.yaml (their models).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from rxcomm.reporting.document import (
    NOT_MEASURED,
    Figure,
    Section,
    Table,
)
from rxcomm.reporting.values import fmt, plus_minus
from rxcomm.schemas.calibration import CalibrationSummary
from rxcomm.schemas.configs import ConfigsSummary

# Paper Table 2 (RX130L, 3D-Creator tracker): max |e| before → after, x y z in mm, α β γ in degrees.
PAPER_TABLE2_MAX = {
    "x": (7.779, 0.272),
    "y": (19.026, 0.310),
    "z": (12.614, 0.414),
    "alpha": (1.140, 0.128),
    "beta": (1.817, 0.191),
    "gamma": (1.160, 0.131),
}


def configs_section(s: ConfigsSummary, image: str | None, criterion: str = "det-root") -> Section:
    return Section(
        "Optimal measurement poses (paper §3.3)",
        [
            Figure("candidates → selected", f"{s.n_candidates} → {s.n_selected}", "≈ 4000 → 32"),
            Figure(
                f"observation index ({criterion}, in average candidates): selected / naive (linear scan)",
                f"{fmt(s.observation_index, digits=4)} / {fmt(s.baseline_observation_index, digits=4)}",
            ),
            Figure(
                "improvement over the linear scan: σ_min ratio (the paper's index) / " + criterion,
                f"×{fmt(s.min_eig_improvement_ratio)} / ×{fmt(s.improvement_ratio)}",
                "×18.5 (σ_min, vs a linear scan)",
            ),
            Figure(
                "expected rms position error after calibration: selected / linear scan / evenly spaced "
                "candidates",
                f"{fmt(s.expected_position_error_m, 1e3)} / "
                f"{fmt(s.baseline_expected_position_error_m, 1e3)} / "
                f"{fmt(s.evenly_spaced_expected_position_error_m, 1e3)} mm",
            ),
            Figure("compute time", fmt(s.seconds, unit="s"), "about 5 min"),
        ],
        image,
        note="The naive baseline is the paper's linear scan: one joint swept at a time from the centre "
        "configuration with the widest feasible sweeps, as many poses as selected. Evenly spaced "
        "candidates are no naive set: with 6-D measurements and 32 poses for 30 parameters any diverse "
        "set is within about 10 % of the best possible prediction error, so the gain over them is "
        "modest. Expected errors are at the tracker noise of cell.yaml.",
    )


def calibration_table(tables: Sequence[Mapping]) -> Table | None:
    """The paper's Table 2 on held-out poses: max |e| and peak-to-peak per axis, before and after
    (and, when measured, the calibration from the naive poses)."""
    by = {(t["pose_set"], t["model"]): t for t in tables}
    nominal, cal, frames, naive = (
        by.get(("heldout", m)) for m in ("nominal", "calibrated", "frames_only", "baseline_poses")
    )
    if nominal is None or cal is None:
        return None
    header = ["axis", "nominal max", "calibrated max", "calibrated p-p", "frames-only max"]
    header += ["naive-poses max"] if naive else []
    header += ["paper max before→after"]
    rows = []
    for i, row in enumerate(cal["rows"]):
        q = row["quantity"]
        scale, unit = (1e3, "mm") if row["unit"] == "m" else (180 / np.pi, "°")
        fr = f"{frames['rows'][i]['max_abs'] * scale:.3f} {unit}" if frames else NOT_MEASURED
        pb, pa = PAPER_TABLE2_MAX[q]
        cells = [
            q,
            f"{nominal['rows'][i]['max_abs'] * scale:.3f} {unit}",
            f"{row['max_abs'] * scale:.3f} {unit}",
            f"±{row['peak_to_peak'] * scale / 2:.3f} {unit}",
            fr,
        ]
        cells += [f"{naive['rows'][i]['max_abs'] * scale:.3f} {unit}"] if naive else []
        rows.append([*cells, f"{pb} → {pa} {unit}"])
    return Table("Held-out errors per axis (paper Table 2)", header, rows)


def calibration_parameter_table(params: Sequence[Mapping]) -> Table | None:
    """The identified geometric errors ± 1σ (translations in mm, rotations in mrad); the parameters
    the fit held at 0 (not identifiable from the poses) in one closing row."""
    if not params:
        return None
    rows = []
    for p in params:
        if p["estimated"]:
            unit = "mrad" if p["name"].rsplit(".", 1)[-1].startswith("r") else "mm"
            rows.append([p["name"], plus_minus(p["value"], p["std"], 1e3), unit])
    fixed = [p["name"] for p in params if not p["estimated"]]
    if fixed:
        rows.append([f"held at 0, not identifiable ({len(fixed)})", ", ".join(fixed), ""])
    return Table("Identified geometric errors ± 1σ", ["parameter", "value", "unit"], rows)


def compliance_table(compliance: Sequence[Mapping]) -> Table | None:
    """Joint compliances ± 1σ and the stiffness they give (first-order σ of 1/c)."""
    if not compliance:
        return None
    rows = []
    for c in compliance:
        k = c.get("stiffness_nm_per_rad")
        k_std = None if k is None else k * c["std"] / c["compliance_rad_per_nm"]
        rows.append(
            [
                c["joint"],
                plus_minus(c["compliance_rad_per_nm"], c["std"], 1e6, 3),
                NOT_MEASURED if k is None else plus_minus(k, k_std, 1e-6, 3),
            ]
        )
    return Table(
        "Joint stiffness from gravity sag ± 1σ",
        ["joint", "compliance [µrad/(N·m)]", "stiffness [MN·m/rad]"],
        rows,
    )


def pose_count_figures(s: CalibrationSummary) -> list[Figure]:
    """How many poses each figure rests on, and how many the campaign could not read (a pose out of the
    tracker's sight, an arm that never came to rest): the selected set's advantage over the naive one
    shrinks with every pose it loses."""
    if s.n_fit is None or s.n_unread_fit_poses is None:
        return []
    naive = "" if s.n_baseline_poses is None else f"; naive {s.n_baseline_poses}"
    lost = [s.n_unread_fit_poses, s.n_unread_validation_poses, s.n_unread_baseline_poses]
    return [
        Figure(
            "poses fitted / held out (naive); without a tracker reading, left out: fit / validation / naive",
            f"{s.n_fit} / {s.n_heldout}{naive}; " + " / ".join(str(k or 0) for k in lost),
        )
    ]


def baseline_pose_figures(s: CalibrationSummary) -> list[Figure]:
    """Held-out errors of the calibration from the naive poses beside the selected poses', when the
    campaign measured both (select-configs --measure-baseline)."""
    if s.n_baseline_poses is None:
        return []
    p = s.baseline_poses_worse_p_value
    return [
        Figure(
            "held-out max position, orientation error calibrating from the selected / the naive "
            "(linear scan) poses",
            f"{fmt(s.heldout_max_position_error_m, 1e3)} / "
            f"{fmt(s.baseline_poses_heldout_max_position_error_m, 1e3)} mm, "
            f"{fmt(s.heldout_max_orientation_error_rad, 180 / np.pi)} / "
            f"{fmt(s.baseline_poses_heldout_max_orientation_error_rad, 180 / np.pi)} °",
        ),
        Figure(
            "held-out rms position error, selected / naive; naive worse pose by pose (one-sided "
            "signed-rank test on the weighted residuals)",
            f"{fmt(s.heldout_rms_position_error_m, 1e3)} / "
            f"{fmt(s.baseline_poses_heldout_rms_position_error_m, 1e3)} mm; "
            + ("no fit" if p is None else f"p = {p:.2g}"),
        ),
        Figure(
            "parameter σ from the naive poses / from the selected (median)",
            f"×{fmt(s.baseline_poses_median_std_ratio)}",
        ),
    ]


def calibration_section(
    s: CalibrationSummary,
    tables: Sequence[Mapping],
    parameters: Sequence[Mapping] = (),
    compliance: Sequence[Mapping] = (),
    prior: CalibrationSummary | None = None,
    notes: Sequence[str] = (),
) -> Section:
    """The summary's figures, Table 2, the parameters ± σ and the joint stiffness (calibration.yaml);
    `prior`: the summary of the same calibration with the prior model's holding torques, if made;
    `notes`: the calibration's own (what the user should act on), in the section's note."""
    named = [calibration_table(tables), calibration_parameter_table(parameters), compliance_table(compliance)]
    return Section(
        "Geometric calibration (paper §3.1–3.4, Table 2)",
        [
            Figure("identifiable parameters", str(s.n_identifiable), "39 → 30 by QR"),
            *pose_count_figures(s),
            Figure(
                "held-out max position error: nominal → calibrated",
                f"{fmt(s.nominal_heldout_max_position_error_m, 1e3)} → "
                f"{fmt(s.heldout_max_position_error_m, 1e3)} mm",
                "max per axis 19.0 → 0.41 mm",
            ),
            Figure(
                "held-out max orientation error after",
                fmt(np.degrees(s.heldout_max_orientation_error_rad), unit="°"),
                "0.19°",
            ),
            Figure(
                "base + tool frames only (honest baseline)",
                fmt(s.frames_only_heldout_max_position_error_m, 1e3, unit="mm"),
            ),
            *baseline_pose_figures(s),
            *model_figures(s, prior),
            Figure("compute time", fmt(s.seconds, unit="s")),
        ],
        tables=[t for t in named if t is not None],
        note=" ".join(
            [
                "Errors are measured on held-out poses the fit never saw, at the tracker noise above.",
                *(f"Calibration note: {n}" + ("" if n[-1:] in ".?!" else ".") for n in notes),
            ]
        ),
    )


def model_figures(s: CalibrationSummary, prior: CalibrationSummary | None = None) -> list[Figure]:
    """The tracker noise used, the model the data chose, the rigid model beside it, the stiffness
    (and, from `prior`, the stiffness the prior model's holding torques give)."""
    out = []
    if s.tracker_position_sigma_m is not None:
        ori = s.tracker_orientation_sigma_rad
        out.append(
            Figure(
                f"tracker noise used ({s.tracker_sigma_source or '?'})",
                f"{fmt(s.tracker_position_sigma_m, 1e3, unit='mm')}"
                + ("" if ori is None else f", {fmt(ori, 1e3, unit='mrad')}"),
            )
        )
    if s.minimal_detectable_blunder_m is not None:
        out.append(
            Figure(
                "blunder the outlier test catches 4 times in 5 (Baarda's minimal detectable): the pose "
                "the fit leans on most / the median component",
                f"{fmt(s.minimal_detectable_blunder_m, 1e3, unit='mm')} (pose "
                f"{s.minimal_detectable_blunder_pose}) / "
                f"{fmt(s.median_minimal_detectable_blunder_m, 1e3, unit='mm')}",
            )
        )
    if s.prior_scale is not None:
        out.append(Figure("priors: the manufacturing classes' σ ×", fmt(s.prior_scale)))
    if s.model is not None:
        out.append(Figure("error model chosen (5-fold cross-validation)", str(s.model)))
    if s.rigid_heldout_max_position_error_m is not None:
        out.append(
            Figure(
                "held-out max position error, rigid full model",
                fmt(s.rigid_heldout_max_position_error_m, 1e3, unit="mm"),
            )
        )
    for joint, value in s.stiffness_nm_per_rad.items():
        std = s.stiffness_std_nm_per_rad.get(joint)
        torques = s.compliance_torque_model or "prior"
        out.append(
            Figure(
                f"{joint} stiffness (from gravity sag, {torques} holding torques)",
                f"{fmt(value, 1e-6)} ± {fmt(std, 1e-6)} MN·m/rad",
            )
        )
        if prior is not None and torques != "prior":
            p, p_std = prior.stiffness_nm_per_rad.get(joint), prior.stiffness_std_nm_per_rad.get(joint)
            out.append(
                Figure(
                    f"{joint} stiffness, same measurements, prior holding torques",
                    "not measured" if p is None else f"{fmt(p, 1e-6)} ± {fmt(p_std, 1e-6)} MN·m/rad",
                )
            )
    if s.mdh_max_position_residual_m is not None:
        out.append(
            Figure(
                "what the plain MDH export cannot express (max over sampled poses)",
                f"{fmt(s.mdh_max_position_residual_m, 1e3, unit='mm')}, "
                f"{fmt(s.mdh_max_orientation_residual_rad, 1e3, unit='mrad')}; with Hayati's β "
                f"{fmt(s.mdh_beta_max_position_residual_m, 1e3, unit='mm')}",
            )
        )
    return out
