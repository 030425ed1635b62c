"""Foxglove's 3D view of a plan, written into the plan's own MCAP, so a plan can be previewed before it
moves anything: ``/plan/tf`` (``foxglove.FrameTransforms``: every URDF link in its parent, FK of the
planned q), ``/plan/tcp`` (``foxglove.PoseInFrame``: the planned TCP in the root link) and
``/robot_description`` (the URDF, for the 3D panel's URDF layer, source: topic), at most
``FOXGLOVE_RATE_HZ`` and the last sample. The kinematics are the robot the plan was made on (the
calibrated one under ``--calibration``). Readers of the trajectory read ``/trajectory`` only.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rxcomm.execution.frames import link_transforms, link_tree, tcp_poses, write_view
from rxcomm.io.foxglove import (
    add_frame_transforms_channel,
    add_pose_channel,
    frame_transforms_template,
    write_robot_description,
)
from rxcomm.io.mcap_io import McapWriter
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.robot import Robot
from rxcomm.schemas.run_log import FOXGLOVE_RATE_HZ, ROBOT_DESCRIPTION_TOPIC

PLAN_TF_TOPIC = "/plan/tf"
PLAN_TCP_TOPIC = "/plan/tcp"
PLAN_VIEW_TOPICS = (PLAN_TF_TOPIC, PLAN_TCP_TOPIC, ROBOT_DESCRIPTION_TOPIC)


def view_rows(t: np.ndarray) -> np.ndarray:
    """Indices of the samples drawn: the first of every 1/FOXGLOVE_RATE_HZ, and the last."""
    slot = np.floor((t - t[0]) * FOXGLOVE_RATE_HZ + 1e-9).astype(np.int64)
    first = np.flatnonzero(np.diff(slot, prepend=-1) > 0)
    return np.union1d(first, [len(t) - 1])


def plan_views(robot: Robot, urdf_text: str | None = None) -> Callable[[McapWriter, Trajectory], None]:
    """The hook `save_trajectory_mcap(views=…)` calls with its writer: writes the 3D channels."""

    def write(w: McapWriter, traj: Trajectory) -> None:
        tree = link_tree(robot)
        rows = view_rows(traj.t)
        q, t = traj.q[rows], traj.t[rows]
        add_frame_transforms_channel(w, PLAN_TF_TOPIC)
        add_pose_channel(w, PLAN_TCP_TOPIC)
        write_robot_description(w, float(traj.t[0]), urdf_text or robot.urdf_path.read_text())
        template = frame_transforms_template(list(tree.pairs))
        links, tcp = link_transforms(robot, tree, q), tcp_poses(robot, q)
        write_view(w, (PLAN_TF_TOPIC, PLAN_TCP_TOPIC), template, tree.root, t, links, tcp)

    return write
