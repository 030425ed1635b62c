"""Excitation design: rest-to-rest Fourier basis, exact gradients, dense limits, conditioning vs baseline."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.execution.plan import prepare_plan
from rxcomm.identification.excitation import design_excitation
from rxcomm.identification.excitation_limits import region_points
from rxcomm.identification.excitation_problem import ExcitationProblem, condition_numbers
from rxcomm.identification.excitation_trajectory import (
    FourierTrajectory,
    fourier_basis,
    sample_trajectory,
    snapped_omega,
)
from rxcomm.io.trajectory import load_trajectory_mcap
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model
from rxcomm.model.base_parameters import base_parameters
from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S, RobotDynamics, prior_parameters
from rxcomm.model.limits import check_limits
from rxcomm.schemas.cell import AllowedRegion, Box, Cell
from rxcomm.schemas.excitation import Excitation, ExcitationSettings, ExcitationSummary

from .conftest import SAMPLES

SMALL = ExcitationSettings(
    harmonics=3, objective_samples=40, check_samples=400, starts=1, max_iterations=25, baseline_trajectories=2
)


@pytest.fixture(scope="module")
def cell_rx():
    return read_yaml_model(SAMPLES / "rx130l" / "cell.yaml", Cell)


@pytest.fixture(scope="module")
def bset_rx(rx130l):
    return base_parameters(rx130l)


@pytest.fixture(scope="module")
def small_problem(rx130l, cell_rx, bset_rx):
    return ExcitationProblem(rx130l, cell_rx.allowed_region, SMALL, bset_rx)


def test_basis_is_rest_to_rest_and_consistent():
    omega, n_h = 0.8, 5
    period = 2 * math.pi / omega
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2 * n_h - 1, 3))
    t = np.linspace(0, period, 2001)
    bq, bv, ba = fourier_basis(t, omega, n_h)
    q, qd, qdd = bq @ x, bv @ x, ba @ x
    # at rest at both ends, back where it started
    for end in (0, -1):
        assert np.abs(qd[end]).max() < 1e-12 and np.abs(qdd[end]).max() < 1e-12
    assert np.allclose(q[0], x[0]) and np.allclose(q[-1], x[0], atol=1e-12)
    # B_v and B_a are the time derivatives of B_q (central differences)
    h = t[1] - t[0]
    assert np.allclose(np.gradient(q, h, axis=0)[1:-1], qd[1:-1], atol=2e-4 * np.abs(qd).max())
    assert np.allclose(np.gradient(qd, h, axis=0)[1:-1], qdd[1:-1], atol=2e-4 * np.abs(qdd).max())


def test_fourier_trajectory_round_trip_and_offset():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((6, 9))
    traj = FourierTrajectory.from_free(0.8, 5, x)
    assert np.allclose(traj.free(), x)
    assert np.allclose(traj.a.sum(axis=1), 0) and np.allclose(traj.b @ np.arange(1, 6), 0)
    t = np.arange(4000) * traj.period_s / 4000
    q, _, _ = traj.evaluate(t)
    assert np.allclose(q.mean(axis=0), traj.q0, atol=1e-9)  # the paper's offset is the mean
    with pytest.raises(ValueError, match="rest-to-rest"):
        FourierTrajectory(0.8, traj.q_start, traj.a + 0.1, traj.b)


def test_snapped_period_is_whole_cycles():
    omega = snapped_omega(0.8, 0.0004)
    cycles = 2 * math.pi / omega / 0.0004
    assert abs(cycles - round(cycles)) < 1e-6 and abs(omega - 0.8) < 1e-4


def test_condition_numbers_match_svd_and_ignore_column_scale():
    rng = np.random.default_rng(2)
    w = rng.standard_normal((300, 20)) * np.logspace(-3, 3, 20)
    c, c_raw = condition_numbers(w)
    wn = w / np.linalg.norm(w, axis=0)
    assert c == pytest.approx(np.linalg.cond(wn), rel=1e-8)
    assert c_raw == pytest.approx(np.linalg.cond(w), rel=1e-6)
    assert condition_numbers(w * np.logspace(2, -2, 20))[0] == pytest.approx(c, rel=1e-8)


@pytest.mark.parametrize("objective", ["cond", "logdet"])
def test_objective_gradient_matches_finite_differences(rx130l, cell_rx, bset_rx, objective):
    prob = ExcitationProblem(
        rx130l, cell_rx.allowed_region, SMALL.model_copy(update={"objective": objective}), bset_rx
    )
    x = prob.random_feasible(np.random.default_rng(3))
    f, g = prob.objective(x)
    num = np.empty_like(x)
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = 1e-6
        num[i] = (prob.objective(x + d)[0] - prob.objective(x - d)[0]) / 2e-6
    assert np.allclose(g, num, rtol=1e-4, atol=1e-5 * np.abs(g).max())


def test_peak_constraint_jacobian_matches_finite_differences(small_problem):
    prob = small_problem
    x = prob.random_feasible(np.random.default_rng(4))
    fun, jac = prob._peak_constraints()
    j = jac(x)
    num = np.empty_like(j)
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = 1e-7
        num[:, i] = (fun(x + d) - fun(x - d)) / 2e-7
    peaks = slice(0, len(j) - prob.n * 2 * prob.n_h)  # the velocity-reversal rows are tested below
    # rows whose peak does not move to another grid sample within ±1e-7 (almost all)
    ok = np.abs(j - num)[peaks].max(axis=1) < 1e-5 * (1 + np.abs(j[peaks]).max(axis=1))
    assert ok.mean() > 0.97
    assert fun(x).min() >= -1e-9  # a random feasible start satisfies every peak constraint


def test_velocity_reversal_constraint_matches_finite_differences(small_problem):
    prob = small_problem
    x = prob.random_feasible(np.random.default_rng(8))
    r, j = prob.crossings(x)
    assert (r > 0).sum() >= 6  # every joint reverses at least once in a period
    jf = j.reshape(r.size, -1)[:, prob.free_mask.ravel()]
    num = np.empty_like(jf)
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = 1e-7
        num[:, i] = (prob.crossings(x + d)[0] - prob.crossings(x - d)[0]).ravel() / 2e-7
    live = r.ravel() > 0.25  # rows left without gradient far from their limit
    assert np.allclose(jf[live], num[live], rtol=1e-4, atol=1e-6 * np.abs(jf).max())


def test_random_feasible_holds_every_limit_densely(rx130l, small_problem):
    prob = small_problem
    x = prob.random_feasible(np.random.default_rng(5))
    traj = prob.trajectory(x)
    samples = sample_trajectory(rx130l, traj, 1, prob.prior)
    assert prob.design_ratios(samples).max() <= 1.0 + 1e-3
    assert 1 < prob.cond(x)[0] < 1e6


def test_a_tightened_resolve_returns_the_tightened_optimum_not_its_start(m900):
    """design_excitation tightens the NLP by a drive-cycle excess and re-solves from the optimum: the
    re-solve must come back within the tightened limits. It returned its start (the optimum it was
    to tighten, better in cond and within the untightened limits), so a 0.3 % torque excess on an
    imported arm (MuJoCo Menagerie's piper) stayed through every re-solve and `excite` failed."""
    converged = SMALL.model_copy(update={"max_iterations": 300})
    cell = read_yaml_model(SAMPLES / "m900" / "cell.yaml", Cell)
    prob = ExcitationProblem(m900, cell.allowed_region, converged, base_parameters(m900))
    x0, _, ok = prob.optimise(prob.random_feasible(np.random.default_rng(5)))
    assert ok and prob.max_ratio(x0) > 0.99, prob.last_message  # an optimum at its limits
    prob.tighten += 0.02
    x, _, ok = prob.optimise(x0)
    # within the tightened limits (to SLSQP's tolerance)
    assert ok and prob.max_ratio(x) <= 1 - prob.tighten + 2e-3, prob.max_ratio(x)


@pytest.mark.slow  # 1.4 s CPU (make test-fast: the unit tier within 60 s)
def test_small_design_is_feasible_at_the_drive_cycle_and_beats_baseline(rx130l, cell_rx, bset_rx):
    d = design_excitation(rx130l, cell_rx.allowed_region, SMALL, bset=bset_rx)
    s = d.samples
    # rest to rest, exactly
    assert np.all(s.qd[[0, -1]] == 0) and np.all(s.qdd[[0, -1]] == 0) and np.allclose(s.q[0], s.q[-1])
    assert s.t[1] - s.t[0] == pytest.approx(rx130l.drives.cycle_s)
    # every limit at every drive cycle, checked independently of the optimiser's CasADi model
    rep = check_limits(rx130l, s.t, s.q, s.qd, s.qdd, s.tau_ff)
    assert rep.max_ratio <= 1.0, rep.worst()
    pts = region_points(rx130l, s.q[::5])
    for name in ("tool", "wrist_centre", "elbow"):
        box = getattr(cell_rx.allowed_region, name)
        assert np.all(pts[name] >= np.array(box.min_m) - 1e-9) and np.all(
            pts[name] <= np.array(box.max_m) + 1e-9
        )
    assert d.max_limit_ratio <= 1.0
    tau = RobotDynamics(rx130l, prior_parameters(rx130l), COULOMB_EPS_NLP_RAD_S).inverse_dynamics(
        s.q, s.qd, s.qdd
    )
    assert np.allclose(tau, s.tau_ff)
    assert d.cond < d.baseline_cond
    # and `run` accepts it: its own dense check of every limit, torque rate included, at the drive cycle
    plan = prepare_plan(rx130l, s, prior_parameters(rx130l), rx130l.drives.cycle_s, limit_tolerance=0.0)
    assert plan.report.max_ratio <= 1.0


def test_fixed_start_is_kept_and_bad_start_refused(rx130l, cell_rx, bset_rx):
    start = [0.2, 0.3, 1.2, 0.0, 0.5, 0.0]
    prob = ExcitationProblem(
        rx130l, cell_rx.allowed_region, SMALL.model_copy(update={"start_rad": start}), bset_rx
    )
    x = prob.random_feasible(np.random.default_rng(6))
    assert np.allclose(prob.trajectory(x).q_start, start)
    assert prob.n_free == 6 * (2 * 3 - 2)
    with pytest.raises(InputError, match="joint_2"):
        ExcitationProblem(
            rx130l,
            cell_rx.allowed_region,
            SMALL.model_copy(update={"start_rad": [0, 3, 0, 0, 0, 0]}),
            bset_rx,
        )


def test_impossible_region_is_infeasible(rx130l, bset_rx):
    far = Box(min_m=(5.0, 5.0, 5.0), max_m=(6.0, 6.0, 6.0))
    region = AllowedRegion(tool=far, wrist_centre=far, elbow=far)
    prob = ExcitationProblem(rx130l, region, SMALL, bset_rx)
    with pytest.raises(InfeasibleError, match="allowed region"):
        prob.random_feasible(np.random.default_rng(0), attempts=5)


@pytest.mark.slow  # 1.6 s CPU (make test-fast: the unit tier within 60 s)
def test_excite_stage_writes_artefact_and_trajectory(tmp_path):
    out = tmp_path / "excitation.yaml"
    res = CliRunner().invoke(
        app,
        [
            "excite",
            "--robot",
            str(SAMPLES / "rx130l"),
            "--cell",
            str(SAMPLES / "rx130l" / "cell.yaml"),
            "-o",
            str(out),
            "--harmonics",
            "3",
            "--starts",
            "1",
            "--max-iterations",
            "20",
            "--baseline-trajectories",
            "2",
        ],
    )
    assert res.exit_code == 0, res.output
    art = read_yaml_artefact(out, Excitation)
    for key, field in ExcitationSummary.model_fields.items():
        assert not field.is_required() or getattr(art.summary, key) is not None
    assert art.summary.max_limit_ratio <= 1.0
    traj, env = load_trajectory_mcap(tmp_path / art.trajectory_file)
    assert env["kind"] == "rxcomm/Trajectory"
    assert np.allclose(traj.q[0], art.q_start_rad) and np.all(traj.qd[0] == 0)
    fourier = FourierTrajectory(art.omega_f_rad_s, art.q_start_rad, art.a_rad_s, art.b_rad_s)
    q, _, _ = fourier.evaluate(traj.t[::1000])
    assert np.allclose(q, traj.q[::1000], atol=1e-9)


def test_excite_stage_refuses_a_bad_start(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "excite",
            "--robot",
            str(SAMPLES / "rx130l"),
            "--cell",
            str(SAMPLES / "rx130l" / "cell.yaml"),
            "-o",
            str(tmp_path / "e.yaml"),
            "--start",
            "0,0,0",
        ],
    )
    assert res.exit_code == 2 and "start" in res.output


@pytest.mark.slow  # two small designs, 2 processes
def test_parallel_starts_give_the_serial_design_exactly(rx130l, cell_rx, bset_rx):
    settings = SMALL.model_copy(update={"starts": 2, "baseline_trajectories": 2})
    serial = design_excitation(rx130l, cell_rx.allowed_region, settings, bset=bset_rx, workers=1)
    parallel = design_excitation(rx130l, cell_rx.allowed_region, settings, bset=bset_rx, workers=2)
    assert np.array_equal(serial.trajectory.free(), parallel.trajectory.free())
    assert [s.cond for s in serial.starts] == [s.cond for s in parallel.starts]
    assert [s.iterations for s in serial.starts] == [s.iterations for s in parallel.starts]
    assert serial.cond == parallel.cond and serial.baseline_conds == parallel.baseline_conds
    # each start is its own seed: the two starts differ (the comparison above could not pass vacuously)
    assert not np.array_equal(serial.starts[0].trajectory.free(), serial.starts[1].trajectory.free())


@pytest.mark.slow
def test_rx130l_default_design_reaches_the_paper_conditioning(rx130l, cell_rx, bset_rx):
    d = design_excitation(rx130l, cell_rx.allowed_region, ExcitationSettings(), bset=bset_rx)
    assert d.cond <= 12.0
    assert d.baseline_cond >= 100.0  # random feasible trajectories of the same form: hundreds or worse
    assert d.max_limit_ratio <= 1.0, d.worst_limit
    assert d.cond_dense <= 12.0  # the drive-cycle data are as well conditioned as the k samples
    assert d.seconds <= 120.0


@pytest.mark.slow
def test_second_robot_design(m900, bset_rx):
    cell = read_yaml_model(SAMPLES / "m900" / "cell.yaml", Cell)
    d = design_excitation(m900, cell.allowed_region, ExcitationSettings(starts=2, baseline_trajectories=4))
    assert d.max_limit_ratio <= 1.0, d.worst_limit
    assert d.cond < d.baseline_cond and d.cond < 30
