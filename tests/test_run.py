"""`rxcomm run` on the protocol test double (IdealBackend): plans, refusals, streaming, faults, campaign.

Physics-dependent figures (lag with and without feed-forward) are in test_run_sim.py. Every server
listens on 127.0.0.1 with an ephemeral port and is stopped by the test; a hard timeout kills a hang.
"""

from __future__ import annotations

import faulthandler
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.cell.backend import AxisFeedback, IdealBackend
from rxcomm.cell.server import CellServer, ServerConfig
from rxcomm.cli import app
from rxcomm.errors import GatewayError, InputError, SafetyStop
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.log_grid import joint_grid_steps
from rxcomm.execution.plan import prepare_plan, resample
from rxcomm.execution.session import choose_ratio
from rxcomm.gateway.client import GatewayClient
from rxcomm.gateway.net import parse_gateway_address
from rxcomm.gateway.registers import DriveState
from rxcomm.io.mcap_io import read_mcap
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import RobotDynamics, prior_parameters
from rxcomm.stages import run as run_stage

from .conftest import SAMPLES
from .runs import CYCLE, DQ, Q0, ROBOT_DIR, cosine_plan, gw, save_plan, start_cell, write_configs

NA_VIRTUAL = "not applicable (virtual time)"


@pytest.fixture(autouse=True)
def hard_timeout():
    faulthandler.dump_traceback_later(120, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture
def cell(rx130l):
    srv = start_cell(rx130l)
    yield srv
    srv.stop()


def axis_states(srv: CellServer) -> list[DriveState | None]:
    with GatewayClient("127.0.0.1", srv.port, timeout_s=1.0) as c:
        return [a.state for a in c.axes()]


# ---- pure parts ------------------------------------------------------------------------------------


def test_resample_matches_the_analytic_plan(rx130l):
    coarse = cosine_plan(Q0, DQ, 1.0, dt=0.01)
    q, qd, qdd = resample(coarse, CYCLE)
    fine = cosine_plan(Q0, DQ, 1.0)
    assert q.shape == fine.q.shape == (2501, 6)
    # Hermite on (q, q̇) is O(h⁴): 10 ms knots on a 1 s cosine → µrad-level position error
    assert np.max(np.abs(q - fine.q)) < 2e-6
    assert np.max(np.abs(qd - fine.qd)) < 2e-5
    assert np.max(np.abs(qdd - fine.qdd)) < 2e-3


def test_feedforward_at_rest_is_holding_plus_inertial_torque(rx130l):
    params = prior_parameters(rx130l)
    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 1.0), params, CYCLE)
    dyn = RobotDynamics(rx130l, params)
    # at q̇ = 0: no Coriolis, no friction; links + balancer spring + M(q)·q̈ (paper eq. 7)
    expect = dyn.gravity_torque(Q0) + dyn.mass_matrix(Q0) @ plan.qdd[0]
    np.testing.assert_allclose(plan.tau_ff[0], expect, atol=1e-9)
    assert np.linalg.norm(plan.qdd[0]) > 1.0  # the cosine starts accelerating: the check has teeth
    no_ff = prepare_plan(rx130l, cosine_plan(Q0, DQ, 1.0), params, CYCLE, feedforward=False)
    assert not no_ff.tau_ff.any()


def test_plan_outside_the_limits_names_limit_joint_and_time(rx130l):
    # J5 driven 0.6 → 2.3 rad in 2 s, past its +120° limit at the end; speed and acceleration stay low
    dq = np.zeros(6)
    dq[4] = 1.7
    centre, half = (rx130l.q_max[4] + rx130l.q_min[4]) / 2, (rx130l.q_max[4] - rx130l.q_min[4]) / 2
    ratio = (Q0[4] + 1.7 - centre) / half
    assert 1.1 < ratio < 1.11
    with pytest.raises(SafetyStop, match=rf"position of joint_5 at t = 2\.0000 s is {ratio:.3f} × its limit"):
        prepare_plan(rx130l, cosine_plan(Q0, dq, 2.0), prior_parameters(rx130l), CYCLE)


def test_malformed_plans_are_input_errors(rx130l):
    params = prior_parameters(rx130l)
    moving = cosine_plan(Q0, DQ, 1.0)
    half = Trajectory(moving.t[:1000], moving.q[:1000], moving.qd[:1000], moving.qdd[:1000])
    with pytest.raises(InputError, match="does not end at rest"):
        prepare_plan(rx130l, half, params, CYCLE)
    five = Trajectory(moving.t, moving.q[:, :5], moving.qd[:, :5], moving.qdd[:, :5])
    with pytest.raises(InputError, match="5 joints, the robot 6"):
        prepare_plan(rx130l, five, params, CYCLE)


def test_interpolation_ratio_follows_the_round_trip():
    assert choose_ratio(np.full(50, 0.4e-3), CYCLE) == 1  # loopback: a block per 2.4 ms is plenty
    assert choose_ratio(np.full(50, 3e-3), CYCLE) == 4  # 3 × 3 ms needs 9 ms per block: R = 4
    # hiccups count: 10 % of 50 ms answers make the mean 5.45 ms, sustained: R = ceil(16.35 / 2.4)
    slow_tail = np.r_[np.full(45, 0.5e-3), np.full(5, 50e-3)]
    assert choose_ratio(slow_tail, CYCLE) == 7


def test_move_is_jerk_limited_within_the_scaled_limits(rx130l):
    goal = Q0 + DQ
    tr = move_trajectory(rx130l, Q0, goal, CYCLE, speed_fraction=0.25)
    np.testing.assert_array_equal(tr.q[-1], goal)
    assert np.all(np.abs(tr.qd) <= 0.25 * rx130l.v_max + 1e-9)
    assert np.all(np.abs(tr.qdd) <= 0.25 * rx130l.a_max + 1e-9)
    jerk = np.diff(tr.qdd, axis=0) / CYCLE
    assert np.all(np.abs(jerk) <= 0.25 * rx130l.a_max / 0.1 * 1.001 + 1e-6)


# ---- end to end on the ideal backend ---------------------------------------------------------------


@pytest.mark.slow
def test_two_second_trajectory_streams_completely(tmp_path, cell, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 2.0))
    out = tmp_path / "log.mcap"
    summary = run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    assert summary["outcome"] == "completed"
    assert summary["underruns"] == NA_VIRTUAL  # a virtual-time cell waits for setpoints
    r = summary["interpolation_ratio"]
    n = summary["n_setpoints"]
    assert n == 5000 // r + (1 if 5000 % r == 0 else 2)  # every R-th drive cycle, the last one kept
    assert summary["n_records"] == n and summary["lost_records"] == 0  # every trace record received
    # ideal drives follow exactly: lag is the 1 µrad position quantisation
    assert max(summary["max_lag_rad"]) <= 1e-6
    assert summary["max_tcp_error_m"] < 5e-6
    assert summary["duration_s"] == pytest.approx(2.0, abs=r * CYCLE)
    log = read_run_log(out)  # a finished MCAP (read_mcap is strict)
    j = log.joints
    assert len(j) == n and np.allclose(np.diff(j.t), r * CYCLE)
    step = joint_grid_steps()["q_demand"]  # the log's angles are on a 2^-21 rad grid (docs/logs.md §1)
    np.testing.assert_allclose(j.q_demand[-1], Q0 + DQ, rtol=0, atol=step / 2)
    np.testing.assert_allclose(j.q_actual, j.q_demand, rtol=0, atol=1e-6 + step)
    # torque actual of the ideal drives is the feed-forward sent, to the 0.1 %-of-rated LSB
    np.testing.assert_allclose(j.tau_actual, j.tau_ff, atol=float(np.max(rx130l.tau_max)) * 1e-3)
    assert len(log.gateway) > n // 6 - 2
    meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
    assert meta["kind"] == "rxcomm/RunLog" and meta["mcap_file"] == "log.mcap"
    assert meta["feedforward"] == "prior" and meta["summary"]["underruns"] == NA_VIRTUAL
    assert [a for a in axis_states(cell)] == [DriveState.SWITCH_ON_DISABLED] * 6  # disabled at the end


@pytest.mark.slow
def test_plan_outside_limits_is_refused_before_contacting_the_gateway(tmp_path, rx130l):
    dq = np.zeros(6)
    dq[1] = 3.0  # J2 far beyond its speed limit in 1 s
    plan = save_plan(tmp_path / "fast.mcap", cosine_plan(Q0, dq, 1.0))
    res = CliRunner().invoke(
        app,
        [
            "run",
            str(plan),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:9",
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    )
    assert res.exit_code == 5, res.output  # a gateway contact would have failed with 4
    assert "outside the robot's limits" in res.output and "joint_2" in res.output
    assert not list(tmp_path.glob("l.*"))


@pytest.mark.slow
def test_not_at_start_is_refused_with_the_distance_then_approached(tmp_path, cell, rx130l):
    start = Q0 + np.array([0.0, 0.05, 0.0, 0.0, -0.2, 0.0])
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(start, DQ, 1.0))
    out = tmp_path / "log.mcap"
    with pytest.raises(
        SafetyStop, match=r"not at the plan's start.*joint_2 0\.0500.*joint_5 0\.2000.*--approach"
    ):
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6  # never enabled
    summary = run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), approach=True, show_progress=False)
    assert summary["outcome"] == "completed" and summary["approach_s"] > 0.5
    with GatewayClient("127.0.0.1", cell.port, timeout_s=1.0) as c:
        np.testing.assert_allclose(c.positions_rad(), start + DQ, atol=2e-6)


def _when(srv: CellServer, executed: int, action, timeout_s: float = 20.0) -> threading.Thread:
    """Run ``action`` in a thread once the cell has executed ``executed`` setpoints."""

    def watch() -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with srv.lock:
                done = srv.core.ring.read_index
            if done >= executed:
                action()
                return
            time.sleep(0.001)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


@pytest.mark.slow
def test_disconnect_mid_stream_stops_drives_keeps_log_exit_4(tmp_path, cell, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 4.0))
    out = tmp_path / "log.mcap"

    def drop() -> None:
        with GatewayClient("127.0.0.1", cell.port, timeout_s=1.0) as c:
            c.sim_drop()

    th = _when(cell, 1500, drop)
    res = CliRunner().invoke(
        app,
        [
            "run",
            str(plan),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            gw(cell),
            "-o",
            str(out),
            "--interpolation-ratio",
            "1",
        ],
    )
    th.join(5)
    assert res.exit_code == 4, res.output
    assert "lost the connection" in res.output or "watchdog" in res.output
    assert not out.exists()  # not a complete output ...
    part = Path(str(out) + ".part")
    log = read_run_log(part)  # ... but a finished, readable log of what ran
    assert 100 < len(log.joints) < 10000  # what arrived before the drop (the trace trails execution)
    assert log.summary["outcome"] == "communication_fault"
    states = axis_states(cell)
    assert DriveState.OPERATION_ENABLED not in states  # the gateway stopped them (torque off)


class LaggingBackend(IdealBackend):
    """Positions follow the demand ``delay`` cycles late: following error = speed × delay."""

    def __init__(self, q0, delay: int, fe_limit: float, **kw):
        super().__init__(q0, following_error_limit_rad=fe_limit, **kw)
        self._hist: list[np.ndarray] = []
        self._delay = delay

    def cycle(self, position_demand_rad, torque_ff_nm, enabled):
        self._hist.append(np.array(position_demand_rad))
        lagged = self._hist[max(0, len(self._hist) - 1 - self._delay)]
        self._hist = self._hist[-self._delay - 1 :]
        fb = super().cycle(lagged, torque_ff_nm, enabled)
        fe = np.where(enabled, position_demand_rad - fb.position_rad, 0.0)
        self._fb = AxisFeedback(fb.position_rad, fb.velocity_rad_s, fb.torque_nm, fe)
        return self._fb


@pytest.mark.slow
def test_following_error_trip_is_a_safety_stop_exit_5(tmp_path, rx130l):
    # peak speed of J4 is 0.6·π/2 ≈ 0.94 rad/s; 10 cycles late → 3.8 mrad > the 2 mrad limit
    backend = LaggingBackend(Q0, delay=10, fe_limit=0.002, rated_torque_nm=np.asarray(rx130l.tau_max))
    srv = start_cell(rx130l, backend)
    try:
        plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 1.0))
        out = tmp_path / "log.mcap"
        with pytest.raises(SafetyStop, match=r"following error \(0x8611\)") as e:
            run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(srv), show_progress=False)
        assert "drives disabled" in str(e.value) and "log kept in" in str(e.value)
        log = read_run_log(Path(str(out) + ".part"))
        fe = np.abs(log.joints.following_error)
        assert fe.max() > 0.0015 and log.summary["outcome"] == "safety_stop"
        assert "joint_6 following error" in str(e.value)  # the fastest axis trips first
        # torque off everywhere: the tripped axis latched in fault, the others disabled
        assert axis_states(srv) == [DriveState.SWITCH_ON_DISABLED] * 5 + [DriveState.FAULT]
    finally:
        srv.stop()


@pytest.mark.slow
def test_a_trip_asked_for_as_the_result_writes_the_log_whole_and_exits_0(tmp_path, rx130l):
    """`--trip-is-result` (the plan without feed-forward, paper Fig. 2): the same 0x8611 trip ends the
    run with NAME.mcap and NAME.yaml written, the stop in the summary, and no exception (exit 0); a
    pose list refuses the option (exit 2)."""
    backend = LaggingBackend(Q0, delay=10, fe_limit=0.002, rated_torque_nm=np.asarray(rx130l.tau_max))
    srv = start_cell(rx130l, backend)
    try:
        plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 1.0))
        out = tmp_path / "log.mcap"
        summary = run_stage.execute(
            plan, ROBOT_DIR, out, gateway=gw(srv), show_progress=False, trip_is_result=True
        )
        assert summary["outcome"] == "safety_stop" and "0x8611" in summary["stop_reason"]
        assert out.is_file() and out.with_suffix(".yaml").is_file() and not Path(str(out) + ".part").exists()
        log = read_run_log(out)
        assert log.summary["outcome"] == "safety_stop" and log.envelope["settings"]["trip_is_result"] is True
        assert np.abs(log.joints.following_error).max() > 0.0015
    finally:
        srv.stop()
    configs = tmp_path / "configs.yaml"
    configs.write_text("kind: rxcomm/Configs\n")
    with pytest.raises(InputError, match="trip-is-result"):
        run_stage.execute(configs, ROBOT_DIR, tmp_path / "m.yaml", show_progress=False, trip_is_result=True)


@pytest.mark.slow
def test_ctrl_c_quick_stops_disables_and_keeps_the_log(tmp_path, cell, rx130l, monkeypatch):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 3.0))
    out = tmp_path / "log.mcap"
    from rxcomm.execution import session as ses

    calls = {"n": 0}
    real = ses._Recorder.__call__

    def interrupting(self, reply):
        real(self, reply)
        # The 20th reply carrying trace records: mid-motion, whatever ratio and prefill the run chose.
        if reply.trace is not None and reply.trace.count > 0:
            calls["n"] += 1
            if calls["n"] == 20:
                raise KeyboardInterrupt

    monkeypatch.setattr(ses._Recorder, "__call__", interrupting)
    with pytest.raises(SafetyStop, match="Ctrl-C"):  # an operator's stop is no drive trip: still .part
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False, trip_is_result=True)
    assert not out.exists()
    log = read_run_log(Path(str(out) + ".part"))
    assert 0 < len(log.joints) < 7500
    assert axis_states(cell) == [DriveState.SWITCH_ON_DISABLED] * 6


def test_non_loopback_gateway_needs_allow_remote(tmp_path):
    with pytest.raises(InputError, match="--allow-remote"):
        parse_gateway_address("10.1.2.3:502", allow_remote=False)
    assert parse_gateway_address("10.1.2.3:502", allow_remote=True) == ("10.1.2.3", 502)
    assert parse_gateway_address("[::1]:1502", allow_remote=False) == ("::1", 1502)
    with pytest.raises(InputError, match="HOST:PORT"):
        parse_gateway_address("localhost", allow_remote=False)


@pytest.mark.slow
def test_unreachable_gateway_is_exit_4(tmp_path, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 1.0))
    with pytest.raises(GatewayError):
        run_stage.execute(plan, ROBOT_DIR, tmp_path / "l.mcap", gateway="127.0.0.1:9", show_progress=False)


# ---- a pose campaign ---------------------------------------------------------------------------


@pytest.mark.slow
def test_pose_campaign_writes_measurements(tmp_path, cell, rx130l):
    poses = [Q0 + 0.3 * DQ, Q0 - 0.2 * DQ, Q0 + np.array([0.2, 0, 0, 0, 0, 0.5])]
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, poses, ["fit", "validation", "baseline"])
    out = tmp_path / "calib-meas.yaml"
    summary = run_stage.execute(cfg, ROBOT_DIR, out, gateway=gw(cell), speed=0.5, show_progress=False)
    assert summary["n_poses"] == 3 and summary["n_valid"] == 3 and summary["underruns"] == NA_VIRTUAL
    meas = yaml.safe_load(out.read_text())
    assert meas["kind"] == "rxcomm/Measurements"
    for p, want, role in zip(meas["poses"], poses, ["fit", "validation", "baseline"], strict=True):
        assert p["valid"] and p["role"] == role
        np.testing.assert_allclose(p["q_rad"], want, atol=2e-6)  # encoders at the pose
        # IdealBackend's pseudo tracker: a fixed function of the joint angles
        expect = [1.0 + 0.1 * np.sin(want[0]), 0.1 * np.sin(want[1]), 0.5 + 0.1 * np.sin(want[2])]
        np.testing.assert_allclose(p["position_m"], expect, atol=2e-6)
    # calibrate reads it
    from rxcomm.calibration.measurements import read_measurements

    ms = read_measurements(out, rx130l)
    assert ms.n == 3 and ms.valid.all()


def test_pose_list_needs_a_yaml_output(tmp_path, rx130l):
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, [Q0], ["fit"])
    with pytest.raises(InputError, match="measurements NAME.yaml"):
        run_stage.execute(cfg, ROBOT_DIR, tmp_path / "m.mcap", gateway="127.0.0.1:9", show_progress=False)


def test_pose_outside_limits_is_refused_before_contacting_the_gateway(tmp_path, rx130l):
    bad = Q0.copy()
    bad[4] = 3.0
    cfg = write_configs(tmp_path / "configs.yaml", rx130l, [Q0, bad], ["fit", "fit"])
    with pytest.raises(SafetyStop, match="pose 1 is outside the joint limits: joint_5"):
        run_stage.execute(cfg, ROBOT_DIR, tmp_path / "m.yaml", gateway="127.0.0.1:9", show_progress=False)


@pytest.mark.slow
def test_read_mcap_of_a_run_log_is_foxglove_shaped(tmp_path, cell, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, 0.25 * DQ, 0.6))
    out = tmp_path / "log.mcap"
    run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    c = read_mcap(out)
    assert set(c.topics) == {
        "/run/joints",
        "/run/gateway",
        "/run/tf",
        "/run/tf_demand",
        "/run/tcp",
        "/run/tcp_demand",
        "/robot_description",
    }
    assert c.topics["/run/joints"].schema_title == "rxcomm.RunJoints"
    assert c.envelope["kind"] == "rxcomm/RunLog"


@pytest.mark.slow
def test_master_stall_trips_the_watchdog_exit_4(tmp_path, cell, rx130l, monkeypatch):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 3.0))
    out = tmp_path / "log.mcap"
    from rxcomm.execution import session as ses

    stalled = {"done": False}
    real = ses._Recorder.__call__

    def stalling(self, reply):  # the master hangs for 0.8 s, longer than the 500 ms watchdog
        real(self, reply)
        # Once motion has produced trace records (whatever ratio and prefill the run chose).
        if not stalled["done"] and reply.trace is not None and reply.trace.count > 0:
            stalled["done"] = True
            time.sleep(0.8)

    monkeypatch.setattr(ses._Recorder, "__call__", stalling)
    with pytest.raises(GatewayError, match=r"heartbeat \(0x8130\)"):
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(cell), show_progress=False)
    log = read_run_log(Path(str(out) + ".part"))
    assert log.summary["outcome"] == "communication_fault" and len(log.joints) > 0
    assert DriveState.OPERATION_ENABLED not in axis_states(cell)


@pytest.mark.slow
def test_drive_fault_mid_stream_is_a_safety_stop_exit_5(tmp_path, cell, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, DQ, 4.0))
    out = tmp_path / "log.mcap"

    def fault_axis_3() -> None:
        with GatewayClient("127.0.0.1", cell.port, timeout_s=1.0) as c:
            c.sim_fault(1 << 2)

    th = _when(cell, 1500, fault_axis_3)
    res = CliRunner().invoke(
        app, ["run", str(plan), "--robot", str(ROBOT_DIR), "--gateway", gw(cell), "-o", str(out)]
    )
    th.join(5)
    assert res.exit_code == 5, res.output
    assert "joint_3 injected (0xff02)" in res.output
    assert read_run_log(Path(str(out) + ".part")).summary["outcome"] == "safety_stop"
    assert DriveState.OPERATION_ENABLED not in axis_states(cell)


@pytest.mark.slow
def test_second_robot_runs_the_same_way(tmp_path, m900):
    q0 = (m900.q_min + m900.q_max) / 2
    dq = 0.15 * (m900.q_max - m900.q_min) * np.array([1, -1, 1, -1, 1, -1])
    backend = IdealBackend(q0, cycle_s=m900.drives.cycle_s, rated_torque_nm=np.asarray(m900.tau_max))
    srv = CellServer(backend, ServerConfig()).start()  # a 500 µs drive cycle
    try:
        plan = save_plan(tmp_path / "plan.mcap", cosine_plan(q0, dq, 3.0))
        summary = run_stage.execute(
            plan, SAMPLES / "m900", tmp_path / "log.mcap", gateway=gw(srv), show_progress=False
        )
        assert summary["outcome"] == "completed" and summary["lost_records"] == 0
        assert summary["n_records"] == summary["n_setpoints"]
        assert max(summary["max_lag_rad"]) <= 1e-6
    finally:
        srv.stop()
