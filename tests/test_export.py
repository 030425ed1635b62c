"""`rxcomm export`: trajectory CSV for a controller and run-log CSV, round-tripped through their readers."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.io.csv_export import read_csv_table, read_run_log_csv, read_trajectory_csv
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import Trajectory, load_trajectory_mcap

from .test_cross_validation import bset_rx, noisy_log, truth_rx  # noqa: F401 - identify's fixture log
from .test_foxglove_log import run_log  # noqa: F401 - the module's run-log fixture
from .test_identification import write_run_log as write_log
from .test_run import DQ, Q0, ROBOT_DIR, save_plan

runner = CliRunner()


def _plan(tmp_path):
    t = np.linspace(0.0, 0.8, 401)
    s = 0.5 - 0.5 * np.cos(np.pi * t / 0.8)
    sd = 0.5 * np.pi / 0.8 * np.sin(np.pi * t / 0.8)
    sdd = 0.5 * (np.pi / 0.8) ** 2 * np.cos(np.pi * t / 0.8)
    tau = 40.0 * np.outer(sdd, DQ) + np.array([0.0, 120.0, 35.0, 1.0, 4.0, 0.2])  # inertial + gravity-like
    traj = Trajectory(t, Q0 + np.outer(s, DQ), np.outer(sd, DQ), np.outer(sdd, DQ), tau)
    return save_plan(tmp_path / "plan.mcap", traj)


def test_trajectory_csv_round_trips_exactly_with_units(tmp_path):
    plan = _plan(tmp_path)
    out = tmp_path / "plan.csv"
    r = runner.invoke(app, ["export", str(plan), "-o", str(out)])
    assert r.exit_code == 0, r.output
    comments, cols = read_csv_table(out)
    # a plan written without joint names: joint1 … in the header (the plan's own names otherwise)
    assert list(cols)[:3] == ["t_s", "q_joint1_rad", "q_joint2_rad"] and "qd_joint6_rad_s" in cols
    assert "qdd_joint1_rad_s2" in cols and "tau_ff_joint6_Nm" in cols
    assert any("rxcomm/Trajectory" in c for c in comments) and any("joint (link) side" in c for c in comments)
    back = read_trajectory_csv(out)
    ref, _ = load_trajectory_mcap(plan)
    for name in ("t", "q", "qd", "qdd", "tau_ff"):
        assert np.array_equal(getattr(back, name), getattr(ref, name)), name  # 17 digits: exact
    assert back.tau_ff[:, 1].min() > 20.0  # the feed-forward is there (120 N·m ± 92), not zeros
    # the summary YAML stands for its MCAP; the default name is beside it
    r = runner.invoke(app, ["export", str(tmp_path / "plan.yaml")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "plan.csv").read_text() == out.read_text()


def test_run_log_csv_round_trips(run_log, tmp_path, rx130l):  # noqa: F811
    path, _ = run_log
    out = tmp_path / "log.csv"
    r = runner.invoke(app, ["export", str(path), "-o", str(out)])
    assert r.exit_code == 0, r.output
    names = list(rx130l.joint_names)
    t, fields = read_run_log_csv(out, names)
    _, cols = read_csv_table(out)
    assert "q_actual_joint_1_rad" in cols and "tau_actual_joint_6_Nm" in cols and "tcp_speed_m_s" in cols
    log = read_run_log(path)
    assert np.array_equal(t, log.joints.t) and set(fields) == set(log.joints.fields)
    for k, v in fields.items():
        assert np.array_equal(v, log.joints[k], equal_nan=True), k
    assert np.nanmax(fields["tcp_speed_m_s"]) > 0.05  # the plan moves the TCP


def test_export_refuses_what_it_cannot_export(tmp_path):
    bad = tmp_path / "junk.mcap"
    bad.write_bytes(b"not an mcap")
    r = runner.invoke(app, ["export", str(bad)])
    assert r.exit_code == 2 and "junk.mcap" in r.output
    other = tmp_path / "other.yaml"
    other.write_text("kind: rxcomm/Configs\nschema_version: 1\n")
    r = runner.invoke(app, ["export", str(other)])
    assert r.exit_code == 2 and "rxcomm/Configs" in r.output and "has no export" in r.output
    r = runner.invoke(app, ["export", str(tmp_path / "missing.mcap")])
    assert r.exit_code == 2 and "missing.mcap" in r.output


def test_identified_dynamics_export_is_identify_s_parameter_table(tmp_path, rx130l, noisy_log):  # noqa: F811
    log = write_log(tmp_path / "excite-log.mcap", noisy_log.t, noisy_log.q, noisy_log.tau)
    out, table = tmp_path / "dynamics.yaml", tmp_path / "params.csv"
    args = [
        "identify",
        "--robot",
        str(ROBOT_DIR),
        "--log",
        str(log),
        "-o",
        str(out),
        "--params-out",
        str(table),
    ]
    assert runner.invoke(app, args).exit_code == 0
    r = runner.invoke(app, ["export", str(out)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "dynamics.csv").read_text() == table.read_text()


def test_every_exporter_names_a_real_kind_and_library_call():
    from rxcomm.schemas.calibration import Calibration
    from rxcomm.schemas.dynamics import Dynamics
    from rxcomm.schemas.kinematics import Kinematics
    from rxcomm.schemas.run_log import RunLog
    from rxcomm.schemas.trajectory import TrajectorySummary
    from rxcomm.stages.export import EXPORTERS, exporter

    kinds = {TrajectorySummary.KIND, RunLog.KIND, Dynamics.KIND, Kinematics.KIND, Calibration.KIND}
    assert set(EXPORTERS) == kinds
    for kind, formats in EXPORTERS.items():
        for fmt in formats:
            assert callable(exporter(kind, fmt)), (kind, fmt)
