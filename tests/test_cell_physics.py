"""The simulated cell's physics: drives, plant, stiction, saturation, trips, tracker, cost per cycle.

Lag figures go through the gateway core in-process (no sockets), so setpoints and feed-forward torques
are quantised exactly as a master's would be (1 µrad, 0.1 % rated torque).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from rxcomm.cell.drives import drive_gains
from rxcomm.cell.gateway_core import GatewayCore
from rxcomm.cell.gateway_machine import Phase
from rxcomm.cell.plant import Plant, _pgs, friction_step
from rxcomm.cell.sim import SimSettings, SimulatedCell, simulated_cell
from rxcomm.cell.truth import load_truth
from rxcomm.errors import InputError
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import Control, DriveState, ErrorCode
from rxcomm.model.dynamics import RobotDynamics
from rxcomm.planning.warm_start import ruckig_profile

from .conftest import SAMPLES

RX_TRUTH = SAMPLES / "rx130l" / "truth.yaml"
M9_TRUTH = SAMPLES / "m900" / "truth.yaml"
# A fast J1–J3 move (wrist held) and a gravity-loaded hold pose (upper arm 57° forward).
Q_A = np.array([-0.8, -0.3, 0.6, 0.0, 0.5, 0.0])
Q_B = np.array([0.8, 0.5, -0.2, 0.0, 0.5, 0.0])
Q_LOADED = np.array([0.0, 1.0, 0.3, 0.0, 0.5, 0.0])
Q_VISIBLE = np.array([-0.4, 0.2, 1.2, 0.0, 0.8, 0.0])  # the probe faces the tracker here


@pytest.fixture(scope="module")
def rx_truth():
    return load_truth(RX_TRUTH)


def cell_at(truth, q0, **kw) -> SimulatedCell:
    return SimulatedCell(truth, SimSettings(q0_rad=tuple(float(x) for x in q0), **kw))


def enabled_core(cell: SimulatedCell) -> GatewayCore:
    core = GatewayCore(cell)
    core.watchdog_ms = 0
    for cw in (R.CW_SHUTDOWN, R.CW_SWITCH_ON, R.CW_ENABLE_OPERATION):
        assert core.handle_write(R.CTRL_CONTROLWORD_ALL, [cw], 0.0) is None
    return core


def stream(core: GatewayCore, pos: np.ndarray, tau: np.ndarray, on_cycle=None) -> np.ndarray:
    """Stream setpoints through the core (virtual time) until it stops cycling; the trace of actual
    positions, one row per drive cycle (settling cycles after the stream included). `on_cycle(k)` is
    called after drive cycle k."""
    assert core.handle_write(R.CTRL_BITS, [int(Control.CLEAR)], 0.0) is None
    assert core.handle_write(R.CTRL_BITS, [int(Control.STREAM_ENABLE)], 0.0) is None
    rows, i, n = [], 0, len(pos)
    while True:
        while i < n and core.ring.level < 600:
            blk = codec.SetpointBlock(
                i,
                0,
                int(R.BlockFlags.END_OF_STREAM) if i + 6 >= n else 0,
                codec.rad_to_counts(pos[i : i + 6]),
                codec.nm_to_torque_counts(tau[i : i + 6], core.rated_nm),
            )
            assert core.handle_write(R.BLOCK_BASE, codec.encode_block(blk), 0.0) is None
            i += 6
        if not core.needs_cycle():
            return np.array(rows)
        core.run_cycle(allow_underrun=False)
        rows.append(core.fb.position_rad.copy())
        if on_cycle is not None:
            on_cycle(len(rows) - 1)


def fast_move(truth, qa, qb, speed=0.7, hold_s=0.4):
    """A ruckig move at `speed` × the velocity limits (accelerations at drives.yaml's limits), preceded
    by a hold at the start; (positions, true-model feed-forward, static-only feed-forward, first moving
    index) sampled at the drive cycle (sample k = the demand at the end of cycle k)."""
    robot = truth.robot
    prof = ruckig_profile(qa, qb, speed * robot.v_max, robot.a_max, 5.0 * robot.a_max)
    dt = robot.drives.cycle_s
    t = np.arange(1, int(round(prof.duration_s / dt)) + 1) * dt
    q, qd, qdd = prof.at(t)
    true = RobotDynamics(robot, truth.params)
    n_hold = int(round(hold_s / dt))
    hold = np.repeat(qa[None], n_hold, axis=0)
    pos = np.vstack([hold, q])
    ff = np.vstack([true.inverse_dynamics(hold, 0 * hold, 0 * hold), true.inverse_dynamics(q, qd, qdd)])
    return pos, ff, n_hold


def tcp_positions(robot, qs: np.ndarray) -> np.ndarray:
    data = robot.create_data()
    out = np.empty((len(qs), 3))
    for i, q in enumerate(qs):
        pin.framesForwardKinematics(robot.model, data, q)
        out[i] = data.oMf[robot.tcp_frame_id].translation
    return out


def lag_run(truth, pos, ff, n_hold, with_ff: bool) -> tuple[np.ndarray, float]:
    """Max |demand − actual| per joint over the move and the max TCP deviation (nominal kinematics)."""
    cell = cell_at(truth, pos[0])
    actual = stream(enabled_core(cell), pos, ff if with_ff else np.zeros_like(ff))[: len(pos)]
    lag = np.abs(pos - actual)[n_hold:]
    every = slice(n_hold, None, 5)
    tcp = np.linalg.norm(
        tcp_positions(truth.robot, pos[every]) - tcp_positions(truth.robot, actual[every]), axis=1
    )
    return lag.max(axis=0), float(tcp.max())


# ---- plant ---------------------------------------------------------------------------------------


def test_plant_is_the_inverse_of_the_true_inverse_dynamics(rx_truth):
    """Applying τ = ID_true(q, q̇, q̈) while every joint slides gives q̈ back (tiny step)."""
    dyn = RobotDynamics(rx_truth.robot, rx_truth.params)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, qdd = (
            rng.uniform(-1, 1, 6),
            rng.uniform(0.2, 1, 6) * rng.choice([-1, 1], 6),
            rng.uniform(-3, 3, 6),
        )
        plant = Plant(rx_truth.robot, rx_truth.params, q, cycle_s=1e-7)
        plant.v = qd.copy()
        plant.step(dyn.inverse_dynamics(q, qd, qdd), np.zeros(6, dtype=bool))
        np.testing.assert_allclose((plant.v - qd) / 1e-7, qdd, atol=2e-5 * (1 + np.abs(qdd).max()))


def test_friction_solver_is_complementary_and_matches_gauss_seidel():
    """Random coupled inertias, velocities at rest or moving, friction caps (some zero): the active-set
    answer satisfies the Coulomb law exactly and equals the Gauss–Seidel fallback's."""
    rng = np.random.default_rng(0)
    h = 4e-4
    for _ in range(500):
        x = rng.normal(size=(6, 6))
        a = x @ x.T + 0.5 * np.eye(6)
        v = rng.normal(size=6) * (rng.random(6) > 0.4)  # some joints at rest
        r = a @ v + h * rng.normal(size=6) * rng.choice([1.0, 30.0, 1e4], 6)
        cap = rng.uniform(0, 50, 6) * (rng.random(6) > 0.1)
        vn, f = friction_step(a, r, h, cap, v)
        np.testing.assert_allclose(a @ vn, r - h * f, atol=1e-9 * (1 + np.abs(r).max()))
        assert np.all(np.abs(f) <= cap * (1 + 1e-9) + 1e-12)
        moving = vn != 0.0
        np.testing.assert_allclose(f[moving], cap[moving] * np.sign(vn[moving]), rtol=1e-12)
        vn_pgs, _ = _pgs(a, r, h, cap)  # the LCP has one solution (h·A⁻¹ is SPD)
        np.testing.assert_allclose(vn, vn_pgs, atol=1e-6)


def test_stiction_holds_below_breakaway_and_slides_above_without_chatter(rx_truth):
    """Drives off, brakes released (torque applied directly): J3 with the static torque plus 0.9·F_c
    stays exactly still; with 1.2·F_c it slides one way; coasting from speed it stops and stays."""
    robot, params = rx_truth.robot, rx_truth.params
    free = np.zeros(6, dtype=bool)
    fc3 = params.coulomb_nm[2]
    plant = Plant(robot, params, Q_LOADED)
    hold = plant.static_torque(Q_LOADED)
    stick = hold.copy()
    stick[[0, 1, 3, 4, 5]] += 0.0  # the other joints sit exactly at their static torque: they stick
    stick[2] += 0.9 * fc3
    for _ in range(2500):
        plant.step(stick, free)
        assert not plant.v.any()
    np.testing.assert_array_equal(plant.q, Q_LOADED)

    slide = hold.copy()
    slide[2] += 1.2 * fc3
    signs = []
    for _ in range(500):
        plant.step(slide, free)
        signs.append(np.sign(plant.v[2]))
    assert plant.v[2] > 0 and set(signs) <= {0.0, 1.0} and signs.count(0.0) <= 1

    coast = plant.static_torque(plant.q)  # friction alone brakes it; gravity balanced
    vs = []
    for _ in range(2500):
        plant.step(coast, free)
        coast = plant.static_torque(plant.q)
        vs.append(plant.v[2])
    vs = np.array(vs)
    stop = int(np.argmax(vs == 0.0))
    assert stop > 0 and np.all(vs[:stop] > 0) and np.all(vs[stop:] == 0.0)  # never below zero, stays


def test_coupled_motor_friction_loads_both_wrist_joints(rx_truth):
    """The RX130L truth's motor 6 (turning at 40·(q̇6 + 0.4·q̇5)) has Coulomb friction of its own: while
    it turns, joint torques Rᵀ·Fc_m·sgn(R·q̇) load joint 5 (16·Fc_m) as well as joint 6 (40·Fc_m); at
    rest it adds nothing (the joints' stiction holds the arm)."""
    robot, params = rx_truth.robot, rx_truth.params
    fc_m = params.motor_coulomb_nm[5]
    assert fc_m > 0
    plain = replace(params, motor_coulomb_nm=np.zeros(6))
    q = Q_LOADED
    for qd in (np.array([0.0, 0, 0, 0, 0.5, 0.3]), np.array([0.0, 0, 0, 0, -0.9, 0.2])):
        dv = []
        for p in (params, plain):
            plant = Plant(robot, p, q, cycle_s=1e-7)
            plant.v = qd.copy()
            plant.step(RobotDynamics(robot, plain).inverse_dynamics(q, qd, np.zeros(6)), np.zeros(6, bool))
            dv.append(plant.v - qd)
        m = RobotDynamics(robot, params).mass_matrix(q)
        tau_extra = -(m @ (dv[0] - dv[1])) / 1e-7  # the torque the motor friction took
        expected = robot.joint_to_motor[5] * fc_m * np.sign(qd[5] + 0.4 * qd[4])
        # joints 1–4 stick in both runs; on joints 5 and 6 the difference is the motor's friction
        np.testing.assert_allclose(tau_extra[4:], expected[4:], atol=1e-3 * fc_m * 40)
        assert abs(expected[4]) == pytest.approx(16 * fc_m)
    plant = Plant(robot, params, q)
    for _ in range(200):
        plant.step(plant.static_torque(q), np.zeros(6, bool))
    np.testing.assert_array_equal(plant.q, q)


def test_brakes_hold_disabled_axes_exactly(rx_truth):
    cell = cell_at(rx_truth, Q_LOADED)
    for _ in range(2500):
        fb = cell.cycle(Q_LOADED, np.zeros(6), np.zeros(6, dtype=bool))
    np.testing.assert_array_equal(cell.plant.q, Q_LOADED)
    assert not fb.torque_nm.any() and not fb.velocity_rad_s.any()


# ---- drives ----------------------------------------------------------------------------------------


def test_gains_follow_the_prior_inertia_not_the_truth(rx_truth):
    g = drive_gains(rx_truth.robot)
    # the P loop on the prior axis 1/(J·s + b) crosses over at 60 rad/s: J·60 where b is small against it
    b = np.asarray(rx_truth.robot.viscous_prior, float)
    np.testing.assert_allclose(np.abs(g.kp_nm_s_per_rad / (1j * 60.0 * g.nominal_inertia_kgm2 + b)), 1.0)
    np.testing.assert_allclose(g.kp_nm_s_per_rad[:3] / g.nominal_inertia_kgm2[:3], 60.0, rtol=1e-3)
    assert np.all(np.diff(g.nominal_inertia_kgm2[:3]) != 0) and g.nominal_inertia_kgm2[5] < 0.1
    true_cell = cell_at(rx_truth, Q_A)
    np.testing.assert_allclose(true_cell.gains.kp_nm_s_per_rad, g.kp_nm_s_per_rad)  # truth plays no part


@pytest.mark.slow
def test_feedforward_cuts_the_lag_at_least_three_times(rx_truth, capsys):
    """The paper's Fig. 2 effect: a J1–J3 move at 70 % of the velocity limits, lag with and without
    the true model's feed-forward torque (quantised over the gateway)."""
    pos, ff, n_hold = fast_move(rx_truth, Q_A, Q_B)
    lag_std, tcp_std = lag_run(rx_truth, pos, ff, n_hold, with_ff=False)
    lag_ff, tcp_ff = lag_run(rx_truth, pos, ff, n_hold, with_ff=True)
    with capsys.disabled():
        print(
            f"\nmax joint lag, mrad: standard {np.round(lag_std * 1e3, 3).tolist()}, "
            f"feed-forward {np.round(lag_ff * 1e3, 4).tolist()}; "
            f"max TCP error: {tcp_std * 1e3:.2f} mm vs {tcp_ff * 1e3:.3f} mm"
        )
    assert np.all(lag_std[:3] >= 3.0 * lag_ff[:3]) and lag_std.max() >= 3.0 * lag_ff.max()
    assert 1e-3 < tcp_std < 30e-3  # the standard drive lags by millimetres
    assert lag_std.max() < 0.5 * drive_gains(rx_truth.robot).following_error_limit_rad[0]  # no trip


@pytest.mark.slow
def test_standard_drive_lags_millimetres_at_one_metre_per_second(rx_truth):
    pos, ff, n_hold = fast_move(rx_truth, Q_A, Q_B, speed=0.4, hold_s=0.3)
    tcp = tcp_positions(rx_truth.robot, pos[n_hold::5])
    speed = np.linalg.norm(np.diff(tcp, axis=0), axis=1) / (5 * rx_truth.robot.drives.cycle_s)
    assert 0.8 < speed.max() < 1.3
    _, tcp_std = lag_run(rx_truth, pos, ff, n_hold, with_ff=False)
    assert 1e-3 < tcp_std < 10e-3


def test_loops_hold_gravity_and_spring_without_drift(rx_truth, capsys):
    """Enabled at a gravity-loaded pose with no feed-forward: the arm sags while the integrators build
    the holding torque (J4, whose static torque just exceeds its Coulomb friction, slips and sticks
    until its integrator breaks it free: stick-slip, as real drives do), then holds within encoder
    counts and does not drift."""
    cell = cell_at(rx_truth, Q_LOADED)
    static = cell.plant.static_torque(Q_LOADED)
    assert abs(static[1]) > 100  # a real load on J2 (gravity minus spring)
    on = np.ones(6, dtype=bool)
    n = int(3.0 / cell.cycle_s)
    err = np.array([cell.cycle(Q_LOADED, np.zeros(6), on).following_error_rad for _ in range(n)])
    tail = np.abs(err[-int(0.5 / cell.cycle_s) :])
    with capsys.disabled():
        print(f"\nhold without feed-forward: max sag {np.round(np.abs(err).max(0) * 1e6).tolist()} µrad")
    assert np.abs(err).max() < 0.5 * cell.following_error_limit_rad.max()  # far from a trip
    assert tail.max() <= 3e-6  # steady state within 3 encoder counts
    np.testing.assert_array_equal(tail[0], tail[-1])  # no drift over the last 0.5 s
    assert cell.standing_still()


def test_reenable_preloads_the_holding_torque(rx_truth):
    cell = cell_at(rx_truth, Q_LOADED)
    on, off = np.ones(6, dtype=bool), np.zeros(6, dtype=bool)
    for _ in range(3000):
        cell.cycle(Q_LOADED, np.zeros(6), on)
    q_hold = cell.feedback().position_rad
    for _ in range(250):
        cell.cycle(q_hold, np.zeros(6), off)
    err = [np.abs(cell.cycle(q_hold, np.zeros(6), on).following_error_rad).max() for _ in range(500)]
    assert max(err) <= 5e-6  # brake released onto the remembered torque: no sag


def test_torque_saturates_at_peak_with_anti_windup(rx_truth):
    cell = cell_at(rx_truth, Q_A)
    on = np.ones(6, dtype=bool)
    static = cell.plant.static_torque(Q_A)
    for _ in range(500):
        cell.cycle(Q_A, static, on)
    peak = rx_truth.robot.tau_max
    push = static.copy()
    push[2] = 2.5 * peak[2]
    for _ in range(25):  # 10 ms of an impossible torque on J3
        fb = cell.cycle(Q_A, push, on)
        assert cell.drives.torque[2] == peak[2]
        assert abs(fb.torque_nm[2] - peak[2]) < 5 * rx_truth.truth.noise.torque_noise_nm[2]
    assert np.all(np.abs(cell.drives.integral) <= peak)
    moved = abs(cell.feedback().following_error_rad[2])
    assert moved > 1e-4  # it did move off
    for _ in range(5000):  # back to the static feed-forward: recovers (stick-slip on J3's friction)
        fb = cell.cycle(Q_A, static, on)
    assert np.abs(fb.following_error_rad).max() < 10e-6 and np.all(np.abs(cell.drives.torque) < peak)


def test_following_error_trips_the_axis(rx_truth):
    cell = cell_at(rx_truth, Q_A)
    core = enabled_core(cell)
    n = 1500
    pos = np.repeat(Q_A[None], n, axis=0)
    v = np.minimum(200.0 * np.arange(n - 250) * cell.cycle_s, 3.0)  # 200 rad/s²: beyond J1's torque
    pos[250:, 0] += np.cumsum(v) * cell.cycle_s
    stream(core, pos, np.zeros((n, 6)))
    assert core.drives[0].error_code == ErrorCode.FOLLOWING_ERROR
    assert core.drives[0].state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
    assert core.phase is Phase.ABORTED and core.error == ErrorCode.FOLLOWING_ERROR
    assert all(d.state is DriveState.QUICK_STOP_ACTIVE for d in core.drives[1:])


def test_demand_is_clamped_to_the_software_limits(rx_truth):
    q_max5 = rx_truth.robot.q_max[4]
    q0 = Q_A.copy()
    q0[4] = q_max5 - 0.02
    cell = cell_at(rx_truth, q0)
    on = np.ones(6, dtype=bool)
    static = cell.plant.static_torque(q0)
    demand = q0.copy()
    for k in range(2500):  # 1 s ramp at 0.1 rad/s: 80 mrad beyond the limit at the end
        demand[4] = q0[4] + 0.1 * k * cell.cycle_s
        fb = cell.cycle(demand, static, on)
    assert cell.plant.q[4] <= q_max5 + 1e-3  # held at the limit (a little overshoot on arrival)
    assert fb.following_error_rad[4] > cell.following_error_limit_rad[4]  # the gateway would trip it


@pytest.mark.slow
def test_quick_stop_from_speed_stays_below_the_trip(rx_truth):
    pos, ff, n_hold = fast_move(rx_truth, Q_A, Q_B, hold_s=0.2)
    cell = cell_at(rx_truth, Q_A)
    core = enabled_core(cell)
    half = n_hold + (len(pos) - n_hold) // 2
    seen = {}

    def stop_half_way(k):
        if k == half:
            seen["v"] = np.abs(cell.plant.v).max()
            core.quick_stop()
        if k >= half:
            seen.setdefault("fe", []).append(np.abs(core.fb.following_error_rad))

    stream(core, pos, np.zeros_like(ff), on_cycle=stop_half_way)  # no feed-forward: the worst lag
    fe = seen["fe"]
    assert seen["v"] > 1.0 and core.error == 0 and core.phase is Phase.ABORTED
    assert all(d.state is DriveState.QUICK_STOP_ACTIVE for d in core.drives)
    assert np.max(fe) < 0.5 * cell.following_error_limit_rad.max()
    assert np.abs(cell.plant.v).max() < 1e-3


# ---- tracker ---------------------------------------------------------------------------------------


def test_tracker_reads_only_at_standstill_and_where_visible(rx_truth):
    probe = cell_at(rx_truth, Q_A)
    assert probe._tracker.visible(Q_VISIBLE) and not probe._tracker.visible(np.zeros(6))
    assert cell_at(rx_truth, np.zeros(6)).tracker() is None  # standing, but the probe faces away
    pos, ff, n_hold = fast_move(rx_truth, Q_A, Q_VISIBLE, hold_s=0.05)
    on = np.ones(6, dtype=bool)
    for k in range(n_hold + 500):
        probe.cycle(pos[k], ff[k], on)
    assert probe.tracker() is None  # moving
    core = enabled_core(cell_at(rx_truth, Q_A))
    stream(core, pos, ff)  # there, then the gateway lets it settle until standstill
    cell = core.backend
    reading = cell.tracker()
    assert reading is not None and cell.standing_still()
    true_pose = cell._tracker.true_pose(cell.plant.q)
    sigma = rx_truth.truth.noise.tracker_position_sigma_m
    assert np.linalg.norm(reading.position_m - true_pose.translation) < 6 * sigma
    assert abs(np.linalg.norm(reading.quaternion_wxyz) - 1) < 1e-12


def test_truth_errors_name_file_and_field(tmp_path):
    bad = tmp_path / "truth.yaml"
    bad.write_text(RX_TRUTH.read_text().replace("robot: .", f"robot: {SAMPLES / 'rx130l'}"))
    load_truth(bad)  # an absolute robot directory works
    bad.write_text(RX_TRUTH.read_text().replace("encoder_lsb_rad: 1.0e-06", "encoder_lsb_rad: -1"))
    with pytest.raises(InputError) as e:
        load_truth(bad)
    assert e.value.file == str(bad) and e.value.field == "noise.encoder_lsb_rad"
    with pytest.raises(InputError) as e:
        simulated_cell(RX_TRUTH, q0=[0, 0, 0, 0, 3.0, 0])
    assert "joint_5" in str(e.value) and e.value.field == "q0"


# ---- cost ------------------------------------------------------------------------------------------


def test_cost_per_cycle_leaves_room_for_realtime(rx_truth, capsys, record_property):
    """CPU µs per drive cycle of the backend on the fast move (the gateway core adds its own). The best
    250-cycle block is asserted (a shared machine's load only ever adds); the median is reported."""
    pos, ff, n_hold = fast_move(rx_truth, Q_A, Q_B, hold_s=0.05)
    cell = cell_at(rx_truth, Q_A)
    on = np.ones(6, dtype=bool)
    blocks = []
    for b in range(0, len(pos) - 250, 250):
        t0 = time.process_time()
        for k in range(b, b + 250):
            cell.cycle(pos[k], ff[k], on)
        blocks.append((time.process_time() - t0) / 250 * 1e6)
    best, median = min(blocks), float(np.median(blocks))
    record_property("sim_us_per_cycle_best", best)
    record_property("sim_us_per_cycle_median", median)
    with capsys.disabled():
        print(f"\nsimulated cell: {best:.0f} µs/cycle best block, {median:.0f} median ({len(blocks)} blocks)")
    assert best < 400.0


@pytest.mark.slow
def test_second_robot_feedforward_cut(capsys):
    """The same drives and plant on the M-900-class sample (500 µs cycle, no balancer spring)."""
    truth = load_truth(M9_TRUTH)
    qa, qb = np.array([-0.6, -0.2, 0.4, 0.0, 0.6, 0.0]), np.array([0.6, 0.4, -0.3, 0.0, 0.6, 0.0])
    pos, ff, n_hold = fast_move(truth, qa, qb)
    lag_std, tcp_std = lag_run(truth, pos, ff, n_hold, with_ff=False)
    lag_ff, tcp_ff = lag_run(truth, pos, ff, n_hold, with_ff=True)
    with capsys.disabled():
        print(
            f"\nm900 max joint lag, mrad: standard {np.round(lag_std * 1e3, 3).tolist()}, feed-forward "
            f"{np.round(lag_ff * 1e3, 4).tolist()}; TCP {tcp_std * 1e3:.2f} mm vs {tcp_ff * 1e3:.3f} mm"
        )
    assert truth.robot.drives.cycle_s == 5e-4 and truth.robot.drives.spring is None
    assert np.all(lag_std[:3] >= 3.0 * lag_ff[:3]) and 0.5e-3 < tcp_std < 30e-3
