"""The planners' electrical-energy objective (issue 29): its value against the exact energy, its optimum
against the ∫τᵀτ plan's energy at the same cycle time, and the equal-conditions criteria failing."""

import dataclasses
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rxcomm.model.energy import BusPowerModel, electrical_energy, energy_split

ROOT = Path(__file__).resolve().parents[1]


def test_bus_power_by_hand_and_against_the_exact_energy(rx130l):
    """Joint 1 at q̇ = 1 rad/s against τ = 10 N·m for 2 s: P = τ·q̇ + R·(τ/(N·k_t))², by hand; a braking
    stretch (P < 0) counts 0 in the exact energy and at most δ/2 in the smooth objective."""
    model = BusPowerModel.of(rx130l, smoothing_w=1.0)
    t = np.linspace(0.0, 2.0, 2001)
    qd, tau = np.zeros((len(t), 6)), np.zeros((len(t), 6))
    qd[:, 0], tau[:, 0] = 1.0, 10.0
    copper = 0.9 * (10.0 / (180 * 0.95)) ** 2  # W
    exact = (10.0 + copper) * 2.0
    assert electrical_energy(rx130l, t, qd, tau) == pytest.approx(exact, rel=1e-12)
    p = 10.0 + copper  # the smooth positive part ½(P + √(P² + δ²)) over the 2 s, δ = 1 W
    assert model.energy(t, qd, tau) == pytest.approx((p + np.sqrt(p * p + 1.0)), rel=1e-12)
    split = energy_split(rx130l, t, qd, tau)
    assert split["copper_j"] == pytest.approx(2 * copper) and split["mechanical_j"] == pytest.approx(20.0)
    # braking half the time: the supply gives nothing then (no regeneration), the smooth form ≤ δ/2
    tau[t > 1.0, 0] = -10.0
    e_exact = electrical_energy(rx130l, t, qd, tau)
    assert e_exact == pytest.approx(10.0 + copper, rel=1e-3)
    assert 0.0 < model.energy(t, qd, tau) - e_exact <= 0.5 * 2.0
    assert energy_split(rx130l, t, qd, tau)["braking_j"] == pytest.approx(10.0 - copper, rel=1e-3)
    # a regenerative supply takes the braking energy back: net ∫P dt (the step costs one sample: 0.01 J)
    regen = replace(rx130l, drives=rx130l.drives.model_copy(update={"regenerative_supply": True}))
    assert electrical_energy(regen, t, qd, tau) == pytest.approx(2 * copper, abs=0.011)
    assert BusPowerModel.of(regen).energy(t, qd, tau) == pytest.approx(2 * copper, abs=0.011)


def test_coupled_wrist_copper_is_the_motor_currents(m900):
    """With a coupled wrist the copper losses are Σ R_w·(τ_m/k_t)² of the motor torques τ_m = R⁻ᵀτ."""
    model = BusPowerModel.of(m900)
    rng = np.random.default_rng(3)
    tau, qd = rng.normal(0, 20, (5, 6)), np.zeros((5, 6))
    tau_m = np.linalg.solve(m900.joint_to_motor.T, tau.T).T
    r_w = np.array([j.winding_resistance_ohm for j in m900.drives.joints])
    copper = np.sum(r_w * (tau_m / m900.torque_constant) ** 2, axis=1)
    regen = model.model_copy(update={"regenerative": True})
    assert regen.power(qd, tau) == pytest.approx(copper, rel=1e-10)


@pytest.mark.slow
def test_cp_energy_objective_beats_the_torque_plan_at_its_cycle_time(rx130l):
    """The path NLP with the energy objective at the cycle time of the k2-weighted ∫τᵀτ plan uses no
    more electrical energy than that plan (the optimum of its own objective), and its objective on the
    nodes agrees with the exact energy of the sampled plan within 0.5 %."""
    from rxcomm.planning.cp import CpSettings, plan_cp
    from rxcomm.planning.paths import load_path
    from rxcomm.planning.timing import PlanDynamics

    _, path = load_path(ROOT / "samples/rx130l/paths/line-near-singularity.yaml", rx130l)
    dyn = PlanDynamics.load(rx130l, None, 0.02)
    torque = plan_cp(rx130l, path, dyn, CpSettings(k2=1e-3))
    t_k2 = torque.duration_s
    energy = plan_cp(rx130l, path, dyn, CpSettings(objective="energy", duration_s=t_k2))
    e_torque = electrical_energy(rx130l, torque.t, torque.qd, torque.tau)
    e_energy = electrical_energy(rx130l, energy.t, energy.qd, energy.tau)
    assert energy.duration_s == pytest.approx(t_k2, abs=2 * rx130l.drives.cycle_s)
    assert e_energy <= e_torque
    assert energy.nlp.bus_energy_j == pytest.approx(e_energy, rel=5e-3)
    assert energy.report.max_ratio <= 1.002
    # slower costs less here (less viscous friction and braking), and below T_opt there is no plan
    slow = plan_cp(rx130l, path, dyn, CpSettings(objective="energy", duration_s=2 * t_k2))
    assert electrical_energy(rx130l, slow.t, slow.qd, slow.tau) < e_energy
    with pytest.raises(Exception, match="below its time-optimal duration"):
        plan_cp(rx130l, path, dyn, CpSettings(objective="energy", duration_s=0.5 * t_k2))


@pytest.mark.slow
def test_cp_energy_plan_far_slower_than_its_fastest_keeps_moving(rx130l):
    """At 8 × its time-optimal duration the ISO line's energy optimum is a law whose σ̇² stays positive
    between the nodes, so the NLP's interval times are the law's. Without the sag row it zig-zagged σ̈ by
    ±5 m/s² between nodes at the speed floor, σ̇² dipped below zero in between, and sampling the law
    crashed on a NaN duration."""
    from rxcomm.planning.cp import CpSettings, plan_cp
    from rxcomm.planning.paths import load_path
    from rxcomm.planning.timing import PlanDynamics

    _, path = load_path(ROOT / "samples/rx130l/paths/iso9283-line.yaml", rx130l)
    dyn = PlanDynamics.load(rx130l, None, 0.02)
    t_opt = plan_cp(rx130l, path, dyn, CpSettings()).duration_s
    slow = plan_cp(rx130l, path, dyn, CpSettings(objective="energy", duration_s=8 * t_opt))
    law = slow.profile
    assert law.duration_s == pytest.approx(slow.nlp.duration_s, rel=0.02)
    assert slow.duration_s == pytest.approx(8 * t_opt, abs=2 * rx130l.drives.cycle_s)
    inside = (slow.t > law.t_nodes[1]) & (slow.t < law.t_nodes[-2])
    assert np.all(slow.sigma_dot[inside] > 0)
    assert slow.report.max_ratio <= 1.002


@pytest.mark.slow
def test_ptp_energy_objective_beats_the_torque_plan_at_its_cycle_time(rx130l):
    from rxcomm.planning.ptp import plan_ptp
    from rxcomm.planning.ptp_problem import PtpDynamics, PtpOptions

    dyn = PtpDynamics.from_parameters(rx130l, None)
    a, b = np.array([-0.8, -0.3, 1.6, 0.4, 0.9, -0.5]), np.array([0.9, 0.2, 1.2, -0.3, 0.6, 0.7])
    base = {"acceleration_limits": True, "n_intervals": 50}
    torque = plan_ptp(rx130l, dyn, a, b, PtpOptions(**base, k2_per_nm2=1e-4))
    bus = BusPowerModel.of(rx130l)
    opts = PtpOptions(**base, objective="energy", bus=bus, duration_s=torque.duration_s)
    energy = plan_ptp(rx130l, dyn, a, b, opts)
    tr, te = torque.trajectory, energy.trajectory
    e_torque = electrical_energy(rx130l, tr.t, tr.qd, tr.tau_ff)
    e_energy = electrical_energy(rx130l, te.t, te.qd, te.tau_ff)
    assert energy.duration_s == pytest.approx(torque.duration_s, abs=2 * rx130l.drives.cycle_s)
    assert e_energy <= e_torque
    assert energy.max_limit_ratio <= 1.002


def test_equal_conditions_criteria_pass_and_fail():
    """Energy at the factory's time and time at the factory's energy, on a curve made to pass and one
    made to fail."""
    from rxcomm.acceptance.verdict import acceptance_rows, time_at_energy
    from rxcomm.schemas.acceptance import Threshold

    th = [
        Threshold(criterion="electrical_energy_at_factory_time", unit="J", max_ratio=1.0),
        Threshold(criterion="cycle_time_at_factory_energy", unit="s", max_ratio=1.0),
    ]
    from rxcomm.schemas.run_log import RunLogSummary

    def run(t, e):  # a completed run's summary with the two figures the criteria read
        return [RunLogSummary.model_construct(outcome="completed", duration_s=t, electrical_energy_j=e)]

    factory, fast = run(6.0, 300.0), run(2.0, 400.0)

    # passing: 280 J at 6 s; the curve 400 J at 2 s → 320 J at 4 s → 280 J at 6 s crosses 300 J at 5 s
    eq, tm = acceptance_rows(th, factory, fast, None, None, run(6.0, 280.0), [run(4.0, 320.0)])
    assert eq.verdict == "PASS" and eq.ratio == pytest.approx(280 / 300)
    assert tm.verdict == "PASS" and tm.commissioned == pytest.approx(5.0) and tm.factory == 6.0
    # made to fail: 310 J at the factory's time; no measured point reaches 300 J
    eq, tm = acceptance_rows(th, factory, fast, None, None, run(6.0, 310.0), [run(4.0, 320.0)])
    assert eq.verdict == "FAIL" and tm.verdict == "not measured" and "every one of 3" in tm.note
    # ... and a curve that reaches the factory's energy only beyond the factory's time fails
    eq, tm = acceptance_rows(th, factory, fast, None, None, run(6.0, 310.0), [run(8.0, 290.0)])
    assert tm.verdict == "FAIL" and tm.commissioned == pytest.approx(7.0)
    # the fastest point already within the factory's energy: that is the time
    assert time_at_energy([(2.0, 250.0), (6.0, 200.0)], 300.0).value == 2.0


def _ptp_energy_case(robot, n_intervals: int, duration_s: float):
    """The PtP energy OCP of `robot` (its prior model, acceleration limits) at a fixed duration, and the
    warm start on its grid stretched to it (rest to rest between two postures)."""
    from rxcomm.planning.ptp import default_kinematic_limits
    from rxcomm.planning.ptp_ocp import PtpOcp
    from rxcomm.planning.ptp_problem import NodeGuess, PtpDynamics, PtpLimits, PtpOptions
    from rxcomm.planning.warm_start import ruckig_profile

    a, b = np.array([-0.8, -0.3, 1.6, 0.4, 0.9, -0.5]), np.array([0.9, 0.2, 1.2, -0.3, 0.6, 0.7])
    opts = PtpOptions(
        acceleration_limits=True,
        n_intervals=n_intervals,
        objective="energy",
        bus=BusPowerModel.of(robot),
        duration_s=duration_s,
        compile=False,
    )
    dyn = PtpDynamics.from_parameters(robot, None)
    ocp = PtpOcp(dyn, PtpLimits.from_robot(robot, acceleration=True), opts)
    profile = ruckig_profile(a, b, *default_kinematic_limits(robot))
    return ocp, dyn, NodeGuess.from_profile(profile, n_intervals).stretched(duration_s), (a, b)


def _dense_energy(robot, ocp, dyn, guess) -> tuple[float, float]:
    """(the OCP's objective at `guess`, the electrical energy of its drive-cycle samples as `accept`
    will measure it with a perfect model)."""
    from rxcomm.planning.ptp import integrate_jerk, sample_solution
    from rxcomm.planning.ptp_problem import NodeGuess, PtpSolution

    # node states by exact integration of the jerk, so the nodes and the samples are one motion
    N, h = guess.jerk.shape[0], guess.duration_s / guess.jerk.shape[0]
    t = np.linspace(0.0, guess.duration_s, N + 1)
    q, qd, qdd = integrate_jerk(guess.q[0], guess.qd[0], guess.qdd[0], guess.jerk, h, t)
    guess = NodeGuess(guess.duration_s, q, qd, qdd, guess.jerk)
    objective = float(ocp._objective(ocp._pack(guess)))
    outcome = dict(objective=objective, status="", success=True, iterations=0, solve_seconds=0.0)
    # (the sampling reads the jerk and the first node; the node torques are not used)
    sol = PtpSolution(**outcome, duration_s=guess.duration_s, q=q, qd=qd, qdd=qdd, jerk=guess.jerk, tau=qd)
    tr = sample_solution(sol, dyn, robot.drives.cycle_s)
    return objective, electrical_energy(robot, tr.t, tr.qd, tr.tau_ff)


def test_ptp_energy_objective_is_the_energy_it_is_judged_on_between_the_nodes(rx130l):
    """The PtP OCP's energy objective is the electrical energy of the drive-cycle samples (`accept`'s
    figure, Coulomb friction as `run` smooths it) within 0.5 %, for the warm start and for the same
    motion with q̇ swinging between the nodes (what the energy optimum of a node-only quadrature did on
    an imported UR5e: 98.65 J objective, 102.15 J sampled). Before: the node trapezoid with the NLP's
    Coulomb smoothing (ε = 0.1) said 1.8 % less than the warm start's samples and 42 % more than the
    swinging motion's."""
    T = 3.0
    ocp, dyn, guess, _ = _ptp_energy_case(rx130l, 30, T)
    objective, dense = _dense_energy(rx130l, ocp, dyn, guess)
    assert objective == pytest.approx(dense, rel=5e-3)
    # q̈ ± 3 rad/s² alternating at the inner nodes on J1–J3: between two inner nodes q̇ swings by
    # ±h·3/4 while their velocities keep one offset (h·3/2, from the first interval)
    N = guess.jerk.shape[0]
    swing = np.zeros_like(guess.qdd)
    swing[1:-1, :3] = 3.0 * np.where(np.arange(1, N) % 2, 1.0, -1.0)[:, None]
    qdd = guess.qdd + swing
    zigzag = dataclasses.replace(guess, qdd=qdd, jerk=np.diff(qdd, axis=0) / (T / N))
    objective, dense = _dense_energy(rx130l, ocp, dyn, zigzag)
    assert objective == pytest.approx(dense, rel=5e-3)


@pytest.mark.slow  # one fixed-time solve in CasADi's virtual machine
def test_ptp_energy_optimum_is_priced_as_it_is_judged_and_beats_its_start(rx130l):
    """The energy-optimal PtP's objective (`quadrature_energy`, the NLP's value) is the electrical energy
    of its drive-cycle samples within 0.5 % (before: 1.99 % below it on this move, the NLP's wide
    Coulomb smoothing), and those samples need no more than the warm start slowed to the same time."""
    from rxcomm.planning.ptp import plan_ptp, quadrature_energy

    ocp, dyn, guess, (a, b) = _ptp_energy_case(rx130l, 30, 3.0)
    res = plan_ptp(rx130l, dyn, a, b, ocp.options, ocp=ocp)
    tr, sol = res.trajectory, res.solution
    dense = electrical_energy(rx130l, tr.t, tr.qd, tr.tau_ff)
    assert sol.objective == pytest.approx(quadrature_energy(sol, dyn, ocp.options.bus), rel=1e-9)
    assert sol.objective == pytest.approx(dense, rel=5e-3)
    assert dense < _dense_energy(rx130l, ocp, dyn, guess)[1]
    assert res.max_limit_ratio <= 1.002
