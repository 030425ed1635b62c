"""One contract, every solver (as toppra runs each of its solver wrappers through one suite).

Every `TimingSolver` (`ToppraTiming`, `NlpTiming`) times the same joint path under the same limits, free
and with a local scale, and is refused the same infeasible case; both PtP transcriptions (the
inverse-dynamics OCP `PtpOcp` and the forward-dynamics shooting peer `ShootingOcp`) solve the same
rest-to-rest move. The contract: rest to rest over the whole path or move, every limit (as scaled)
held at the solver's nodes, the same optimum within the transcriptions' difference, a failure raised as
`InfeasibleError` naming the path (timing) or reported as status + message (`rxcomm.errors.SolveOutcome`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from rxcomm.errors import InfeasibleError, SolveOutcome, SolveStatus
from rxcomm.io.yaml_io import load_yaml
from rxcomm.planning.cp import CpSettings, plan_limits
from rxcomm.planning.cp_grid import toppra_grid
from rxcomm.planning.path_ik import JointPath, solve_path_ik
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.paths import CartesianPath, build_path
from rxcomm.planning.ptp import default_kinematic_limits
from rxcomm.planning.ptp_ocp import PtpOcp
from rxcomm.planning.ptp_problem import NodeGuess, PtpDynamics, PtpLimits, PtpOptions
from rxcomm.planning.ptp_shooting import ShootingOcp
from rxcomm.planning.timing import NlpProblem, NlpTiming, PlanDynamics, TimingSolver, ToppraTiming
from rxcomm.planning.topp import PlanLimits, time_optimal
from rxcomm.planning.warm_start import ruckig_profile
from rxcomm.schemas.path import PathSpec

from .conftest import SAMPLES

INTERVALS = 40
NODE_TOLERANCE = 1e-3  # limits at the nodes: what the solvers' constraints hold, to IPOPT's tolerance


@dataclass(frozen=True, eq=False)
class Case:
    path: CartesianPath
    jp: JointPath
    limits: PlanLimits  # no torque-rate limit: toppra cannot hold one, so both solve one problem
    dynamics: PlanDynamics
    grid: np.ndarray
    curvature: np.ndarray


@pytest.fixture(scope="module")
def case(rx130l) -> Case:
    path = build_path(PathSpec.model_validate(load_yaml(SAMPLES / "rx130l/paths/iso9283-line.yaml")))
    jp = solve_path_ik(rx130l, path, path.spec.branch)
    limits = plan_limits(rx130l, CpSettings(torque_rate=False))
    dynamics = PlanDynamics.load(rx130l, None, 0.02)
    grid = toppra_grid(jp, INTERVALS, rx130l.a_max)
    return Case(path, jp, limits, dynamics, grid, np.linalg.norm(path.position(grid, 2), axis=1))


def toppra_solver(c: Case) -> TimingSolver:
    first = time_optimal(c.jp.spline, c.jp.length_m, c.grid, c.limits, c.dynamics.exact, c.curvature)
    assert first.outcome.status is SolveStatus.SOLVED, first.outcome.message
    return ToppraTiming(c.jp, c.path.name, c.grid, c.limits, c.dynamics, c.curvature, first, {})


def nlp_solver(c: Case) -> TimingSolver:
    warm = time_optimal(c.jp.spline, c.jp.length_m, c.grid, c.limits, c.dynamics.exact, c.curvature)
    problem = NlpProblem(c.dynamics, c.jp, c.path, c.limits, INTERVALS)
    return NlpTiming(
        problem, warm.profile, k1=1.0, k2=0.0, regrid_below=0.0, target_ratio=1.003, timings_s={}
    )


SOLVERS = {"toppra": toppra_solver, "nlp": nlp_solver}


def node_ratios(c: Case, profile: PathProfile) -> dict[str, np.ndarray]:
    """|value| / limit of joint velocity, acceleration and torque at the profile's nodes [N+1, dof]."""
    s, sd, sdd = profile.sigma, profile.sd, profile.sdd
    qs, qss = c.jp(s, 1), c.jp(s, 2)
    qd = qs * sd[:, None]
    qdd = qs * sdd[:, None] + qss * (sd**2)[:, None]
    tau = c.dynamics.exact(c.jp(s), qd, qdd)
    return {
        "v_max": np.abs(qd) / c.limits.v_max,
        "a_max": np.abs(qdd) / c.limits.a_max,
        "tau_max": np.abs(tau) / c.limits.tau_max,
    }


def check_profile(c: Case, solver: TimingSolver, profile: PathProfile, scale: dict) -> None:
    """The contract of a solved profile: on the solver's grid, rest to rest over the whole path, every
    limit times its local factor held at the nodes."""
    assert profile.sigma[0] == 0.0 and profile.sigma[-1] == pytest.approx(c.jp.length_m, rel=1e-12)
    np.testing.assert_allclose(profile.sigma, solver.grid)
    assert profile.sd[0] == pytest.approx(0.0, abs=1e-9) and profile.sd[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(profile.sd[1:-1] > 0) and profile.duration_s > 0
    for attr, ratio in node_ratios(c, profile).items():
        factor = scale.get(attr, np.ones_like(solver.grid))
        factor = factor if factor.ndim == 2 else factor[:, None]
        assert np.max(ratio / factor) <= 1 + NODE_TOLERANCE, (attr, float(np.max(ratio / factor)))


@pytest.fixture(scope="module")
def free_durations(case) -> dict[str, float]:
    return {name: make(case).solve({}).duration_s for name, make in SOLVERS.items()}


@pytest.mark.parametrize("name", SOLVERS)
def test_a_free_solve_is_rest_to_rest_within_every_limit_and_keeps_its_grid(case, name):
    solver = SOLVERS[name](case)
    assert solver.method == name
    profile = solver.solve({})
    check_profile(case, solver, profile, {})
    if isinstance(solver, NlpTiming):
        assert solver.result.outcome.status is SolveStatus.SOLVED
    # some limit binds somewhere: a solver that idles would pass the limit checks above
    peak = max(float(np.max(r)) for r in node_ratios(case, profile).values())
    assert peak > 0.98


@pytest.mark.parametrize("name", SOLVERS)
def test_a_local_scale_is_held_where_it_is_given_and_costs_time(case, name, free_durations):
    solver = SOLVERS[name](case)
    n = len(solver.grid)
    half = np.ones((n, 6))
    half[n // 3 : 2 * n // 3] = 0.5  # the middle third at half the joint speed
    scale = {"v_max": half}
    profile = solver.solve(scale)
    check_profile(case, solver, profile, scale)
    assert profile.duration_s > 1.02 * free_durations[name]


@pytest.mark.slow
@pytest.mark.parametrize("name", SOLVERS)
def test_no_torque_to_hold_the_arm_is_an_infeasible_error_naming_the_path(case, name):
    solver = SOLVERS[name](case)
    tiny = {"tau_max": np.full((len(solver.grid), 6), 0.05)}  # 5 % of the peak torques: gravity wins
    with pytest.raises(InfeasibleError, match=f"path {case.path.name!r}"):
        solver.solve(tiny)


def test_both_timings_reach_the_same_optimum(free_durations):
    # toppra is time-optimal on its grid (piecewise-constant σ̈); the NLP's continuous σ̈ on the same
    # limits can only be as fast or a little slower
    t_toppra, t_nlp = free_durations["toppra"], free_durations["nlp"]
    assert 0.99 * t_toppra <= t_nlp <= 1.05 * t_toppra


def test_a_failed_toppra_solve_says_so_as_status_and_message(case):
    limits = PlanLimits(case.limits.v_max, case.limits.a_max, 0.05 * case.limits.tau_max)
    res = time_optimal(
        case.jp.spline, case.jp.length_m, case.grid, limits, case.dynamics.exact, case.curvature
    )
    assert not res.ok and res.outcome.status is SolveStatus.INFEASIBLE
    assert "uncontrollable" in res.outcome.message


def test_ipopt_statuses_map_onto_the_one_convention():
    assert SolveOutcome.from_ipopt("Solve_Succeeded", True, 12).ok
    infeasible = SolveOutcome.from_ipopt("Infeasible_Problem_Detected", False, 40)
    assert infeasible.status is SolveStatus.INFEASIBLE and "40 iterations" in infeasible.message
    budget = SolveOutcome.from_ipopt("Maximum_Iterations_Exceeded", False, 3000)
    assert budget.status is SolveStatus.NOT_CONVERGED
    with pytest.raises(InfeasibleError, match="plan: IPOPT Maximum_Iterations_Exceeded after 3000"):
        budget.raise_if_failed("plan")


# ---- both PtP transcriptions on one move ----------------------------------------------------------


@pytest.mark.slow  # the shooting peer is the slow formulation by design (architecture §7)
def test_both_ptp_transcriptions_solve_one_move_alike(m900):
    dyn = PtpDynamics.from_parameters(m900)
    limits, opts = PtpLimits.from_robot(m900), PtpOptions(n_intervals=12, max_wall_s=120)
    q0, q1 = np.array([0.0, 0.2, -0.2, 0.0, 0.5, 0.0]), np.array([0.4, 0.3, -0.1, 0.2, 0.6, 0.3])
    warm = ruckig_profile(q0, q1, *default_kinematic_limits(m900))
    solutions = {
        "collocation": PtpOcp(dyn, limits, opts).solve(q0, q1, NodeGuess.from_profile(warm, 12)),
        "shooting": ShootingOcp(dyn, limits, opts).solve(q0, q1, warm),
    }
    for name, sol in solutions.items():
        outcome = SolveOutcome.from_ipopt(sol.status, sol.success, sol.iterations)
        assert outcome.status is SolveStatus.SOLVED, (name, outcome.message)
        np.testing.assert_allclose(sol.q[0], q0, atol=1e-8, err_msg=name)
        np.testing.assert_allclose(sol.q[-1], q1, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(sol.qd[[0, -1]], 0.0, atol=1e-6, err_msg=name)
        assert np.max(np.abs(sol.qd) / m900.v_max) <= 1 + NODE_TOLERANCE, name
        assert np.max(np.abs(sol.tau) / m900.tau_max) <= 1 + NODE_TOLERANCE, name
    a, b = (s.duration_s for s in solutions.values())
    assert b == pytest.approx(a, rel=0.05)
