"""plan-ptp: the jerk-controlled OCP, its dense check, the warm start, the shooting peer and the stage."""

from __future__ import annotations

import dataclasses
import shutil

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.calibration.loading import load_calibrated_robot
from rxcomm.cli import app
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.trajectory import load_trajectory_mcap
from rxcomm.io.yaml_io import read_yaml_model, write_yaml_artefact
from rxcomm.model.base_parameters import base_parameters, dynamics_artefact_fields
from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S, RobotDynamics, prior_parameters, truth_parameters
from rxcomm.model.geometric_errors import ErrorModel
from rxcomm.model.geometric_errors import parameter_names as geometric_parameter_names
from rxcomm.model.kinematics import cardan_xyz, solve_pose_ik, tcp_pose
from rxcomm.model.symbolic import inverse_dynamics_function
from rxcomm.planning.cp import CpSettings, plan_cp
from rxcomm.planning.paths import load_path
from rxcomm.planning.ptp import (
    PtpNotConverged,
    check_boundary_state,
    default_kinematic_limits,
    integrate_jerk,
    kinematic_fallback,
    plan_ptp,
    sample_solution,
    tcp_box_ratio,
)
from rxcomm.planning.ptp_ocp import PtpOcp, node_function
from rxcomm.planning.ptp_problem import PTP_COULOMB_EPS_RAD_S, NodeGuess, PtpDynamics, PtpLimits, PtpOptions
from rxcomm.planning.ptp_shooting import ShootingOcp, forward_dynamics_function
from rxcomm.planning.timing import PlanDynamics
from rxcomm.planning.warm_start import feasible_profile, ruckig_profile, scaled_profile
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.path import Branch
from rxcomm.schemas.truth import CellTruth

from .artefacts import synthetic_calibration
from .conftest import SAMPLES

RUNNER = CliRunner()
# architecture §9: the line near the wrist singularity, TCP orientation rpy (180°, 45°, 180°)
LINE_START_M = (1.05, -0.60, 0.35)
LINE_END_M = (1.05, 0.60, 0.35)


def _line_pose(p) -> np.ndarray:
    angles = cardan_xyz(pin.rpy.rpyToMatrix(np.pi, np.pi / 4, np.pi))
    return np.concatenate([p, angles])


@pytest.fixture(scope="module")
def line_ends(rx130l):
    """q_start, q_goal of the line near the wrist singularity (elbow up, J5 > 0), by IK."""
    branch = Branch(shoulder="front", elbow="up", wrist="positive")
    q0 = solve_pose_ik(rx130l, _line_pose(LINE_START_M), branch, "start")
    q1 = solve_pose_ik(rx130l, _line_pose(LINE_END_M), branch, "goal", near=q0)
    return q0, q1


@pytest.fixture(scope="module")
def rx_dyn(rx130l):
    return PtpDynamics.from_parameters(rx130l)


# --- warm start -------------------------------------------------------------------------------------
def test_ruckig_profile_is_rest_to_rest_within_its_limits():
    v, a, j = np.array([2.0, 3.0]), np.array([5.0, 8.0]), np.array([100.0, 200.0])
    p = ruckig_profile([0.0, 1.0], [1.2, -0.5], v, a, j)
    t = np.linspace(0.0, p.duration_s, 2001)
    q, qd, qdd = p.at(t)
    np.testing.assert_allclose(q[0], [0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(q[-1], [1.2, -0.5], atol=1e-9)
    np.testing.assert_allclose(qd[[0, -1]], 0.0, atol=1e-9)
    np.testing.assert_allclose(qdd[[0, -1]], 0.0, atol=1e-9)
    assert np.all(np.abs(qd) <= v * (1 + 1e-9)) and np.all(np.abs(qdd) <= a * (1 + 1e-9))
    jerk = np.diff(qdd, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(jerk) <= j * (1 + 1e-6))
    # FD of q is the profile's velocity (the profile is consistent, not three unrelated arrays)
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[1:-1], qd[1:-1], atol=2e-4)
    # a time scaling by s: 1/s longer
    assert scaled_profile([0.0, 1.0], [1.2, -0.5], v, a, j, 0.5).duration_s == pytest.approx(2 * p.duration_s)


def test_feasible_profile_bisects_to_the_limit():
    v, a, j = np.array([2.0]), np.array([5.0]), np.array([100.0])

    def ratio(p):  # a pretend dense check: peak acceleration against 1.25 rad/s²
        t = np.linspace(0.0, p.duration_s, 501)
        return float(np.max(np.abs(p.at(t)[2])) / 1.25)

    p, r = feasible_profile([0.0], [1.0], v, a, j, ratio)
    assert 0.99 <= r <= 1.0


# --- OCP pieces -------------------------------------------------------------------------------------
def test_integrate_jerk_is_exact_and_continuous():
    rng = np.random.default_rng(3)
    jerk, h = rng.normal(0, 50, (7, 3)), 0.02
    t = np.linspace(0.0, 7 * h, 7001)
    q, qd, qdd = integrate_jerk(np.zeros(3), np.ones(3), -np.ones(3), jerk, h, t)
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[2:-2], qd[2:-2], atol=1e-6)
    # (central differences straddle the jerk steps at the nodes: error ≤ |Δu|·dt/4)
    np.testing.assert_allclose(np.gradient(qd, t, axis=0)[2:-2], qdd[2:-2], atol=5e-3)
    dt = t[1] - t[0]
    assert np.max(np.abs(np.diff(qdd, axis=0))) <= np.max(np.abs(jerk)) * dt * 1.001  # no jumps at nodes


def test_dynamics_split_matches_symbolic(rx130l, rx_dyn):
    """τ − Coulomb part equals the symbolic model without Coulomb friction (the rate-limited torque)."""
    params = prior_parameters(rx130l)
    no_coulomb = inverse_dynamics_function(
        rx130l, dataclasses.replace(params, coulomb_nm=np.zeros(rx130l.n)), PTP_COULOMB_EPS_RAD_S
    )
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-1, 1, (20, 6)) for _ in range(3))
    tau = rx_dyn.torque(q, qd, qdd)
    np.testing.assert_allclose(
        rx_dyn.rate_torque(q, qd, tau), np.asarray(no_coulomb.map(20)(q.T, qd.T, qdd.T)).T
    )
    # and the full torque is the library's smooth-friction model
    ref = RobotDynamics(rx130l, params, coulomb_eps_rad_s=PTP_COULOMB_EPS_RAD_S).inverse_dynamics(q, qd, qdd)
    np.testing.assert_allclose(tau, ref, atol=1e-9)


def test_node_torque_rate_matches_finite_differences(rx130l, rx_dyn):
    """The NLP's exact τ̇ (AD along the motion) equals the slope of τ along an exact jerk trajectory."""
    f = node_function(rx_dyn)
    rng = np.random.default_rng(1)
    q0, qd0, qdd0 = rng.uniform(-1, 1, 6), rng.uniform(-1, 1, 6), rng.uniform(-5, 5, 6)
    u = rng.uniform(-50, 50, 6)
    h = 1e-6
    t = np.array([0.0, h])
    q, qd, qdd = integrate_jerk(q0, qd0, qdd0, u[None], 1.0, t)
    tau = rx_dyn.torque(q, qd, qdd)
    slope = rx_dyn.rate_torque(q, qd, tau)
    fd = (slope[1] - slope[0]) / h
    _, _, rate_right = (np.asarray(x).ravel() for x in f(q0, qd0, qdd0, np.zeros(6), u))
    np.testing.assert_allclose(rate_right, fd, rtol=1e-4, atol=1e-2)


def test_forward_dynamics_matches_pinocchio(rx130l, rx_dyn):
    fd = forward_dynamics_function(rx_dyn)
    ref = RobotDynamics(rx130l, prior_parameters(rx130l), coulomb_eps_rad_s=PTP_COULOMB_EPS_RAD_S)
    rng = np.random.default_rng(2)
    for _ in range(5):
        q, qd, tau = rng.uniform(-1, 1, 6), rng.uniform(-1, 1, 6), rng.uniform(-100, 100, 6)
        np.testing.assert_allclose(
            np.asarray(fd(q, qd, tau)).ravel(), ref.forward_dynamics(q, qd, tau), atol=1e-8
        )


def test_boundary_state_checks(rx130l, rx_dyn):
    lim = PtpLimits.from_robot(rx130l)
    q = np.zeros(6)
    q[1] = 3.0
    with pytest.raises(InputError) as e:
        check_boundary_state(rx_dyn, lim, q, "start", rx130l.joint_names)
    assert e.value.field == "start[joint_2]"
    weak = dataclasses.replace(lim, tau_max=np.full(6, 10.0))
    q[1] = -1.5  # arm stretched: J2 holds ~180 N·m even with the spring
    with pytest.raises(InfeasibleError, match=r"goal \[joint_2\]: holding torque") as e:
        check_boundary_state(rx_dyn, weak, q, "goal", rx130l.joint_names, rx130l.drives_path)
    assert e.value.file == str(rx130l.drives_path) and e.value.field == "joints[1].peak_torque_nm"


# --- small solves (fast) ----------------------------------------------------------------------------
@pytest.mark.slow  # 0.7 s CPU (make test-fast: the unit tier within 60 s)
def test_small_solve_on_second_robot_meets_the_dense_check(m900):
    dyn = PtpDynamics.from_parameters(m900)
    q0 = np.array([-0.5, 0.3, -0.4, 0.2, 0.6, 0.0])
    q1 = np.array([0.6, 0.1, -0.1, -0.4, 0.9, 1.0])
    res = plan_ptp(m900, dyn, q0, q1, PtpOptions(n_intervals=24))
    tr = res.trajectory
    assert res.solution.success
    np.testing.assert_allclose(tr.q[0], q0, atol=1e-9)
    np.testing.assert_allclose(tr.q[-1], q1, atol=1e-9)
    np.testing.assert_allclose(tr.qd[[0, -1]], 0.0, atol=1e-9)
    assert np.allclose(np.diff(tr.t), m900.drives.cycle_s)
    assert res.max_limit_ratio <= 1.01
    assert res.active_fraction() > 0.8  # time-optimal: some limit is active most of the time
    # the kinematic warm start is slower than the dynamic optimum
    assert res.duration_s < res.warm_start.duration_s
    # the sampled torques are the model's (not the NLP's node values interpolated)
    ref = RobotDynamics(m900, prior_parameters(m900), coulomb_eps_rad_s=PTP_COULOMB_EPS_RAD_S)
    np.testing.assert_allclose(
        tr.tau_ff[::50], ref.inverse_dynamics(tr.q[::50], tr.qd[::50], tr.qdd[::50]), atol=1e-8
    )


def test_not_converged_raises_with_status_and_fallback_is_feasible(rx130l, rx_dyn):
    q0 = np.array([-0.5, 0.3, 1.2, 0.4, 0.5, -0.5])
    q1 = np.array([0.5, 0.4, 1.0, -0.4, 0.6, 0.5])
    with pytest.raises(PtpNotConverged) as e:
        plan_ptp(rx130l, rx_dyn, q0, q1, PtpOptions(n_intervals=8, max_iter=3))
    assert e.value.exit_code == 3
    assert "Maximum_Iterations_Exceeded" in str(e.value)
    tr, rep = kinematic_fallback(rx130l, rx_dyn, q0, q1)
    assert 0.98 <= rep.max_ratio <= 1.0  # the fastest time scaling that fits
    slower = ruckig_profile(q0, q1, *default_kinematic_limits(rx130l))
    assert tr.duration_s < slower.duration_s  # faster than the plain drive-limit profile
    np.testing.assert_allclose(tr.q[-1], q1, atol=1e-9)


# --- the stage ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_cli_joint_states_to_mcap_and_summary(tmp_path, m900):
    out = tmp_path / "ptp.mcap"
    r = RUNNER.invoke(
        app,
        [
            "plan-ptp", "--robot", str(SAMPLES / "m900"),
            "--start", "-0.5,0.3,-0.4,0.2,0.6,0.0", "--goal", "0.6,0.1,-0.1,-0.4,0.9,1.0",
            "--time-intervals", "12", "--plot", "-o", str(out),
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    traj, env = load_trajectory_mcap(out)
    summary = yaml.safe_load(out.with_suffix(".yaml").read_text())["summary"]
    for key in ("duration_s", "solve_seconds", "max_limit_ratio", "active_fraction", "q_start", "q_goal"):
        assert key in summary
    assert summary["max_limit_ratio"] <= 1.01
    assert summary["duration_s"] == pytest.approx(traj.duration_s)
    np.testing.assert_allclose(traj.q[-1], summary["q_goal"], atol=1e-9)
    assert env["summary"]["duration_s"] == summary["duration_s"]
    assert out.with_suffix(".png").stat().st_size > 10_000


def test_cli_start_outside_limits_is_exit_2_naming_the_joint(tmp_path):
    r = RUNNER.invoke(
        app,
        ["plan-ptp", "--robot", str(SAMPLES / "rx130l"), "--start", "0,3.0,0,0,0,0", "--goal", "0,0,1,0,0,0",
         "-o", str(tmp_path / "x.mcap")],
    )  # fmt: skip
    assert r.exit_code == 2
    assert "start[joint_2]" in r.output
    assert not (tmp_path / "x.mcap").exists()


def test_cli_unreachable_pose_is_exit_2(tmp_path):
    r = RUNNER.invoke(
        app,
        ["plan-ptp", "--robot", str(SAMPLES / "rx130l"), "--start", "0,0,1,0,0.5,0",
         "--goal", "pose:3.0,0,0.5,3.14159,0,0", "-o", str(tmp_path / "x.mcap")],
    )  # fmt: skip
    assert r.exit_code == 2
    assert "goal" in r.output and "unreachable" in r.output


def test_cli_bad_numbers_are_exit_2(tmp_path):
    r = RUNNER.invoke(
        app,
        ["plan-ptp", "--robot", str(SAMPLES / "rx130l"), "--start", "0,0,1", "--goal", "0,0,1,0,0,0",
         "-o", str(tmp_path / "x.mcap")],
    )  # fmt: skip
    assert r.exit_code == 2 and "start" in r.output


@pytest.mark.slow
def test_cli_no_convergence_is_exit_3_and_writes_fallback_only_when_asked(tmp_path):
    args = ["plan-ptp", "--robot", str(SAMPLES / "rx130l"), "--start", "-0.5,0.3,1.2,0.4,0.5,-0.5",
            "--goal", "0.5,0.4,1.0,-0.4,0.6,0.5", "--time-intervals", "8",
            "--max-wall-s", "0.001"]  # fmt: skip
    r = RUNNER.invoke(app, [*args, "-o", str(tmp_path / "a.mcap")])
    assert r.exit_code == 3 and "Maximum_WallTime_Exceeded" in r.output
    assert not (tmp_path / "a.mcap").exists()
    r = RUNNER.invoke(app, [*args, "--fallback", "-o", str(tmp_path / "b.mcap")])
    assert r.exit_code == 3
    summary = yaml.safe_load((tmp_path / "b.yaml").read_text())["summary"]
    assert summary["fallback"] is True and summary["max_limit_ratio"] <= 1.0
    assert summary["solver_status"] == "Maximum_WallTime_Exceeded"


# --- Done-when targets (slow: full-size solves) --------------------------------------------------------
@pytest.mark.slow
def test_ptp_near_singularity_beats_cp_within_limits(rx130l, rx_dyn, line_ends):
    """Paper §5.5: PtP between the CP line's end states takes 0.67 s against the line's 1.04 s."""
    _, path = load_path(SAMPLES / "rx130l" / "paths" / "line-near-singularity.yaml", rx130l)
    settings = CpSettings()
    cp = plan_cp(rx130l, path, PlanDynamics.load(rx130l, None, settings.coulomb_eps_rad_s), settings)
    q0, q1 = cp.q[0], cp.q[-1]
    np.testing.assert_allclose(q0, line_ends[0], atol=1e-6)  # the same end states as our pose IK
    np.testing.assert_allclose(q1, line_ends[1], atol=1e-6)
    res = plan_ptp(rx130l, rx_dyn, q0, q1, PtpOptions(n_intervals=50))
    assert cp.duration_s > 1.3  # architecture §9: ≈ 1.47 s, the speed dips near the wrist singularity
    assert res.duration_s <= 0.7 * cp.duration_s
    assert res.max_limit_ratio <= 1.01


@pytest.mark.slow
def test_same_optimum_from_two_warm_starts(rx130l, rx_dyn, line_ends):
    q0, q1 = line_ends
    opts = PtpOptions(n_intervals=50)
    a = plan_ptp(rx130l, rx_dyn, q0, q1, opts)
    slow = ruckig_profile(q0, q1, *default_kinematic_limits(rx130l, speed=0.4))
    assert slow.duration_s > 1.8 * a.warm_start.duration_s  # a genuinely different guess
    b = plan_ptp(rx130l, rx_dyn, q0, q1, opts, warm_start=slow)
    assert b.duration_s == pytest.approx(a.duration_s, rel=0.01)
    assert b.max_limit_ratio <= 1.01


@pytest.mark.slow
def test_energy_weight_trades_little_time_for_much_torque(rx130l, rx_dyn, line_ends):
    q0, q1 = line_ends
    fast = plan_ptp(rx130l, rx_dyn, q0, q1, PtpOptions(n_intervals=50))
    soft = plan_ptp(rx130l, rx_dyn, q0, q1, PtpOptions(n_intervals=50, k2_per_nm2=1.5e-6))
    assert soft.tau_squared_integral <= 0.7 * fast.tau_squared_integral
    assert soft.duration_s <= 1.10 * fast.duration_s
    assert soft.max_limit_ratio <= 1.01


@pytest.mark.slow
def test_shooting_peer_reaches_the_same_time(rx130l, rx_dyn, line_ends):
    """The forward-dynamics multiple shooting solves the same problem (coarse grid to keep it short)."""
    q0, q1 = line_ends
    opts = PtpOptions(n_intervals=20, max_wall_s=120)
    ours = plan_ptp(rx130l, rx_dyn, q0, q1, opts)
    peer = ShootingOcp(rx_dyn, PtpLimits.from_robot(rx130l), opts)
    sol = peer.solve(q0, q1, ours.warm_start)
    assert sol.success, sol.status
    assert sol.max_defect < 1e-4
    assert sol.duration_s == pytest.approx(ours.solution.duration_s, rel=0.03)


@pytest.mark.slow
def test_ocp_reuse_gives_the_same_answer(m900):
    """A built NLP serves other end points: the cache is keyed by dynamics, limits and options only."""
    dyn = PtpDynamics.from_parameters(m900)
    ocp = PtpOcp(dyn, PtpLimits.from_robot(m900), PtpOptions(n_intervals=10))
    q0, q1 = np.array([0.0, 0.2, -0.2, 0.0, 0.5, 0.0]), np.array([0.4, 0.3, -0.1, 0.2, 0.6, 0.3])
    prof = ruckig_profile(q0, q1, *default_kinematic_limits(m900))
    s1 = ocp.solve(q0, q1, NodeGuess.from_profile(prof, 10))
    s2 = ocp.solve(
        q1, q0, NodeGuess.from_profile(ruckig_profile(q1, q0, *default_kinematic_limits(m900)), 10)
    )
    assert s1.success and s2.success
    np.testing.assert_allclose(s1.q[-1], q1, atol=1e-9)
    np.testing.assert_allclose(s2.q[-1], q0, atol=1e-9)
    tr = sample_solution(s1, dyn, m900.drives.cycle_s, q1)
    np.testing.assert_allclose(tr.q[-1], q1)


@pytest.mark.slow
def test_cli_uses_identified_dynamics(tmp_path, m900):
    """With --dynamics the torques are the identified model's, not the URDF prior's."""
    truth = read_yaml_model(SAMPLES / "m900" / "truth.yaml", CellTruth)
    true = truth_parameters(m900, truth)
    bset = base_parameters(m900, n_samples=300, seed=0)
    fields = dynamics_artefact_fields(m900, bset, bset.project(true), full=true)
    summary = {"n_base_params": bset.n_base, "validation_nrmse": [0.0] * 6, "validation_rms_nm": [0.0] * 6}
    dyn_file = write_yaml_artefact(
        tmp_path / "dynamics.yaml",
        Dynamics(**Dynamics.envelope({}, {}, {**summary, "seconds": 0.0}), **fields),
    )
    out = tmp_path / "ptp.mcap"
    r = RUNNER.invoke(
        app,
        ["plan-ptp", "--robot", str(SAMPLES / "m900"), "--start", "-0.5,0.3,-0.4,0.2,0.6,0.0",
         "--goal", "0.6,0.1,-0.1,-0.4,0.9,1.0", "--time-intervals", "12", "--dynamics", str(dyn_file),
         "-o", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    traj, env = load_trajectory_mcap(out)
    assert env["settings"]["dynamics_model"] == "identified" and "dynamics" in env["inputs"]
    # the plan's τ_ff is the torque `run` streams: its friction smoothing, not the NLP's
    ident = RobotDynamics(m900, true, coulomb_eps_rad_s=COULOMB_EPS_NLP_RAD_S)
    prior = RobotDynamics(m900, prior_parameters(m900), coulomb_eps_rad_s=COULOMB_EPS_NLP_RAD_S)
    s = slice(None, None, 40)
    np.testing.assert_allclose(
        traj.tau_ff[s], ident.inverse_dynamics(traj.q[s], traj.qd[s], traj.qdd[s]), atol=1e-8
    )
    assert np.abs(traj.tau_ff[s] - prior.inverse_dynamics(traj.q[s], traj.qd[s], traj.qdd[s])).max() > 1.0


def test_pose_ik_honours_the_calibration(tmp_path, rx130l):
    """A TCP pose is reached by the calibrated robot (mm-level errors), not the nominal one."""
    names = geometric_parameter_names(rx130l)
    values = {"joint_2.tx": 0.003, "joint_3.tz": -0.002, "joint_2.rz": 0.004, "tool.tz": 0.001}
    cal = synthetic_calibration(rx130l, values, names=names, summary={"n_identifiable": 30})
    cal_file = write_yaml_artefact(tmp_path / "calibration.yaml", cal)
    robot = load_calibrated_robot(rx130l, cal_file)
    pose = _line_pose(LINE_START_M)
    branch = Branch(shoulder="front", elbow="up", wrist="positive")
    q_cal = solve_pose_ik(robot, pose, branch, "start")
    q_nom = solve_pose_ik(rx130l, pose, branch, "start")
    errors = ErrorModel.from_mapping(rx130l, values)
    p_cal, _ = tcp_pose(rx130l, q_cal, errors)
    np.testing.assert_allclose(p_cal, LINE_START_M, atol=1e-8)
    assert np.linalg.norm(tcp_pose(rx130l, q_nom, errors)[0] - LINE_START_M) > 1e-3  # nominal IK misses


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None, reason="no C compiler")
def test_compiled_node_functions_match_and_are_cached(tmp_path, monkeypatch, m900):
    monkeypatch.setenv("RXCOMM_CACHE_DIR", str(tmp_path))
    dyn, lim = PtpDynamics.from_parameters(m900), PtpLimits.from_robot(m900)
    monkeypatch.delenv("RXCOMM_NO_COMPILE", raising=False)
    plain = PtpOcp(dyn, lim, PtpOptions(n_intervals=10, compile=False))
    assert not list(tmp_path.glob("casadi/*.so"))
    opts = PtpOptions(n_intervals=10, compile=True)
    x = np.random.default_rng(0).uniform(0.2, 0.8, plain.nx)
    lam = np.random.default_rng(1).normal(size=len(plain.row_kinds))
    # the default (compile None: -O0) and --compile (-O1): each the Jacobian, gradient and Hessian of
    # the node window, compiled once, equal to the virtual machine's
    for options, n_libs in ((PtpOptions(n_intervals=10), 3), (opts, 6)):
        fast = PtpOcp(dyn, lim, options)
        for name, args in (
            ("nlp_jac_g", (x, [])),
            ("nlp_grad_f", (x, [])),
            ("nlp_hess_l", (x, [], 1.0, lam)),
        ):
            a, b = plain.solver.get_function(name)(*args), fast.solver.get_function(name)(*args)
            a, b = (a, b) if isinstance(a, tuple) else ((a,), (b,))
            for u, v in zip(a, b, strict=True):
                np.testing.assert_allclose(
                    np.asarray(ca.densify(v)), np.asarray(ca.densify(u)), rtol=1e-9, atol=1e-9
                )
        assert len(list(tmp_path.glob("casadi/*.so"))) == n_libs
    libs = sorted(p.name for p in tmp_path.glob("casadi/*.so"))
    again = PtpOcp(dyn, lim, opts)  # from the cache: no compiler run
    assert again.build_seconds < 5.0
    assert sorted(p.name for p in tmp_path.glob("casadi/*.so")) == libs
    q0, q1 = np.array([0.0, 0.2, -0.2, 0.0, 0.5, 0.0]), np.array([0.4, 0.3, -0.1, 0.2, 0.6, 0.3])
    res = plan_ptp(m900, dyn, q0, q1, opts, ocp=again)
    assert res.solution.success and res.max_limit_ratio <= 1.01


@pytest.mark.slow  # 1.0 s CPU (make test-fast: the unit tier within 60 s)
def test_tcp_box_keeps_the_tcp_inside(m900):
    dyn = PtpDynamics.from_parameters(m900)
    q0, q1 = np.array([-0.8, 0.3, -0.4, 0.2, 0.6, 0.0]), np.array([0.8, 0.3, -0.4, -0.4, 0.9, 1.0])
    box = ((-1.0, -1.0, 0.0), (0.30, 1.0, 2.0))  # the free motion swings the TCP out to x ≈ 0.36 m
    free = plan_ptp(m900, dyn, q0, q1, PtpOptions(n_intervals=20))
    boxed = plan_ptp(m900, dyn, q0, q1, PtpOptions(n_intervals=20, tcp_box_m=box))
    assert tcp_box_ratio(m900, free.trajectory.q, box) > 1.05  # (|x − centre| / half-size)
    assert boxed.tcp_box_ratio <= 1.01 and boxed.max_limit_ratio <= 1.01
    assert boxed.duration_s >= free.duration_s * 0.999  # a constraint more cannot make it faster


def test_every_summary_key_plan_ptp_can_write_is_a_typed_field():
    """The re-solves' widened margins (`margin_<limit>`) and the per-limit ratios are written into the
    summary by name; one not in TrajectorySummary stopped plan-ptp on an imported UR5e
    ("margin_velocity: extra inputs are not permitted") after the whole solve."""
    from rxcomm.planning.ptp_ocp import LIMIT_NAMES
    from rxcomm.schemas.trajectory import TrajectorySummary

    names = set(TrajectorySummary.model_fields["summary"].annotation.model_fields)
    missing = [f"margin_{k}" for k in LIMIT_NAMES if f"margin_{k}" not in names]
    missing += [f"max_{k}_ratio" for k in LIMIT_NAMES if f"max_{k}_ratio" not in names]
    assert not missing, missing
