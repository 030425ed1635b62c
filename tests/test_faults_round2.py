"""The fault matrix, second round (issue 27): every output checked, foreign and stale artefacts
refused, every stop controlled.

Each test names the numbered case(s) of the issue it covers (docs/reliability.md lists them with the
first round's); each fails on a600d80 and passes here. What the user sees (exit code, one-line
message naming the file) and what is left behind (the input untouched, a kept ``.part``, disabled
drives) are asserted, never only "no exception". 127.0.0.1 only; every server a test starts, it stops.
"""

from __future__ import annotations

import builtins
import errno
import fcntl
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cell.server import TimeMode
from rxcomm.cli import app
from rxcomm.errors import GatewayError, InputError, SafetyStop
from rxcomm.execution.log import recovered_path
from rxcomm.gateway.client import GatewayClient
from rxcomm.gateway.registers import DriveState
from rxcomm.io import files, mcap_io
from rxcomm.io.files import check_outputs, lock_path
from rxcomm.io.mcap_io import McapWriter
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import SCHEMA_TITLE, TOPIC, load_trajectory_mcap
from rxcomm.io.yaml_io import load_yaml, write_yaml_artefact
from rxcomm.model.artefact_checks import accepting, physical_problems
from rxcomm.model.base_parameters import base_parameters, dynamics_artefact_fields, load_dynamics
from rxcomm.model.dynamics import prior_parameters
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages import run as run_stage
from rxcomm.stages.report import stale_artefacts

from .conftest import ROOT, SAMPLES
from .test_run import DQ, Q0, axis_states, cell, cosine_plan, gw, save_plan, write_configs  # noqa: F401

ROBOT_DIR = SAMPLES / "rx130l"
CLI = [sys.executable, "-c", "from rxcomm.cli import main; main()"]
runner = CliRunner()


def one_error_line(res) -> str:
    """The run's single `error:` line (rxcomm's own message, no traceback)."""
    assert "Traceback" not in res.output, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


# ---- 1, 2: an output that is an input ---------------------------------------------------------------


def test_export_refuses_its_own_input_and_its_summary(tmp_path):
    """Case 1: `export cp.mcap -o cp.mcap` (and `-o cp.yaml`, the summary beside it) is exit 2 and
    both files stay as they were."""
    plan = save_plan(tmp_path / "cp.mcap", cosine_plan(Q0, DQ, 0.2))
    before = {p: p.read_bytes() for p in (plan, plan.with_suffix(".yaml"))}
    for out in (plan, plan.with_suffix(".yaml")):
        res = runner.invoke(app, ["export", str(plan), "-o", str(out)])
        assert res.exit_code == 2, res.output
        assert "is also the input" in one_error_line(res)
    assert {p: p.read_bytes() for p in before} == before
    load_trajectory_mcap(plan)  # still the plan, its summary still its own


def test_calibrate_refuses_an_mdh_csv_over_its_measurements(tmp_path):
    """Case 2: `--mdh-out m/track.yaml` writes m/track.csv beside it: refused (exit 2, naming the CSV
    and the option) when that is the tracker CSV read, before anything is read."""
    m = tmp_path / "m"
    m.mkdir()
    track = m / "track.csv"
    track.write_text("t,x,y,z\n0,1,2,3\n")  # no valid CSV needed: the check comes first
    before = track.read_bytes()
    res = runner.invoke(
        app,
        [
            "calibrate",
            "--robot",
            str(ROBOT_DIR),
            "--measurements",
            str(track),
            "--mdh-out",
            str(m / "track.yaml"),
            "-o",
            str(m / "c.yaml"),
        ],
    )
    assert res.exit_code == 2, res.output
    line = one_error_line(res)
    assert "mdh-out CSV" in line and "track.csv" in line and "is also the input measurements" in line
    assert track.read_bytes() == before and not (m / "c.yaml").exists()


# ---- 3: an earlier .part is moved aside, never replaced ----------------------------------------------


def test_an_earlier_part_is_moved_aside_and_named(tmp_path, capsys):
    out = tmp_path / "run.mcap"
    files.part_path(out).write_bytes(b"first killed run")
    check_outputs({"output": out})
    files.release_outputs()
    assert (tmp_path / "run.mcap.part.1").read_bytes() == b"first killed run"
    files.part_path(out).write_bytes(b"second")
    check_outputs({"output": out})
    assert (tmp_path / "run.mcap.part.2").read_bytes() == b"second"
    assert not files.part_path(out).exists()
    err = capsys.readouterr().err
    assert "run.mcap.part.1" in err and "run.mcap.part.2" in err and "recover-log" in err
    assert recovered_path(tmp_path / "run.mcap.part.2") == tmp_path / "run.2.recovered.mcap"


@pytest.mark.slow
def test_a_rerun_keeps_the_killed_runs_part(tmp_path, cell, capfd):  # noqa: F811
    """Case 3 end to end: a run with the `-o` of a killed run completes and the killed run's
    `.part` is still there, as `.part.1`, named on stderr."""
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 1.5))
    out = tmp_path / "log.mcap"
    killed = files.part_path(out)
    killed.write_bytes(b"the killed run's records")
    run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    assert out.is_file() and read_run_log(out).summary["outcome"] == "completed"
    assert (tmp_path / "log.mcap.part.1").read_bytes() == b"the killed run's records"
    assert "log.mcap.part.1" in capfd.readouterr().err


# ---- 4: one writer per output, one make per build directory -----------------------------------------


@pytest.mark.process  # a second writer in another process
def test_a_second_writer_of_an_output_stops_naming_the_lock(tmp_path):
    out = tmp_path / "log.mcap"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from rxcomm.io.files import lock_output; import sys, time; lock_output({str(out)!r}); "
            "print('held', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        t0 = time.monotonic()
        with pytest.raises(InputError, match=r"another process is writing this output .*\.log\.mcap\.lock"):
            check_outputs({"output": out})
        assert time.monotonic() - t0 < 1.0
    finally:
        holder.kill()
        holder.wait(10)
    check_outputs({"output": out})  # the holder is gone: the lock is free (a stale lock file is no lock)
    assert lock_path(out).exists()
    files.release_outputs()
    assert not lock_path(out).exists()


@pytest.mark.make
def test_a_second_make_commission_on_one_build_stops_at_once_naming_the_lock(tmp_path):
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    shutil.copytree(ROBOT_DIR, tmp_path / "samples" / "rx130l")
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").touch()
    (tmp_path / "build").mkdir()
    env = {k: v for k, v in os.environ.items() if k not in {"MAKEFLAGS", "MFLAGS", "MAKELEVEL"}}
    make = ["make", "--no-print-directory"]
    assert (
        subprocess.run([*make, "-t", "commission"], cwd=tmp_path, env=env, capture_output=True).returncode
        == 0
    )
    with open(tmp_path / "build" / ".make.lock", "w") as lock:  # the first make, building
        fcntl.flock(lock, fcntl.LOCK_EX)
        t0 = time.monotonic()
        second = subprocess.run([*make, "commission"], cwd=tmp_path, env=env, capture_output=True, text=True)
        took = time.monotonic() - t0
    assert second.returncode != 0 and took < 5.0
    assert "build/.make.lock" in second.stderr and "another make commission" in second.stderr
    done = subprocess.run([*make, "commission"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0 and "commissioning report" in done.stdout  # lock free: it builds


# ---- 5: missing directories are created by every stage ----------------------------------------------


@pytest.mark.slow
def test_run_and_campaign_into_missing_directories(tmp_path, cell, rx130l):  # noqa: F811
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 1.5))
    out = tmp_path / "newdir" / "sub" / "log.mcap"
    run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    assert out.is_file() and out.with_suffix(".yaml").is_file()
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, [Q0 + 0.2 * DQ, Q0], ["fit", "fit"])
    meas = tmp_path / "other" / "deeper" / "meas.yaml"
    summary = run_stage.execute(cfg, ROBOT_DIR, meas, gateway=gw(cell), speed=0.5, show_progress=False)
    assert summary["n_valid"] == 2 and meas.is_file()
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6


# ---- 6: a full disk mid-run is a controlled stop ----------------------------------------------------


class _FullAfter:
    """A file whose writes fail with ENOSPC once ``budget`` bytes are written (a full file system)."""

    def __init__(self, f, budget: list[int]):
        self._f, self._budget = f, budget

    def write(self, data) -> int:
        n = len(data)
        if n > self._budget[0]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._budget[0] -= n
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


def _disk_of(monkeypatch, module, budget_bytes: int, match: str) -> None:
    """Files ``module`` opens whose name contains ``match`` fill up after ``budget_bytes``."""
    budget = [budget_bytes]
    real = builtins.open

    def limited(path, mode="r", *a, **k):
        f = real(path, mode, *a, **k)
        return _FullAfter(f, budget) if "w" in mode and match in str(path) else f

    monkeypatch.setattr(module, "open", limited, raising=False)


@pytest.mark.slow
def test_a_full_disk_mid_run_stops_the_robot_and_names_the_log(tmp_path, cell, monkeypatch):  # noqa: F811
    """Case 6: the run log's disk fills 200 KB in: quick stop, drives disabled, exit 2 naming
    NAME.mcap.part (kept), no `.part.part`."""
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 2.0))
    out = tmp_path / "log.mcap"
    _disk_of(monkeypatch, mcap_io, 200_000, "log.mcap")
    with pytest.raises(InputError) as e:
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), interpolation_ratio=1, show_progress=False)
    msg = str(e.value)
    assert e.value.exit_code == 2 and "No space left on device" in msg and "quick stop sent" in msg
    assert "log.mcap.part" in msg and ".part.part" not in msg and "drives disabled" in msg
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6
    assert files.part_path(out).exists() and not out.exists()


@pytest.mark.slow
def test_a_full_disk_mid_campaign_keeps_the_poses_taken(tmp_path, cell, rx130l, monkeypatch):  # noqa: F811
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, [Q0 + 0.2 * DQ, Q0, Q0 - 0.2 * DQ], ["fit"] * 3)
    meas = tmp_path / "meas.yaml"
    size = []  # the first pose's file fits, the second's does not

    real = builtins.open

    def limited(path, mode="r", *a, **k):
        f = real(path, mode, *a, **k)
        if "w" in mode and "meas.yaml" in str(path):
            size.append(path)
            return _FullAfter(f, [10**9 if len(size) == 1 else 0])
        return f

    monkeypatch.setattr(files, "open", limited, raising=False)
    with pytest.raises(InputError) as e:
        run_stage.execute(cfg, ROBOT_DIR, meas, gateway=gw(cell), speed=0.5, show_progress=False)
    msg = str(e.value)
    assert "No space left on device" in msg and "meas.yaml.part" in msg and ".part.part" not in msg
    assert "drives disabled" in msg
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6
    kept = load_yaml(tmp_path / "meas.yaml.part")
    assert len(kept["poses"]) == 1 and kept["summary"]["outcome"] == "running"


# ---- 7: trajectory time stamps -----------------------------------------------------------------------


def _mcap_with_times(path: Path, *blocks: np.ndarray) -> Path:
    """A trajectory MCAP (and its summary) whose samples are written block by block, in this order."""
    from rxcomm.io.yaml_io import write_mcap_summary

    t = np.concatenate(blocks)
    n = len(t)
    q = Q0 + np.outer(np.linspace(0, 1, n), 0.01 * DQ)
    cols = {"q": q, "qd": np.zeros((n, 6)), "qdd": np.zeros((n, 6)), "tau_ff": np.zeros((n, 6))}
    summary = {
        "duration_s": float(t.max() - t.min()),
        "solve_seconds": 0.0,
        "max_limit_ratio": 0.1,
        "active_fraction": 0.0,
        "q_start": q[0].tolist(),
        "q_goal": q[-1].tolist(),
    }
    env = TrajectorySummary.envelope({}, {}, summary)
    data = {**env, "topic": TOPIC, "n_samples": n, "fields": list(cols)}
    with McapWriter(path, env) as w:
        start = 0
        for b in blocks:
            sl = slice(start, start + len(b))
            w.write_arrays(TOPIC, t[sl], {k: v[sl] for k, v in cols.items()}, schema_title=SCHEMA_TITLE)
            w.flush()
            start += len(b)
        w.finish(before_rename=lambda part: write_mcap_summary(TrajectorySummary, data, path, part))
    return path


def test_trajectory_times_backwards_or_with_a_hole_are_refused(tmp_path):
    dt = 400e-6
    t = np.arange(2000) * dt
    back = _mcap_with_times(tmp_path / "back.mcap", t[1000:], t[:1000])
    with pytest.raises(
        InputError, match=r"back\.mcap: /trajectory\.log_time: log time goes backwards at t = 0\.000000 s"
    ):
        load_trajectory_mcap(back)
    holed = t.copy()
    holed[1000:] += 0.29
    hole = _mcap_with_times(tmp_path / "hole.mcap", holed)
    with pytest.raises(
        InputError, match=r"hole\.mcap: /trajectory\.log_time: log time steps from 0\.399600 s to 0\.690000 s"
    ):
        load_trajectory_mcap(hole)
    res = runner.invoke(
        app,
        [
            "run",
            str(hole),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:1",
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    )
    assert res.exit_code == 2 and "hole" in one_error_line(res)  # before any gateway is contacted
    ok = _mcap_with_times(tmp_path / "ok.mcap", t)
    assert load_trajectory_mcap(ok)[0].n == 2000  # the check passes a uniform trajectory


# ---- 8, 9: dynamics and calibrations that claim another or an impossible robot -----------------------


def _dynamics_file(path: Path, robot, params, inputs: dict | None = None) -> Path:
    bset = base_parameters(robot, n_samples=100, seed=0)
    fields = dynamics_artefact_fields(robot, bset, bset.project(params), full=params)
    summary = {
        "n_base_params": bset.n_base,
        "validation_nrmse": [0.0] * 6,
        "validation_rms_nm": [0.0] * 6,
        "seconds": 0.0,
    }
    return write_yaml_artefact(path, Dynamics(**Dynamics.envelope(inputs or {}, {}, summary), **fields))


def _j1_inertia_minus(robot, kgm2: float):
    p = prior_parameters(robot)
    inertial = p.inertial.copy()
    inertial[0, 9] -= kgm2  # link 1's Izz about J1's axis
    from dataclasses import replace

    return replace(p, inertial=inertial)


@pytest.mark.slow
def test_physically_inconsistent_dynamics_are_refused_unless_allowed(tmp_path, rx130l, capsys):
    """Case 8: J1 inertia −35 kg·m² makes M(q) indefinite: refused by the loader (so run and the
    planners), exit 2 naming the file; with --allow-inconsistent a warning. The prior passes."""
    assert physical_problems(rx130l, prior_parameters(rx130l)) == []
    bad = _dynamics_file(tmp_path / "bad.yaml", rx130l, _j1_inertia_minus(rx130l, 35.0))
    with pytest.raises(
        InputError,
        match=r"bad\.yaml: parameters: physically inconsistent dynamics: "
        r"the mass matrix M\(q\) is not positive definite",
    ):
        load_dynamics(bad, rx130l)
    with accepting(allow_inconsistent=True):
        load_dynamics(bad, rx130l)
    assert "warning" in capsys.readouterr().err
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 0.2))
    res = runner.invoke(
        app,
        [
            "run",
            str(plan),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:1",
            "--dynamics",
            str(bad),
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    )
    assert res.exit_code == 2 and "--allow-inconsistent" in one_error_line(res)
    res = runner.invoke(
        app,
        [
            "plan-ptp",
            "--robot",
            str(ROBOT_DIR),
            "--start",
            "0,0,1.5,0,0,0",
            "--goal",
            "0.3,0,1.5,0,0,0",
            "--dynamics",
            str(bad),
            "-o",
            str(tmp_path / "p.mcap"),
        ],
    )
    assert res.exit_code == 2 and "not positive definite" in one_error_line(res)


def test_another_robots_dynamics_and_calibration_are_refused_unless_asked(tmp_path, rx130l, capsys):
    """Case 9: same joint names, another URDF (a 0.1 m longer upper arm): the envelope's urdf hash
    differs. Refused naming it; `--other-robot` accepts with a warning naming the difference."""
    other = tmp_path / "other.urdf"
    text = rx130l.urdf_path.read_text()
    other.write_text(text.replace("<robot", "<!-- a 0.1 m longer upper arm -->\n<robot", 1))
    inputs = {"urdf": other, "drives": rx130l.drives_path}
    dyn = _dynamics_file(tmp_path / "dynamics.yaml", rx130l, prior_parameters(rx130l), inputs)
    with pytest.raises(
        InputError,
        match=r"dynamics\.yaml: inputs: made for other robot files than .* \(urdf: made with sha256",
    ):
        load_dynamics(dyn, rx130l)
    with accepting(other_robot=True):
        load_dynamics(dyn, rx130l)
    assert "made for other robot files (urdf" in capsys.readouterr().err
    from rxcomm.calibration.loading import load_calibrated_robot

    from .artefacts import synthetic_calibration

    cal = synthetic_calibration(rx130l, {"joint_2.tx": 1e-4})
    cal = cal.model_copy(
        update={"inputs": {"urdf": files_sha(other), "drives": files_sha(rx130l.drives_path)}}
    )
    cal_file = write_yaml_artefact(tmp_path / "calibration.yaml", cal)
    with pytest.raises(InputError, match="made for other robot files"):
        load_calibrated_robot(rx130l, cal_file)
    same = cal.model_copy(update={"inputs": {"urdf": files_sha(rx130l.urdf_path)}})
    load_calibrated_robot(rx130l, write_yaml_artefact(tmp_path / "own.yaml", same))  # its own robot: fine


def files_sha(path: Path) -> str:
    from rxcomm.schemas.plain import sha256_file

    return sha256_file(path)


# ---- 10: a stale chain -------------------------------------------------------------------------------


def test_a_summary_that_is_not_its_mcaps_is_refused(tmp_path):
    """Case 10: cp.mcap replaced by another plan's MCAP (its summary unchanged): run, plan-cycles and
    export refuse it, naming mcap_sha256."""
    a = save_plan(tmp_path / "cp.mcap", cosine_plan(Q0, DQ, 0.2))
    b = save_plan(tmp_path / "other.mcap", cosine_plan(Q0, 0.5 * DQ, 0.3))
    shutil.copy(b, a)
    with pytest.raises(
        InputError, match=r"cp\.mcap: mcap_sha256: its summary cp\.yaml was written for an MCAP"
    ):
        load_trajectory_mcap(a)
    for args in (
        ["export", str(a), "-o", str(tmp_path / "cp.csv")],
        ["plan-cycles", str(a), "--robot", str(ROBOT_DIR), "--cycles", "2", "-o", str(tmp_path / "c.mcap")],
        [
            "run",
            str(a),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:1",
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and "mcap_sha256" in one_error_line(res), (args, res.output)


@pytest.mark.slow
def test_run_warns_of_a_dynamics_other_than_the_plans_and_report_notes_a_replaced_input(tmp_path, rx130l):
    from rxcomm.execution.guards import other_model_warning

    dyn = _dynamics_file(tmp_path / "dynamics.yaml", rx130l, prior_parameters(rx130l))
    traj = cosine_plan(Q0, DQ, 0.2)
    summary = {
        "duration_s": traj.duration_s,
        "solve_seconds": 0.0,
        "max_limit_ratio": 0.5,
        "active_fraction": 0.0,
        "q_start": traj.q[0].tolist(),
        "q_goal": traj.q[-1].tolist(),
    }
    from rxcomm.io.trajectory import save_trajectory_mcap

    plan = tmp_path / "cp.mcap"
    save_trajectory_mcap(plan, traj, TrajectorySummary.envelope({"dynamics": dyn}, {}, summary))
    assert other_model_warning(plan, dyn) is None
    assert stale_artefacts(tmp_path) == []
    planned_with = dyn.read_bytes()
    other = _dynamics_file(tmp_path / "dynamics.yaml", rx130l, _j1_inertia_minus(rx130l, 0.5))  # replaced
    warning = other_model_warning(plan, other)
    assert warning is not None and "planned with another dynamics model" in warning
    assert stale_artefacts(tmp_path) == ["cp.yaml was made from an older dynamics.yaml"]
    # an input named by its role, whose file is another one of the build (make commission PLANT=mujoco:
    # identify's `calibration` is calibration-prior.yaml beside calibration.yaml), is not replaced
    (tmp_path / "dynamics-prior.yaml").write_bytes(planned_with)
    assert stale_artefacts(tmp_path) == []
    (tmp_path / "dynamics-prior.yaml").unlink()
    from rxcomm.stages.report import build_report

    report, _ = build_report(tmp_path)
    assert "Built on replaced inputs" in report.preamble and "older dynamics.yaml" in report.preamble


# ---- 11: accept compares the same task ----------------------------------------------------------------


@pytest.mark.slow
def test_accept_refuses_one_log_twice_and_logs_of_different_tasks(tmp_path, cell):  # noqa: F811
    logs = {}
    for name, dq in (("a", DQ), ("b", -DQ)):
        plan = save_plan(tmp_path / f"plan-{name}.mcap", cosine_plan(Q0, dq, 1.5))
        logs[name] = tmp_path / f"run-{name}.mcap"
        run_stage.execute(plan, ROBOT_DIR, logs[name], gateway=gw(cell), approach=True, show_progress=False)
    base = [
        "accept",
        "--thresholds",
        str(SAMPLES / "rx130l" / "acceptance.yaml"),
        "-o",
        str(tmp_path / "v.yaml"),
    ]
    res = runner.invoke(app, [*base, "--factory-log", str(logs["a"]), "--commissioned-log", str(logs["a"])])
    assert res.exit_code == 2 and "is the same run log" in one_error_line(res)
    res = runner.invoke(app, [*base, "--factory-log", str(logs["a"]), "--commissioned-log", str(logs["b"])])
    assert res.exit_code == 2 and "did not execute the same task" in one_error_line(res)


# ---- 12: SIGTERM -------------------------------------------------------------------------------------


@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c(tmp_path, cell):  # noqa: F811
    from .test_faults import streamed_s, wait_for

    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 6.0))
    out = tmp_path / "log.mcap"
    proc = subprocess.Popen(
        [*CLI, "run", str(plan), "--robot", str(ROBOT_DIR), "--gateway", gw(cell), "-o", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_for(lambda: streamed_s(cell) >= 0.5 or proc.poll() is not None, 60, 0.005)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        err = proc.stderr.read()
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 5, err
    assert (
        "terminated (SIGTERM): quick stop sent" in err and "drives disabled" in err and "log kept in" in err
    )
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6
    log = read_run_log(files.part_path(out))
    assert len(log.joints) > 100 and log.summary["outcome"] == "safety_stop"


# ---- 13: option ranges ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "option, value, field",
    [
        ("--interpolation-ratio", "0", "interpolation-ratio"),
        ("--interpolation-ratio", "65", "interpolation-ratio"),
        ("--speed-fraction", "0", "speed-fraction"),
        ("--speed-fraction", "1.5", "speed-fraction"),
        ("--speed-fraction", "nan", "speed-fraction"),
    ],
)
def test_run_option_out_of_range_is_exit_2(tmp_path, option, value, field):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 0.2))
    res = runner.invoke(
        app, ["run", str(plan), "--robot", str(ROBOT_DIR), "-o", str(tmp_path / "l.mcap"), option, value]
    )
    assert res.exit_code == 2, res.output
    assert f"error: {field}: {value}" in one_error_line(res)


# ---- 14: what the drives are in, the approach, the gateway's address -----------------------------------


@pytest.mark.slow
def test_a_stop_during_the_approach_says_approach(tmp_path, cell):  # noqa: F811
    from .test_run import _when

    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0 + 0.5 * DQ, DQ, 2.0))  # not where the arm is

    def fault() -> None:
        with GatewayClient("127.0.0.1", cell.port, timeout_s=1.0) as c:
            c.sim_fault(0b1)

    th = _when(cell, 500, fault)
    with pytest.raises(SafetyStop, match="during the approach move to the plan's start") as e:
        run_stage.execute(
            plan, ROBOT_DIR, tmp_path / "l.mcap", gateway=gw(cell), approach=True, show_progress=False
        )
    th.join(5)
    # J1 latched its fault, the others are disabled: the message says so, not "drives disabled" alone
    assert "drives disabled except joint_1" in str(e.value) and "in fault" in str(e.value)


@pytest.mark.socket  # a fake gateway on 127.0.0.1
@pytest.mark.parametrize("reply", [None, b"\x00garbage that is no Modbus frame\xff" * 3])
def test_a_silent_or_garbage_gateway_is_named_in_our_words(tmp_path, reply):
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    stop = threading.Event()

    def serve() -> None:
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                continue
            conn.settimeout(0.2)
            while not stop.is_set():
                try:
                    if conn.recv(260) and reply is not None:
                        conn.sendall(reply)
                except TimeoutError:
                    continue
                except OSError:
                    break
            conn.close()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 3.0))
        with pytest.raises(GatewayError) as e:
            run_stage.execute(
                plan, ROBOT_DIR, tmp_path / "l.mcap", gateway=f"127.0.0.1:{port}", show_progress=False
            )
    finally:
        stop.set()
        th.join(5)
        srv.close()
    msg = str(e.value)
    assert f"127.0.0.1:{port}" in msg and "Modbus Error" not in msg and "[Input/Output]" not in msg
    # pymodbus drops a reply it cannot parse: garbage reads as silence, and the message says both
    assert "no valid Modbus TCP answer from the gateway" in msg and "silent, or not an rxcomm" in msg


# ---- 15: robot-info on a robot too weak for its payload ----------------------------------------------


def test_robot_info_prints_the_figures_then_exit_3_for_a_payload_too_heavy(tmp_path):
    robot = tmp_path / "weak"
    shutil.copytree(ROBOT_DIR, robot)
    drives = robot / "drives.yaml"
    drives.write_text(
        drives.read_text().replace("rated_payload: {mass_kg: 5.0,", "rated_payload: {mass_kg: 500.0,")
    )
    res = runner.invoke(app, ["robot-info", "--robot", str(robot)])
    assert res.exit_code == 3, res.output
    assert "degrees of freedom" in res.output and "gravity alone needs" in res.output
    assert res.output.index("degrees of freedom") < res.output.index("error:")


# ---- 16: a stop names what held the master ------------------------------------------------------------


def test_stall_watch_tells_a_descheduled_master_from_its_own_work(monkeypatch):
    """Clocks driven by the test (a loaded machine makes real CPU shares unpredictable): a pause off
    the CPU, one on it, one in the garbage collector."""
    from rxcomm.execution import stalls

    clock = {"wall": 0.0, "cpu": 0.0}

    class FakeTime:
        @staticmethod
        def perf_counter():
            return clock["wall"]

        @staticmethod
        def process_time():
            return clock["cpu"]

    monkeypatch.setattr(stalls, "time", FakeTime)
    for cpu_s, gc_s, cause in (
        (0.05, 0.0, "the master was not scheduled (a loaded machine)"),
        (1.1, 0.0, "the master's own work or another thread holding the GIL"),
        (1.2, 0.9, "the garbage collector"),
    ):
        with stalls.StallWatch() as w:
            w.reply()
            clock["wall"] += 0.2
            w.reply()
            w._gc("start", {})
            clock["wall"] += gc_s
            w._gc("stop", {})
            clock["wall"] += 1.3 - gc_s
            clock["cpu"] += cpu_s
            w.reply()
        assert w.longest_s == pytest.approx(1.3) and w.longest_at_s == pytest.approx(0.2)
        assert w.describe().endswith(cause), w.describe()
        assert f"was 1.30 s 0.20 s into the stream ({cpu_s / 1.3:.0%} of it" in w.describe()


@pytest.mark.slow
def test_a_watchdog_stop_names_the_masters_pause(tmp_path, cell, monkeypatch):  # noqa: F811
    """The master hangs 0.8 s (off the CPU) mid-stream: the watchdog stop says how long and why."""
    from rxcomm.execution import session as ses

    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 3.0))
    stalled = {"done": False}
    real = ses._Recorder.__call__

    def stalling(self, reply):
        real(self, reply)
        if not stalled["done"] and reply.trace is not None and reply.trace.count > 0:
            stalled["done"] = True
            time.sleep(0.8)

    monkeypatch.setattr(ses._Recorder, "__call__", stalling)
    with pytest.raises(GatewayError) as e:
        run_stage.execute(plan, ROBOT_DIR, tmp_path / "log.mcap", gateway=gw(cell), show_progress=False)
    msg = str(e.value)
    assert "heartbeat (0x8130)" in msg and "the master's longest pause between gateway replies was 0.8" in msg
    assert "the master was not scheduled" in msg
    # case 14: the watchdog faulted every drive; the message says so instead of "drives disabled"
    assert "drives in fault, not disabled (joint_1 0x8130" in msg


def test_stall_watch_tells_a_master_falling_behind_from_one_pause(monkeypatch):
    """Fake clocks: at 2500 setpoints/s needed, a master writing 1500/s with 4 ms pauses fell behind;
    one 0.9 s pause that ate a 1 s lead is named as the pause, with the rates after it."""
    from rxcomm.execution import stalls

    clock = {"wall": 0.0, "cpu": 0.0}

    class FakeTime:
        @staticmethod
        def perf_counter():
            return clock["wall"]

        @staticmethod
        def process_time():
            return clock["cpu"]

    monkeypatch.setattr(stalls, "time", FakeTime)
    with stalls.StallWatch(sample_s=400e-6) as slow:  # a 1 s prefill, then 1500 written/s
        written, executed = 2500, 0
        for _ in range(300):
            slow.reply(written, executed)
            clock["wall"] += 0.004
            clock["cpu"] += 0.002
            written, executed = written + 6, executed + 10
    text = slow.describe()
    assert text.startswith("the master fell behind the stream, over the last 1.00 s it wrote 1500 "), text
    assert "the stream needs 2500/s (executed 2500/s), its lead peaked at 1.00 s" in text
    assert (
        "this process had 50% of a CPU; the master's longest pause between gateway replies was 0.00" in text
    )

    with stalls.StallWatch(sample_s=400e-6) as paused:  # 1 s lead held, then 0.9 s without a reply
        written, executed = 2500, 0
        for _ in range(300):
            paused.reply(written, executed)
            clock["wall"] += 0.0024
            written, executed = written + 6, executed + 6
        clock["wall"] += 0.9
        paused.reply(written, executed + 2250)
    text = paused.describe()
    assert text.startswith("the master's longest pause between gateway replies was 0.90 s 0.72 s into"), text
    assert "the master was not scheduled (a loaded machine); over the last" in text
    assert slow.describe(watchdog=True).startswith("the master's longest pause")  # the pause tripped it


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.parametrize("stall", ["slow master", "one pause"])
def test_an_underrun_stop_names_the_stall(rx130l, monkeypatch, stall):
    """Realtime cell, ratio 1 (2500 setpoints/s): a master made slower than the stream (4 ms more per
    reply) or paused once for 0.6 s beyond its 0.2 s lead underruns, and the stop says which."""
    from rxcomm.execution import session as ses
    from rxcomm.execution.plan import prepare_plan
    from rxcomm.execution.session import RunSettings, StreamSettings
    from rxcomm.execution.trajectory_run import run_trajectory

    from .test_faults import ideal_cell

    real = ses._Recorder.__call__
    paused = {"done": False}

    def stalling(self, reply):
        real(self, reply)
        if stall == "slow master":
            time.sleep(0.004)
        elif not paused["done"] and reply.trace is not None and reply.trace.count > 0:
            paused["done"] = True
            time.sleep(0.6)

    monkeypatch.setattr(ses._Recorder, "__call__", stalling)
    lead = StreamSettings(interpolation_ratio=1, lead_s=0.2, prefill_s=0.2, watchdog_ms=2000)
    srv = ideal_cell(rx130l, TimeMode.REALTIME)
    try:
        params = prior_parameters(rx130l)
        plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 4.0), params, 400e-6)
        with GatewayClient("127.0.0.1", srv.port, timeout_s=0.5) as client:
            res = run_trajectory(client, rx130l, plan, params, RunSettings(stream=lead))
    finally:
        srv.stop()
    msg = str(res.error)
    assert isinstance(res.error, GatewayError) and "underrun (0xff01)" in msg, msg
    assert "the stream needs 2500/s" in msg
    wrote = float(re.search(r"it wrote (\d+) setpoints/s", msg).group(1))
    if stall == "slow master":
        assert msg.startswith("stream stopped by the gateway: setpoint underrun"), msg
        assert "the master fell behind the stream, over the last" in msg and wrote < 2000
    else:
        assert re.search(r"longest pause between gateway replies was 0\.[6-9]\d s", msg), msg
        assert "the master was not scheduled (a loaded machine)" in msg


def test_raised_priority_lowers_every_threads_nice_and_restores_it_or_says_why_not(monkeypatch):
    """Where allowed, every thread of the process (the embedded cell's too) streams at nice −10 and
    is back afterwards; where not, nothing changes and the note says why (a stop message quotes it)."""
    from rxcomm.execution import stalls

    def nice_of(tid: int) -> int:
        return os.getpriority(os.PRIO_PROCESS, tid)

    started, release = threading.Event(), threading.Event()
    tid = {}

    def other() -> None:
        tid["other"] = threading.get_native_id()
        started.set()
        release.wait(10)

    t = threading.Thread(target=other, daemon=True)
    t.start()
    started.wait(10)
    me = threading.get_native_id()
    before = {me: nice_of(me), tid["other"]: nice_of(tid["other"])}
    try:
        with stalls.raised_priority(-10) as note:
            during = {k: nice_of(k) for k in before}
        if note == "the stream ran at nice -10":
            assert during == {k: -10 for k in before}
        else:  # not root and no CAP_SYS_NICE
            assert note.startswith("the stream's priority was not raised (") and during == before
        assert {k: nice_of(k) for k in before} == before

        def refuse(*a):
            raise PermissionError(1, "Operation not permitted")

        monkeypatch.setattr(stalls.os, "setpriority", refuse)
        with stalls.raised_priority(-10) as note:
            assert note == "the stream's priority was not raised (Operation not permitted)"
    finally:
        release.set()
        t.join(10)
