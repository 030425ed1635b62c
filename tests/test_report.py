"""The report renders every section from artefact summaries, opens with a verdict, closes with the
paper's figures beside ours, and says "not measured" for what the build lacks."""

import base64
import math
import re
from pathlib import Path

import pytest
import yaml

from rxcomm.reporting import html, markdown
from rxcomm.reporting.calibration import (
    calibration_parameter_table,
    calibration_section,
    calibration_table,
    compliance_table,
)
from rxcomm.reporting.document import Figure, Report, Section, Verdict, ratio_verdict
from rxcomm.reporting.identification import dynamics_parameter_table, dynamics_section
from rxcomm.reporting.markdown import render_sections
from rxcomm.reporting.runs import execution_section, trajectory_section
from rxcomm.reporting.targets import (
    StageTargets,
    acceptance_verdict,
    feedforward_row,
    identification_row,
    runs_row,
    stage_verdicts,
    verdict_note,
)
from rxcomm.schemas.acceptance import Acceptance
from rxcomm.schemas.acceptance import VerdictRow as AcceptanceRow
from rxcomm.schemas.calibration import CalibrationSummary
from rxcomm.schemas.dynamics import DynamicsSummary
from rxcomm.schemas.run_log import RunLog, RunLogSummary
from rxcomm.schemas.run_settings import RunLogSettings
from rxcomm.schemas.trajectory import TrajectoryFigures


def _p(model, figures: dict):
    """A summary holding only the figures a test sets (the others unset, as `model_construct` leaves
    them): the sections read attributes of the kind's model, as they do from an artefact."""
    unset = {n: None for n, f in model.model_fields.items() if f.is_required()}
    return model.model_construct(**(unset | figures))


def _logs(runs: dict) -> dict:
    """Run logs as the report holds them (RunLog models) from their top-level fields."""
    return {
        n: RunLog.model_construct(**r | {"settings": RunLogSettings(**r.get("settings", {}))})
        for n, r in runs.items()
    }


def test_calibration_table_has_papers_numbers_and_ours_in_mm_and_degrees():
    rows = [
        {"quantity": q, "unit": u, "max_abs": v, "peak_to_peak": 2 * v, "rms": v / 2}
        for q, u, v in [("x", "m", 1e-3), ("y", "m", 2e-3), ("z", "m", 3e-3)]
        + [("alpha", "rad", 1e-3), ("beta", "rad", 2e-3), ("gamma", "rad", 3e-3)]
    ]
    tables = [
        {
            "pose_set": "heldout",
            "model": m,
            "n_poses": 16,
            "max_position_error_m": 1e-3,
            "max_orientation_error_rad": 1e-3,
            "rows": rows,
        }
        for m in ("nominal", "calibrated", "frames_only")
    ]
    table = calibration_table(tables)
    assert ["y", "2.000 mm", "2.000 mm", "±2.000 mm", "2.000 mm", "19.026 → 0.31 mm"] in table.rows
    assert table.rows[3][1] == "0.057 °"  # 1 mrad
    assert "naive-poses max" not in table.header
    naive = {**tables[1], "model": "baseline_poses"}
    table = calibration_table([*tables, naive])
    assert "naive-poses max" in table.header
    assert [
        "y",
        "2.000 mm",
        "2.000 mm",
        "±2.000 mm",
        "2.000 mm",
        "2.000 mm",
        "19.026 → 0.31 mm",
    ] in table.rows


def test_render_shows_ours_in_the_stage_and_the_paper_beside_ours_at_the_end():
    ff = {"max_lag_rad": [1e-4] * 6, "max_tcp_error_m": 1e-4, "underruns": 0}
    noff = {"max_lag_rad": [1e-3] * 6, "max_tcp_error_m": 2e-3, "underruns": 0}
    text = render_sections(
        "t", "p", [execution_section(_p(RunLogSummary, ff), _p(RunLogSummary, noff), "run-ff.png")]
    )
    stage, paper = text.split("## Comparison with the paper")
    assert "| lag reduction by feed-forward (worst joint) | ×10.0 |" in stage and "model-based ≪" not in stage
    assert "| lag reduction by feed-forward (worst joint) | ×10.0 | Fig. 2: model-based ≪ standard |" in paper
    assert "![" in stage and "run-ff.png" in stage


# A calibration summary's figures the section always shows.
_CALIBRATION_FIGURES = {
    "n_identifiable": 30,
    "nominal_heldout_max_position_error_m": 1e-2,
    "heldout_max_position_error_m": 1.5e-4,
    "heldout_max_orientation_error_rad": 3e-4,
    "frames_only_heldout_max_position_error_m": 5e-3,
    "seconds": 0.1,
}


def test_calibration_section_shows_the_naive_poses_beside_the_selected_when_measured():
    s = dict(_CALIBRATION_FIGURES)
    assert "naive" not in render_sections("t", "p", [calibration_section(_p(CalibrationSummary, s), [])])
    s |= {
        "n_baseline_poses": 32,
        "heldout_rms_position_error_m": 9e-5,
        "baseline_poses_heldout_max_position_error_m": 3.2e-4,
        "baseline_poses_heldout_max_orientation_error_rad": 6e-4,
        "baseline_poses_heldout_rms_position_error_m": 1.6e-4,
        "baseline_poses_worse_p_value": 2.5e-7,
        "baseline_poses_median_std_ratio": 4.1,
    }
    text = render_sections("t", "p", [calibration_section(_p(CalibrationSummary, s), [])])
    assert "| 0.15 / 0.32 mm, 0.0172 / 0.0344 ° |" in text
    assert "0.09 / 0.16 mm; p = 2.5e-07" in text and "×4.1" in text


def test_calibration_section_states_the_blunder_its_poses_let_the_test_catch():
    """The minimal detectable blunder (calibrate's summary, tests/test_calibration_robust.py) reaches
    the customer's report, with the pose it is worst at; a summary without it shows nothing."""
    figures = {"minimal_detectable_blunder_m": 8.53e-3, "minimal_detectable_blunder_pose": 7}
    figures["median_minimal_detectable_blunder_m"] = 5.8e-3
    text = render_sections(
        "t", "p", [calibration_section(_p(CalibrationSummary, _CALIBRATION_FIGURES | figures), [])]
    )
    (row,) = [line for line in text.splitlines() if "minimal detectable" in line]
    assert "(pose 7)" in row and "8.53" in row and "5.8" in row
    bare = render_sections("t", "p", [calibration_section(_p(CalibrationSummary, _CALIBRATION_FIGURES), [])])
    assert "minimal detectable" not in bare


def test_calibration_section_carries_the_calibrations_notes():
    """What calibrate told the user to act on reaches the customer's report (on main the section's
    note was fixed text, and claimed a simulated cell whose joints bend, whatever the robot)."""
    s = _p(CalibrationSummary, _CALIBRATION_FIGURES)
    notes = ["poses without a tracker reading, left out: 3 of 32 fit", "a moved tracker?"]
    text = render_sections("t", "p", [calibration_section(s, [], notes=notes)])
    assert "Calibration note: poses without a tracker reading, left out: 3 of 32 fit." in text
    assert "Calibration note: a moved tracker?" in text and "?." not in text
    assert "simulated cell" not in render_sections("t", "p", [calibration_section(s, [])])


def test_dynamics_section_says_not_scored_for_a_joint_that_did_not_move():
    s = {
        "n_base_params": 61,
        "friction": "both",
        "validation_rms_nm": [0.64, 0.39, 0.13, None, 0.046, 0.076],
        "validation_nrmse": [0.002, 0.001, 0.001, None, 0.004, 0.012],
        "validation_r2": [0.99995, 0.99999, 0.99999, None, 0.99985, 0.99885],
        "validation_standstill_in_band_fraction": [None, None, None, 1.0, None, None],
        "validation": "log: validation-log.mcap",
        "cutoff_hz": 10.0,
        "rows_per_parameter": 12.4,
        "seconds": 0.2,
    }
    text = render_sections("t", "p", [dynamics_section(_p(DynamicsSummary, s), None)])
    assert "[0.64, 0.39, 0.13, not scored, 0.046, 0.076] N·m" in text
    assert "[0.2, 0.1, 0.1, not scored, 0.4, 1.2] %" in text
    assert "0.9999, 0.9989]" in text and "no standstill" in text and "10 Hz; 12.4" in text
    assert "0 %" not in text and "0.00 %" not in text
    assert "| not measured / not measured |" in text  # no fit or cross-validation figures: never 0
    assert "fitted regrouped" not in text
    # a joint whose static friction is below its torque noise has no band to be inside: said so
    viscous = s | {
        "validation_standstill_in_band_fraction": [None, None, None, None, 0.95, None],
        "validation_stiction_band_below_noise": [True, False, False, True, False, False],
    }
    text = render_sections("t", "p", [dynamics_section(_p(DynamicsSummary, viscous), None)])
    assert "| [band < noise, no standstill, no standstill, band < noise, 0.95, no standstill] |" in text
    # with the rows counted (dynamics.yaml from now on) the share is said as rows: 2 of 4 is thin
    counted = viscous | {
        "validation_standstill_in_band_fraction": [None, None, None, None, 0.5, None],
        "validation_standstill_rows": [3, 0, 0, 250, 4, 0],
    }
    text = render_sections("t", "p", [dynamics_section(_p(DynamicsSummary, counted), None)])
    assert "| [band < noise, no standstill, no standstill, band < noise, 2 of 4, no standstill] |" in text
    regrouped = dynamics_section(_p(DynamicsSummary, s | {"kinematics_regrouped": "j1.mcy"}), None)
    assert (
        "this log could not (their effect sits in J1's friction offset"
        in (text := render_sections("t", "p", [regrouped]))
        and "| j1.mcy |" in text
    )
    s |= {
        "fit_rms_nm": [0.45, 0.4, 0.17, 0.04, 0.019, 0.02],
        "cv_rms_nm": [0.49, 0.42, 0.18, 0.042, 0.022, 0.021],
        "cv_folds_scored": 5,
        "cutoff_hz": 40.0,
        "cutoff_choice": "auto: least mean cross-validated held-out NRMSE (5 Hz: 0.45 %, 40 Hz: 0.14 %)",
    }
    text = render_sections("t", "p", [dynamics_section(_p(DynamicsSummary, s), None)])
    assert "[0.45, 0.4, 0.17, 0.04, 0.019, 0.02] N·m / [0.49, 0.42, 0.18, 0.042, 0.022, 0.021] N·m" in text
    assert (
        "40 Hz (auto: least mean cross-validated held-out NRMSE (5 Hz: 0.45 %, 40 Hz: 0.14 %)); 12.4" in text
    )


def test_a_limit_ratio_above_one_is_flagged_within_tolerance_or_as_a_violation():
    ok = ratio_verdict("cp", 0.9898, 1e-3, "run")
    assert ok.verdict is Verdict.passed and ok.note == ""
    within = ratio_verdict("cp", 1.0006, 1e-3, "`run`'s limit_tolerance in run-ff.yaml")
    assert within.verdict is Verdict.passed and within.measured == "1.0006"
    assert (
        "0.06 % above the limit: within the tolerance of 0.1 %" in within.note
        and "run-ff.yaml" in within.note
    )
    beyond = ratio_verdict("cp", 1.0015, 1e-3, "run")
    assert beyond.verdict is Verdict.failed and "0.15 % above the limit: a violation" in beyond.note
    missing = ratio_verdict("cp", None, 1e-3, "run")
    assert missing.verdict is Verdict.not_measured and missing.measured == "not measured"
    # the same flag beside the figure in the stage section
    sec = trajectory_section("cp", _p(TrajectoryFigures, _TRAJ | {"max_limit_ratio": 1.0006}), None, "1.04 s")
    assert "1.0006 (0.06 % above the limit: within the tolerance" in render_sections("t", "", [sec])


_TRAJ = {"duration_s": 1.4648, "max_limit_ratio": 0.99, "active_fraction": 0.96, "solve_seconds": 2.4}


def test_trajectory_section_names_the_binding_limit_and_every_limits_ratio():
    s = _TRAJ | {
        "max_velocity_ratio": 0.949,
        "max_acceleration_ratio": 0.99,
        "worst_limit": "acceleration joint_4",
    }
    text = render_sections("t", "", [trajectory_section("cp", _p(TrajectoryFigures, s), None, "1.04 s")])
    assert "| max ratio per limit | velocity 0.9490, acceleration 0.9900 |" in text
    assert "| binding limit | acceleration joint_4 |" in text


def test_the_verdict_of_an_empty_build_is_not_measured_throughout_never_zero():
    rows = stage_verdicts({}, {})
    assert len(rows) == 8 and all(r.verdict is Verdict.not_measured for r in rows)
    assert all(r.measured == "not measured" for r in rows)
    assert verdict_note(rows) == "0 of 8 criteria pass, 0 fail, 8 not measured."


def test_stage_verdicts_against_the_targets():
    summaries = {
        "calibration": {"heldout_max_position_error_m": 0.6e-3, "heldout_max_orientation_error_rad": 1e-3},
        "dynamics": {"validation_r2": [0.999, 0.97, None, 0.99, 0.98, 0.995]},
        "run-ff": {"max_lag_rad": [1e-4, 2e-4, 8.7e-4]},
        "run-noff": {"max_lag_rad": [1e-3, 2.96e-2, 1e-3]},
        "cp": {"max_limit_ratio": 1.0006},
        "ptp": {"max_limit_ratio": 0.99},
    }
    runs = {
        "run-ff.yaml": {"summary": {"outcome": "completed", "underruns": 0}},
        "run-ptp.yaml": {"summary": {"outcome": "stopped", "underruns": 2}},
        "sim.yaml": {"summary": {"outcome": "completed", "underruns": "not applicable (virtual time)"}},
    }
    models = {"calibration": CalibrationSummary, "dynamics": DynamicsSummary, "cp": TrajectoryFigures}
    models |= {"ptp": TrajectoryFigures, "run-ff": RunLogSummary, "run-noff": RunLogSummary}
    summaries = {k: _p(models[k], v) for k, v in summaries.items()}
    runs = {n: RunLog.model_construct(summary=_p(RunLogSummary, r["summary"])) for n, r in runs.items()}
    rows = {r.criterion.split(":")[0] + r.criterion[-12:]: r for r in stage_verdicts(summaries, runs)}
    by = list(rows.values())
    pos, ori, r2, ff, exc, cp, ptp, run = by
    assert pos.verdict is Verdict.failed and pos.measured == "0.6 mm" and pos.note == "missed by 0.1 mm"
    assert ori.verdict is Verdict.passed and ori.measured == "0.0573 °"
    assert r2.verdict is Verdict.passed and r2.measured == "0.9700" and "5 of 6 joints moved" in r2.note
    assert ff.verdict is Verdict.passed and ff.measured == "×34.0" and ff.note == "29.6 → 0.87 mrad"
    assert exc.verdict is Verdict.not_measured
    assert cp.verdict is Verdict.passed and "within the tolerance" in cp.note
    assert ptp.verdict is Verdict.passed
    assert run.verdict is Verdict.failed and run.measured == "2 of 3 completed, 2 underruns"
    assert run.note == "not completed: run-ptp.yaml; underruns not applicable (virtual time) in 1 of 3"
    virtual = {"a.yaml": runs["sim.yaml"]}
    assert runs_row(virtual).measured == "1 of 1 completed, underruns not applicable (virtual time)"
    strict = StageTargets(validation_r2_min=0.98)
    assert identification_row(summaries["dynamics"], strict).verdict is Verdict.failed


def test_a_trip_without_feed_forward_is_reported_as_a_bound_and_only_when_asked_for():
    """The plan without feed-forward may trip the drives (MuJoCo Menagerie's ARX L5: J6 0x8611 at 0.097
    s, its lag at the 35 mrad window): the lag ratio is then a lower bound (≥), the stop is named,
    and `runs_row` counts it only where the run was told the trip is its result (--trip-is-result)."""
    reason = (
        "axis fault (stop cause 5), following error (0x8611) at t = 0.097 s (joint6 following error (0x8611))"
    )
    ff = _p(RunLogSummary, {"max_lag_rad": [1e-4, 2e-4, 8.7e-4]})
    noff = _p(
        RunLogSummary, {"max_lag_rad": [1e-3, 3.5e-2, 1e-3], "outcome": "safety_stop", "stop_reason": reason}
    )
    row = feedforward_row(ff, noff, StageTargets())
    assert row.verdict is Verdict.passed and row.measured == "≥ ×40.2"
    assert row.note == f"35 → 0.87 mrad; without feed-forward: {reason}"
    text = render_sections("t", "", [execution_section(ff, noff, None)])
    assert "(until the drives tripped: axis fault" in text and "| ≥ ×40.2 |" in text

    def log(trip_is_result):
        return RunLog.model_construct(summary=noff, settings=RunLogSettings(trip_is_result=trip_is_result))

    asked = runs_row({"run-noff.yaml": log(True)})
    assert asked.verdict is Verdict.passed and asked.note.startswith("run-noff.yaml: tripped as its result")
    assert runs_row({"run-noff.yaml": log(None)}).verdict is Verdict.failed


def test_parameter_tables_carry_sigma_in_stated_units():
    dyn = dynamics_parameter_table(
        [
            {"name": "joint_2.mcx_R", "independent": "joint_2.mcx", "value": -2.0, "relative_std": 0.01},
            {"name": "joint_1.Izz_R", "independent": "joint_1.Izz", "value": 4.0, "relative_std": None},
        ]
    )
    assert dyn.rows[0] == ["joint_2.mcx_R", "-2 ± 0.02", "kg·m", "1 %"]
    assert dyn.rows[1] == ["joint_1.Izz_R", "4 (σ not measured)", "kg·m²", "not measured"]
    # a parameter at its bound of 0 keeps its σ (stored apart: |0| · relative σ cannot carry it)
    at_bound = {"name": "joint_4.fc", "independent": "joint_4.fc", "value": 0.0, "relative_std": math.inf}
    row = dynamics_parameter_table([at_bound | {"std": 0.023}]).rows[0]
    assert row == ["joint_4.fc", "0 ± 0.023", "N·m", "none (value 0)"]
    drive = [("joint_3.rotor_inertia", "kg·m²"), ("joint_1.offset", "N·m"), ("spring.kL0", "N")]
    rows = dynamics_parameter_table(
        [{"name": n, "independent": n, "value": 1.0, "relative_std": 0.01} for n, _ in drive]
    ).rows
    assert [r[2] for r in rows] == [u for _, u in drive]  # drive and spring parameters have units too
    cal = calibration_parameter_table(
        [
            {"name": "base.tx", "value": -2.1e-3, "std": 1.3e-5, "estimated": True},
            {"name": "joint_2.rx", "value": -5.8e-4, "std": 9.8e-6, "estimated": True},
            {"name": "joint_1.tx", "value": 0.0, "std": None, "estimated": False},
        ]
    )
    assert cal.rows == [
        ["base.tx", "-2.1 ± 0.013", "mm"],
        ["joint_2.rx", "-0.58 ± 0.0098", "mrad"],
        ["held at 0, not identifiable (1)", "joint_1.tx", ""],
    ]
    stiff = compliance_table(
        [{"joint": "joint_2", "compliance_rad_per_nm": 1e-6, "std": 1e-7, "stiffness_nm_per_rad": 1e6}]
    )
    assert stiff.rows == [["joint_2", "1 ± 0.1", "1 ± 0.1"]]  # µrad/(N·m), MN·m/rad: σ_k/k = σ_c/c


# a 1×1 PNG
PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8BQDwAEhQGAhKmMIQAAAABJRU5ErkJggg=="
)


def test_html_is_self_contained_opens_with_the_verdict_and_embeds_every_figure():
    verdict = stage_verdicts({"cp": _p(TrajectoryFigures, {"max_limit_ratio": 1.0025})}, {})
    sections = [
        Section("Stage A", [Figure("x", "1 mm", "2 mm")], image="a.png"),
        Section("Stage B", [Figure("y", "not measured")], image="gone.png"),
    ]
    report = Report("r", "made `here`", verdict, sections, verdict_note(verdict))
    png = PNG
    page = html.render(report, lambda name: png if name == "a.png" else None)
    assert page.index('id="checks"') < page.index("Stage A") < page.index('id="paper"')
    assert page.count("data:image/png;base64,") == 1
    assert base64.b64encode(png).decode() in page
    assert "figure gone.png: not produced in this build" in page
    assert not re.search(r"(src|href)=\"(?!data:)", page) and "<script" not in page
    assert '<td class="fail">fail</td>' in page and "<code>here</code>" in page
    md = markdown.render(report, "../build/")
    assert "](../build/a.png)" in md and md.index("## Commissioning checks") < md.index("## Stage A")


def test_report_of_an_empty_build_says_not_measured_and_writes_both_files(tmp_path):
    from typer.testing import CliRunner

    from rxcomm.cli import app

    (tmp_path / "build").mkdir()
    res = CliRunner().invoke(
        app, ["report", str(tmp_path / "build"), "-o", str(tmp_path / "out" / "report.md")]
    )
    assert res.exit_code == 0, res.output
    md = (tmp_path / "out" / "report.md").read_text()
    page = (tmp_path / "out" / "report.html").read_text()
    # the stage targets and the acceptance of the robot as a whole (no verdict.yaml: not measured)
    assert md.splitlines()[2] == (
        "**NOT ACCEPTED — not measured: no verdict.yaml in this build (`rxcomm accept`)**"
    )
    assert "0 of 8 checks pass, 0 fail, 8 not measured." in md and 'id="checks"' in page
    assert "| acceptance: factory vs commissioned | not measured |" in md
    assert md.index("## Acceptance: factory vs commissioned") < md.index("## Commissioning checks")
    for title in ("Geometric calibration", "Dynamic identification", "Every executed run"):
        assert title in md and title in page
    assert "| calibration.yaml in this build | not measured |" in md
    assert "| 0 |" not in md
    assert "commissioned against no cell (no run log in this directory)" in md


def test_the_preamble_says_what_the_run_logs_ran_on():
    from rxcomm.reporting.runs import ran_on

    sim = {"embedded_cell": True, "gateway": "127.0.0.1:40123", "settings": {}}
    real = {"embedded_cell": False, "gateway": "192.168.0.10:502", "settings": {}}
    assert (
        ran_on(_logs({"a.yaml": sim, "b.yaml": sim}))
        == "the simulated cell `run` started itself (2 of 2 run logs)"
    )
    # a real gateway is named by its address, never called the simulated cell
    assert ran_on(_logs({"a.yaml": real})) == "the gateway at 192.168.0.10:502 (1 of 1 run logs)"
    # a log that names its plant says which (an older log without one does not guess)
    mj = {**sim, "settings": {"plant": "mujoco"}}
    assert ran_on(_logs({"a.yaml": mj, "b.yaml": mj})) == (
        "the simulated cell `run` started itself, MuJoCo plant (2 of 2 run logs)"
    )
    assert "rxcomm's own plant (1 of 2" in ran_on(
        _logs({"a.yaml": mj, "b.yaml": {**sim, "settings": {"plant": "own"}}})
    )
    both = ran_on(_logs({"a.yaml": sim, "b.yaml": real, "c.yaml": real}))
    assert both == (
        "the simulated cell `run` started itself (1 of 3 run logs) and the gateway at 192.168.0.10:502 "
        "(2 of 3 run logs)"
    )


def test_stiffness_from_identified_torques_is_shown_beside_the_prior_torques():
    s = _CALIBRATION_FIGURES | {
        "compliance_torque_model": "identified",
        "stiffness_nm_per_rad": {"J3": 4.3e5},
        "stiffness_std_nm_per_rad": {"J3": 4e4},
    }
    prior = _p(
        CalibrationSummary, {"stiffness_nm_per_rad": {"J3": 5.6e5}, "stiffness_std_nm_per_rad": {"J3": 5e4}}
    )
    s |= {
        "mdh_max_position_residual_m": 1.47e-3,
        "mdh_max_orientation_residual_rad": 1.39e-3,
        "mdh_beta_max_position_residual_m": 0.0,  # exact: the export writes round-off as 0
    }
    text = render_sections("t", "p", [calibration_section(_p(CalibrationSummary, s), [], prior=prior)])
    assert "cannot express (max over sampled poses) | 1.47 mm, 1.39 mrad; with Hayati's β 0 mm" in text
    assert "J3 stiffness (from gravity sag, identified holding torques) | 0.43 ± 0.04 MN·m/rad" in text
    assert "J3 stiffness, same measurements, prior holding torques | 0.56 ± 0.05 MN·m/rad" in text
    # A prior pass without a stiffness (its model chose no compliance) says so, never 0.
    text = render_sections(
        "t", "p", [calibration_section(_p(CalibrationSummary, s), [], prior=_p(CalibrationSummary, {}))]
    )
    assert "prior holding torques | not measured" in text


def test_the_acceptance_rows_open_the_verdict_with_factory_commissioned_and_ratio():
    acceptance = {
        "rows": [
            {"criterion": "AP_p", "unit": "m", "factory": 0.0042, "commissioned": 0.00021, "ratio": 0.05,
             "threshold": "≤ 0.0003 m", "max_commissioned": 0.0003, "max_ratio": None, "verdict": "PASS",
             "note": "worst of 5: P3, 30 cycles"},
            {"criterion": "cycle_time", "unit": "s", "factory": 7.83, "commissioned": None, "ratio": None,
             "threshold": "ratio ≤ 0.7", "max_commissioned": None, "max_ratio": 0.7,
             "verdict": "not measured", "note": "commissioned: no run log"},
            {"criterion": "electrical_energy", "unit": "J", "factory": 268.3, "commissioned": 407.8,
             "ratio": 1.52, "threshold": "ratio ≤ 1", "max_commissioned": None, "max_ratio": 1.0,
             "verdict": "FAIL", "note": "sum of 2 run(s)"},
        ],
        "summary": {"verdict": "FAIL", "n_pass": 1, "n_fail": 1, "n_not_measured": 1},
    }  # fmt: skip
    rows = acceptance_verdict(
        Acceptance.model_construct(rows=[AcceptanceRow(**r) for r in acceptance["rows"]])
    )
    assert [r.verdict for r in rows] == [Verdict.passed, Verdict.not_measured, Verdict.failed]
    verdict = [*rows, *stage_verdicts({}, {})]
    report = Report("r", "preamble", verdict, [Section("Stage A", [Figure("x", "1 mm")])])
    md = markdown.render(report)
    lines = md.splitlines()
    header = "| criterion | factory | commissioned | ratio | threshold | verdict | note |"
    assert header in lines and lines.index(header) < md[: md.index("## Stage A")].count("\n")
    assert "| AP_p | 4.2 mm | 0.21 mm | 0.05 | ≤ 0.3 mm | pass | worst of 5: P3, 30 cycles |" in lines
    assert (
        "| cycle_time | 7.83 s | not measured | — | ratio ≤ 0.7 | not measured | commissioned: no run log |"
        in lines
    )
    assert "| electrical_energy | 268.3 J | 407.8 J | 1.52 | ratio ≤ 1 | fail | sum of 2 run(s) |" in lines
    # the acceptance rows come first, before the stage targets
    assert md.index("| AP_p |") < md.index("| electrical_energy |") < md.index("| calibration")


def test_a_renamed_summary_field_fails_the_report_naming_file_and_field(tmp_path, rx130l):
    """Issue 28: a summary field renamed (by a producer or by hand) is an error naming the file and the
    field, never a figure the report prints as "not measured"."""
    from rxcomm.errors import InputError
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.stages.report import build_report
    from tests.artefacts import synthetic_calibration

    art = synthetic_calibration(rx130l, {"base.tx": 1e-4})
    data = art.model_dump(mode="json")
    data["summary"]["heldout_max_position_error_mm"] = data["summary"].pop("heldout_max_position_error_m")
    write_yaml_artefact(tmp_path / "calibration.yaml", art)
    report, _ = build_report(tmp_path)  # the file as written reads
    (tmp_path / "calibration.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(InputError) as err:
        build_report(tmp_path)
    assert "calibration.yaml" in str(err.value.file)
    assert "heldout_max_position_error_m" in str(err.value)


def test_report_and_accept_code_read_summaries_as_attributes():
    """Issue 28's grep: no summary read by key in the report or accept code."""
    root = Path(__file__).resolve().parents[1] / "rxcomm"
    files = [root / "stages" / "report.py", root / "stages" / "accept.py"]
    files += sorted((root / "reporting").glob("*.py")) + sorted((root / "acceptance").glob("*.py"))
    hits = [
        f"{f.name}:{i}"
        for f in files
        for i, line in enumerate(f.read_text().splitlines(), 1)
        if "summary.get(" in line or '["summary"][' in line or "['summary'][" in line
    ]
    assert not hits
