"""The feed-forward's Coulomb term on joints that barely move (`execution.plan.coulomb_weight`,
architecture §6.1): its value across slow reversals against the old smooth sign, its continuity, and
the lag it removes in the simulated cell."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rxcomm.cell.truth import load_truth
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.plan import coulomb_weight, model_torque, sliding_weight
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


def _m900_lags(moves: list[tuple[int, float, float, float]], end_s: float, window_s: tuple[float, float]):
    """Max |demand − actual| per joint within ``window_s`` on our plant (M900 truth, the arm starting at
    rest on its demand), the TRUE model fed forward: (the smooth sign throughout, what `run` sends:
    `prepare_plan`'s feed-forward). ``moves``: (joint, start s, duration s, Δq rad) 1 − cos bumps."""
    from rxcomm.execution.plan import prepare_plan
    from rxcomm.io.trajectory import Trajectory

    truth = load_truth(SAMPLES / "m900" / "truth.yaml")
    robot, params = truth.robot, truth.params
    dt = robot.drives.cycle_s
    t = np.arange(int(round(end_s / dt)) + 1) * dt
    q, qd, qdd = (np.zeros((len(t), 6)) for _ in range(3))
    for j, t0, dur, dq in moves:
        a, b, c = _bump(t, t0, dur, dq)
        q[:, j] += a
        qd[:, j] += b
        qdd[:, j] += c
    q0 = np.array([-0.34724, 0.60513, 2.23524, -0.0012062, 0.29242, 2.79684])
    q += q0
    smooth = RobotDynamics(robot, params, coulomb_eps_rad_s=EPS).inverse_dynamics(q, qd, qdd)
    sent = prepare_plan(robot, Trajectory(t, q, qd, qdd), params, dt).tau_ff
    inside = (t >= window_s[0]) & (t <= window_s[1])
    out = []
    for ff in (smooth, sent):
        actual = stream(enabled_core(cell_at(truth, q0)), q, ff)[: len(q)]
        out.append(np.abs(q - actual)[inside].max(axis=0))
    return out


def test_a_joint_that_stops_into_a_dwell_does_not_wind_up_against_its_next_move():
    """The M900's ISO line cycles in miniature (architecture §6.1, "through stops and reversals"): J1–J3
    turn 0.05 rad on a 1 − cos speed profile (its slow tail like the cycles' return move), rest 0.3 s,
    and turn back in 0.5 s. With the smooth sign the feed-forward's friction fades below ε before the
    joints stop, they stop short, and in the dwell their integrators wind up the friction against the
    move back: J1 lags 1.98 mrad as it starts. Held through the stop, the joints stop on their demand."""
    moves = [(j, 0.0, 1.0, 0.05) for j in range(3)] + [(j, 1.3, 0.5, -0.05) for j in range(3)]
    smooth, sent = _m900_lags(moves, 1.9, (1.3, 1.55))
    print(f"\nmax lag J1–J3 after the dwell, mrad: smooth sign {smooth[:3] * 1e3}, sent {sent[:3] * 1e3}")
    assert smooth[0] > 1.5e-3
    assert np.all(sent[:3] < 0.3 * smooth[:3]) and sent[:3].max() < 0.6e-3


def test_a_slow_reversal_gets_the_friction_of_its_new_direction():
    """J2 reverses at 0.06 rad/s² (the M900's ISO line at 0.1 m/s reverses J2 at ≈ 0.08): the smooth
    sign takes 0.6 s to swing through ±0.76·Fc while the joint's friction flips as it passes rest; J2
    lags 0.82 mrad. The sign flipped over FLIP_S at the reversal: ≤ 0.4 mrad."""
    smooth, sent = _m900_lags([(1, 0.0, 1.0, -0.015), (1, 0.4, 1.2, 0.03)], 1.8, (0.3, 1.0))
    print(
        f"\nJ2 max lag around its reversal, mrad: smooth sign {smooth[1] * 1e3:.3f}, sent {sent[1] * 1e3:.3f}"
    )
    assert smooth[1] > 0.6e-3 and sent[1] < 0.4 * smooth[1] and sent[1] < 0.4e-3


def test_the_held_sign_is_continuous_and_lets_go_at_rest():
    """`held_sign` on the creeping-joint plan above: never steeper than the smooth sign plus the flip's
    3·Δt/FLIP_S (the torque-rate limits the planners kept hold), ±its stretch's peak down to each stop,
    zero once a joint has rested RELEASE_S, the smooth sign where nothing stops or reverses."""
    from rxcomm.execution.plan import FLIP_S, RELEASE_S, held_sign

    _, qd, _ = _plan()
    smooth, held = np.tanh(qd / EPS), held_sign(qd, DT)
    assert np.all(np.abs(np.diff(held, axis=0)) <= np.abs(np.diff(smooth, axis=0)) + 3 * DT / FLIP_S + 1e-12)
    t = np.arange(len(qd)) * DT
    # J1 slides to rest at 0.6 s: its peak held to the stop (the smooth sign had faded to 0), 0 after
    stop = np.flatnonzero(qd[:, 0] > 0)[-1]
    assert held[stop, 0] > 0.99 and smooth[stop, 0] < 0.01
    assert np.all(held[t >= 0.6 + RELEASE_S + DT, 0] == 0.0)
    # a joint reversing at 0.5 s without resting: the new stretch's peak from FLIP_S/2 after it on
    tr = np.arange(int(1.2 / DT) + 1) * DT
    qd_rev = (0.03 * np.sin(2 * np.pi * tr) * (tr < 1.0))[:, None]  # then 0.2 s at rest
    rev = held_sign(qd_rev, DT)[:, 0]
    back = (tr >= 0.5 + FLIP_S / 2) & (qd_rev[:, 0] < 0)
    np.testing.assert_allclose(rev[back], -np.tanh(0.03 / EPS), rtol=1e-9)
    assert np.abs(np.tanh(qd_rev[back, 0] / EPS)).min() < 0.01  # where the smooth sign had faded
    # a creeping joint (weight 0 on its first direction) reversing straight into a faster stretch
    # (weight 1): the weighted stretches are blended, so its weight's step at the reversal steps nothing
    qd_creep = (np.where(tr < 0.5, 0.004, 0.010) * np.sin(2 * np.pi * tr) * (tr < 1.0))[:, None]
    w = coulomb_weight(qd_creep)
    assert w[0, 0] == 0.0 and w[-1, 0] == 1.0
    step = np.abs(np.diff(held_sign(qd_creep, DT, weight=w), axis=0))
    assert np.all(step <= np.abs(np.diff(w * np.tanh(qd_creep / EPS), axis=0)) + 3 * DT / FLIP_S + 1e-12)
    # a fast reversal (the smooth sign swings within FLIP_S): the smooth sign exactly, up to the stop
    qd_fast = (0.3 * np.sin(2 * np.pi * tr) * (tr < 1.0))[:, None]
    fast = held_sign(qd_fast, DT)
    np.testing.assert_array_equal(fast[tr < 0.75, 0], np.tanh(qd_fast[tr < 0.75, 0] / EPS))
    assert fast[np.flatnonzero(qd_fast[:, 0])[-1], 0] < -0.99  # held into the final rest
    # a plan without rests or reversals: the smooth sign exactly
    qd_one_way = np.outer(np.sin(np.linspace(0, np.pi, 501)), [0.03, -0.2])
    np.testing.assert_array_equal(held_sign(qd_one_way, DT), np.tanh(qd_one_way / EPS))


def test_a_pause_without_reversal_keeps_the_held_sign_continuous():
    """A joint that touches rest for one sample and goes on the same way (an excitation's period
    boundary, q̇ = −sin² shape twice) and then stops into a rest: held through the pause at the running
    maximum, no step. The first version held the stretch before the pause and restarted the next from
    the smooth sign's 0: a step of Fc in one drive cycle (RX130L J1 35 N·m, 3.1 × its torque-rate limit
    in run's check of `test_end_to_end_on_the_simulated_cell`)."""
    from rxcomm.execution.plan import FLIP_S, held_sign

    t = np.arange(int(1.3 / DT) + 1) * DT
    qd = (-0.05 * np.sin(2 * np.pi * t) ** 2 * (t <= 1.0))[:, None]  # 0 only at 0, 0.5 s and from 1 s
    assert np.sum((np.abs(qd[:, 0]) < 1e-12) & (t < 1.0)) == 2
    held, smooth = held_sign(qd, DT)[:, 0], np.tanh(qd[:, 0] / EPS)
    assert np.all(np.abs(np.diff(held)) <= np.abs(np.diff(smooth)) + 3 * DT / FLIP_S + 1e-12)
    mid = np.flatnonzero(np.isclose(t, 0.5))[0]
    assert np.isclose(held[mid], -np.tanh(0.05 / EPS), rtol=1e-3) and abs(smooth[mid]) < 1e-12  # held
    assert held[-1] == 0.0  # let go in the final rest


def test_a_joint_whose_held_sign_breaks_its_torque_rate_limit_keeps_the_smooth_sign():
    """The planners time a stop with the smooth sign; held to rest and let go over RELEASE_S, the sign
    can take a joint's torque rate above its limit where the plan kept it (RX130L J2 at the end of the
    ISO line at 0.1 m/s, rated load: 1.105 ×, and `run` refused `make acceptance`'s plan). J2 slides
    0.02 rad in 1 s to rest with its torque-rate limit at 700 N·m/s: the smooth sign's torque rate is
    about 150 N·m/s, the held sign's release 1.5·Fc/RELEASE_S = 900. The plan is run with J2 on the
    smooth sign, named; J1 (held, within its limit) keeps the held sign."""
    from rxcomm.execution.plan import prepare_plan
    from rxcomm.io.trajectory import Trajectory

    robot = load_robot(SAMPLES / "rx130l")
    joints = [
        j.model_copy(update={"torque_rate_max_nm_per_s": 700.0}) if i == 1 else j
        for i, j in enumerate(robot.drives.joints)
    ]
    robot = replace(robot, drives=robot.drives.model_copy(update={"joints": joints}))
    params, dt = prior_parameters(robot), robot.drives.cycle_s
    t = np.arange(int(round(1.3 / dt)) + 1) * dt
    q, qd, qdd = (np.zeros((len(t), 6)) for _ in range(3))
    for j, dq in ((0, 0.02), (1, 0.02)):
        a, b, c = _bump(t, 0.0, 1.0, dq)
        q[:, j], qd[:, j], qdd[:, j] = a, b, c
    q += np.array([0.0, -0.3, 1.8, 0.0, 0.8, 0.0])
    held, smooth = model_torque(robot, params, q, qd, qdd, dt), model_torque(robot, params, q, qd, qdd)
    rate = np.abs(np.gradient(held, t, axis=0)).max(axis=0) / robot.tau_rate_max
    assert rate[1] > 1.2 and np.abs(np.gradient(smooth[:, 1], t)).max() < 0.3 * 700.0
    plan = prepare_plan(robot, Trajectory(t, q, qd, qdd), params, dt)
    assert [name for name, _ in plan.smooth_sign_joints] == ["joint_2"]
    assert plan.smooth_sign_joints[0][1] == pytest.approx(rate[1])
    np.testing.assert_array_equal(plan.tau_ff[:, 1], smooth[:, 1])
    np.testing.assert_array_equal(plan.tau_ff[:, 0], held[:, 0])
    assert np.abs(held[:, 0] - smooth[:, 0]).max() > 10.0  # J1 really is on the held sign
    assert plan.report.max_ratio <= 1.0
