"""Geometric error model of a 6R arm, its identification Jacobian and identifiable subset (paper §3.1).

The model (architecture §7 calibrate): 48 parameters, each group a small twist δ = [tx, ty, tz, rx, ry, rz]
(m, m, m, rad, rad, rad; Pinocchio's order: linear then angular) applied **on the right** of a nominal
placement, placement' = placement · exp6(δ):

- `{joint}.*` (6 per joint) on the joint's placement in its parent (the URDF `<origin>`), i.e. between
  the parent link and the joint's rotation. The rotation about the joint's own axis is the joint
  (encoder) **offset**; the two other rotations are axis **misalignments**; the translations are
  **length** errors (the paper's r23 = [l2, 0, 0] + [pe2x, pe2y, pe2z]).
- `base.*` (6): the robot base in the measurement (tracker) frame, on top of the nominal
  `tracker_to_base` placement from the cell layout: base_in_tracker = tracker_to_base · exp6(δ_base).
- `tool.*` (6): the TCP in the flange, on top of drives.yaml's nominal TCP: tcp' = tcp · exp6(δ_tool).

So the measured TCP pose is

    X(q) = tracker_to_base · exp6(δ_base) · Π_j [M_j · exp6(δ_j) · Rot(axis_j, q_j)] · F_tcp · exp6(δ_tool).

`ErrorModel.apply(robot)` builds a NEW Pinocchio model (never mutating the shared one) whose FK gives
exp6(δ_base) · Π ... — the robot's TCP in its *nominal* base frame, i.e. the base error is folded into
the placement of the joint(s) attached to the base. So `kinematics.tcp_pose(robot, q, errors)` is the
real TCP in the cell's nominal robot base frame, and `measured_pose` = tracker_to_base · that.

Paper symbols: p_n are the nominal placements M_j, F_tcp of the URDF / drives.yaml; p_e is
`ErrorModel.values` (the paper's p_e ∈ R³⁹ is a subset of our 48: 6·3 lengths, 6 offsets, 6·2
misalignments, 3 base terms); z_E = f_DKe(q, p_n, p_e) is `measured_pose`; Θ̂ (= ∂e/∂p_e, the
identification Jacobian, eq. 11) is `identification_jacobians` (up to sign: we differentiate the
prediction, the paper the error e = z_M − f_DKe); Λ = ΘᵀΘ is the information matrix of §3.3.

Identification Jacobian. Rows are the measured quantity's first-order change: position of the
measured point in the tracker frame (m) and, unless `position_only`, the orientation increment ω
(rad) with R(p + dp) = exp([ω]×)·R(p) (tracker frame). Columns follow `parameter_names`. It is
analytic: a twist δ at a frame with world pose B moves everything after it by the spatial twist
Ad(B)·Jexp6(δ)·dδ (Jexp6 the right Jacobian of exp6, exact at δ ≠ 0), and a point p moves by
v + ω × p. Checked against central finite differences in tests.

Identifiability (paper §3.1, §4.1 QR). A 6R arm measured in full pose has 30 identifiable parameters
(4 per joint axis line + 6 for the tool; the base is absorbed by joint 1), 27 for the position of one
off-axis point. `identifiable_parameters` finds them by a pivoted QR of the stacked Jacobian of many
poses with unit-norm columns (orientation rows × a characteristic length so rad compares to m): the
rank is the number of |R_kk| > `tol`·|R_00| (default 1e-8; structural dependencies give ≈1e-15, the
smallest kept ≈1e-2, so any tol in 1e-12…1e-4 gives the same set). Which member of each dependent
group is kept follows `PREFERENCE` (base first, then joints outward — offsets, misalignments, lengths —
then tool); each dropped parameter is reported with the kept parameters it is a combination of.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin
import scipy.linalg

from rxcomm.errors import InputError
from rxcomm.model.robot import Robot

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")
BASE, TOOL = "base", "tool"


def parameter_names(robot: Robot) -> tuple[str, ...]:
    """The 48 names: base.tx … base.rz, {joint}.tx … {joint}.rz per joint in chain order, tool.*."""
    groups = (BASE, *robot.joint_names, TOOL)
    return tuple(f"{g}.{c}" for g in groups for c in COMPONENTS)


def characteristic_length_m(robot: Robot) -> float:
    """Sum of the link lengths from joint 2 to the TCP (m): converts rad to m in scalings.

    RX130L: 0.625 + 0.4 + 0.525 + 0.11 + 0.15 = 1.81 m.
    """
    model = robot.model
    lengths = [np.linalg.norm(model.jointPlacements[j].translation) for j in range(2, model.njoints)]
    lengths.append(np.linalg.norm(model.frames[robot.tcp_frame_id].placement.translation))
    return float(max(sum(lengths), 1e-3))


def _joint_axes(robot: Robot) -> np.ndarray:
    """Unit rotation axis of each joint in its own frame, [n, 3] (from the joint's motion subspace)."""
    model, data = robot.model, robot.create_data()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    axes = np.zeros((robot.n, 3))
    for j in range(1, model.njoints):
        jac = pin.getJointJacobian(model, data, j, pin.LOCAL)
        col = jac[:, model.joints[j].idx_v]
        axes[j - 1] = col[3:] / np.linalg.norm(col[3:])
    return axes


def _check_serial(robot: Robot) -> None:
    model = robot.model
    if any(model.parents[j] != j - 1 for j in range(1, model.njoints)):
        raise InputError(
            "the error model needs a serial chain (joint j's parent is joint j−1)", field="joint"
        )
    if model.frames[robot.tcp_frame_id].parentJoint != model.njoints - 1:
        raise InputError("the TCP must be attached to the last joint", field="tcp.parent_frame")


@dataclass(frozen=True, eq=False)
class ErrorModel:
    """Values of the 48 error parameters (SI), in `parameter_names(robot)` order. Immutable."""

    names: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        v = np.array(self.values, dtype=float).reshape(-1)
        if v.shape != (len(self.names),):
            raise ValueError(f"{len(self.names)} names but {v.size} values")
        v.setflags(write=False)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "values", v)

    @classmethod
    def zeros(cls, robot: Robot) -> ErrorModel:
        names = parameter_names(robot)
        return cls(names, np.zeros(len(names)))

    @classmethod
    def from_mapping(
        cls, robot: Robot, mapping: Mapping[str, float], *, file: str | None = None, field: str | None = None
    ) -> ErrorModel:
        """From `{name: value}`; missing names are 0, unknown names are an InputError."""
        names = parameter_names(robot)
        index = {n: i for i, n in enumerate(names)}
        unknown = [k for k in mapping if k not in index]
        if unknown:
            raise InputError(
                f"unknown error parameter(s) {unknown[:5]} for robot {robot.name!r} "
                f"(expected names like {names[6]!r}, base.*, tool.*)",
                file=file,
                field=field,
            )
        v = np.zeros(len(names))
        for k, val in mapping.items():
            v[index[k]] = float(val)
        return cls(names, v)

    def as_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.values, strict=True)}

    def with_values(self, values: np.ndarray) -> ErrorModel:
        return ErrorModel(self.names, values)

    def twist(self, group: str) -> np.ndarray:
        """The 6-vector δ of `group` ('base', a joint name, 'tool')."""
        i = self.names.index(f"{group}.tx")
        return np.array(self.values[i : i + 6])

    def _check(self, robot: Robot) -> None:
        if self.names != parameter_names(robot):
            raise InputError(f"error model does not belong to robot {robot.name!r} (parameter names differ)")

    def apply(self, robot: Robot) -> Robot:
        """A new `Robot` whose kinematics include these errors (base error folded into joint 1).

        The robot passed in is untouched (its Pinocchio model is copied).
        """
        self._check(robot)
        _check_serial(robot)
        model = pin.Model(robot.model)
        base = pin.exp6(self.twist(BASE))
        for j, name in enumerate(robot.joint_names, start=1):
            m = model.jointPlacements[j] * pin.exp6(self.twist(name))
            model.jointPlacements[j] = base * m if model.parents[j] == 0 else m
        frame = model.frames[robot.tcp_frame_id]
        frame.placement = frame.placement * pin.exp6(self.twist(TOOL))
        model.frames[robot.tcp_frame_id] = frame
        return robot.with_model(model)


def _se3(placement: pin.SE3 | None) -> pin.SE3:
    return pin.SE3.Identity() if placement is None else placement


def measured_pose(
    robot: Robot, q: np.ndarray, errors: ErrorModel | None = None, tracker_to_base: pin.SE3 | None = None
) -> pin.SE3:
    """The TCP pose in the tracker frame: tracker_to_base · exp6(δ_base) · FK_δ(q) · tool error."""
    r = robot if errors is None else errors.apply(robot)
    data = r.create_data()
    pin.forwardKinematics(r.model, data, np.asarray(q, dtype=float))
    return _se3(tracker_to_base) * pin.updateFramePlacement(r.model, data, r.tcp_frame_id)


# ---------------------------------------------------------------------------------------------------
# Batched kinematics (numpy): thousands of poses per call for pose selection and calibration.


def _hom(m: pin.SE3) -> np.ndarray:
    return np.asarray(m.homogeneous, dtype=float)


def _rodrigues(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """[N, 3, 3] rotations about a fixed unit axis."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


@dataclass(frozen=True)
class _Chain:
    """World (tracker) poses along the chain for N configurations, all [N, 4, 4] (or [N, n, 4, 4])."""

    after_base: np.ndarray  # tracker_to_base · exp6(δ_base), [4, 4]
    joint_frames: np.ndarray  # frame after M_j·exp6(δ_j), before Rot(q_j): [N, n, 4, 4]
    tcp: np.ndarray  # TCP after the tool error: [N, 4, 4]

    def point(self, point: np.ndarray | None = None) -> np.ndarray:
        """[N, 3] positions of `point` (in the TCP frame; None: the TCP origin)."""
        x = self.tcp
        return x[:, :3, 3] if point is None else x[:, :3, 3] + x[:, :3, :3] @ np.asarray(point, dtype=float)


def _chain(
    robot: Robot, qs: np.ndarray, errors: ErrorModel | None, tracker_to_base: pin.SE3 | None
) -> _Chain:
    errors = ErrorModel.zeros(robot) if errors is None else errors
    errors._check(robot)
    _check_serial(robot)
    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    n_pose = qs.shape[0]
    model = robot.model
    axes = _joint_axes(robot)
    after_base = _hom(_se3(tracker_to_base) * pin.exp6(errors.twist(BASE)))
    t = np.broadcast_to(after_base, (n_pose, 4, 4)).copy()
    frames = np.empty((n_pose, robot.n, 4, 4))
    rot = np.zeros((n_pose, 4, 4))
    rot[:, 3, 3] = 1.0
    for j, name in enumerate(robot.joint_names, start=1):
        m = _hom(model.jointPlacements[j] * pin.exp6(errors.twist(name)))
        b = t @ m
        frames[:, j - 1] = b
        rot[:, :3, :3] = _rodrigues(axes[j - 1], qs[:, j - 1])
        t = b @ rot
    tool = _hom(model.frames[robot.tcp_frame_id].placement * pin.exp6(errors.twist(TOOL)))
    return _Chain(after_base, frames, t @ tool)


def predict_poses(
    robot: Robot,
    qs: np.ndarray,
    errors: ErrorModel | None = None,
    tracker_to_base: pin.SE3 | None = None,
    point: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Batched `measured_pose`: (positions [N, 3] of the TCP or of `point` (in the TCP frame), rotations
    [N, 3, 3]) in the tracker frame (the base frame when `tracker_to_base` is None)."""
    ch = _chain(robot, qs, errors, tracker_to_base)
    return ch.point(point), ch.tcp[:, :3, :3]


def _skew(v: np.ndarray) -> np.ndarray:
    s = np.zeros(v.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2], s[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    s[..., 1, 0], s[..., 2, 0], s[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return s


def _adjoint(h: np.ndarray) -> np.ndarray:
    """Ad of [..., 4, 4] placements (Pinocchio order: linear then angular)."""
    r, p = h[..., :3, :3], h[..., :3, 3]
    ad = np.zeros(h.shape[:-2] + (6, 6))
    ad[..., :3, :3] = r
    ad[..., 3:, 3:] = r
    ad[..., :3, 3:] = _skew(p) @ r
    return ad


def identification_jacobians(
    robot: Robot,
    qs: np.ndarray,
    errors: ErrorModel | None = None,
    tracker_to_base: pin.SE3 | None = None,
    position_only: bool = False,
    point: np.ndarray | None = None,
    joints: bool = False,
) -> np.ndarray:
    """[N, 6 or 3, 48]: ∂(measured point position, orientation increment)/∂(error parameters) per pose.

    `point`: the measured point in the TCP frame (default the TCP origin). Tracker frame when
    `tracker_to_base` is given, else the base frame (σ of ΘᵀΘ does not depend on that choice).
    With `joints`, n columns more (48 + j): ∂/∂q_j of the erroneous chain, joint j turning about its
    own axis (a spatial twist Ad(B_j)·[0; axis_j], B_j the frame before Rot(q_j)); joint compliance
    (a deflection δq_j = c_j·τ_j) enters the measured pose through them.
    """
    errors = ErrorModel.zeros(robot) if errors is None else errors
    ch = _chain(robot, qs, errors, tracker_to_base)
    n_pose = ch.tcp.shape[0]
    p = ch.point(point)
    spatial = np.empty((n_pose, 6, 6 * (robot.n + 2)))
    spatial[:, :, 0:6] = _adjoint(ch.after_base) @ pin.Jexp6(errors.twist(BASE))
    for j, name in enumerate(robot.joint_names):
        spatial[:, :, 6 * (j + 1) : 6 * (j + 2)] = _adjoint(ch.joint_frames[:, j]) @ pin.Jexp6(
            errors.twist(name)
        )
    spatial[:, :, -6:] = _adjoint(ch.tcp) @ pin.Jexp6(errors.twist(TOOL))
    # A spatial twist (v, ω) moves a point p by v + ω × p = v − [p]× ω.
    pos, rot = spatial[:, :3] - _skew(p) @ spatial[:, 3:], spatial[:, 3:]
    if joints:
        w = np.einsum("njab,jb->nja", ch.joint_frames[:, :, :3, :3], _joint_axes(robot))  # world axes
        o = ch.joint_frames[:, :, :3, 3]  # [N, n, 3] points on the axes
        pos = np.concatenate([pos, np.cross(w, p[:, None, :] - o).transpose(0, 2, 1)], axis=2)  # ω × (p − o)
        rot = np.concatenate([rot, w.transpose(0, 2, 1)], axis=2)
    return _rows(pos, rot, position_only)


def _rows(pos: np.ndarray, rot: np.ndarray, position_only: bool) -> np.ndarray:
    """[N, 3 or 6, k]: the position rows, then (unless `position_only`) the orientation rows."""
    return pos if position_only else np.concatenate([pos, rot], axis=1)


def joint_offset_names(robot: Robot) -> tuple[str, ...]:
    """Per joint, the error parameter that is its encoder offset (the rotation about its own axis)."""
    axes = _joint_axes(robot)
    return tuple(
        f"{name}.{COMPONENTS[3 + int(np.argmax(np.abs(axes[j])))]}"
        for j, name in enumerate(robot.joint_names)
    )


# ---------------------------------------------------------------------------------------------------
# Identifiable subset


def preference_order(robot: Robot) -> list[int]:
    """Parameter indices in the order the QR selection prefers to keep them.

    Base first (the robot's mounting in the cell), then joints from the base outward, within a joint
    the offset (rotation about its own axis), then the misalignments, then the lengths; the tool last.
    """
    names = parameter_names(robot)
    order = [names.index(f"{BASE}.{c}") for c in COMPONENTS]
    axes = _joint_axes(robot)
    for j, name in enumerate(robot.joint_names):
        about = int(np.argmax(np.abs(axes[j])))
        rots = [3 + about] + [3 + k for k in range(3) if k != about]
        trans = [about] + [k for k in range(3) if k != about][::-1]
        order += [names.index(f"{name}.{COMPONENTS[c]}") for c in rots + trans]
    order += [names.index(f"{TOOL}.{c}") for c in COMPONENTS]
    return order


@dataclass(frozen=True)
class IdentifiableSet:
    """The identifiable parameters: `indices`/`names` into the 48, and each dropped one with why."""

    indices: tuple[int, ...]
    names: tuple[str, ...]
    dropped: tuple[tuple[str, str], ...]
    rank: int
    tolerance: float
    smallest_kept_ratio: float  # |R_kk|/|R_00| of the weakest kept column (pivoted QR)
    largest_dropped_ratio: float  # … of the strongest dropped one: the gap the tolerance sits in

    def __len__(self) -> int:
        return len(self.indices)


def measurement_scaling(robot: Robot, position_only: bool) -> tuple[np.ndarray, np.ndarray]:
    """(row weights [rows], column scales [48]) making Θ dimensionless-comparable in metres.

    Rows: position in m, orientation in rad × L (L = `characteristic_length_m`). Columns: translations
    in m, rotations in rad × L, i.e. columns are multiplied by 1 (translations) or 1/L (rotations).
    """
    length = characteristic_length_m(robot)
    rows = np.ones(3) if position_only else np.array([1, 1, 1, length, length, length], dtype=float)
    cols = np.tile(np.array([1, 1, 1, 1 / length, 1 / length, 1 / length]), robot.n + 2)
    return rows, cols


def random_poses(robot: Robot, n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, dof] joint vectors uniform within the joint limits."""
    return rng.uniform(robot.q_min, robot.q_max, size=(n, robot.n))


def identifiable_parameters(
    robot: Robot,
    poses: np.ndarray,
    position_only: bool = False,
    point: np.ndarray | None = None,
    *,
    errors: ErrorModel | None = None,
    tol: float = 1e-8,
) -> IdentifiableSet:
    """The identifiable parameters from the stacked Jacobian at `poses` [N, dof] (pivoted QR, see module).

    Use enough varied poses (e.g. `random_poses(robot, 60, rng)`) to get the structural set; on a
    measured pose set it tells which parameters those poses can identify.
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    names = parameter_names(robot)
    jac = identification_jacobians(robot, poses, errors, None, position_only, point)
    row_w, col_s = measurement_scaling(robot, position_only)
    a = (jac * row_w[None, :, None]).reshape(-1, len(names)) * col_s
    norms = np.linalg.norm(a, axis=0)
    scale = norms.max()
    live = norms > tol * scale
    a_unit = np.where(live, a / np.where(live, norms, 1.0), 0.0)
    _, r, piv = scipy.linalg.qr(a_unit, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    ratios = diag / diag[0]
    rank = int(np.sum(ratios > tol))
    # Choose which columns to keep: greedy in preference order, keeping a column when its component
    # orthogonal to the kept ones exceeds the gap-centred threshold (geometric mean of the gap).
    lo = ratios[rank] if rank < len(ratios) else 0.0
    thresh = np.sqrt(max(ratios[rank - 1], 1e-300) * max(lo, 1e-300)) if rank > 0 else 1.0
    # A floor at √tol: a column whose part outside the kept span is below it is dependent to round-off
    # (the UR5e's parallel J2–J4 give one at 3e-8 of its norm, under the gap's centre 2e-8 × 1.2);
    # keeping it would leave a truly independent direction out and the set singular.
    thresh = max(thresh, float(np.sqrt(tol)))
    kept: list[int] = []
    basis = np.zeros((a_unit.shape[0], 0))
    for i in preference_order(robot):
        if not live[i]:
            continue
        c = a_unit[:, i]
        resid = c - basis @ (basis.T @ c)
        resid = resid - basis @ (basis.T @ resid)  # re-orthogonalise
        nr = np.linalg.norm(resid)
        if nr > thresh:
            kept.append(i)
            basis = np.column_stack([basis, resid / nr])
    if len(kept) != rank:
        kept = sorted(int(i) for i in piv[:rank])
    kept_sorted = tuple(sorted(kept))
    dropped = []
    k_mat = a_unit[:, list(kept_sorted)]
    for i in range(len(names)):
        if i in kept_sorted:
            continue
        if not live[i]:
            what = "the measured point" if position_only else "the measured pose"
            dropped.append((names[i], f"does not affect {what}"))
            continue
        coef, *_ = np.linalg.lstsq(k_mat, a_unit[:, i], rcond=None)
        top = np.argsort(-np.abs(coef))[:3]
        terms = ", ".join(f"{names[kept_sorted[t]]} ({coef[t]:+.3f})" for t in top if abs(coef[t]) > 0.02)
        dropped.append((names[i], f"a combination of {terms}" if terms else "linearly dependent"))
    return IdentifiableSet(
        indices=kept_sorted,
        names=tuple(names[i] for i in kept_sorted),
        dropped=tuple(dropped),
        rank=rank,
        tolerance=tol,
        smallest_kept_ratio=float(ratios[rank - 1]) if rank else 0.0,
        largest_dropped_ratio=float(lo),
    )


def identifiable_count(
    robot: Robot, position_only: bool = False, point: Sequence[float] | None = None, n_poses: int = 60
) -> int:
    """Number of structurally identifiable parameters (random poses, fixed seed)."""
    poses = random_poses(robot, n_poses, np.random.default_rng(0))
    pt = None if point is None else np.asarray(point, dtype=float)
    return len(identifiable_parameters(robot, poses, position_only, pt))


def placement_to_se3(xyz_m: Sequence[float], rpy_rad: Sequence[float]) -> pin.SE3:
    """A URDF-style placement (translation, rpy with R = Rz·Ry·Rx) as `pin.SE3`."""
    return pin.SE3(pin.rpy.rpyToMatrix(np.asarray(rpy_rad, dtype=float)), np.asarray(xyz_m, dtype=float))


def se3_to_xyz_rpy(m: pin.SE3) -> tuple[list[float], list[float]]:
    """Inverse of `placement_to_se3` (plain lists, ready for YAML/URDF)."""
    return [float(v) for v in m.translation], [float(v) for v in pin.rpy.matrixToRpy(m.rotation)]
