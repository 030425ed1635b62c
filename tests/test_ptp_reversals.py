"""plan-ptp writes only plans `run` accepts: the Coulomb-friction step of a velocity reversal included.

The NLP's torque-rate rows leave Coulomb friction out; `run` checks the rate of the whole torque
(friction smoothed with ε = 0.02 rad/s), whose step at a reversal is ≈ Fc·|q̈|/ε. Robots the project
does not ship (a sample's drives.yaml with more friction, as an identification may find: the chain's
RX130L J3 came out at 15.2 N·m against the prior's 12) make that step exceed the limit at full
deceleration; the energy-weighted optima (k2 > 0) reverse joints there.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from rxcomm.errors import InfeasibleError
from rxcomm.execution.plan import prepare_plan
from rxcomm.model.dynamics import prior_parameters
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE
from rxcomm.model.robot import Robot, load_robot
from rxcomm.planning.ptp import plan_ptp
from rxcomm.planning.ptp_problem import PtpDynamics, PtpOptions

from .conftest import SAMPLES

M900_START = np.array([-0.5, 0.3, -0.4, 0.2, 0.6, 0.0])
M900_GOAL = np.array([0.6, 0.1, -0.1, -0.4, 0.9, 1.0])
# the reference task's PtP on the RX130L: the end states of the line near the wrist singularity
RX_START = np.array([-0.5923, 0.5216, 1.6893, 1.0829, 0.4761, -1.4807])
RX_GOAL = np.array([0.6093, 0.5213, 1.6871, -1.0660, 0.4751, 1.4736])


def robot_with_friction(tmp_path: Path, sample: str, coulomb_nm: dict[int, float]) -> Robot:
    """A copy of a sample robot with other joint Coulomb friction (drives.yaml, joint index → N·m)."""
    d = tmp_path / f"{sample}-friction"
    shutil.copytree(SAMPLES / sample, d)
    drives = yaml.safe_load((d / "drives.yaml").read_text())
    for j, fc in coulomb_nm.items():
        drives["joints"][j]["coulomb_friction_nm"] = fc
    (d / "drives.yaml").write_text(yaml.safe_dump(drives))
    return load_robot(d)


def run_check(robot: Robot, traj):
    """What `run` does before streaming: resample, the model's torque, every limit (no tolerance yet)."""
    return prepare_plan(robot, traj, prior_parameters(robot), robot.drives.cycle_s, limit_tolerance=np.inf)


@pytest.fixture(scope="module")
def rough_m900(tmp_path_factory):
    """The M900 with 1.7–2.3 × its friction on J2–J4: J3's step at 14 rad/s² is 1.7 × its 2500 N·m/s."""
    return robot_with_friction(tmp_path_factory.mktemp("m900"), "m900", {1: 14.0, 2: 6.0, 3: 2.0})


@pytest.mark.slow  # 1.7 s CPU (make test-fast: the unit tier within 60 s)
def test_energy_weighted_plan_passes_runs_check_at_a_reversal(rough_m900):
    robot = rough_m900
    res = plan_ptp(
        robot,
        PtpDynamics.from_parameters(robot),
        M900_START,
        M900_GOAL,
        PtpOptions(n_intervals=24, k2_per_nm2=1e-4, acceleration_limits=True),
    )
    checked = run_check(robot, res.trajectory)
    # the planner's dense check is run's: the same ratios, the friction step included
    planner, run = res.report.max_by_limit(), checked.report.max_by_limit()
    assert planner["torque_rate"] == pytest.approx(run["torque_rate"], rel=1e-6)
    assert checked.report.max_ratio <= 1.0 + SAMPLED_LIMIT_TOLERANCE
    # the step was there to be planned for: J3 reverses, and the first solve (no caps) broke the limit
    assert res.resolves >= 1
    qd3 = res.trajectory.qd[:, 2]
    assert np.any(np.sign(qd3[1:-1]) != np.sign(qd3[2:])) and np.ptp(qd3) > 0.5
    fc, eps = 6.0, 0.02
    assert fc * robot.a_max[2] / eps > 1.6 * robot.tau_rate_max[2]


@pytest.mark.slow  # 1.0 s CPU (make test-fast: the unit tier within 60 s)
def test_plan_still_beyond_a_limit_is_refused(rough_m900):
    """Without re-solves the step stays: plan-ptp refuses (exit 3) rather than write what run refuses."""
    robot = rough_m900
    with pytest.raises(InfeasibleError, match=r"torque_rate limit of j3 at t = .* \(run accepts ≤ 1\.002\)"):
        plan_ptp(
            robot,
            PtpDynamics.from_parameters(robot),
            M900_START,
            M900_GOAL,
            PtpOptions(n_intervals=24, k2_per_nm2=1e-4, acceleration_limits=True),
            max_resolves=0,
        )


@pytest.mark.slow
@pytest.mark.parametrize("k2", [0.0, 1e-5, 1e-4, 1e-3, 1e-2])
@pytest.mark.parametrize("which", ["rx130l", "m900"])
def test_every_energy_weight_gives_a_plan_run_accepts(tmp_path, rough_m900, which, k2):
    """The task's k2 range on the RX130L with the friction the chain identifies (J3 16 N·m, the chain
    15.2: a J3 reversal at 8 rad/s² is 1.07 × its 6000 N·m/s) and on the rough M900."""
    if which == "rx130l":
        robot, q0, q1 = robot_with_friction(tmp_path, "rx130l", {2: 16.0}), RX_START, RX_GOAL
    else:
        robot, q0, q1 = rough_m900, M900_START, M900_GOAL
    opts = PtpOptions(n_intervals=50, k2_per_nm2=k2, acceleration_limits=True)
    res = plan_ptp(robot, PtpDynamics.from_parameters(robot), q0, q1, opts)
    checked = run_check(robot, res.trajectory)
    assert checked.report.max_ratio <= 1.0 + SAMPLED_LIMIT_TOLERANCE
    assert res.max_limit_ratio == pytest.approx(checked.report.max_ratio, rel=1e-6)


def test_a_torque_rate_bound_that_did_not_bind_is_lowered_again(m900):
    """`tighten_torque_rate` scales the NLP's torque-rate rows around a sample above the limit by the
    excess. Where that bound did not bind (the excess lies between the nodes: an imported arm's start
    from rest with the Coulomb ramp on top, MuJoCo Menagerie's piper at 1.0067 × its J1 limit), the
    next pass found the same excess and set the same bound, and four re-solves ended where they
    began: the bound compounds over passes."""
    from rxcomm.io.trajectory import Trajectory
    from rxcomm.planning.ptp import tighten_torque_rate
    from rxcomm.planning.ptp_problem import PtpLimits

    n, nodes, margin = 101, 20, 0.05
    t = np.linspace(0.0, 1.0, n)
    still = np.zeros((n, 6))
    traj = Trajectory(t, still + 0.3, still, still, still + 1.0)  # no friction ramp: not a reversal
    dynamics, limits = PtpDynamics.from_parameters(m900), PtpLimits.from_robot(m900)
    rate = np.zeros((n, 6))
    rate[3:6, 0] = 1.0 + 10 * SAMPLED_LIMIT_TOLERANCE  # three samples over, one excess per pass
    caps, scale = np.full((nodes + 1, 6), np.inf), np.ones((nodes + 1, 6))
    shrink = 1.0 - 10 * SAMPLED_LIMIT_TOLERANCE - margin
    for passes in (1, 2):
        tighten_torque_rate(traj, dynamics, limits, rate, caps, scale, margin)
        assert scale[0, 0] == pytest.approx(shrink**passes)
    assert np.all(np.isinf(caps)) and np.all(scale[:, 1:] == 1.0)


def test_the_output_shift_carries_motor_friction():
    """`PtpDynamics.output_shift` is the sampled plan's torque minus the NLP's (so the energy objective
    prices what `run` computes), motor friction included: on the RX130L's coupled wrist with Coulomb
    friction only at the motors, it is Rᵀ·Fc_m·(tanh(v_m/0.02) − tanh(v_m/0.1)) at v_m = R·q̇ / |diag R|,
    computed here by hand; dropping the motor term leaves a shift of zero and fails this."""
    from dataclasses import replace

    robot = load_robot(SAMPLES / "rx130l")
    assert robot.has_motor_friction
    fc_m = np.array([0.0, 0.0, 0.0, 0.0, 3.0, 1.5])
    params = replace(prior_parameters(robot), coulomb_nm=np.zeros(robot.n), motor_coulomb_nm=fc_m)
    dyn = PtpDynamics.from_parameters(robot, params)
    rng = np.random.default_rng(4)
    r = robot.joint_to_motor
    for _ in range(5):
        q = rng.uniform(robot.q_min, robot.q_max)
        qd, qdd = rng.uniform(-0.15, 0.15, 6), rng.normal(0, 1, 6)
        vm = r @ qd / np.abs(np.diag(r))
        by_hand = r.T @ (fc_m * (np.tanh(vm / 0.02) - np.tanh(vm / 0.1)))
        shift = np.array(dyn.output_shift(qd)).ravel()
        difference = np.array(dyn.output(q, qd, qdd) - dyn.inv_dyn(q, qd, qdd)).ravel()
        assert np.abs(by_hand).max() > 1.0  # the case can fail: the coupled J5 sees both motors
        np.testing.assert_allclose(shift, by_hand, atol=1e-9)
        np.testing.assert_allclose(difference, by_hand, atol=1e-9)
