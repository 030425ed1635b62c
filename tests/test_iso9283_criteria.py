"""ISO 9283 criteria against hand-computed values on synthetic attained poses and paths, the test
cube and P1–P5 of both sample robots, the pose-cycle plan, and a full campaign's timing."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rxcomm.acceptance.criteria import (
    corner_overshoot,
    path_criteria,
    plane_crossings,
    pose_criteria,
    velocity_criteria,
)
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.model.kinematics import frame_placement
from rxcomm.planning.iso9283 import (
    POSE_CYCLE_ORDER,
    _cube_geometry,
    cube_from_rectangle,
    cycloidal_move,
    pose_cycle_joints,
    pose_cycle_trajectory,
)
from rxcomm.planning.paths import rpy_matrix
from rxcomm.schemas.path import PathSpec

from .conftest import SAMPLES

MM, MRAD = 1e-3, 1e-3


def test_pose_barycentre_and_rp_with_three_sigma():
    # attained x = 0, 1, 2, 5 mm about a command at x = −1 mm: barycentre 2 mm, AP_p = 3 mm;
    # l = 2, 1, 0, 3 mm, l̄ = 1.5, S_l = sqrt((0.25 + 0.25 + 2.25 + 2.25) / 3) = sqrt(5/3)
    x = np.zeros((4, 3))
    x[:, 0] = np.array([0.0, 1.0, 2.0, 5.0]) * MM
    c = pose_criteria(x, np.array([-1.0 * MM, 0, 0]))
    assert c.n == 4
    np.testing.assert_allclose(c.barycentre_m, [2 * MM, 0, 0], atol=1e-15)
    assert c.AP_p == pytest.approx(3 * MM)
    np.testing.assert_allclose(c.AP_xyz, [3 * MM, 0, 0], atol=1e-15)
    assert c.RP_l == pytest.approx((1.5 + 3 * np.sqrt(5 / 3)) * MM)  # 5.373 mm
    assert c.AP_abc is None  # no orientation given


def test_pose_orientation_ap_and_rp():
    # attained = command turned about z by 1, 2, 3, 6 mrad: AP_c = 3 mrad, S_c = sqrt(14/3) mrad
    r_c = rpy_matrix((np.pi, 0.0, 0.0))
    angles = np.array([1.0, 2.0, 3.0, 6.0]) * MRAD
    r = np.array([Rotation.from_rotvec([0, 0, a]).as_matrix() @ r_c for a in angles])
    c = pose_criteria(np.zeros((4, 3)), np.zeros(3), r, r_c)
    np.testing.assert_allclose(c.AP_abc, [0, 0, 3 * MRAD], atol=1e-12)
    np.testing.assert_allclose(c.RP_abc, [0, 0, 3 * np.sqrt(14 / 3) * MRAD], atol=1e-12)
    assert c.RP_l == pytest.approx(0.0, abs=1e-15)


def test_one_cycle_has_no_repeatability():
    c = pose_criteria(np.array([[1e-3, 0, 0]]), np.zeros(3))
    assert c.AP_p == pytest.approx(1e-3) and c.RP_l is None


def test_nan_poses_are_left_out():
    x = np.array([[1e-3, 0, 0], [np.nan] * 3, [3e-3, 0, 0]])
    c = pose_criteria(x, np.zeros(3))
    assert c.n == 2 and c.AP_p == pytest.approx(2e-3)


def line_command(m: int = 50):
    s = np.linspace(0.01, 0.99, m)
    return np.column_stack([s, 0 * s, 0 * s]), np.tile([1.0, 0, 0], (m, 1))


def test_at_over_cycles_on_a_line():
    # two cycles 1 mm and 3 mm beside the line: barycentre 2 mm off (AT_p), each 1 mm from it (RT_p)
    pts, tan = line_command()
    x = np.linspace(-0.05, 1.05, 997)
    cycles = [np.column_stack([x, np.full_like(x, d * MM), 0 * x]) for d in (1.0, 3.0)]
    pc = path_criteria(pts, tan, cycles)
    assert pc.n == 2
    assert pc.AT_p == pytest.approx(2 * MM, abs=1e-12)
    assert pc.RT_p == pytest.approx(1 * MM, abs=1e-12)  # l̄ = 1 mm, S_l = 0


def test_at_is_the_worst_plane_and_rt_has_three_sigma():
    # cycles diverge linearly along x: offsets (0, 2, 4) mm · x; at x = 0.99 the barycentre is
    # 1.98 mm off, l = (1.98, 0, 1.98) mm → l̄ = 1.32 mm, S_l = 1.1432 mm → RT = 4.7495 mm
    pts, tan = line_command()
    x = np.linspace(-0.05, 1.05, 1101)
    cycles = [np.column_stack([x, k * 2 * MM * x, 0 * x]) for k in (0, 1, 2)]
    pc = path_criteria(pts, tan, cycles)
    assert pc.AT_p == pytest.approx(2 * MM * 0.99, rel=1e-9)
    ell = np.array([1.98, 0.0, 1.98]) * MM
    assert pc.RT_p == pytest.approx(ell.mean() + 3 * ell.std(ddof=1), rel=1e-9)


def test_crossing_is_interpolated_between_samples_and_the_nearest_one():
    # a circle of radius 0.1 sampled coarsely: the plane through (0.1, 0, 0) normal to y is crossed at
    # (0.1, 0) and at (−0.1, 0); the nearest is taken, interpolated on the chord
    a = np.linspace(-np.pi, np.pi, 37)
    circle = 0.1 * np.column_stack([np.cos(a + 0.05), np.sin(a + 0.05), 0 * a])
    x = plane_crossings(circle, np.array([[0.1, 0, 0]]), np.array([[0, 1.0, 0]]))
    assert x[0, 1] == pytest.approx(0.0, abs=1e-15)
    assert x[0, 0] == pytest.approx(0.1, abs=5e-4)  # on the chord, inside the arc


def test_at_on_circles_of_other_radii():
    a = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    pts = 0.1 * np.column_stack([np.cos(a), np.sin(a), 0 * a])
    tan = np.column_stack([-np.sin(a), np.cos(a), 0 * a])
    b = np.linspace(-0.1, 2 * np.pi + 0.1, 4000)
    cycles = [r * np.column_stack([np.cos(b), np.sin(b), 0 * b]) for r in (0.101, 0.103)]
    pc = path_criteria(pts, tan, cycles)
    assert pc.AT_p == pytest.approx(2 * MM, abs=1e-6)
    assert pc.RT_p == pytest.approx(1 * MM, abs=1e-6)


def test_corner_overshoot():
    # command (0,0) → (1,0) → (1,1); the attained path runs 2 mm past x = 1 after the corner, then
    # comes back: CO = 2 mm at that corner
    command = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], float)
    dense = np.concatenate(
        [np.linspace(command[0], command[1], 500), np.linspace(command[1], command[2], 500)]
    )
    y = np.linspace(0, 1, 1000)
    bump = 2 * MM * np.exp(-(((y - 0.02) / 0.01) ** 2))
    attained = np.concatenate(
        [np.linspace(command[0], command[1], 400), np.column_stack([1 + bump, y, 0 * y])]
    )
    co, per = corner_overshoot(dense, command[1:2], np.array([[0, 1.0, 0]]), [attained], zone_m=0.1)
    assert co == pytest.approx(2 * MM, rel=1e-3) and per.shape == (1,)
    # beyond the zone an excursion does not count
    far = attained.copy()
    far[-300:, 0] += 5 * MM
    co_far, _ = corner_overshoot(dense, command[1:2], np.array([[0, 1.0, 0]]), [far], zone_m=0.1)
    assert co_far == pytest.approx(2 * MM, rel=1e-3)


def test_path_velocity_accuracy_and_repeatability():
    # command plateau 1.0 m/s; cycles average 0.99, 1.00, 1.02 m/s on it: AV = +0.333 %,
    # RV = 3 · std(0.99, 1.00, 1.02) / 1.0
    ramp = np.concatenate([np.linspace(0, 1, 50), np.ones(200), np.linspace(1, 0, 50)])
    att = [ramp * v for v in (0.99, 1.00, 1.02)]
    vc = velocity_criteria(att, [ramp] * 3)
    assert vc.command_speed_m_per_s == pytest.approx(1.0)
    v = np.array([0.99, 1.00, 1.02])
    assert pytest.approx(v.mean() - 1.0, rel=1e-6) == vc.AV
    assert pytest.approx(3 * v.std(ddof=1), rel=1e-6) == vc.RV


# --- the cube, P1–P5 and the pose cycle on both sample robots ---------------------------------------


def test_cube_and_p1_to_p5_round_trip_through_the_rectangle(robot):
    spec = read_yaml_model(SAMPLES / robot.name / "paths" / "iso9283-rectangle.yaml", PathSpec)
    cube = cube_from_rectangle(spec)
    corners, pts = _cube_geometry(cube.centre_m, cube.side_m)
    np.testing.assert_allclose(cube.plane_corners_m, corners, atol=2e-6)  # the spec rounds to 1 µm
    for k in ("P1", "P2", "P3", "P4", "P5"):
        np.testing.assert_allclose(cube.points_m[k], pts[k], atol=2e-6)
    # the inclined plane: C1, C2 on the bottom face, C3, C4 on the top, P1 its centre
    assert corners[0][2] == pytest.approx(cube.centre_m[2] - cube.side_m / 2, abs=1e-9)
    assert corners[2][2] == pytest.approx(cube.centre_m[2] + cube.side_m / 2, abs=1e-9)
    diag = np.sqrt(3) * cube.side_m
    assert np.linalg.norm(pts["P2"] - corners[0]) == pytest.approx(0.1 * diag)


def test_pose_cycle_plan_visits_p1_to_p5_in_the_standards_order(robot):
    spec = read_yaml_model(SAMPLES / robot.name / "paths" / "iso9283-rectangle.yaml", PathSpec)
    cube = cube_from_rectangle(spec)
    joints = pose_cycle_joints(robot, cube, spec.branch)
    data = robot.create_data()
    rot = rpy_matrix(cube.rpy_rad)
    for k, q in joints.items():  # IK reaches each test pose with the cube's orientation
        m = frame_placement(robot, data, q, robot.tcp_frame_id)
        np.testing.assert_allclose(m.translation, cube.points_m[k], atol=1e-6)
        np.testing.assert_allclose(m.rotation, rot, atol=1e-6)
    dt = robot.drives.cycle_s
    move = cycloidal_move(0.5 * robot.v_max, 0.5 * robot.a_max, dt)
    traj, order = pose_cycle_trajectory(joints, 3, 0.4, move, dt)
    assert order == ["P1"] + 3 * [*POSE_CYCLE_ORDER[1:], "P1"]
    assert np.allclose(np.diff(traj.t), dt)
    assert np.all(np.abs(traj.qd) <= 0.5 * robot.v_max * (1 + 1e-9))  # the limits given
    assert np.all(np.abs(traj.qdd) <= 0.5 * robot.a_max * (1 + 1e-9))
    # each pose is held for the dwell: zero commanded velocity, at its joint angles
    still = np.all(traj.qd == 0, axis=1)
    d = np.diff(np.concatenate([[0], still.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    assert len(starts) == len(order)
    for a, b, k in zip(starts, ends, order, strict=True):
        assert (b - a) * dt == pytest.approx(0.4, abs=1.5 * dt)  # + the move's last, resting sample
        np.testing.assert_allclose(traj.q[a], joints[k], atol=1e-12)


def test_a_full_campaigns_criteria_take_under_a_second():
    """30 pose cycles at P1–P5 and 10 cycles of 4 paths at 1 kHz tracker samples (pure criteria)."""
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    r_c = np.eye(3)
    for _ in range(5):
        pose_criteria(rng.normal(0, 1e-4, (30, 3)), np.zeros(3), np.tile(r_c, (30, 1, 1)), r_c)
    pts, tan = line_command(200)
    x = np.linspace(-0.05, 1.05, 1500)  # 1.5 s of path at 1 kHz per cycle
    for _ in range(4):
        cycles = [np.column_stack([x, rng.normal(0, 1e-4, x.size), 0 * x]) for _ in range(10)]
        path_criteria(pts, tan, cycles)
    wall = time.perf_counter() - t0
    assert wall < 1.0, wall


def test_repeated_path_cycles_in_one_log_are_found(rx130l):
    """repeat_cycles: n runs of a path with return moves and dwells; path_cycles finds the n forward
    runs (the returns go the other way) and each holds the tracker samples of its own run."""
    from rxcomm.acceptance.campaign import EvaluationSettings, TrackedLog, path_cycles
    from rxcomm.planning.iso9283 import repeat_cycles
    from rxcomm.schemas.path import PathSpec

    dt = rx130l.drives.cycle_s
    move = cycloidal_move(0.5 * rx130l.v_max, 0.5 * rx130l.a_max, dt)
    q0, q1 = np.array([0.0, -0.2, 0.5, 0.0, 0.8, 0.0]), np.array([0.6, 0.1, 0.3, 0.2, 0.6, 0.3])
    path = move(q0, q1)
    traj = repeat_cycles(path, 4, 0.3, move, dt)
    assert traj.q.shape[0] == 4 * (len(path.t) - 1) + 1 + 3 * (len(move(q1, q0).t) - 1 + 2 * 750)
    np.testing.assert_allclose(traj.q[-1], q1, atol=1e-12)
    data = rx130l.create_data()
    a, b = (frame_placement(rx130l, data, q, rx130l.tcp_frame_id).translation for q in (q0, q1))
    spec = PathSpec.model_validate(
        {
            "kind": "rxcomm/Path",
            "schema_version": 1,
            "name": "test",
            "geometry": {"type": "line", "start_m": a.tolist(), "end_m": b.tolist()},
            "orientation": {"mode": "hold", "rpy_rad": [np.pi, 0, 0]},
        }
    )
    t_tr = np.arange(0, traj.t[-1], 1e-3)
    p_tr = np.column_stack([np.interp(t_tr, traj.t, traj.q[:, i]) for i in range(3)])  # any positions
    log = TrackedLog("x", traj.t, traj.q, t_tr, p_tr, None)
    cycles = path_cycles(rx130l, log, spec, EvaluationSettings())
    assert len(cycles) == 4
    for c in cycles:
        assert len(c.position_m) == pytest.approx(path.t[-1] / 1e-3, abs=2)
        assert c.command_speed_m_per_s.max() > 0.1


def test_a_closed_paths_rounding_step_between_dwells_is_no_cycle(rx130l):
    """On a closed path (start = end, a circle) the return move is a rounding step of a setpoint or
    two between the dwells: it starts and ends at the path's ends but travels nothing, so it is not
    a cycle; the n passes are."""
    from rxcomm.acceptance.campaign import EvaluationSettings, TrackedLog, path_cycles
    from rxcomm.planning.iso9283 import repeat_cycles
    from rxcomm.schemas.path import PathSpec

    dt = rx130l.drives.cycle_s
    move = cycloidal_move(0.5 * rx130l.v_max, 0.5 * rx130l.a_max, dt)
    q0 = np.array([0.3, 0.1, 1.8, 0.0, 1.2, -2.8])
    data = rx130l.create_data()
    p0 = frame_placement(rx130l, data, q0, rx130l.tcp_frame_id).translation
    # one pass: J1 out and back (the TCP leaves the start and returns), ending 1e-12 rad off its start
    out = move(q0, q0 + np.array([0.4, 0, 0, 0, 0, 0]))
    back = move(out.q[-1], q0 + 1.2e-12)
    one = type(out)(
        np.arange(len(out.t) + len(back.t) - 1) * dt,
        np.vstack([out.q, back.q[1:]]),
        np.vstack([out.qd, back.qd[1:]]),
        np.vstack([out.qdd, back.qdd[1:]]),
    )
    traj = repeat_cycles(one, 3, 0.3, move, dt)
    spec = PathSpec.model_validate(
        {
            "kind": "rxcomm/Path",
            "schema_version": 1,
            "name": "closed",
            "geometry": {"type": "circle", "centre_m": (p0 + [0, 0, -0.1]).tolist(), "normal": [1, 0, 0],
                         "radius_m": 0.1, "start_direction": [0, 0, 1], "sweep_rad": 2 * np.pi},
            "orientation": {"mode": "hold", "rpy_rad": [np.pi, 0, 0]},
        }
    )  # fmt: skip
    t_tr = np.arange(0, traj.t[-1], 1e-3)
    p_tr = np.column_stack([np.interp(t_tr, traj.t, traj.q[:, i]) for i in range(3)])
    log = TrackedLog("x", traj.t, traj.q, t_tr, p_tr, None)
    cycles = path_cycles(rx130l, log, spec, EvaluationSettings())
    assert len(cycles) == 3
    assert all(len(c.position_m) == pytest.approx(one.t[-1] / 1e-3, abs=2) for c in cycles)


def test_settle_drift_is_the_motion_across_the_measuring_window():
    """A steady drift of d across the window reads 0.8·d (the means of its first and last fifth sit
    at 10 % and 90 % of it); tracker noise averages out; a settled arm reads ~0."""
    from rxcomm.acceptance.campaign import settle_drift_m

    n = 500
    drift = np.linspace(0.0, 0.3e-3, n)[:, None] * np.array([[0.6, 0.8, 0.0]])  # 0.3 mm along a unit vector
    assert settle_drift_m(drift) == pytest.approx(0.3e-3 * (n - n // 5) / (n - 1), rel=1e-9)  # ≈ 0.8·d
    noise = np.random.default_rng(0).normal(0.0, 50e-6, (n, 3))  # the cell's tracker σ, per axis
    assert settle_drift_m(noise + 1.0) < 20e-6  # σ of the difference of two 100-sample means: 7 µm per axis
    assert settle_drift_m(np.ones((n, 3))) == 0.0


def test_pose_dwells_are_the_still_runs_of_the_demand_long_enough():
    from rxcomm.acceptance.campaign import EvaluationSettings, TrackedLog, pose_dwells_s

    dt = 0.004
    # still 0.6 s, move 0.2 s, still 0.1 s (shorter than min_dwell_s: no dwell), move, still 1.5 s
    q = np.concatenate(
        [np.zeros(150), np.linspace(0, 1, 50), np.ones(25), np.linspace(1, 2, 50), 2 * np.ones(376)]
    )
    log = TrackedLog("x", np.arange(len(q)) * dt, q[:, None], np.zeros(2), np.zeros((2, 3)), None)
    got = pose_dwells_s(log, EvaluationSettings(min_dwell_s=0.2))
    # each linspace starts on the value held before it, so the dwells are 150 and 376 zero steps of dt
    assert got == pytest.approx([150 * dt, 376 * dt], abs=1e-9)


def test_path_cycles_are_grouped_by_command_speed_fastest_first():
    from rxcomm.acceptance.campaign import speed_groups

    # 100 %, 50 % and 10 % of 1 m/s, each cycle's plateau a little off (±2 %): three groups
    speeds = [0.5, 1.0, 0.1, 0.99, 0.51, 0.102, 1.01, 0.49]
    assert speed_groups(speeds) == [[6, 1, 3], [4, 0, 7], [5, 2]]
    assert speed_groups([0.4]) == [[0]]
    assert speed_groups([1.0, 0.94]) == [[0], [1]]  # 6 % apart: two speeds


def test_time_scaling_keeps_the_path_and_divides_speeds_by_k():
    from rxcomm.io.trajectory import Trajectory
    from rxcomm.planning.iso9283 import time_scaled

    dt = 0.001
    t = np.arange(1001) * dt  # 1 s of q = sin(π t) on one joint
    q = np.sin(np.pi * t)[:, None]
    traj = Trajectory(t, q, np.pi * np.cos(np.pi * t)[:, None], -(np.pi**2) * np.sin(np.pi * t)[:, None])
    slow = time_scaled(traj, 2.5, dt)  # k = 2.5
    assert slow.duration_s == pytest.approx(2.5) and slow.t[1] - slow.t[0] == pytest.approx(dt)
    ts = slow.t
    # linear interpolation between the 1 ms samples: error ≤ h²/8·max|q̈| = 1.2e-6 rad
    np.testing.assert_allclose(slow.q[:, 0], np.sin(np.pi * ts / 2.5), atol=1.3e-6)
    np.testing.assert_allclose(slow.qd[:, 0], np.pi / 2.5 * np.cos(np.pi * ts / 2.5), atol=1e-5)
    np.testing.assert_allclose(slow.qdd[:, 0], -(np.pi**2) / 6.25 * np.sin(np.pi * ts / 2.5), atol=1e-5)
