"""Optimal measurement poses for geometric calibration (paper §3.3; DESIGN §7 select-configs).

1. **Candidates.** A joint grid (default 13 equal intervals per axis, their midpoints: 13⁶ ≈ 4.8 M
   configurations) is streamed in blocks with bounded memory: FK is split into the arm (q1..q3, one
   4×4 per grid point of the first three axes) and the wrist (q4..q6, relative 4×4s computed once),
   so a block of configurations costs one batched product. Each configuration is checked against
   the cell (`feasibility` gives the same checks for arbitrary poses): TCP, wrist centre and elbow
   in the workspace box and above the floor; TCP and wrist centre clear of the base capsule and the
   TCP clear of the upper-arm capsule (`schemas.cell.SelfCollision`); the probe visible to the
   tracker (range, view cone, probe facing the tracker; both cones narrowed by the cell's
   `visibility_margin_rad` so that the real robot's errors keep the chosen poses in view). The
   feasible ones are sub-sampled on the fly to `max_candidates` by priority sampling (the k smallest
   of a seeded uniform key per candidate, i.e. a uniform random subset, as a reservoir), then sorted
   in grid order.

   About q6: with the TCP on the flange axis (RX130L) q6 does not move the TCP, only turns the probe
   about it; it matters for full-pose measurement (it excites the tool/joint-6 orientation terms)
   and for the visibility only if the probe axis is off the flange axis. So it stays in the grid;
   with `position` measurement of an on-axis TCP use `intervals` with 1 for q6.

2. **Observation index.** Per candidate the identification Jacobian over the identifiable
   parameters (nominal model), scaled Θ̃ = W·Θ·S·T. Rows W: position in m, orientation in rad × σ_p/σ_o
   (the tracker's noise ratio from `cell.yaml`), so Λ = Σ Θ̃ᵢᵀΘ̃ᵢ over the chosen poses is the fit's
   Fisher information up to σ_p². Columns S·T: translations m, rotations rad × L, then whitened by the
   candidates' mean information (TᵀF̄T = I, F̄ = mean ΘᵢᵀΘᵢ), so Λ is counted in "average candidate
   poses": a set of n poses as informative as the average candidate in every direction has Λ = n·I,
   and the index does not depend on the tracker frame, on unit choices or on how the parameters are
   scaled. Criteria (all maximised): `det-root` det(Λ)^(1/p) (the default), `min-eig`
   B = λ_min(Λ) = σ_min(ΘᵀΘ) (the paper's), `cond` reported as cond(Λ) = λ_max/λ_min (minimised).

   Why det-root is the default: what the user gets from the poses is the prediction error after
   calibration, σ_p²·trace(Θ_c Λ⁻¹ Θ_cᵀ) at a pose c. With 6-D measurements and 32 poses for 30
   parameters every diverse set is within ~10 % of the best possible (I-optimal) set; maximising
   λ_min alone pushes the one weakest combination (J5 offset vs J6 misalignment) at the expense of
   the others (in a plain metre scaling its sets predicted worse than evenly spaced candidates);
   det-root predicts best (see `expected_errors`, reported for the chosen set and both baselines).

3. **Exchange algorithm** (paper steps 1–4). Random nonsingular start of `n_start` poses; remove-and-
   replace while it improves; add the best pose until `n`; final remove-and-replace; `restarts`
   times with a seeded generator, keeping the best. Each move changes Λ by ±Θ̃ᵢᵀΘ̃ᵢ (rank ≤ 6, a sum
   of rank-one updates), so Λ is never rebuilt. The search over all candidates for the best addition
   costs one batched product: in Λ's eigenbasis a second-order perturbation estimate of the new
   λ_min (weakest direction's gain minus its coupling to the others) ranks every candidate, and the
   best `n_exact` (32) by that estimate are evaluated exactly (30×30 eigenvalues); the exact best of
   those is taken (tests check it equals the brute-force best). For `det-root` the matrix
   determinant lemma gives a candidate's exact value from a 6×6 determinant, and the trace of that
   6×6 bounds it from both sides, so only the few candidates whose bound can still win are evaluated.
   Removal is evaluated exactly for every chosen pose.

   Cost (RX130L, 4,000 candidates, 30 parameters, one BLAS thread): ≈0.1 s per restart (det-root),
   ≈0.25 s (min-eig).

4. **Baselines.** The naive baseline is the paper's "linear scan of the workspace" (`linear_scan`):
   from one centre configuration each joint is swept alone along its grid line, as many poses as
   the selection, spread evenly over the sweeps; the centre is the candidate with the widest
   feasible sweeps, so it is the best such scan. Beside it, as many evenly spaced candidates in
   grid order (`evenly_spaced`): not a naive set at all, since a stride through a uniform random
   subset of the grid is as diverse as a random draw. RX130L at the defaults, expected rms position
   error after calibration: selected 0.039 mm, evenly spaced candidates 0.042 mm (within the
   spread of one campaign), linear scan 0.16 mm.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import pinocchio as pin

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.geometric_errors import (
    IdentifiableSet,
    _chain,
    _joint_axes,
    _rodrigues,
    characteristic_length_m,
    identifiable_parameters,
    identification_jacobians,
    measurement_scaling,
    placement_to_se3,
    random_poses,
)
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import Cell

Progress = Callable[[int, int], None]


class Criterion(StrEnum):
    MIN_EIG = "min-eig"
    DET_ROOT = "det-root"
    COND = "cond"


# ---------------------------------------------------------------------------------------------------
# Cell checks (shared by the grid stream and arbitrary poses)

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


# ---------------------------------------------------------------------------------------------------
# The candidate grid, streamed


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


# ---------------------------------------------------------------------------------------------------
# Information blocks and the observation index


def information_blocks(
    robot: Robot,
    qs: np.ndarray,
    ident: IdentifiableSet,
    position_only: bool = False,
    point: np.ndarray | None = None,
    orientation_weight_m: float | None = None,
) -> np.ndarray:
    """Θ̃ per pose, [N, rows, p]: the scaled identification Jacobian over the identifiable parameters.

    Rows: position (first 3) in m, orientation in rad × `orientation_weight_m` (default L; the
    tracker's σ_p/σ_o makes Λ the fit's Fisher information up to σ_p²). Columns: translations m,
    rotations rad × L.
    """
    jac = identification_jacobians(robot, qs, None, None, position_only, point)
    row_w, col_s = measurement_scaling(robot, position_only)
    if orientation_weight_m is not None and not position_only:
        row_w = np.array([1.0, 1.0, 1.0] + [orientation_weight_m] * 3)
    idx = list(ident.indices)
    return jac[:, :, idx] * row_w[None, :, None] * col_s[idx][None, None, :]


def normalise_to_candidates(blocks: np.ndarray, n_candidates: int | None = None) -> np.ndarray:
    """Blocks in parameter coordinates where the mean candidate's information is the identity.

    Θ̃ → Θ̃·T with TᵀF̄T = I, F̄ = mean Θ̃ᵢᵀΘ̃ᵢ over the first `n_candidates` blocks (default all; any
    further blocks are other poses, e.g. a baseline, put in the same coordinates): Λ of a set is then
    counted in average candidate poses, and `min-eig`/`cond` no longer depend on how the parameters
    are scaled (det-root changes by a constant factor only). Raises InfeasibleError when the
    candidates cannot identify the set.
    """
    cand = blocks[:n_candidates]
    mean_info = np.einsum("nri,nrj->ij", cand, cand) / cand.shape[0]
    d, v = np.linalg.eigh(mean_info)
    if d[0] <= 1e-12 * d[-1]:
        raise InfeasibleError(
            f"the {cand.shape[0]} candidates leave a parameter combination unobservable "
            f"(λ_min/λ_max of their mean information {d[0] / d[-1]:.1e}): widen the grid or the cell"
        )
    return blocks @ (v / np.sqrt(d))


def expected_errors(
    chosen: np.ndarray, targets: np.ndarray, position_sigma_m: float, orientation_weight_m: float | None
) -> tuple[float, float | None]:
    """Expected rms (position m, orientation rad) prediction error over the `targets` poses (blocks,
    e.g. all candidates) after a fit to the `chosen` poses' blocks: σ_p·sqrt(mean_c trace(Θ̃_c Λ⁻¹
    Θ̃_cᵀ)) for the position rows, the orientation rows divided by their weight. Needs blocks with
    Fisher row weights (orientation σ_p/σ_o)."""
    lam = np.einsum("nri,nrj->ij", chosen, chosen)
    ev = np.linalg.eigvalsh(lam)
    if ev[0] <= 1e-12 * ev[-1]:
        return math.inf, (math.inf if orientation_weight_m else None)
    inv = np.linalg.inv(lam)

    def rms(rows: np.ndarray) -> float:
        mean_info = np.einsum("nri,nrj->ij", rows, rows) / rows.shape[0]
        return math.sqrt(max(float(np.trace(mean_info @ inv)), 0.0))

    pos = position_sigma_m * rms(targets[:, :3])
    if targets.shape[1] == 3 or not orientation_weight_m:
        return pos, None
    return pos, position_sigma_m * rms(targets[:, 3:]) / orientation_weight_m


def selection_blocks(
    robot: Robot,
    cell: Cell,
    qs: np.ndarray,
    ident: IdentifiableSet,
    point: np.ndarray | None = None,
    n_candidates: int | None = None,
) -> tuple[np.ndarray, float]:
    """(blocks, orientation row weight): the Fisher-weighted, candidate-whitened Θ̃ that selection
    and `expected_errors` use (module docstring, 2.); the first `n_candidates` poses (default all)
    are the candidates that define the whitening."""
    tracker = cell.tracker
    weight = tracker.position_sigma_m / tracker.orientation_sigma_rad
    position_only = tracker.measures == "position"
    raw = information_blocks(robot, qs, ident, position_only, point, weight)
    return normalise_to_candidates(raw, n_candidates), weight


def _score(lam: np.ndarray, criterion: Criterion) -> np.ndarray:
    """Criterion value to MAXIMISE for [..., p, p] information matrices."""
    if criterion is Criterion.DET_ROOT:
        sign, logdet = np.linalg.slogdet(lam)
        return np.where(sign > 0, np.exp(logdet / lam.shape[-1]), 0.0)
    ev = np.linalg.eigvalsh(lam)
    if criterion is Criterion.MIN_EIG:
        return np.maximum(ev[..., 0], 0.0)
    return np.maximum(ev[..., 0], 0.0) / ev[..., -1]


def observation_index(blocks: np.ndarray, criterion: Criterion | str = Criterion.DET_ROOT) -> float:
    """The index of a pose set given its blocks [n, rows, p] (cond reported as λ_max/λ_min)."""
    criterion = Criterion(criterion)
    lam = np.einsum("nri,nrj->ij", blocks, blocks)
    s = float(_score(lam, criterion))
    if criterion is Criterion.COND:
        return math.inf if s <= 0 else 1.0 / s
    return s


@dataclass
class _Search:
    """Exchange-algorithm state over a fixed candidate set (blocks [N, r, p])."""

    blocks: np.ndarray
    criterion: Criterion
    n_exact: int = 32
    evaluations: int = field(default=0)

    def _estimate(self, a: np.ndarray, d: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Second-order perturbation estimate of the criterion after adding each candidate.

        In Λ's eigenbasis (B = A·V, G = BᵀB): λ_min ≈ d₀ + G₀₀ − Σⱼ G₀ⱼ² / (dⱼ + Gⱼⱼ − d₀ − G₀₀), the
        last term the coupling to the other directions; λ_max likewise (for `cond`).
        """
        b = a @ v  # [N, r, p]
        g_diag = np.einsum("nrj,nrj->nj", b, b)
        lo = d[0] + g_diag[:, 0]
        c0 = np.einsum("nr,nrj->nj", b[:, :, 0], b[:, :, 1:])
        gap = np.maximum(d[1:] + g_diag[:, 1:] - lo[:, None], 1e-12 * max(d[-1], 1e-300))
        lo = lo - np.sum(c0**2 / gap, axis=1)
        if self.criterion is Criterion.COND:
            hi = d[-1] + g_diag[:, -1]
            return np.maximum(lo, 0.0) / hi
        return lo

    def gram(self, i: int | np.ndarray) -> np.ndarray:
        a = self.blocks[i]
        return np.einsum("...ri,...rj->...ij", a, a)

    def best_add(self, lam: np.ndarray, exclude: np.ndarray) -> tuple[int, float]:
        """argmax over candidates not excluded of score(Λ + Θ̃ᵢᵀΘ̃ᵢ), exact (branch and bound)."""
        a = self.blocks
        allowed = ~exclude
        if self.criterion is Criterion.DET_ROOT:
            sign, logdet = np.linalg.slogdet(lam)
            if sign <= 0:
                lam = lam + np.eye(lam.shape[0]) * 1e-12 * np.trace(lam)
                sign, logdet = np.linalg.slogdet(lam)
            # det(Λ + AᵀA) = det Λ · det(I + X), X = A Λ⁻¹ Aᵀ = WWᵀ (W = A L⁻ᵀ, Λ = LLᵀ): a 6×6 per
            # candidate. Branch and bound on t = tr X = ‖W‖²: 1 + t ≤ det(I + X) ≤ (1 + t/r)^r, so
            # candidates are evaluated exactly in order of t until no bound can beat the best.
            n_cand, r, p = a.shape
            w = (a.reshape(-1, p) @ np.linalg.inv(np.linalg.cholesky(lam)).T).reshape(n_cand, r, p)
            t = np.einsum("nrp,nrp->n", w, w)
            t[~allowed] = -np.inf
            order = np.argsort(-t)
            order = order[np.isfinite(t[order])]
            best_i, best_ld = -1, -np.inf
            for start in range(0, order.size, self.n_exact):
                chunk = order[start : start + self.n_exact]
                if r * math.log1p(t[chunk[0]] / r) <= best_ld:
                    break
                wc = w[chunk]
                _, ld = np.linalg.slogdet(np.eye(r) + wc @ wc.transpose(0, 2, 1))
                self.evaluations += chunk.size
                j = int(np.argmax(ld))
                if ld[j] > best_ld:
                    best_i, best_ld = int(chunk[j]), float(ld[j])
            if best_i < 0:
                return -1, -np.inf
            return best_i, float(np.exp((logdet + best_ld) / p))
        d, v = np.linalg.eigh(lam)
        est = self._estimate(a, d, v)
        est[~allowed] = -np.inf
        top = np.argsort(-est)[: self.n_exact]
        top = top[np.isfinite(est[top])]
        if top.size == 0:
            return -1, -np.inf
        vals = _score(lam + self.gram(top), self.criterion)
        self.evaluations += top.size
        j = int(np.argmax(vals))
        best_i, best_v = int(top[j]), float(vals[j])
        return best_i, best_v

    def best_remove(self, lam: np.ndarray, chosen: list[int]) -> tuple[int, float]:
        """Position in `chosen` whose removal keeps the score highest, and that score."""
        vals = _score(lam[None] - self.gram(np.array(chosen)), self.criterion)
        self.evaluations += len(chosen)
        j = int(np.argmax(vals))
        return j, float(vals[j])


def _exchange(
    search: _Search, chosen: list[int], lam: np.ndarray, max_moves: int
) -> tuple[list[int], np.ndarray, int]:
    """Remove-and-replace while it improves (paper steps 2 and 4). Returns (chosen, Λ, moves)."""
    n_cand = search.blocks.shape[0]
    score = float(_score(lam, search.criterion))
    moves = 0
    while moves < max_moves:
        j, _ = search.best_remove(lam, chosen)
        out = chosen[j]
        lam_minus = lam - search.gram(out)
        exclude = np.zeros(n_cand, dtype=bool)
        exclude[chosen] = True
        exclude[out] = False
        i, val = search.best_add(lam_minus, exclude)
        if i < 0 or i == out or val <= score * (1 + 1e-9):
            break
        chosen = chosen[:j] + chosen[j + 1 :] + [i]
        lam = lam_minus + search.gram(i)
        score = val
        moves += 1
    return chosen, lam, moves


@dataclass(frozen=True)
class SelectionResult:
    indices: np.ndarray  # into the candidate blocks, in the order chosen
    observation_index: float  # as reported (cond: λ_max/λ_min)
    score: float  # maximised value
    restart_indices: tuple[float, ...]  # the index each restart reached
    moves: int
    evaluations: int
    seconds: float


def select_poses(
    blocks: np.ndarray,
    n: int,
    criterion: Criterion | str = Criterion.DET_ROOT,
    restarts: int = 5,
    seed: int = 0,
    n_start: int | None = None,
) -> SelectionResult:
    """The paper's exchange algorithm over candidate blocks [N, rows, p] (see the module docstring).

    Raises InfeasibleError when the candidates cannot make Λ nonsingular (too few or too similar).
    """
    t0 = time.perf_counter()
    criterion = Criterion(criterion)
    n_cand, rows, p = blocks.shape
    n_min = math.ceil(p / rows)
    if n < n_min:
        raise InputError(
            f"{n} poses of {rows} rows cannot identify {p} parameters: need at least {n_min}", field="n"
        )
    if n > n_cand:
        raise InfeasibleError(
            f"only {n_cand} feasible candidates for {n} poses: relax the cell or refine the grid"
        )
    n0 = min(n, max(n_min + 2, n // 2)) if n_start is None else max(min(n_start, n), n_min)
    rng = np.random.default_rng(seed)
    search = _Search(blocks, criterion)
    best: tuple[float, list[int]] | None = None
    reached: list[float] = []
    moves = 0
    for _ in range(max(restarts, 1)):
        for _attempt in range(200):
            chosen = [int(i) for i in rng.choice(n_cand, size=n0, replace=False)]
            lam = np.einsum("nri,nrj->ij", blocks[chosen], blocks[chosen])
            ev = np.linalg.eigvalsh(lam)
            if ev[0] > 1e-10 * ev[-1]:
                break
        else:
            raise InfeasibleError(
                f"no nonsingular start among {n_cand} candidates after 200 random draws of {n0}: "
                "the candidates cannot identify all parameters (too few, or all alike)"
            )
        chosen, lam, m1 = _exchange(search, chosen, lam, 10 * n)
        while len(chosen) < n:
            exclude = np.zeros(n_cand, dtype=bool)
            exclude[chosen] = True
            i, _ = search.best_add(lam, exclude)
            if i < 0:
                break
            chosen.append(i)
            lam = lam + search.gram(i)
        chosen, lam, m2 = _exchange(search, chosen, lam, 10 * n)
        moves += m1 + m2
        s = float(_score(lam, criterion))
        reached.append(s)
        if best is None or s > best[0]:
            best = (s, chosen)
    assert best is not None
    score, chosen = best
    report = (lambda s: math.inf if s <= 0 else 1.0 / s) if criterion is Criterion.COND else (lambda s: s)
    return SelectionResult(
        indices=np.array(chosen),
        observation_index=report(score),
        score=score,
        restart_indices=tuple(report(s) for s in reached),
        moves=moves,
        evaluations=search.evaluations,
        seconds=time.perf_counter() - t0,
    )


def evenly_spaced(n_candidates: int, n: int) -> np.ndarray:
    """Indices of n evenly spaced candidates in grid order (the reference set "evenly spaced
    candidates": as diverse as a random draw of the candidates)."""
    return np.unique(np.round(np.linspace(0, n_candidates - 1, n)).astype(int))


@dataclass(frozen=True)
class LinearScan:
    """The paper's naive baseline: one joint moved at a time through its grid values."""

    q: np.ndarray  # [m, dof]: the centre, then the sweep of joint 1, joint 2, …
    centre: np.ndarray  # [dof]
    per_joint: tuple[int, ...]  # poses of each joint's sweep besides the centre


def linear_scan(candidates: CandidateSet, n: int, centres: np.ndarray | None = None) -> LinearScan:
    """A linear scan of the joint grid (the paper's baseline for its ×18.5): from one centre
    configuration each joint is swept alone over the grid values that passed the cell checks, and
    n poses (the centre once) are spread evenly along the six sweeps.

    The centre is the candidate (of `centres`, indices into the candidates; default all) whose six
    grid lines keep the most poses feasible: the widest sweeps the cell allows (most of the
    shortest sweep, then most in all), so the baseline is the best linear scan there is, not a
    strawman. Feasibility is read from the streamed grid's mask, not checked again. Shares are
    equal per joint, capped by a sweep's feasible count; fewer than n poses only when all six
    sweeps together have fewer.
    """
    cand = candidates
    pool = cand.grid_index if centres is None else cand.grid_index[np.asarray(centres, dtype=int)]
    if pool.size == 0 or n < 1:
        raise InputError("a linear scan needs at least one centre and one pose", field="n")
    shape = tuple(a.size for a in cand.axes)
    dof, width = len(shape), max(shape)
    sub = np.array(np.unravel_index(pool, shape))  # [dof, C]: each centre's grid indices
    # sweep[c, j, k]: centre c with joint j at its k-th grid value is feasible and not the centre.
    sweep = np.zeros((pool.size, dof, width), dtype=bool)
    for j, size in enumerate(shape):
        line = np.repeat(sub[:, :, None], size, axis=2)
        line[j] = np.arange(size)
        ok = cand.feasible[np.ravel_multi_index(tuple(line), shape)]
        ok[np.arange(pool.size), sub[j]] = False
        sweep[:, j, :size] = ok
    count = sweep.sum(axis=2)
    c = int(np.argmax(count.min(axis=1) * (dof * width + 1) + count.sum(axis=1)))
    share = np.zeros(dof, dtype=int)
    for _ in range(n - 1):  # one pose at a time to the joint with the smallest share that has room
        room = np.flatnonzero(share < count[c])
        if room.size == 0:
            break
        share[room[np.argmin(share[room])]] += 1
    centre = np.array([cand.axes[j][sub[j, c]] for j in range(dof)])
    qs = [centre]
    for j in range(dof):
        along = np.flatnonzero(sweep[c, j])
        for k in along[evenly_spaced(along.size, share[j])] if share[j] else []:
            q = centre.copy()
            q[j] = cand.axes[j][k]
            qs.append(q)
    return LinearScan(q=np.array(qs), centre=centre, per_joint=tuple(int(v) for v in share))


@dataclass(frozen=True)
class BaselineSet:
    """A reference pose set scored like the selection: its index, the selection's ratio over it
    (`None` when it is singular), and the rms prediction error calibrating from it should leave
    over the candidates (position m, orientation rad or None) at the tracker noise of cell.yaml."""

    q: np.ndarray
    observation_index: float
    improvement_ratio: float | None
    expected_error: tuple[float, float | None]


@dataclass(frozen=True)
class PoseSelection:
    candidates: CandidateSet
    identifiable: IdentifiableSet
    measurement: str  # "pose" | "position"
    characteristic_length_m: float
    criterion: Criterion
    selection: SelectionResult
    q_selected: np.ndarray
    q_validation: np.ndarray
    expected_error: tuple[float, float | None]  # of the selected set, as BaselineSet.expected_error
    # The naive baseline, the paper's linear scan of the joint grid (`linear_scan`).
    baseline: BaselineSet
    scan: LinearScan
    # σ_min(Λ) of the selected set over the linear scan's: the paper's ×18.5 figure, whatever the criterion.
    min_eig_improvement_ratio: float | None
    # The stronger reference: as many evenly spaced candidates (`evenly_spaced`).
    evenly_spaced: BaselineSet


def _improvement(selected: float, other: float, criterion: Criterion) -> float | None:
    if criterion is Criterion.COND:  # reported as λ_max/λ_min: smaller is better
        return other / selected if math.isfinite(other) else None
    return selected / other if other > 0 else None


def select_measurement_poses(
    robot: Robot,
    cell: Cell,
    n: int = 32,
    *,
    intervals: int | tuple[int, ...] = 13,
    max_candidates: int | None = 4000,
    criterion: Criterion | str = Criterion.DET_ROOT,
    restarts: int = 5,
    seed: int = 0,
    n_validation: int = 32,
    point: np.ndarray | None = None,
    progress: Progress | None = None,
) -> PoseSelection:
    """Candidates from the grid, identifiable set, exchange selection, the linear-scan baseline and
    evenly spaced candidates beside it, validation poses."""
    criterion = Criterion(criterion)
    cand = stream_candidates(robot, cell, intervals, max_candidates, seed, progress)
    n_cand = cand.q.shape[0]
    if n_cand < n:
        raise InfeasibleError(
            f"only {n_cand} of {cand.n_grid} grid configurations pass the cell checks "
            f"(rejected: {cand.rejected}); {n} poses requested: relax the cell or refine the grid"
        )
    position_only = cell.tracker.measures == "position"
    rng = np.random.default_rng(seed)
    ident = identifiable_parameters(robot, random_poses(robot, 60, rng), position_only, point)
    scan = linear_scan(cand, n)
    stacked, weight = selection_blocks(robot, cell, np.vstack([cand.q, scan.q]), ident, point, n_cand)
    blocks, scan_blocks = stacked[:n_cand], stacked[n_cand:]
    sigma_p = cell.tracker.position_sigma_m
    sel = select_poses(blocks, n, criterion, restarts, seed)

    def reference(q: np.ndarray, b: np.ndarray) -> BaselineSet:
        index = observation_index(b, criterion)
        return BaselineSet(
            q=q,
            observation_index=index,
            improvement_ratio=_improvement(sel.observation_index, index, criterion),
            expected_error=expected_errors(b, blocks, sigma_p, weight),
        )

    even = evenly_spaced(n_cand, n)
    rest = np.setdiff1d(np.arange(n_cand), sel.indices)
    val_idx = np.sort(rng.choice(rest, size=min(n_validation, rest.size), replace=False))
    return PoseSelection(
        candidates=cand,
        identifiable=ident,
        measurement="position" if position_only else "pose",
        characteristic_length_m=characteristic_length_m(robot),
        criterion=criterion,
        selection=sel,
        q_selected=cand.q[sel.indices],
        q_validation=cand.q[val_idx],
        expected_error=expected_errors(blocks[sel.indices], blocks, sigma_p, weight),
        baseline=reference(scan.q, scan_blocks),
        scan=scan,
        min_eig_improvement_ratio=_improvement(
            observation_index(blocks[sel.indices], Criterion.MIN_EIG),
            observation_index(scan_blocks, Criterion.MIN_EIG),
            Criterion.MIN_EIG,
        ),
        evenly_spaced=reference(cand.q[even], blocks[even]),
    )
