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


def test_render_puts_paper_beside_ours():
    ff = {"max_lag_rad": [1e-4] * 6, "max_tcp_error_m": 1e-4, "underruns": 0}
    noff = {"max_lag_rad": [1e-3] * 6, "max_tcp_error_m": 2e-3, "underruns": 0}
    text = rep.render("t", "p", [rep.execution_section(ff, noff, "run-ff.png")])
    assert "| lag reduction by feed-forward (worst joint) | ×10.0 | Fig. 2" in text
    assert "![" in text and "run-ff.png" in text
