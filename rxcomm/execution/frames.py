"""The robot's frame transforms along a run, for Foxglove's 3D panel: FK of the logged joints.

Each URDF link (and the TCP frame of drives.yaml) is given in its parent link, the tree the URDF
itself has, so Foxglove's URDF layer draws every link at its logged place. The actual robot uses the
URDF's link names; the commanded one the same tree with every frame prefixed ``demand/`` (its root at
the actual root), so a second URDF layer with that frame prefix shows it in the same 3D view.
``FoxgloveFrames`` writes these channels (and the TCP poses, the URDF) into a run log as it is recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.io.foxglove import (
    add_frame_transforms_channel,
    add_pose_channel,
    frame_transforms_json,
    frame_transforms_template,
    pose_in_frame,
    write_robot_description,
)
from rxcomm.io.mcap_io import McapWriter
from rxcomm.model.robot import Robot
from rxcomm.schemas.run_log import (
    FOXGLOVE_RATE_HZ,
    ROBOT_DESCRIPTION_TOPIC,
    TCP_DEMAND_TOPIC,
    TCP_TOPIC,
    TF_DEMAND_TOPIC,
    TF_TOPIC,
    TF_TRACKER_TOPIC,
    TRACKER_POSE_TOPIC,
    RunLogTopic,
)

DEMAND_PREFIX = "demand/"
# The per-sample views' values in fixed point: 1 µm, and 1e-6 of a quaternion component (~2 µrad),
# below anything a 3D view shows; the views then take half the bytes (docs/logs.md §2).
VIEW_DECIMALS = 6


@dataclass(frozen=True)
class CalibratedView:
    """A calibration in a run log's 3D view (run --calibration): the calibrated robot (FK of the
    frames and TCP poses), its URDF text (``/robot_description``) and the root link's pose in the
    tracker frame (``/run/tf_tracker``: the tracker frame in the tree)."""

    robot: Robot
    urdf_text: str
    tracker_to_base: pin.SE3


@dataclass(frozen=True)
class LinkTree:
    """(parent, child) frame names and Pinocchio frame ids of every link below the root and the TCP."""

    root: str
    pairs: tuple[tuple[str, str], ...]
    ids: tuple[tuple[int, int], ...]

    def prefixed(self, prefix: str) -> tuple[tuple[str, str], ...]:
        """The same tree under ``prefix`` (as a URDF layer's frame prefix names it), its root hung
        from the unprefixed root: the first pair is (root, prefix + root), at identity."""
        return ((self.root, prefix + self.root), *((prefix + a, prefix + b) for a, b in self.pairs))


def link_tree(robot: Robot) -> LinkTree:
    """The links of ``robot`` as the URDF chains them (fixed joints included) plus the TCP frame."""
    m = robot.model
    keep = [i for i, f in enumerate(m.frames) if f.type == pin.FrameType.BODY or i == robot.tcp_frame_id]

    def parent_link(i: int) -> int:
        j = m.frames[i].parentFrame
        while j > 0 and j not in keep:
            j = m.frames[j].parentFrame
        return j

    ids = [(parent_link(i), i) for i in keep if parent_link(i) > 0]
    root = next(m.frames[i].name for i in keep if parent_link(i) == 0)
    pairs = tuple((m.frames[a].name, m.frames[b].name) for a, b in ids)
    return LinkTree(root, pairs, tuple(ids))


def link_transforms(robot: Robot, tree: LinkTree, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``q`` [n, dof]: translation [n, m, 3] (m) and rotation x-y-z-w [n, m, 4] of every
    child in its parent (``tree.pairs`` order)."""
    m = robot.model
    data = robot.create_data()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, k = q.shape[0], len(tree.ids)
    trans, rot = np.zeros((n, k, 3)), np.zeros((n, k, 4))
    for r in range(n):
        pin.framesForwardKinematics(m, data, q[r])
        for c, (a, b) in enumerate(tree.ids):
            rel = data.oMf[a].actInv(data.oMf[b])
            trans[r, c] = rel.translation
            rot[r, c] = pin.Quaternion(rel.rotation).coeffs()  # x, y, z, w
    return trans, rot


def tcp_poses(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP position [n, 3] (m) and orientation x-y-z-w [n, 4] in the base (root link) frame."""
    m = robot.model
    data = robot.create_data()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    pos, rot = np.zeros((len(q), 3)), np.zeros((len(q), 4))
    for r in range(len(q)):
        pin.framesForwardKinematics(m, data, q[r])
        f = data.oMf[robot.tcp_frame_id]
        pos[r], rot[r] = f.translation, pin.Quaternion(f.rotation).coeffs()
    return pos, rot


def write_view(
    w: McapWriter,
    topics: tuple[str, str],
    template: str,
    root: str,
    t: np.ndarray,
    links: tuple[np.ndarray, np.ndarray],
    tcp: tuple[np.ndarray, np.ndarray],
    decimals: int | None = None,
) -> None:
    """One robot's 3D view at log times ``t`` (s): on ``topics[0]`` the links' FrameTransforms
    (``template`` of `frame_transforms_template` filled with ``links``, `link_transforms`), on
    ``topics[1]`` the TCP's PoseInFrame in the ``root`` link (``tcp``, `tcp_poses`)."""
    tf_topic, tcp_topic = topics
    ns = w.time_origin_ns + np.round(t * 1e9).astype(np.int64)
    for i in range(len(t)):
        stamp_ns, t_i = int(ns[i]), float(t[i])
        w.write_json(tf_topic, t_i, frame_transforms_json(template, stamp_ns, links[0][i], links[1][i]))
        w.write(tcp_topic, t_i, pose_in_frame(stamp_ns, root, tcp[0][i], tcp[1][i], decimals))


class FoxgloveFrames:
    """The 3D panel's channels of a run log: FK of every k-th sample (k: at most FOXGLOVE_RATE_HZ)."""

    def __init__(
        self,
        w: McapWriter,
        robot: Robot,
        sample_s: float,
        view: CalibratedView | None = None,
        decimals: int | None = VIEW_DECIMALS,
    ) -> None:
        """With a ``view`` (a calibration) the frames are FK of the calibrated robot, the URDF is the
        calibrated one and the ``tracker`` frame joins the tree (``/run/tf_tracker`` once).
        ``decimals``: the per-sample views' fixed point (None: every digit, the layouts before)."""
        self.w, self.robot, self.sample_s = w, robot if view is None else view.robot, sample_s
        self.decimals = decimals
        self.stride = max(1, math.ceil(1.0 / (FOXGLOVE_RATE_HZ * sample_s) - 1e-9))  # at most the rate
        self.tree = link_tree(robot)
        self.n = 0
        self.n_tracker = 0
        self.tracker_period_s: float | None = None
        self._templates: dict[str, str] = {}
        for topic in (TF_TOPIC, TF_DEMAND_TOPIC):
            add_frame_transforms_channel(w, topic)
        for topic in (TCP_TOPIC, TCP_DEMAND_TOPIC):
            add_pose_channel(w, topic)
        write_robot_description(w, 0.0, robot.urdf_path.read_text() if view is None else view.urdf_text)
        self.has_tracker_frame = view is not None
        if view is not None:
            inv = view.tracker_to_base.inverse()  # the tracker frame in the root link
            add_frame_transforms_channel(w, TF_TRACKER_TOPIC)
            text = frame_transforms_json(
                frame_transforms_template([(self.tree.root, "tracker")]),
                w.time_origin_ns,
                inv.translation[None, :],
                pin.Quaternion(inv.rotation).coeffs()[None, :],
            )
            w.write_json(TF_TRACKER_TOPIC, 0.0, text)

    def write(self, first: int, q_demand: np.ndarray, q_actual: np.ndarray) -> None:
        """Rows ``first…`` of the joint log; writes those whose index is a multiple of the stride."""
        rows = np.arange(first, first + len(q_actual))
        pick = (rows % self.stride == 0) & np.all(np.isfinite(q_actual), axis=1)
        if not pick.any():
            return
        t = rows[pick] * self.sample_s
        tree = self.tree
        demand_pairs = list(tree.prefixed(DEMAND_PREFIX))
        for q, tf_topic, tcp_topic, pairs in (
            (q_actual[pick], TF_TOPIC, TCP_TOPIC, list(tree.pairs)),
            (q_demand[pick], TF_DEMAND_TOPIC, TCP_DEMAND_TOPIC, demand_pairs),
        ):
            trans, rot = link_transforms(self.robot, tree, q)
            if tf_topic == TF_DEMAND_TOPIC:  # the prefixed root at the actual root
                trans = np.concatenate([np.zeros((len(q), 1, 3)), trans], axis=1)
                rot = np.concatenate([np.tile([0.0, 0.0, 0.0, 1.0], (len(q), 1, 1)), rot], axis=1)
            template = self._templates.setdefault(tf_topic, frame_transforms_template(pairs, self.decimals))
            tcp = tcp_poses(self.robot, q)
            write_view(
                self.w, (tf_topic, tcp_topic), template, tree.root, t, (trans, rot), tcp, self.decimals
            )
        self.n += int(pick.sum())

    def tracker(
        self, t_s: np.ndarray, position_m: np.ndarray, quaternion_wxyz: np.ndarray, rate_hz: float
    ) -> None:
        """The tracker's TCP as ``/run/tracker_pose`` (foxglove.PoseInFrame in frame ``tracker``), at
        log times ``t_s`` (s from the start, the joint log's axis): every k-th sample of a tracker
        at ``rate_hz``, at most FOXGLOVE_RATE_HZ like the other 3D channels. Once per log."""
        if self.n_tracker:
            raise ValueError("tracker poses already written")
        add_pose_channel(self.w, TRACKER_POSE_TOPIC)
        self.tracker_stride = max(1, math.ceil(rate_hz / FOXGLOVE_RATE_HZ - 1e-9))
        self.tracker_period_s = self.tracker_stride / rate_hz
        k = self.tracker_stride
        t, position_m, quaternion_wxyz = (
            np.asarray(t_s, dtype=float)[::k],
            position_m[::k],
            quaternion_wxyz[::k],
        )
        ns = self.w.time_origin_ns + np.round(t * 1e9).astype(np.int64)
        xyzw = np.asarray(quaternion_wxyz, dtype=float)[:, [1, 2, 3, 0]]
        for i in range(len(t)):
            self.w.write(
                TRACKER_POSE_TOPIC, t[i], pose_in_frame(int(ns[i]), "tracker", position_m[i], xyzw[i])
            )
        self.n_tracker = len(t)

    def topics(self) -> list[RunLogTopic]:
        period = self.stride * self.sample_s
        tf = {"transforms": "foxglove.FrameTransform per link in its parent link (m, quaternion x-y-z-w)"}
        tcp = {"pose": f"TCP pose in {self.tree.root} (m, quaternion x-y-z-w)"}
        return (
            [
                RunLogTopic(topic=TF_TOPIC, period_s=period, n_messages=self.n, fields=tf),
                RunLogTopic(topic=TF_DEMAND_TOPIC, period_s=period, n_messages=self.n, fields=tf),
                RunLogTopic(topic=TCP_TOPIC, period_s=period, n_messages=self.n, fields=tcp),
                RunLogTopic(topic=TCP_DEMAND_TOPIC, period_s=period, n_messages=self.n, fields=tcp),
                RunLogTopic(
                    topic=ROBOT_DESCRIPTION_TOPIC,
                    period_s=None,
                    n_messages=1,
                    fields={"data": "the URDF (XML)"},
                ),
            ]
            + (
                [
                    RunLogTopic(
                        topic=TF_TRACKER_TOPIC,
                        period_s=None,
                        n_messages=1,
                        fields={
                            "transforms": f"the tracker frame in {self.tree.root} (m, quaternion x-y-z-w)"
                        },
                    )
                ]
                if self.has_tracker_frame
                else []
            )
            + (
                [
                    RunLogTopic(
                        topic=TRACKER_POSE_TOPIC,
                        period_s=self.tracker_period_s,
                        n_messages=self.n_tracker,
                        fields={"pose": "the tracker's TCP pose in frame tracker (m, quaternion x-y-z-w)"},
                    )
                ]
                if self.n_tracker
                else []
            )
        )
