"""Shared helpers of the tests that plan and run trajectories (test_run.py and the modules that stream,
export or measure a run): the rest-to-rest cosine plan, saving it as a trajectory artefact, a pose list,
starting a protocol test double cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rxcomm.cell.backend import IdealBackend
from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
from rxcomm.io.trajectory import Trajectory, save_trajectory_mcap
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.schemas.configs import ConfigPose, Configs
from rxcomm.schemas.trajectory import TrajectorySummary

from .conftest import SAMPLES

ROBOT_DIR = SAMPLES / "rx130l"
Q0 = np.array([0.1, -0.4, 1.0, 0.0, 0.6, -0.2])
DQ = np.array([0.4, 0.3, -0.3, 0.6, -0.4, 0.8])
CYCLE = 400e-6


def cosine_plan(q0: np.ndarray, dq: np.ndarray, duration_s: float, dt: float = CYCLE) -> Trajectory:
    """Rest-to-rest q0 → q0 + dq with a (1 − cos) profile."""
    t = np.arange(int(round(duration_s / dt)) + 1) * dt
    w = np.pi / duration_s
    s, sd, sdd = 0.5 - 0.5 * np.cos(w * t), 0.5 * w * np.sin(w * t), 0.5 * w * w * np.cos(w * t)
    return Trajectory(t, q0 + np.outer(s, dq), np.outer(sd, dq), np.outer(sdd, dq))


def save_plan(path: Path, traj: Trajectory) -> Path:
    summary = {
        "duration_s": traj.duration_s,
        "solve_seconds": 0.0,
        "max_limit_ratio": 0.5,
        "active_fraction": 0.0,
        "q_start": traj.q[0].tolist(),
        "q_goal": traj.q[-1].tolist(),
    }
    save_trajectory_mcap(path, traj, TrajectorySummary.envelope({}, {"timing": "test"}, summary))
    return path


def start_cell(rx130l, backend=None, mode: TimeMode = TimeMode.VIRTUAL) -> CellServer:
    backend = backend or IdealBackend(Q0, rated_torque_nm=np.asarray(rx130l.tau_max))
    return CellServer(backend, ServerConfig(time_mode=mode)).start()


def gw(srv: CellServer) -> str:
    return f"127.0.0.1:{srv.port}"


def write_configs(path: Path, robot, poses: list[np.ndarray], roles: list[str]) -> Path:
    summary = {
        "n_candidates": 10,
        "n_selected": len(poses),
        "observation_index": 1.0,
        "baseline_observation_index": 1.0,
        "improvement_ratio": 1.0,
        "seconds": 0.0,
    }
    # a hand-made pose list: what select-configs would have recorded for it
    settings = dict(n=len(poses), intervals=1, max_candidates=0, criterion="min-eig", restarts=0)
    settings |= dict(n_validation=0, seed=0, measure_baseline=False)
    cfg = Configs(
        **Configs.envelope({}, settings, summary),
        robot=robot.name,
        joint_names=list(robot.joint_names),
        criterion="min-eig",
        measurement="pose",
        characteristic_length_m=1.0,
        identifiable=[],
        poses=[ConfigPose(q_rad=p.tolist(), role=r) for p, r in zip(poses, roles, strict=True)],
        baseline_poses_rad=[],
        baseline_centre_rad=[],
        evenly_spaced_poses_rad=[],
    )
    write_yaml_artefact(path, cfg)
    return path
