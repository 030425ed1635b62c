"""ISO 9283 row (issue 17): every criterion of a full test campaign — 30 pose cycles through P1–P5 and
10 cycles of each of the 4 test paths with the tracker at 1 kHz — from tracker data in memory (the
logs' reading is the run log reader's, benchmarked with it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.table import Row, median_seconds
from rxcomm.acceptance.campaign import EvaluationSettings, TrackedLog, path_entries, pose_entries
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.model.kinematics import frame_placement
from rxcomm.model.robot import load_robot
from rxcomm.planning.iso9283 import (
    cube_from_rectangle,
    cycloidal_move,
    pose_cycle_joints,
    pose_cycle_trajectory,
)
from rxcomm.planning.paths import build_curve, rpy_matrix
from rxcomm.schemas.path import PathSpec

ROBOT = Path(__file__).resolve().parent.parent / "samples" / "rx130l"
RATE_HZ = 1000.0


def campaign(n_pose_cycles: int, n_path_cycles: int):
    robot = load_robot(ROBOT)
    specs = {p.stem: read_yaml_model(p, PathSpec) for p in sorted((ROBOT / "paths").glob("iso9283-*.yaml"))}
    rect = specs["iso9283-rectangle"]
    cube = cube_from_rectangle(rect)
    joints = pose_cycle_joints(robot, cube, rect.branch)
    dt = robot.drives.cycle_s
    traj, _ = pose_cycle_trajectory(
        joints, n_pose_cycles, 0.5, cycloidal_move(0.5 * robot.v_max, 0.5 * robot.a_max, dt), dt
    )
    rng = np.random.default_rng(0)
    data = robot.create_data()
    t = np.arange(0, traj.t[-1], 1 / RATE_HZ)
    knots = traj.t[:: int(0.05 / dt)]  # FK every 50 ms, the tracker's path interpolated between
    p_knots = np.array(
        [frame_placement(robot, data, q, robot.tcp_frame_id).translation for q in traj.q[:: int(0.05 / dt)]]
    )
    pos = np.column_stack([np.interp(t, knots, p_knots[:, i]) for i in range(3)])
    rot = np.tile(rpy_matrix(cube.rpy_rad), (len(t), 1, 1))
    poses = TrackedLog("poses", traj.t, traj.q, t, pos + rng.normal(0, 5e-5, pos.shape), rot)
    paths = {}
    for name, spec in specs.items():
        curve = build_curve(spec.geometry)
        duration = curve.length_m / 1.0  # 1 m/s
        tj = np.arange(0, duration, dt)
        s = tj / duration * curve.length_m
        q_a, q_b = joints["P2"], joints["P4"]
        q = q_a + np.outer(s / curve.length_m, q_b - q_a)
        tt = np.arange(0, duration, 1 / RATE_HZ)
        p = curve.eval(tt / duration * curve.length_m, 0)
        paths[name] = [
            TrackedLog(name, tj, q, tt, p + rng.normal(0, 5e-5, p.shape), None) for _ in range(n_path_cycles)
        ]
    return robot, cube, specs, poses, paths


def rows(quick: bool) -> list[Row]:
    robot, cube, specs, poses, paths = campaign(30, 10)
    s = EvaluationSettings(match_m=10.0)  # the synthetic joint motion is not the path: every move is a cycle
    rot_cmd = rpy_matrix(cube.rpy_rad)

    def every_criterion() -> None:
        pose_entries(robot, [poses], cube.points_m, rot_cmd, s)
        for name, logs in paths.items():
            path_entries(robot, name, specs[name], logs, s)

    wall = median_seconds(every_criterion, repeats=3 if quick else 5)
    return [
        Row(
            "iso9283",
            "ISO 9283 criteria from a full campaign (30 pose + 4×10 path cycles, 1 kHz)",
            "s",
            wall,
            target="≤ 1 s",
        )
    ]
