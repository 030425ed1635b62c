"""The calibration workspace: which joint configurations the cell allows, and the candidate grid
streamed from them (paper §3.3, step 1 of `rxcomm.calibration.pose_selection`).

A joint grid (default 13 equal intervals per axis, their midpoints: 13⁶ ≈ 4.8 M configurations) is
streamed in blocks with bounded memory: FK is split into the arm (q1..q3, one 4×4 per grid point of the
first three axes) and the wrist (q4..q6, relative 4×4s computed once), so a block costs one batched
product. Each configuration is checked against the cell (`feasibility` gives the same checks for
arbitrary poses): TCP, wrist centre and elbow in the workspace box and above the floor; TCP and wrist
centre clear of the base capsule and the TCP clear of the upper-arm capsule; the probe visible to the
tracker (range, view cone, probe facing the tracker, both narrowed by `visibility_margin_rad`). The
feasible ones are sub-sampled on the fly to `max_candidates` by priority sampling (a uniform random
subset, as a reservoir), then sorted in grid order.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.model.geometric_errors import (
    _chain,
    _joint_axes,
    _rodrigues,
    placement_to_se3,
)
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import Cell

Progress = Callable[[int, int], None]


REASONS = (
    "ok",
    "workspace",
    "self_collision",
    "tracker_range",
    "tracker_cone",
    "probe_facing",
    "joint_limits",
)


def _seg_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points p [..., 3] to segments a–b [..., 3] (broadcast)."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


@dataclass(frozen=True)
class _CellGeometry:
    box_lo: np.ndarray
    box_hi: np.ndarray
    floor_min_z: float
    base_clear: float
    arm_clear: float
    r_tb: np.ndarray  # tracker_to_base rotation
    t_tb: np.ndarray
    view_axis: np.ndarray  # unit, tracker frame
    cos_cone: float
    range_min: float
    range_max: float
    probe_axis: np.ndarray  # unit, TCP frame
    cos_probe: float

    @classmethod
    def from_cell(cls, cell: Cell) -> _CellGeometry:
        ws, sc, tr = cell.workspace, cell.self_collision, cell.tracker
        t2b = placement_to_se3(tr.tracker_to_base.xyz_m, tr.tracker_to_base.rpy_rad)
        view = np.array(tr.view_axis_in_tracker, dtype=float)
        probe = np.array(tr.probe_axis_in_tcp, dtype=float)
        return cls(
            box_lo=np.array(ws.box.min_m),
            box_hi=np.array(ws.box.max_m),
            floor_min_z=ws.floor_z_m + ws.floor_clearance_m,
            base_clear=sc.base_radius_m + sc.margin_m,
            arm_clear=sc.upper_arm_radius_m + sc.margin_m,
            r_tb=t2b.rotation.copy(),
            t_tb=t2b.translation.copy(),
            view_axis=view / np.linalg.norm(view),
            cos_cone=math.cos(tr.half_angle_rad - tr.visibility_margin_rad),
            range_min=tr.range_min_m,
            range_max=tr.range_max_m,
            probe_axis=probe / np.linalg.norm(probe),
            cos_probe=math.cos(tr.probe_half_angle_rad - tr.visibility_margin_rad),
        )

    def inside(self, p: np.ndarray) -> np.ndarray:
        return np.all((p >= self.box_lo) & (p <= self.box_hi), axis=-1) & (p[..., 2] >= self.floor_min_z)

    def check(
        self,
        tcp: np.ndarray,
        probe_world: np.ndarray,
        wrist: np.ndarray,
        elbow: np.ndarray,
        shoulder: np.ndarray,
    ) -> np.ndarray:
        """Reason code per configuration (index into REASONS; 0 = feasible). Arrays broadcast."""
        shape = np.broadcast_shapes(tcp.shape[:-1], wrist.shape[:-1], elbow.shape[:-1])
        code = np.zeros(shape, dtype=np.int8)

        def mark(bad: np.ndarray, reason: int) -> None:
            code[(code == 0) & np.broadcast_to(bad, shape)] = reason

        mark(~(self.inside(tcp) & self.inside(wrist) & self.inside(elbow)), 1)
        origin = np.zeros(3)
        near_base = (_seg_dist(tcp, origin, shoulder) < self.base_clear) | (
            _seg_dist(wrist, origin, shoulder) < self.base_clear
        )
        mark(near_base | (_seg_dist(tcp, shoulder, elbow) < self.arm_clear), 2)
        p_t = tcp @ self.r_tb.T + self.t_tb  # TCP in the tracker frame
        dist = np.linalg.norm(p_t, axis=-1)
        mark((dist < self.range_min) | (dist > self.range_max), 3)
        mark(p_t @ self.view_axis < self.cos_cone * dist, 4)
        facing = -np.sum((probe_world @ self.r_tb.T) * p_t, axis=-1)
        mark(facing < self.cos_probe * dist, 5)
        return code


def feasibility(robot: Robot, cell: Cell, qs: np.ndarray) -> np.ndarray:
    """Reason code per pose [N] (0 feasible; see REASONS) for arbitrary joint vectors [N, 6]."""
    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    geo = _CellGeometry.from_cell(cell)
    ch = _chain(robot, qs, None, None)
    origin = ch.joint_frames[..., :3, 3]  # joint j's origin (its rotation does not move it)
    probe = ch.tcp[:, :3, :3] @ geo.probe_axis
    wrist, elbow, shoulder = (
        origin[:, j - 1] for j in (robot.wrist_joint_id, robot.elbow_joint_id, robot.shoulder_joint_id)
    )
    code = geo.check(ch.tcp[:, :3, 3], probe, wrist, elbow, shoulder)
    outside = np.any((qs < robot.q_min - 1e-12) | (qs > robot.q_max + 1e-12), axis=1)
    code[outside] = REASONS.index("joint_limits")
    return code


def grid_axes(robot: Robot, intervals: int | tuple[int, ...]) -> list[np.ndarray]:
    """Midpoints of `intervals` equal intervals of each joint's range (per joint if a tuple)."""
    counts = (intervals,) * robot.n if isinstance(intervals, int) else tuple(intervals)
    if len(counts) != robot.n or any(c < 1 for c in counts):
        raise InputError(f"grid intervals must be {robot.n} positive counts, got {counts}", field="intervals")
    return [
        lo + (np.arange(c) + 0.5) * (hi - lo) / c
        for lo, hi, c in zip(robot.q_min, robot.q_max, counts, strict=True)
    ]


@dataclass(frozen=True)
class CandidateSet:
    q: np.ndarray  # [N, 6], grid order
    grid_index: np.ndarray  # [N] flat index into the grid (C order over `axes`)
    axes: tuple[np.ndarray, ...]  # the grid values of each joint
    feasible: np.ndarray  # [n_grid] bool: the configuration passed the cell checks
    n_grid: int
    n_feasible: int
    rejected: dict[str, int]
    seconds: float


def _hom(m: pin.SE3) -> np.ndarray:
    return np.asarray(m.homogeneous, dtype=float)


def _rot4(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    r = np.zeros((len(angles), 4, 4))
    r[:, :3, :3] = _rodrigues(axis, angles)
    r[:, 3, 3] = 1.0
    return r


def stream_candidates(
    robot: Robot,
    cell: Cell,
    intervals: int | tuple[int, ...] = 13,
    max_candidates: int | None = 4000,
    seed: int = 0,
    progress: Progress | None = None,
    block: int = 24,
) -> CandidateSet:
    """Stream the joint grid through the cell checks; keep a seeded uniform subset of the feasible.

    Memory is O(block · |wrist grid| + max_candidates) plus one byte per grid configuration (the
    feasibility mask `linear_scan` reads: 4.8 MB at 13⁶). `max_candidates=None` keeps every
    feasible configuration (memory then grows with their number).
    """
    t0 = time.perf_counter()
    if robot.n != 6:
        raise InputError(f"pose selection handles 6-axis arms, this one has {robot.n}", field="joint")
    axes_q = grid_axes(robot, intervals)
    geo = _CellGeometry.from_cell(cell)
    model = robot.model
    ax = _joint_axes(robot)
    m = [_hom(model.jointPlacements[j]) for j in range(1, 7)]
    f_tcp = _hom(model.frames[robot.tcp_frame_id].placement)
    # Arm: all (q1, q2, q3) grid points.
    g1, g2, g3 = np.meshgrid(axes_q[0], axes_q[1], axes_q[2], indexing="ij")
    g1, g2, g3 = g1.ravel(), g2.ravel(), g3.ravel()
    t1 = m[0] @ _rot4(ax[0], g1)
    b2 = t1 @ m[1]
    t2 = b2 @ _rot4(ax[1], g2)
    b3 = t2 @ m[2]
    t3 = b3 @ _rot4(ax[2], g3)
    shoulder, elbow = b2[:, :3, 3], b3[:, :3, 3]
    # Wrist: all (q4, q5, q6) relative to frame 3.
    h4, h5, h6 = np.meshgrid(axes_q[3], axes_q[4], axes_q[5], indexing="ij")
    h4, h5, h6 = h4.ravel(), h5.ravel(), h6.ravel()
    w4 = m[3] @ _rot4(ax[3], h4)
    b5 = w4 @ m[4]
    w = b5 @ _rot4(ax[4], h5) @ m[5] @ _rot4(ax[5], h6) @ f_tcp
    wrist_rel = b5[:, :3, 3]  # wrist centre (joint-5 origin) in frame 3
    w_pos = w[:, :3, 3]
    w_probe = w[:, :3, :3] @ geo.probe_axis
    n_arm, n_wrist = len(g1), len(h4)
    rng = np.random.default_rng(seed)
    keep_key = np.empty(0)
    keep_idx = np.empty(0, dtype=np.int64)
    counts = np.zeros(len(REASONS), dtype=np.int64)
    feasible = np.zeros(n_arm * n_wrist, dtype=bool)
    elbow_ok = geo.inside(elbow)
    for start in range(0, n_arm, block):
        sl = slice(start, min(start + block, n_arm))
        r3, p3 = t3[sl, :3, :3], t3[sl, :3, 3]
        tcp = np.einsum("bij,wj->bwi", r3, w_pos) + p3[:, None]
        probe = np.einsum("bij,wj->bwi", r3, w_probe)
        wrist = np.einsum("bij,wj->bwi", r3, wrist_rel) + p3[:, None]
        code = geo.check(tcp, probe, wrist, elbow[sl, None], shoulder[sl, None])
        code[~elbow_ok[sl]] = 1
        counts += np.bincount(code.ravel(), minlength=len(REASONS))
        feasible[sl.start * n_wrist : sl.stop * n_wrist] = code.ravel() == 0
        ok = np.flatnonzero(code.ravel() == 0)
        if ok.size:
            flat = np.int64(start) * n_wrist + ok
            keys = rng.random(ok.size)
            keep_key = np.concatenate([keep_key, keys])
            keep_idx = np.concatenate([keep_idx, flat])
            if max_candidates is not None and keep_key.size > max_candidates:
                sel = np.argpartition(keep_key, max_candidates - 1)[:max_candidates]
                keep_key, keep_idx = keep_key[sel], keep_idx[sel]
        if progress is not None:
            progress(min(start + block, n_arm) * n_wrist, n_arm * n_wrist)
    keep_idx = np.sort(keep_idx)
    arm_i, wrist_i = np.divmod(keep_idx, n_wrist)
    q = np.column_stack([g1[arm_i], g2[arm_i], g3[arm_i], h4[wrist_i], h5[wrist_i], h6[wrist_i]])
    return CandidateSet(
        q=q,
        grid_index=keep_idx,
        axes=tuple(axes_q),
        feasible=feasible,
        n_grid=n_arm * n_wrist,
        n_feasible=int(counts[0]),
        rejected={REASONS[i]: int(counts[i]) for i in range(1, len(REASONS))},
        seconds=time.perf_counter() - t0,
    )
