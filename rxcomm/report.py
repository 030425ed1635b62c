"""The commissioning report: every stage's headline figures beside the paper's, with the figures.

Pure functions over artefact summaries (plain mappings read from the YAML files) → Markdown text.
Reading the files is the `report` stage's job.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

# Paper Table 2 (RX130L, 3D-Creator tracker): max |e| before → after, x y z in mm, α β γ in degrees.
PAPER_TABLE2_MAX = {
    "x": (7.779, 0.272),
    "y": (19.026, 0.310),
    "z": (12.614, 0.414),
    "alpha": (1.140, 0.128),
    "beta": (1.817, 0.191),
    "gamma": (1.160, 0.131),
}


@dataclass(frozen=True)
class Figure:
    """One headline number: ours, the paper's, and what it answers."""

    what: str
    ours: str
    paper: str = ""


@dataclass(frozen=True)
class Section:
    title: str
    figures: Sequence[Figure]
    image: str | None = None
    note: str = ""
    table: str = ""


def _f(x: object, scale: float = 1.0, digits: int = 3, unit: str = "") -> str:
    if x is None:
        return "—"
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


def calibration_table(tables: Sequence[Mapping]) -> str:
    """The paper's Table 2 on held-out poses: max |e| and peak-to-peak per axis, before and after
    (and, when measured, the calibration from the naive poses)."""
    by = {(t["pose_set"], t["model"]): t for t in tables}
    nominal, cal, frames, naive = (
        by.get(("heldout", m)) for m in ("nominal", "calibrated", "frames_only", "baseline_poses")
    )
    if nominal is None or cal is None:
        return ""
    extra = " naive-poses max |" if naive else ""
    lines = [
        "| axis | nominal max | calibrated max | calibrated p-p | frames-only max |"
        + extra
        + " paper max before→after |",
        "|---|---|---|---|---|" + ("---|" if naive else "") + "---|",
    ]
    for i, row in enumerate(cal["rows"]):
        q = row["quantity"]
        scale, unit = (1e3, "mm") if row["unit"] == "m" else (180 / np.pi, "°")
        fr = frames["rows"][i]["max_abs"] * scale if frames else float("nan")
        pb, pa = PAPER_TABLE2_MAX[q]
        before = nominal["rows"][i]["max_abs"] * scale
        nv = f" {naive['rows'][i]['max_abs'] * scale:.3f} {unit} |" if naive else ""
        lines.append(
            f"| {q} | {before:.3f} {unit} | {row['max_abs'] * scale:.3f} {unit} "
            f"| ±{row['peak_to_peak'] * scale / 2:.3f} {unit} | {fr:.3f} {unit} |{nv} {pb} → {pa} {unit} |"
        )
    return "\n".join(lines)


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


def calibration_section(s: Mapping, tables: Sequence[Mapping]) -> Section:
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
            *model_figures(s),
            Figure("compute time", _f(s["seconds"], unit="s")),
        ],
        table=calibration_table(tables),
        note="Errors are measured on held-out poses the fit never saw, on the simulated cell's tracker "
        "(σ = 0.05 mm, 0.1 mrad), whose joints bend under gravity.",
    )


def model_figures(s: Mapping) -> list[Figure]:
    """The tracker noise used, the model the data chose, the rigid model beside it, the stiffness."""
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
            out.append(
                Figure(
                    f"{joint} stiffness (from gravity sag)",
                    f"{_f(value, 1e-6)} ± {_f(std, 1e-6)} MN·m/rad",
                )
            )
    return out


def excitation_section(s: Mapping, image: str | None) -> Section:
    return Section(
        "Optimal exciting trajectory (paper §4.2)",
        [
            Figure("cond(W), unit-norm columns", _f(s["cond"]), "N = 5, ω_f = 0.8 rad/s, k = 80"),
            Figure("random feasible Fourier trajectory (median)", _f(s["baseline_cond"])),
            Figure("cond(W) unnormalised", _f(s.get("cond_raw"))),
            Figure("densely sampled max limit ratio", _f(s.get("max_limit_ratio"), digits=4), "≤ 1"),
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
        return "—"

    def one(v: float) -> str:
        return _f(v, scale) if decimals is None else f"{float(v) * scale:.{decimals}f}"

    text = ", ".join(none if v is None else one(v) for v in values)
    return f"[{text}]" + (f" {unit}" if unit else "")


def dynamics_section(s: Mapping, image: str | None) -> Section:
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
                "low-pass cut-off; fit rows per base parameter",
                f"{_f(cutoff, unit='Hz')}; {_f(rows)}",
            ),
            Figure("compute time", _f(s["seconds"], unit="s")),
        ],
        image,
        note=f"validated on {s.get('validation', '?')}; a joint that did not move there is not scored.",
    )


def trajectory_section(title: str, s: Mapping, image: str | None, paper_duration: str) -> Section:
    return Section(
        title,
        [
            Figure("duration", _f(s["duration_s"], digits=4, unit="s"), paper_duration),
            Figure("max limit ratio, sampled at the drive cycle", _f(s["max_limit_ratio"], digits=4), "≤ 1"),
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
        Figure("min buffered lead while feeding", _f(ff.get("min_lead_s"), unit="s"), "≥ 0.1 s"),
        Figure("cell cycle overruns", _f(ff.get("cell_overruns")), "0"),
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


UNIT_TEXT = {"1": "", "N2m2s": " N²·m²·s"}


def _value(x: float | None, unit: str) -> str:
    """A verdict-table value: in mm for lengths (the ISO 9283 criteria), "not measured" for None."""
    if x is None:
        return "not measured"
    if unit == "m":
        return f"{x * 1e3:.3g} mm"
    return f"{x:.4g}" + UNIT_TEXT.get(unit, f" {unit}")


def verdict_table(acceptance: Mapping) -> str:
    """The report's opening table (an `rxcomm/Acceptance` artefact as plain data): criterion, factory,
    commissioned, ratio, threshold, verdict; the overall verdict under it."""
    lines = [
        "| criterion | factory | commissioned | ratio | threshold | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for r in acceptance["rows"]:
        ratio = "—" if r["ratio"] is None else f"{r['ratio']:.3g}"
        bounds = [] if r["max_commissioned"] is None else [f"≤ {_value(r['max_commissioned'], r['unit'])}"]
        bounds += [] if r["max_ratio"] is None else [f"ratio ≤ {r['max_ratio']:g}"]
        f, c = _value(r["factory"], r["unit"]), _value(r["commissioned"], r["unit"])
        lines.append(f"| {r['criterion']} | {f} | {c} | {ratio} | {', '.join(bounds)} | **{r['verdict']}** |")
    s = acceptance["summary"]
    notes = [f"{r['criterion']}: {r['note']}" for r in acceptance["rows"] if r["verdict"] == "not measured"]
    lines += [
        "",
        *([f"Not measured: {'; '.join(notes)}.", ""] if notes else []),
        f"Verdict: **{s['verdict']}** ({s['n_pass']} pass, {s['n_fail']} fail, {s['n_not_measured']} not "
        "measured). Factory: nominal kinematics, no feed-forward, a generic controller's timing from the "
        "catalogue limits; commissioned: calibrated kinematics, identified feed-forward, the optimal "
        "planners. The reference task is the CP path and the PtP move between its end states.",
    ]
    return "\n".join(lines)


def render(title: str, preamble: str, sections: Sequence[Section], lead: str = "") -> str:
    """Markdown: the title, `lead` (the acceptance verdict table) first, then the preamble and sections."""
    out = [f"# {title}", ""] + ([lead, ""] if lead else []) + [preamble, ""]
    for sec in sections:
        out += [f"## {sec.title}", "", "| figure | rxcomm | paper |", "|---|---|---|"]
        out += [f"| {f.what} | {f.ours} | {f.paper} |" for f in sec.figures]
        out.append("")
        if sec.table:
            out += [sec.table, ""]
        if sec.note:
            out += [sec.note, ""]
        if sec.image:
            out += [f"![{sec.title}]({sec.image})", ""]
    return "\n".join(out)
