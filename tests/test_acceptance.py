"""Acceptance verdict (rxcomm.acceptance.verdict, `rxcomm accept`): hand-checked rows."""

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.acceptance.verdict import Measured, acceptance_rows, overall, task_value, verdict_row
from rxcomm.cli import app
from rxcomm.io.yaml_io import load_yaml, read_yaml_model
from rxcomm.schemas.acceptance import AcceptanceThresholds, Threshold
from rxcomm.schemas.iso9283 import Iso9283
from rxcomm.schemas.run_log import RunLogSummary

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()


def iso(values: dict[tuple[str, str], float | None], speed: float | None = 1.0) -> Iso9283:
    """A synthetic ISO 9283 artefact with the given (key, target) → value."""
    criteria = [
        {
            "key": k,
            "target": t,
            "value": v,
            "unit": "m",
            "cycles": 30 if t.startswith("P") else 10,
            "command_speed_m_per_s": None if t.startswith("P") else speed,
            "log": "x.mcap",
            "note": "" if v is not None else "no tracker channel",
        }
        for (k, t), v in values.items()
    ]
    env = Iso9283.envelope({}, {"paths": "paths"}, {"n_criteria": len(criteria), "n_measured": 0})
    return Iso9283(
        **env,
        robot="r",
        cube={
            "centre_m": (1, 0, 1),
            "side_m": 0.5,
            "rpy_rad": (3.14, 0, 0),
            "plane_corners_m": [(0, 0, 0)] * 4,
            "points_m": {f"P{i}": (0, 0, 0) for i in range(1, 6)},
        },
        base_frame={"xyz_m": (0, 0, 0), "rpy_rad": (0, 0, 0), "source": "cell"},
        criteria=criteria,
    )


def t(**kw) -> Threshold:
    return Threshold.model_validate(kw)


def test_rows_by_hand():
    ths = [
        t(criterion="AP_p", unit="m", max_commissioned=0.0003),
        t(
            criterion="AT_p",
            unit="m",
            target="iso9283-line",
            command_speed_m_per_s=1.0,
            max_commissioned=0.0005,
        ),
        t(criterion="cycle_time", unit="s", max_ratio=0.7),
        t(criterion="RP_l", unit="m", max_ratio=1.1, max_commissioned=0.0001),
        t(criterion="electrical_energy", unit="J", max_ratio=1.0),
    ]
    f_iso = iso({("AP_p", "P1"): 0.002, ("AP_p", "P2"): -0.004, ("AT_p", "iso9283-line"): 0.0035,
                 ("RP_l", "P1"): 0.00005})  # fmt: skip
    c_iso = iso({("AP_p", "P1"): 0.0001, ("AP_p", "P2"): 0.00025, ("AT_p", "iso9283-line"): 0.0006,
                 ("RP_l", "P1"): 0.00006})  # fmt: skip
    f_runs = [
        _run({"duration_s": 4.0, "electrical_energy_j": 900.0}),
        _run({"duration_s": 3.0, "electrical_energy_j": None}),
    ]
    c_runs = [
        _run({"duration_s": 1.5, "electrical_energy_j": 800.0}),
        _run({"duration_s": 1.0, "electrical_energy_j": 10.0}),
    ]
    rows = acceptance_rows(ths, f_runs, c_runs, f_iso, c_iso)
    ap, at, ct, rp, el = rows
    # AP: the worst |value| over P1..P5 in each state: 0.004 → 0.00025, ratio 0.0625, ≤ 0.0003: PASS
    assert (ap.factory, ap.commissioned, ap.verdict) == (0.004, 0.00025, "PASS")
    assert ap.ratio == pytest.approx(0.0625) and ap.threshold == "≤ 0.0003 m"
    # AT on the line at 1 m/s: 0.0006 > 0.0005: FAIL
    assert at.verdict == "FAIL" and at.criterion == "AT_p iso9283-line at 1 m/s"
    # cycle time: (1.5 + 1.0) / (4 + 3) = 0.357 ≤ 0.7: PASS
    assert ct.factory == 7.0 and ct.commissioned == 2.5 and ct.ratio == pytest.approx(2.5 / 7)
    assert ct.verdict == "PASS"
    # RP: ratio 1.2 > 1.1 though 0.00006 ≤ 0.0001: both bounds must hold: FAIL
    assert rp.ratio == pytest.approx(1.2) and rp.verdict == "FAIL"
    # electrical energy: the factory's second run was not measured → the ratio cannot be formed
    assert el.factory is None and el.commissioned == 810.0 and el.ratio is None
    assert el.verdict == "not measured" and "run 2 has no electrical_energy_j" in el.note
    assert overall(rows) == {
        "verdict": "FAIL",
        "accepted": False,
        "verdict_line": "NOT ACCEPTED — 2 of 5 acceptance criteria failed: AT_p iso9283-line at 1 m/s, RP_l; "
        "1 not measured: electrical_energy",
        "n_criteria": 5,
        "n_pass": 2,
        "n_fail": 2,
        "n_not_measured": 1,
    }
    # every row passing, and only then: ACCEPTED
    passing = [r for r in rows if r.verdict == "PASS"]
    assert overall(passing)["verdict_line"] == "ACCEPTED" and overall(passing)["accepted"] is True
    assert overall([])["accepted"] is False  # no criterion judged accepts nothing


def test_missing_measurements_are_not_measured_never_pass():
    ths = [
        t(criterion="AP_p", unit="m", max_commissioned=0.0003),
        t(criterion="cycle_time", unit="s", max_ratio=0.7),
    ]
    rows = acceptance_rows(ths, [], [], None, None)
    assert [r.verdict for r in rows] == ["not measured", "not measured"]
    assert all(r.factory is None and r.commissioned is None and r.ratio is None for r in rows)
    assert overall(rows)["verdict"] == "incomplete"
    # an ISO value that is null (no tracker channel) is not measured, named by its target
    rows = acceptance_rows(ths[:1], [], [], None, iso({("AP_p", "P1"): 0.0001, ("AP_p", "P3"): None}))
    assert rows[0].verdict == "not measured" and "P3: no tracker channel" in rows[0].note
    # a path criterion at another speed does not match the threshold's 1 m/s
    th = t(criterion="AT_p", unit="m", target="iso9283-line", command_speed_m_per_s=1.0, max_commissioned=1.0)
    rows = acceptance_rows([th], [], [], None, iso({("AT_p", "iso9283-line"): 0.0001}, speed=0.5))
    assert rows[0].verdict == "not measured"
    assert "measured at a command speed of 0.5 m/s only, not 1 m/s" in rows[0].note
    # a stopped run is no cycle time
    assert task_value("cycle_time", [_run({"duration_s": 1.0, "outcome": "stopped"})]).value is None
    rows = acceptance_rows([t(criterion="AP_p", unit="m", max_commissioned=1.0)], [], [], None, iso({}))
    assert rows[0].verdict == "not measured"


def test_thresholds_file_is_checked():
    for robot in ("rx130l", "m900"):
        spec = read_yaml_model(ROOT / f"samples/{robot}/acceptance.yaml", AcceptanceThresholds)
        assert {c.criterion for c in spec.criteria} >= {"AP_p", "AT_p", "cycle_time"}
    with pytest.raises(ValueError, match="AP_p is in m, not s"):
        t(criterion="AP_p", unit="s", max_commissioned=1.0)
    with pytest.raises(ValueError, match="give max_commissioned, max_ratio or both"):
        t(criterion="AP_p", unit="m")
    with pytest.raises(ValueError, match="reference-task figure"):
        t(criterion="cycle_time", unit="s", target="P1", max_ratio=0.7)


def _run_log(path: Path, duration: float, tau2: float, energy: float | None) -> Path:
    """A run-log summary YAML as `run` writes it (only the fields accept reads are meaningful)."""
    data = {
        "kind": "rxcomm/RunLog",
        "schema_version": 1,
        "created": "2026-01-01T00:00:00Z",
        "rxcomm_version": "0",
        "inputs": {},
        "settings": {},
        "summary": {
            "underruns": 0,
            "max_lag_rad": [0.0] * 6,
            "rms_lag_rad": [0.0] * 6,
            "max_tcp_error_m": 0.0,
            "duration_s": duration,
            "tau_squared_integral_nm2_s": tau2,
            "electrical_energy_j": energy,
            "outcome": "completed",
        },  # fmt: skip
        "mcap_file": path.with_suffix(".mcap").name,
        "mcap_sha256": "0" * 64,
        "joint_names": [f"j{i}" for i in range(6)],
        "cycle_s": 0.0004,
        "interpolation_ratio": 1,
        "sample_s": 0.0004,
        "feedforward": "none",
        "gateway": "127.0.0.1:1",
        "embedded_cell": True,
        "topics": [],
    }
    path.write_text(yaml.safe_dump(data))
    return path


def test_cli_writes_the_verdict(tmp_path):
    f1, f2 = (
        _run_log(tmp_path / "f1.yaml", 4.8, 2e5, 900.0),
        _run_log(tmp_path / "f2.yaml", 3.0, 1.4e5, 500.0),
    )
    c1, c2 = _run_log(tmp_path / "c1.yaml", 1.1, 3e5, 800.0), _run_log(tmp_path / "c2.yaml", 0.9, 2e5, 400.0)
    out = tmp_path / "verdict.yaml"
    args = ["accept", "--thresholds", str(ROOT / "samples/rx130l/acceptance.yaml"), "-o", str(out)]
    args += ["--factory-log", str(f1), "--factory-log", str(f2.with_suffix(".mcap"))]
    args += ["--commissioned-log", str(c1), "--commissioned-log", str(c2)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    v = load_yaml(out)
    assert v["kind"] == "rxcomm/Acceptance" and v["summary"]["verdict"] == "FAIL"  # τᵀτ grew
    by = {r["criterion"]: r for r in v["rows"]}
    assert by["cycle_time"]["ratio"] == pytest.approx(2.0 / 7.8) and by["cycle_time"]["verdict"] == "PASS"
    assert by["tau_squared_integral"]["verdict"] == "FAIL"
    # energy is judged at equal time only: no slowed commissioned run given, not measured
    eq = by["electrical_energy_at_factory_time"]
    assert eq["factory"] == pytest.approx(1400) and eq["verdict"] == "not measured"
    assert by["AP_p"]["verdict"] == "not measured"  # no ISO 9283 artefact given
    # unequal task lists are bad input (exit 2) naming the option
    res = runner.invoke(app, args[:-2])
    assert res.exit_code == 2 and "commissioned-log" in res.output


@pytest.mark.slow
def test_factory_and_optimal_runs_on_the_cell_give_a_cycle_time_verdict(tmp_path):
    """The ISO line planned by the generic controller (catalogue, no feed-forward) and by the optimal
    planner on the prior model (prior feed-forward), both run on the simulated cell: cycle time and
    energy from the measured torques, the verdict on the cycle-time ratio."""
    import numpy as np

    from rxcomm.io.run_log import read_run_log
    from rxcomm.model.energy import motion_energy
    from rxcomm.model.robot import load_robot
    from rxcomm.stages import accept
    from rxcomm.stages import plan_cp as plan_stage
    from rxcomm.stages import run as run_stage

    robot_dir = ROOT / "samples/rx130l"
    path = robot_dir / "paths/iso9283-line.yaml"
    plan_stage.command(robot_dir, path, tmp_path / "f.mcap", timing="catalogue")
    plan_stage.command(robot_dir, path, tmp_path / "c.mcap")
    kw = dict(interpolation_ratio=1, approach=True, show_progress=False)
    f = run_stage.execute(tmp_path / "f.mcap", robot_dir, tmp_path / "run-f.mcap", feedforward=False, **kw)
    c = run_stage.execute(tmp_path / "c.mcap", robot_dir, tmp_path / "run-c.mcap", **kw)
    for s, log in ((f, "run-f.mcap"), (c, "run-c.mcap")):
        assert s["electrical_energy_j"] > 0 and s["tau_squared_integral_nm2_s"] > 0
        j = read_run_log(tmp_path / log).joints
        t = np.arange(len(j)) * s["sample_s"]
        again = motion_energy(load_robot(robot_dir), t, j.q_actual, j.tau_actual)
        # the summary sums the float64 samples, the log stores float32 (docs/logs.md): ~1e-8 relative
        assert again["electrical_energy_j"] == pytest.approx(s["electrical_energy_j"], rel=1e-6)
    th = tmp_path / "acceptance.yaml"
    th.write_text(
        "kind: rxcomm/AcceptanceThresholds\nschema_version: 1\ncriteria:\n"
        "  - {criterion: cycle_time, unit: s, max_ratio: 0.7}\n"
        "  - {criterion: AT_p, unit: m, target: iso9283-line, max_commissioned: 0.0005}\n"
    )
    summary = accept.command(
        th, tmp_path / "verdict.yaml", [tmp_path / "run-f.mcap"], [tmp_path / "run-c.mcap"]
    )
    rows = {r["criterion"]: r for r in load_yaml(tmp_path / "verdict.yaml")["rows"]}
    ratio = c["duration_s"] / f["duration_s"]
    print(f"\nISO line: factory {f['duration_s']:.3f} s, optimal {c['duration_s']:.3f} s, ratio {ratio:.3f}")
    assert rows["cycle_time"]["ratio"] == pytest.approx(ratio) and ratio < 0.7
    assert rows["cycle_time"]["verdict"] == "PASS"
    assert rows["AT_p iso9283-line"]["verdict"] == "not measured"  # no ISO 9283 artefact given
    assert summary["verdict"] == "incomplete"


def test_an_unmeasured_path_says_why():
    th = t(criterion="AT_p", unit="m", target="iso9283-line", command_speed_m_per_s=1.0, max_commissioned=1.0)
    art = iso({("AT_p", "iso9283-line"): None}, speed=None)
    rows = acceptance_rows([th], [], [], None, art)
    assert rows[0].verdict == "not measured" and "iso9283-line: no tracker channel" in rows[0].note


def test_a_factory_that_cannot_reach_the_command_speed_is_said_so():
    th = t(
        criterion="AT_p", unit="m", target="iso9283-line", command_speed_m_per_s=1.0, max_commissioned=0.0005
    )
    f_iso = iso({("AT_p", "iso9283-line"): 0.0076}, speed=0.643)
    c_iso = iso({("AT_p", "iso9283-line"): 0.0004}, speed=1.0)
    (row,) = acceptance_rows([th], [], [], f_iso, c_iso)
    assert row.verdict == "PASS" and row.factory is None and row.ratio is None
    assert row.note == (
        "worst of 1: iso9283-line, 10 cycles; factory: measured at a command speed of 0.643 m/s only, "
        "not 1 m/s"
    )


def _run(figures: dict) -> RunLogSummary:
    """A run log summary holding only the figures a test sets."""
    return RunLogSummary.model_construct(**figures)


def test_a_ratio_missing_for_its_commissioned_value_does_not_blame_the_factory():
    """cycle_time_at_factory_energy on the UR5e (MuJoCo Menagerie): every commissioned point needs more
    energy than the factory, so no commissioned value; the factory's 7.401 s is not "0"."""
    t = Threshold(criterion="cycle_time_at_factory_energy", unit="s", max_ratio=1.0)
    row = verdict_row(t, Measured(7.401, "run-factory-cp.yaml"), Measured(None, "every point needs more"))
    assert row.verdict == "not measured" and row.note == "commissioned: every point needs more"
    zero = verdict_row(t, Measured(0.0), Measured(1.0, "c"))
    assert zero.verdict == "not measured" and zero.note == "factory value is 0"
    both = verdict_row(t, Measured(None, "no log"), Measured(None, "no log"))
    assert both.note == "both states: no log"
