"""The commissioning report's sections: each stage's headline figures, parameter tables ± σ and
plots, every run, with the paper's value where it has one (shown in the closing comparison).

Pure functions over artefact summaries (plain mappings read from the YAML files) → `reporting`
sections; the verdict rows are `report_targets`'. Reading the files is the `report` stage's job.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from rxcomm.reporting import markdown
from rxcomm.reporting.document import (
    DEFAULT_TOLERANCE,
    NOT_MEASURED,
    Figure,
    Report,
    Section,
    Table,
    Tolerance,
    Verdict,
    VerdictRow,
    ratio_note,
)

# Paper Table 2 (RX130L, 3D-Creator tracker): max |e| before → after, x y z in mm, α β γ in degrees.
PAPER_TABLE2_MAX = {
    "x": (7.779, 0.272),
    "y": (19.026, 0.310),
    "z": (12.614, 0.414),
    "alpha": (1.140, 0.128),
    "beta": (1.817, 0.191),
    "gamma": (1.160, 0.131),
}


def _f(x: object, scale: float = 1.0, digits: int = 3, unit: str = "") -> str:
    if x is None:
        return NOT_MEASURED
    if isinstance(x, str):  # e.g. "not applicable (virtual time)": said as it is, never as a number
        return x
    if isinstance(x, list | tuple):
        return "[" + ", ".join(_f(v, scale, digits) for v in x) + "]" + (f" {unit}" if unit else "")
    return f"{float(x) * scale:.{digits}g}" + (f" {unit}" if unit else "")


def configs_section(s: Mapping, image: str | None, criterion: str = "det-root") -> Section:
    return Section(
        "Optimal measurement poses (paper §3.3)",
        [
            Figure("candidates → selected", f"{s['n_candidates']} → {s['n_selected']}", "≈ 4000 → 32"),
            Figure(
                f"observation index ({criterion}, in average candidates): selected / naive (linear scan)",
                f"{_f(s['observation_index'], digits=4)} / {_f(s['baseline_observation_index'], digits=4)}",
            ),
            Figure(
                "improvement over the linear scan: σ_min ratio (the paper's index) / " + criterion,
                f"×{_f(s.get('min_eig_improvement_ratio'))} / ×{_f(s['improvement_ratio'])}",
                "×18.5 (σ_min, vs a linear scan)",
            ),
            Figure(
                "expected rms position error after calibration: selected / linear scan / evenly spaced "
                "candidates",
                f"{_f(s.get('expected_position_error_m'), 1e3)} / "
                f"{_f(s.get('baseline_expected_position_error_m'), 1e3)} / "
                f"{_f(s.get('evenly_spaced_expected_position_error_m'), 1e3)} mm",
            ),
            Figure("compute time", _f(s["seconds"], unit="s"), "about 5 min"),
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


def _pm(value: float, std: float | None, scale: float, digits: int = 4) -> str:
    if std is None:
        return f"{value * scale:.{digits}g} (fixed)"
    return f"{value * scale:.{digits}g} ± {std * scale:.2g}"


def calibration_parameter_table(params: Sequence[Mapping]) -> Table | None:
    """The identified geometric errors ± 1σ (translations in mm, rotations in mrad); the parameters
    the fit held at 0 (not identifiable from the poses) in one closing row."""
    if not params:
        return None
    rows = []
    for p in params:
        if p["estimated"]:
            unit = "mrad" if p["name"].rsplit(".", 1)[-1].startswith("r") else "mm"
            rows.append([p["name"], _pm(p["value"], p["std"], 1e3), unit])
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
                _pm(c["compliance_rad_per_nm"], c["std"], 1e6, 3),
                NOT_MEASURED if k is None else _pm(k, k_std, 1e-6, 3),
            ]
        )
    return Table(
        "Joint stiffness from gravity sag ± 1σ",
        ["joint", "compliance [µrad/(N·m)]", "stiffness [MN·m/rad]"],
        rows,
    )


def baseline_pose_figures(s: Mapping) -> list[Figure]:
    """Held-out errors of the calibration from the naive poses beside the selected poses', when the
    campaign measured both (select-configs --measure-baseline)."""
    if "n_baseline_poses" not in s:
        return []
    p = s.get("baseline_poses_worse_p_value")
    return [
        Figure(
            "held-out max position, orientation error calibrating from the selected / the naive "
            "(linear scan) poses",
            f"{_f(s['heldout_max_position_error_m'], 1e3)} / "
            f"{_f(s.get('baseline_poses_heldout_max_position_error_m'), 1e3)} mm, "
            f"{_f(s.get('heldout_max_orientation_error_rad'), 180 / np.pi)} / "
            f"{_f(s.get('baseline_poses_heldout_max_orientation_error_rad'), 180 / np.pi)} °",
        ),
        Figure(
            "held-out rms position error, selected / naive; naive worse pose by pose (one-sided "
            "signed-rank test on the weighted residuals)",
            f"{_f(s.get('heldout_rms_position_error_m'), 1e3)} / "
            f"{_f(s.get('baseline_poses_heldout_rms_position_error_m'), 1e3)} mm; "
            + ("no fit" if p is None else f"p = {p:.2g}"),
        ),
        Figure(
            "parameter σ from the naive poses / from the selected (median)",
            f"×{_f(s.get('baseline_poses_median_std_ratio'))}",
        ),
    ]


def calibration_section(
    s: Mapping,
    tables: Sequence[Mapping],
    parameters: Sequence[Mapping] = (),
    compliance: Sequence[Mapping] = (),
    prior: Mapping | None = None,
) -> Section:
    """The summary's figures, Table 2, the parameters ± σ and the joint stiffness (calibration.yaml);
    `prior`: the summary of the same calibration with the prior model's holding torques, if made."""
    named = [calibration_table(tables), calibration_parameter_table(parameters), compliance_table(compliance)]
    return Section(
        "Geometric calibration (paper §3.1–3.4, Table 2)",
        [
            Figure("identifiable parameters", str(s["n_identifiable"]), "39 → 30 by QR"),
            Figure(
                "held-out max position error: nominal → calibrated",
                f"{_f(s['nominal_heldout_max_position_error_m'], 1e3)} → "
                f"{_f(s['heldout_max_position_error_m'], 1e3)} mm",
                "max per axis 19.0 → 0.41 mm",
            ),
            Figure(
                "held-out max orientation error after",
                _f(np.degrees(s["heldout_max_orientation_error_rad"]), unit="°"),
                "0.19°",
            ),
            Figure(
                "base + tool frames only (honest baseline)",
                _f(s["frames_only_heldout_max_position_error_m"], 1e3, unit="mm"),
            ),
            *baseline_pose_figures(s),
            *model_figures(s, prior),
            Figure("compute time", _f(s["seconds"], unit="s")),
        ],
        tables=[t for t in named if t is not None],
        note="Errors are measured on held-out poses the fit never saw, at the tracker noise above; the "
        "simulated cell's joints bend under gravity.",
    )


def model_figures(s: Mapping, prior: Mapping | None = None) -> list[Figure]:
    """The tracker noise used, the model the data chose, the rigid model beside it, the stiffness
    (and, from `prior`, the stiffness the prior model's holding torques give)."""
    out = []
    if "tracker_position_sigma_m" in s:
        ori = s.get("tracker_orientation_sigma_rad")
        out.append(
            Figure(
                f"tracker noise used ({s.get('tracker_sigma_source', '?')})",
                f"{_f(s['tracker_position_sigma_m'], 1e3, unit='mm')}"
                + ("" if ori is None else f", {_f(ori, 1e3, unit='mrad')}"),
            )
        )
    if "model" in s:
        out.append(Figure("error model chosen (5-fold cross-validation)", str(s["model"])))
    if s.get("rigid_heldout_max_position_error_m") is not None:
        out.append(
            Figure(
                "held-out max position error, rigid full model",
                _f(s["rigid_heldout_max_position_error_m"], 1e3, unit="mm"),
            )
        )
    for key, value in s.items():
        if key.startswith("stiffness_") and key.endswith("_nm_per_rad") and "_std_" not in key:
            joint = key[len("stiffness_") : -len("_nm_per_rad")]
            std = s.get(f"stiffness_{joint}_std_nm_per_rad")
            torques = s.get("compliance_torque_model", "prior")
            out.append(
                Figure(
                    f"{joint} stiffness (from gravity sag, {torques} holding torques)",
                    f"{_f(value, 1e-6)} ± {_f(std, 1e-6)} MN·m/rad",
                )
            )
            if prior is not None and torques != "prior":
                p, p_std = prior.get(key), prior.get(f"stiffness_{joint}_std_nm_per_rad")
                out.append(
                    Figure(
                        f"{joint} stiffness, same measurements, prior holding torques",
                        "not measured" if p is None else f"{_f(p, 1e-6)} ± {_f(p_std, 1e-6)} MN·m/rad",
                    )
                )
    if s.get("mdh_max_position_residual_m") is not None:
        out.append(
            Figure(
                "what the plain MDH export cannot express (max over sampled poses)",
                f"{_f(s['mdh_max_position_residual_m'], 1e3, unit='mm')}, "
                f"{_f(s.get('mdh_max_orientation_residual_rad'), 1e3, unit='mrad')}; with Hayati's β "
                f"{_f(s.get('mdh_beta_max_position_residual_m'), 1e3, unit='mm')}",
            )
        )
    return out


def excitation_section(s: Mapping, image: str | None, tol: Tolerance = DEFAULT_TOLERANCE) -> Section:
    return Section(
        "Optimal exciting trajectory (paper §4.2)",
        [
            Figure("cond(W), unit-norm columns", _f(s["cond"]), "N = 5, ω_f = 0.8 rad/s, k = 80"),
            Figure("random feasible Fourier trajectory (median)", _f(s["baseline_cond"])),
            Figure("cond(W) unnormalised", _f(s.get("cond_raw"))),
            Figure("densely sampled max limit ratio", ratio_note(s.get("max_limit_ratio"), *tol)),
            Figure("binding limit", _f(s.get("worst_limit"))),
            Figure("duration", _f(s["duration_s"], unit="s")),
            Figure("compute time", _f(s["seconds"], unit="s")),
        ],
        image,
    )


def _per_joint(
    values: Sequence[float | None] | None,
    scale: float = 1.0,
    unit: str = "",
    none: str = "not scored",
    decimals: int | None = None,
) -> str:
    """Per-joint figures (3 significant digits, or `decimals` fixed); None (a joint that did not move
    on the validation data) is "not scored"."""
    if values is None:
        return NOT_MEASURED

    def one(v: float) -> str:
        return _f(v, scale) if decimals is None else f"{float(v) * scale:.{decimals}f}"

    text = ", ".join(none if v is None else one(v) for v in values)
    return f"[{text}]" + (f" {unit}" if unit else "")


def _cutoff_choice(s: Mapping) -> str:
    """ " (auto: why)" for a cut-off chosen from the data; nothing for one given."""
    choice = str(s.get("cutoff_choice") or "")
    return f" ({choice})" if choice.startswith("auto") else ""


_UNITS = {"m": "kg", "mcx": "kg·m", "mcy": "kg·m", "mcz": "kg·m", "fc": "N·m", "fv": "N·m·s/rad"}
_UNITS |= {"offset": "N·m", "rotor_inertia": "kg·m²", "kL0": "N"}


def dynamics_parameter_table(params: Sequence[Mapping]) -> Table | None:
    """The identified base parameters ± 1σ (σ = |value| · relative σ), in the independent parameter's
    SI unit; σ not available (a parameter fixed by the fit) is said so."""
    if not params:
        return None
    rows = []
    for p in params:
        kind = p["independent"].rsplit(".", 1)[-1]
        unit = "kg·m²" if kind.startswith("I") else _UNITS.get(kind, "SI")
        rel = p.get("relative_std")
        std = None if rel is None else abs(p["value"]) * rel
        rel_text = NOT_MEASURED if rel is None else f"{rel * 100:.2g} %"
        rows.append(
            [p["name"], _pm(p["value"], std, 1.0).replace("(fixed)", "(σ not measured)"), unit, rel_text]
        )
    return Table("Identified base parameters ± 1σ", ["base parameter", "value", "unit", "relative σ"], rows)


def friction_table(friction: Sequence[Mapping]) -> Table | None:
    if not friction:
        return None
    rows = [
        [f["joint"], f"{f['coulomb_nm']:.4g}", f"{f['viscous_nm_s_per_rad']:.4g}", f"{f['offset_nm']:.4g}"]
        for f in friction
    ]
    return Table(
        "Identified friction per joint",
        ["joint", "Coulomb [N·m]", "viscous [N·m·s/rad]", "offset [N·m]"],
        rows,
    )


def dynamics_section(
    s: Mapping, image: str | None, parameters: Sequence[Mapping] = (), friction: Sequence[Mapping] = ()
) -> Section:
    tables = [t for t in (dynamics_parameter_table(parameters), friction_table(friction)) if t]
    cutoff = s.get("cutoff_hz")
    rows = s.get("rows_per_parameter")
    return Section(
        "Dynamic identification (paper §4.1, §4.3, Fig. 5b)",
        [
            Figure(
                "base parameters (friction model)", f"{s['n_base_params']} ({s.get('friction', 'joint')})"
            ),
            Figure(
                "validation RMS prediction error per joint, moving rows (headline)",
                _per_joint(s["validation_rms_nm"], unit="N·m"),
            ),
            Figure(
                "validation NRMSE per joint",
                _per_joint(s["validation_nrmse"], 100, "%"),
                "Fig. 5b: close match",
            ),
            Figure("validation R² per joint", _per_joint(s.get("validation_r2"), decimals=4)),
            Figure(
                "standstill rows inside the stiction band, per joint",
                _per_joint(s.get("validation_standstill_in_band_fraction"), none="no standstill"),
            ),
            Figure(
                "fit RMS error per joint beside the cross-validated held-out RMS (contiguous folds)",
                f"{_per_joint(s.get('fit_rms_nm'), unit='N·m')} / "
                f"{_per_joint(s.get('cv_rms_nm') if s.get('cv_folds_scored') else None, unit='N·m')}",
            ),
            Figure(
                "low-pass cut-off; fit rows per base parameter",
                f"{_f(cutoff, unit='Hz')}{_cutoff_choice(s)}; {_f(rows)}",
            ),
            Figure("compute time", _f(s["seconds"], unit="s")),
        ],
        image,
        note=f"validated on {s.get('validation', '?')}; a joint that did not move there is not scored.",
        tables=tables,
    )


LIMITS = ("position", "velocity", "acceleration", "torque", "torque_rate")


def trajectory_section(
    title: str, s: Mapping, image: str | None, paper_duration: str, tol: Tolerance = DEFAULT_TOLERANCE
) -> Section:
    per_limit = ", ".join(
        f"{k.replace('_', ' ')} {s[f'max_{k}_ratio']:.4f}" for k in LIMITS if f"max_{k}_ratio" in s
    )
    return Section(
        title,
        [
            Figure("duration", _f(s["duration_s"], digits=4, unit="s"), paper_duration),
            Figure("max limit ratio, sampled at the drive cycle", ratio_note(s["max_limit_ratio"], *tol)),
            Figure("max ratio per limit", per_limit or NOT_MEASURED),
            Figure("binding limit", _f(s.get("worst_limit"))),
            Figure("fraction of time with a limit active", _f(s["active_fraction"]), "≈ 1 (time-optimal)"),
            Figure("solve time", _f(s["solve_seconds"], unit="s")),
        ],
        image,
    )


def ptp_vs_cp_figure(cp: Mapping, ptp: Mapping) -> Figure:
    return Figure(
        "PtP / CP duration between the same end states",
        _f(ptp["duration_s"] / cp["duration_s"]),
        "0.67 s / 1.04 s = 0.64",
    )


def execution_section(ff: Mapping, noff: Mapping | None, image: str | None) -> Section:
    figs = [
        Figure("max joint lag with feed-forward", _f(ff["max_lag_rad"], 1e3, unit="mrad")),
        Figure("max TCP error with feed-forward", _f(ff["max_tcp_error_m"], 1e3, unit="mm")),
        Figure("underruns", _f(ff["underruns"])),
        Figure("min buffered lead while feeding", _f(ff.get("min_lead_s"), unit="s")),
        Figure("cell cycle overruns", _f(ff.get("cell_overruns"))),
    ]
    if noff is not None:
        figs += [
            Figure("max joint lag without feed-forward", _f(noff["max_lag_rad"], 1e3, unit="mrad")),
            Figure("max TCP error without feed-forward", _f(noff["max_tcp_error_m"], 1e3, unit="mm")),
            Figure(
                "lag reduction by feed-forward (worst joint)",
                f"×{max(noff['max_lag_rad']) / max(ff['max_lag_rad']):.1f}",
                "Fig. 2: model-based ≪ standard",
            ),
        ]
    return Section("Execution with model-based feed-forward (paper §2.3, Fig. 2)", figs, image)


def _worst(values: Sequence[float] | None, scale: float) -> str:
    return NOT_MEASURED if not values else f"{max(values) * scale:.3g}"


def runs_section(runs: Mapping[str, Mapping], images: Sequence[str]) -> Section:
    """Every executed run of the build (run log name → its RunLog artefact), one row each."""
    header = ["run log", "feed-forward", "outcome", "duration [s]", "max lag, worst joint [mrad]"]
    header += ["rms lag, worst joint [mrad]", "max TCP error [mm]", "underruns", "min lead [s]"]
    rows = []
    for name, art in runs.items():
        s = art["summary"]
        rows.append(
            [
                name,
                str(art.get("feedforward", NOT_MEASURED)),
                _f(s.get("outcome")) + (f" ({s['stop_reason']})" if s.get("stop_reason") else ""),
                _f(s["duration_s"], digits=4),
                _worst(s["max_lag_rad"], 1e3),
                _worst(s["rms_lag_rad"], 1e3),
                _f(s["max_tcp_error_m"], 1e3),
                _f(s["underruns"]),
                _f(s.get("min_lead_s")),
            ]
        )
    return Section(
        "Every executed run",
        [Figure("runs executed on the cell", str(len(runs)) if runs else NOT_MEASURED)],
        tables=[Table("", header, rows)] if rows else [],
        images=images,
        note="Lags are following errors q_demand − q_actual; the TCP error is FK of demand vs actual joints "
        "through the nominal model (it cannot see the geometric errors calibration removes).",
    )


def missing_section(title: str, names: Sequence[str]) -> Section:
    """A stage whose artefacts this build lacks: its figures are not measured, said so."""
    return Section(title, [Figure(f"{', '.join(names)} in this build", NOT_MEASURED)])


def render(title: str, preamble: str, sections: Sequence[Section]) -> str:
    """Markdown of sections alone (no verdict rows): what a test of one section reads."""
    return markdown.render(Report(title, preamble, [], sections))


def _accept_value(x: float | None, unit: str) -> str:
    """A value of the acceptance table: lengths in mm (the ISO 9283 criteria), "not measured" for None."""
    if x is None:
        return NOT_MEASURED
    if unit == "m":
        return f"{x * 1e3:.3g} mm"
    return f"{x:.4g}" + {"1": "", "N2m2s": " N²·m²·s"}.get(unit, f" {unit}")


ACCEPT_VERDICT = {"PASS": Verdict.passed, "FAIL": Verdict.failed, "not measured": Verdict.not_measured}


def acceptance_verdict(acceptance: Mapping | None) -> list[VerdictRow]:
    """The verdict rows of an `rxcomm/Acceptance` artefact (`rxcomm accept`, plain data): factory,
    commissioned, ratio, threshold per criterion; one "not measured" row when the build has none."""
    if acceptance is None:
        return [
            VerdictRow(
                "acceptance: factory vs commissioned", NOT_MEASURED, "acceptance.yaml", Verdict.not_measured,
                "no verdict.yaml in the build (`rxcomm accept`)",
            )
        ]  # fmt: skip
    out = []
    for r in acceptance["rows"]:
        bounds = (
            [] if r["max_commissioned"] is None else [f"≤ {_accept_value(r['max_commissioned'], r['unit'])}"]
        )
        bounds += [] if r["max_ratio"] is None else [f"ratio ≤ {r['max_ratio']:g}"]
        out.append(
            VerdictRow(
                criterion=r["criterion"],
                measured=_accept_value(r["commissioned"], r["unit"]),
                threshold=", ".join(bounds),
                verdict=ACCEPT_VERDICT[r["verdict"]],
                note=r["note"],
                factory=_accept_value(r["factory"], r["unit"]),
                ratio="—" if r["ratio"] is None else f"{r['ratio']:.3g}",
            )
        )
    return out
