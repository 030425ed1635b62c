"""plan-cp rows: toppra as wrapped here against a bare toppra call on the same path in the same run, the
path NLP (energy / torque-rate variant), the whole stage, and the quality of the plans (paper §5.3: the
CP line "computed in one second")."""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pinocchio as pin
import toppra
import toppra.algorithm
import toppra.constraint as tc

from bench.table import Row, median_seconds
from rxcomm.io.yaml_io import load_yaml
from rxcomm.model.dynamics import RobotDynamics, prior_parameters
from rxcomm.model.robot import Robot, load_robot
from rxcomm.model.spring import spring_regressor
from rxcomm.planning import cp, path_nlp
from rxcomm.planning.cp_grid import toppra_grid
from rxcomm.planning.path_ik import solve_path_ik
from rxcomm.planning.path_nlp import _solver, optimise_path
from rxcomm.planning.paths import build_path
from rxcomm.planning.timing import NlpProblem, PlanDynamics
from rxcomm.planning.topp import PlanLimits, ToppraPath, time_optimal
from rxcomm.schemas.path import PathSpec

ROOT = Path(__file__).resolve().parent.parent
LINE = ROOT / "samples/rx130l/paths/line-near-singularity.yaml"


def median_cpu_seconds(fn, repeats: int) -> float:
    """Median process CPU time: on a shared, loaded machine wall time can be 2-3× the compute."""
    fn()
    out = []
    for _ in range(repeats):
        c0 = time.process_time()
        fn()
        out.append(time.process_time() - c0)
    return float(np.median(out))


def lean_inverse_dynamics(robot: Robot, rd: RobotDynamics):
    """The same model as `rd` for one sample at a time, written for speed: what a toppra user
    would hand to `JointTorqueConstraint` (the peer gets the fastest honest function)."""
    model, data, rotor, p = rd.model, rd.data, rd.rotor_matrix, rd.params
    k = robot.spring_joint_index
    spring = robot.drives.spring

    def inv_dyn(q, qd, qdd):
        tau = pin.rnea(model, data, q, qd, qdd) + rotor @ qdd
        tau += p.coulomb_nm * np.sign(qd) + p.viscous_nm_s_per_rad * qd + p.offset_nm
        if k is not None:
            tau[k] += spring_regressor(spring, q[k]) @ p.spring
        return tau

    return inv_dyn


@contextmanager
def ipopt_as_before():
    """The path NLP with IPOPT's options before issue 32 (`path_nlp.SPEED_OPTIONS` off), for a before
    column measured in the same run."""
    saved = path_nlp.SPEED_OPTIONS
    path_nlp.SPEED_OPTIONS = {}
    _solver.cache_clear()
    try:
        yield
    finally:
        path_nlp.SPEED_OPTIONS = saved
        _solver.cache_clear()


def bench_plan_cp(quick: bool = False) -> list[Row]:
    """The rows of `make bench` for plan-cp (medians over repeats, peers in the same process)."""
    repeats = 3 if quick else 9
    robot = load_robot(ROOT / "samples/rx130l")
    spec = PathSpec.model_validate(load_yaml(LINE))
    path = build_path(spec)
    jp = solve_path_ik(robot, path, spec.branch)
    params = prior_parameters(robot)
    rd = RobotDynamics(robot, params)
    limits = PlanLimits(robot.v_max, robot.a_max, robot.tau_max)
    grid = np.linspace(0.0, jp.length_m, 201)  # 200 intervals, the paper's grid

    def ours():
        return time_optimal(jp.spline, jp.length_m, grid, limits, rd.inverse_dynamics)

    inv_one = lean_inverse_dynamics(robot, rd)
    bare_path = ToppraPath(jp.spline, jp.length_m, robot.n)

    def bare():
        cons = [
            tc.JointVelocityConstraint(np.c_[-robot.v_max, robot.v_max]),
            tc.JointAccelerationConstraint(
                np.c_[-robot.a_max, robot.a_max], discretization_scheme=tc.DiscretizationType.Interpolation
            ),
            tc.JointTorqueConstraint(
                inv_one, np.c_[-robot.tau_max, robot.tau_max], np.zeros(robot.n),
                discretization_scheme=tc.DiscretizationType.Interpolation,
            ),
        ]  # fmt: skip
        algo = toppra.algorithm.TOPPRA(
            cons, bare_path, gridpoints=grid, solver_wrapper="seidel", parametrizer="ParametrizeConstAccel"
        )
        return algo.compute_trajectory()

    t_ours = median_seconds(ours, repeats)
    t_bare = median_seconds(bare, repeats)
    c_ours, c_bare = median_cpu_seconds(ours, repeats), median_cpu_seconds(bare, repeats)
    d_ours, d_bare = ours().profile.duration_s, bare().duration

    # The NLP alone (energy weight and torque-rate limits), warm from toppra, solver built beforehand.
    dyn = PlanDynamics.from_parameters(robot, params, 0.02)
    settings = cp.CpSettings(k2=1e-5)
    lim = cp.plan_limits(robot, settings)
    tgrid = toppra_grid(jp, 200, robot.a_max)
    warm = time_optimal(jp.spline, jp.length_m, tgrid, lim, dyn.exact).profile
    setup = NlpProblem(dyn, jp, path, lim, 200).setup(warm)
    t0 = time.perf_counter()
    _solver(201, robot.n, True, False, 500)
    build = time.perf_counter() - t0

    def nlp():
        return optimise_path(
            jp.spline, setup.grid, setup.pd, setup.dpd, lim, warm, coulomb_eps_rad_s=0.02, k2=1e-5
        )

    t_nlp = median_seconds(nlp, repeats)
    c_nlp = median_cpu_seconds(nlp, max(3, repeats // 3))
    res = nlp()
    # before issue 32: IPOPT's adaptive barrier with its safeguard and residual checks, same run
    with ipopt_as_before():
        t_nlp_before = median_seconds(nlp, repeats)
        c_nlp_before = median_cpu_seconds(nlp, max(3, repeats // 3))
        res_before = nlp()
        c_plan_before = median_cpu_seconds(lambda: cp.plan_cp(robot, path, dyn, cp.CpSettings()), 3)

    # The whole plan (IK, statics, toppra, two NLP passes, drive-cycle sampling, dense checks).
    plans = []

    def whole():
        plans.append(cp.plan_cp(robot, path, dyn, cp.CpSettings()))

    t_plan = median_seconds(whole, max(2, repeats // 3))
    c_plan = median_cpu_seconds(whole, 3)
    plan = plans[-1]
    fast = cp.plan_cp(robot, path, dyn, cp.CpSettings(method="toppra", torque_rate=False))
    toppra_target = "≤ 20 ms, ≤ 1.5× peer"
    nlp_label = f"{res.iterations} it, T = {res.duration_s:.5f} s"
    before_nlp = f"before ({res_before.iterations} it, T = {res_before.duration_s:.5f} s)"
    return [
        Row("plan-cp", "toppra, 200-interval line", "s", t_ours, "≈ 1 s (MUSCOD-II)",
            "bare toppra", t_bare, toppra_target),
        Row("plan-cp", "toppra, 200-interval line, CPU", "s", c_ours, "",
            "bare toppra", c_bare, toppra_target),
        Row("plan-cp", "toppra duration of that line", "s", d_ours, "", "bare toppra", d_bare, "≈ peer"),
        Row("plan-cp", f"path NLP solve, k2 > 0 + torque rate ({nlp_label})", "s", t_nlp, "≈ 1 s",
            before_nlp, t_nlp_before, "≤ 0.2 s, ≤ 0.3 s in the chain"),
        Row("plan-cp", "path NLP solve, k2 > 0 + torque rate, CPU", "s", c_nlp, "≈ 1 s", before_nlp,
            c_nlp_before, "≤ 0.2 s"),
        Row("plan-cp", "path NLP build (once per N)", "s", build, "", "", None, ""),
        Row("plan-cp", f"NLP iterations ({res.status})", "", float(res.iterations), "", "", None, ""),
        Row("plan-cp", "whole plan-cp (IK → checked samples)", "s", t_plan, "≈ 1 s", "", None, "≤ 0.5 s"),
        Row("plan-cp", "whole plan-cp, CPU", "s", c_plan, "≈ 1 s", "before (IPOPT options)", c_plan_before,
            "≤ 0.5 s"),
        Row("plan-cp", "singular line duration (torque rate)", "s", plan.duration_s, "1.04 s (their line)",
            "toppra alone", fast.duration_s, "architecture §9 ≈ 1.47 s"),
        Row("plan-cp", "active fraction (≥ 98 % of a limit)", "", plan.active_fraction, "one always active",
            "toppra alone", fast.active_fraction, "≥ 0.95"),
        Row("plan-cp", "max limit ratio on the drive-cycle samples", "", plan.report.max_ratio, "",
            "toppra alone", fast.report.max_ratio, "≤ 1.01"),
    ]  # fmt: skip


def rows(quick: bool) -> list[Row]:
    return bench_plan_cp(quick)


if __name__ == "__main__":
    for r in bench_plan_cp(quick=True):
        print(r)
