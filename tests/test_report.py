"""The report renders every section from artefact summaries and puts the paper's figures beside ours."""

from rxcomm import report as rep


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
    text = rep.calibration_table(tables)
    assert "| y | 2.000 mm | 2.000 mm | ±2.000 mm | 2.000 mm | 19.026 → 0.31 mm |" in text
    assert "| alpha | 0.057 °" in text  # 1 mrad
    assert "naive" not in text
    naive = {**tables[1], "model": "baseline_poses"}
    text = rep.calibration_table([*tables, naive])
    assert "naive-poses max |" in text
    assert "| y | 2.000 mm | 2.000 mm | ±2.000 mm | 2.000 mm | 2.000 mm | 19.026 → 0.31 mm |" in text


def test_render_puts_paper_beside_ours():
    ff = {"max_lag_rad": [1e-4] * 6, "max_tcp_error_m": 1e-4, "underruns": 0}
    noff = {"max_lag_rad": [1e-3] * 6, "max_tcp_error_m": 2e-3, "underruns": 0}
    text = rep.render("t", "p", [rep.execution_section(ff, noff, "run-ff.png")])
    assert "| lag reduction by feed-forward (worst joint) | ×10.0 | Fig. 2" in text
    assert "![" in text and "run-ff.png" in text


def test_calibration_section_shows_the_naive_poses_beside_the_selected_when_measured():
    s = {
        "n_identifiable": 30,
        "nominal_heldout_max_position_error_m": 1e-2,
        "heldout_max_position_error_m": 1.5e-4,
        "heldout_max_orientation_error_rad": 3e-4,
        "frames_only_heldout_max_position_error_m": 5e-3,
        "seconds": 0.1,
    }
    assert "naive" not in rep.render("t", "p", [rep.calibration_section(s, [])])
    s |= {
        "n_baseline_poses": 32,
        "heldout_rms_position_error_m": 9e-5,
        "baseline_poses_heldout_max_position_error_m": 3.2e-4,
        "baseline_poses_heldout_max_orientation_error_rad": 6e-4,
        "baseline_poses_heldout_rms_position_error_m": 1.6e-4,
        "baseline_poses_worse_p_value": 2.5e-7,
        "baseline_poses_median_std_ratio": 4.1,
    }
    text = rep.render("t", "p", [rep.calibration_section(s, [])])
    assert "| 0.15 / 0.32 mm, 0.0172 / 0.0344 ° |" in text
    assert "0.09 / 0.16 mm; p = 2.5e-07" in text and "×4.1" in text


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
    text = rep.render("t", "p", [rep.dynamics_section(s, None)])
    assert "[0.64, 0.39, 0.13, not scored, 0.046, 0.076] N·m" in text
    assert "[0.2, 0.1, 0.1, not scored, 0.4, 1.2] %" in text
    assert "0.9999, 0.9989]" in text and "no standstill" in text and "10 Hz; 12.4" in text
    assert "0 %" not in text and "0.00 %" not in text


def test_the_report_opens_with_the_verdict_table():
    acceptance = {
        "rows": [
            {
                "criterion": "AP_p",
                "unit": "m",
                "factory": 0.0042,
                "commissioned": 0.00021,
                "ratio": 0.05,
                "threshold": "≤ 0.0003 m",
                "max_commissioned": 0.0003,
                "max_ratio": None,
                "verdict": "PASS",
                "note": "",
            },
            {
                "criterion": "cycle_time",
                "unit": "s",
                "factory": 7.83,
                "commissioned": None,
                "ratio": None,
                "threshold": "ratio ≤ 0.7",
                "max_commissioned": None,
                "max_ratio": 0.7,
                "verdict": "not measured",
                "note": "no run log",
            },
        ],  # fmt: skip
        "summary": {"verdict": "incomplete", "n_pass": 1, "n_fail": 0, "n_not_measured": 1},
    }
    ff = {"max_lag_rad": [1e-4] * 6, "max_tcp_error_m": 1e-4, "underruns": 0}
    text = rep.render("t", "preamble", [rep.execution_section(ff, None, None)], rep.verdict_table(acceptance))
    lines = text.splitlines()
    assert lines[2] == "| criterion | factory | commissioned | ratio | threshold | verdict |"
    assert "| AP_p | 4.2 mm | 0.21 mm | 0.05 | ≤ 0.3 mm | **PASS** |" in lines
    assert "| cycle_time | 7.83 s | not measured | — | ratio ≤ 0.7 | **not measured** |" in lines
    # the table comes before the preamble and every section
    assert text.index("| criterion |") < text.index("preamble") < text.index("## ")
    assert "Verdict: **incomplete** (1 pass, 0 fail, 1 not measured)" in text
    assert "Not measured: cycle_time: no run log." in text
