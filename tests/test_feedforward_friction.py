"""The feed-forward's Coulomb term on joints that barely move (`execution.plan.coulomb_weight`,
architecture §6.1): its value across slow reversals against the old smooth sign, its continuity, and
the lag it removes in the simulated cell."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rxcomm.cell.truth import load_truth
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.plan import model_torque, sliding_weight
from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S as EPS
from rxcomm.model.dynamics import RobotDynamics, prior_parameters
from rxcomm.model.robot import load_robot

from .conftest import SAMPLES
from .test_cell_physics import cell_at, enabled_core, stream

DT = 0.0005


def _bump(t: np.ndarray, t0: float, dur: float, dq: float) -> tuple[np.ndarray, ...]:
    """A rest-to-rest move of dq over [t0, t0 + dur] (1 − cos speed profile): q, q̇, q̈ offsets."""
    w = 2 * np.pi / dur
    s = np.clip(t - t0, 0.0, dur)
    on = (t > t0) & (t < t0 + dur)
    q = dq * (s / dur - np.sin(w * s) / (2 * np.pi))
    return q, on * dq / dur * (1 - np.cos(w * s)), on * dq / dur * w * np.sin(w * s)


def _plan(n_joints: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """J1 swings fast; J2 slides, then reverses slowly (peak 0.5ε); J3 creeps at 0.75ε; J4 creeps at
    ≈ 0.52ε (the M900 CP line's J4 in miniature), reversing twice through rests; J5 creeps the same
    way twice with a rest between, never reversing."""
    t = np.arange(int(1.8 / DT) + 1) * DT
    q, qd, qdd = (np.zeros((len(t), n_joints)) for _ in range(3))
    moves = [  # (joint, [(start s, duration s, dq rad)]): peak speed 2·dq/duration
        (0, [(0.0, 0.6, 0.3)]),
        (1, [(0.0, 0.4, 0.05), (0.5, 0.4, -0.002)]),
        (2, [(0.0, 0.5, 0.75 * EPS * 0.5 / 2)]),
        (3, [(0.0, 0.4, -0.0021), (0.5, 0.3, 0.0016), (1.0, 0.4, -0.0021)]),
        (4, [(0.0, 0.4, -0.0021), (0.6, 0.4, -0.0021)]),
    ]
    for j, bumps in moves:
        for t0, dur, dq in bumps:
            a, b, c = _bump(t, t0, dur, dq)
            q[:, j] += a
            qd[:, j] += b
            qdd[:, j] += c
    return q, qd, qdd


def test_creeping_joint_gets_no_coulomb_term_until_it_reverses():
    """The new term against the old smooth sign, joint and motor friction (the RX130L's motor 6 turns
    with q6 + 0.4·q5: J5 creeping makes it creep too)."""
    robot = load_robot(SAMPLES / "rx130l")
    params = replace(prior_parameters(robot), motor_coulomb_nm=np.array([0, 0, 0, 0, 0, 0.6]))
    no_coulomb = replace(params, coulomb_nm=np.zeros(6), motor_coulomb_nm=np.zeros(6))
    q0 = np.array([0.0, -0.3, 1.2, 0.0, 0.6, 0.0])
    dq, qd, qdd = _plan()
    q = q0 + dq
    assert 0.5 * EPS < np.abs(qd[:, 3]).max() < 0.55 * EPS and np.sum(np.diff(np.sign(qd[:, 3])) != 0) >= 4
    rest = RobotDynamics(robot, no_coulomb, coulomb_eps_rad_s=EPS).inverse_dynamics(q, qd, qdd)
    old_c = RobotDynamics(robot, params, coulomb_eps_rad_s=EPS).inverse_dynamics(q, qd, qdd) - rest
    new_c = model_torque(robot, params, q, qd, qdd) - rest
    fc = params.coulomb_nm
    # J4: the old term swung to −0.48·Fc on its first creep; the new one keeps < 2 % of it until J4
    # reverses (its peak speed 0.53ε is just inside the smoothstep's band)
    w = sliding_weight(qd)
    first = np.arange(len(q)) * DT < 0.5
    assert old_c[first, 3].min() < -0.4 * fc[3] and w[3] < 0.02
    np.testing.assert_allclose(new_c[first, 3], w[3] * old_c[first, 3], rtol=0, atol=1e-12)
    # from the first reversal on, the smooth sign (±0.48·Fc): it helps the integrator swing 2·Fc
    np.testing.assert_allclose(new_c[~first, 3], old_c[~first, 3], rtol=0, atol=1e-12)
    assert old_c[~first, 3].max() > 0.4 * fc[3]
    # J5 creeps one way through a rest, and motor 6 with it: no Coulomb term at all on J5 and J6
    assert old_c[:, 4].min() < -0.4 * fc[4] and np.abs(old_c[:, 5]).max() > 0.05
    assert np.abs(new_c[:, 4:]).max() < 0.02 * np.abs(old_c[:, 4:]).max()
    # J1 slides: the planners' smooth sign exactly; J2 reverses at 0.5ε after sliding: kept too
    np.testing.assert_allclose(new_c[:, :2], old_c[:, :2], rtol=0, atol=1e-12)
    assert np.abs(old_c[qd[:, 1] < 0, 1]).max() > 0.3 * fc[1]
    # J3 creeps at 0.75ε at most: half the smooth sign (the smoothstep's middle)
    np.testing.assert_allclose(w[2], 0.5, atol=0.02)
    np.testing.assert_allclose(new_c[:, 2], w[2] * old_c[:, 2], rtol=0, atol=1e-12)
    # continuous as the smooth sign and never steeper: sample-to-sample steps at most the old ones
    assert np.all(np.abs(np.diff(new_c, axis=0)) <= np.abs(np.diff(old_c, axis=0)) + 1e-12)


def test_a_step_in_the_peak_speed_changes_the_weight_continuously():
    """Across the band [0.5ε, ε] a joint's weight rises smoothly with its peak speed in the plan (so two
    nearly equal plans get nearly equal feed-forwards), 0 below, 1 above."""
    peaks = np.linspace(0.3, 1.2, 91) * EPS
    t = np.linspace(0, 1, 201)
    qd = np.outer(np.sin(np.pi * t), peaks)
    w = sliding_weight(qd)
    assert np.all(w[peaks <= 0.5 * EPS] == 0) and np.all(w[peaks >= EPS] == 1)
    assert np.all(np.diff(w) >= 0) and np.abs(np.diff(w)).max() < 0.04


def test_the_lag_of_a_creeping_joint_after_its_approach_drops_in_the_cell():
    """The M900 CP line's J4 (architecture §6.1) on our plant: the arm approaches the line's start
    from zero as `run --approach` does (J4 creeps 1.2 mrad in 2.6 s, its integrator ends holding the
    friction), then J4 turns on 2 mrad at ≤ 0.0105 rad/s. The true model's feed-forward with the old
    smooth sign pushes it 2.9 mrad past its demand; with `coulomb_weight` it follows within 0.1."""
    truth = load_truth(SAMPLES / "m900" / "truth.yaml")
    robot, params = truth.robot, truth.params
    dt = robot.drives.cycle_s
    q_start = np.array([-0.34724, 0.60513, 2.23524, -0.0012062, 0.29242, 2.79684])
    approach = move_trajectory(robot, np.zeros(6), q_start, dt, 0.2)
    t = np.arange(1, int(round(0.3 / dt)) + 1) * dt
    a, b, c = _bump(t, 0.0, 0.3, -0.00157)
    q = np.repeat(q_start[None], len(t), axis=0)
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    q[:, 3] += a
    qd[:, 3], qdd[:, 3] = b, c
    assert 0.5 * EPS < np.abs(qd[:, 3]).max() < 0.55 * EPS
    old_dyn = RobotDynamics(robot, params, coulomb_eps_rad_s=EPS)

    def j4_lag(torque) -> float:
        pos = np.vstack([approach.q, q])
        ff = np.vstack([torque(approach.q, approach.qd, approach.qdd), torque(q, qd, qdd)])
        actual = stream(enabled_core(cell_at(truth, np.zeros(6))), pos, ff)[: len(pos)]
        lag = (pos - actual)[len(approach.q) :, 3]
        return float(np.sqrt(np.mean(lag**2)))

    old = j4_lag(old_dyn.inverse_dynamics)
    new = j4_lag(lambda *s: model_torque(robot, params, *s))
    print(f"\nJ4 rms lag after the approach: smooth sign {old * 1e3:.3f} mrad, weighted {new * 1e3:.3f}")
    assert old > 1.0e-3 and new < 0.1e-3 and new < old / 10
