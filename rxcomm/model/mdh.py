"""A serial 6R robot as modified Denavit–Hartenberg parameters (Craig's convention), the form most
controllers take, and what that form cannot express.

Craig's MDH: frame i is fixed to link i with Z_i along joint i's axis; from frame i−1 to frame i

    T_i = Rx(α_{i−1}) · Tx(a_{i−1}) · Rz(θ_i) · Tz(d_i),   θ_i = q_i + θ_offset_i,

X_{i−1} along the common normal from axis i−1 to axis i. The TCP in the robot's base frame is
B · T_1 · … · T_n · E with B (base → frame 0) and E (frame n → TCP) general placements.

Construction (`mdh_from_robot`), from the robot's joint axis lines at q = 0 (any URDF, calibrated
or not; axes from the joint Jacobian, so the URDF's own frame choice does not matter):

- consecutive axes that are not parallel: X along u_i × u_{i+1}, the origin at the foot of the
  common normal on axis i (exact: any two skew lines have one common normal);
- parallel axes (within `parallel_tol_rad`; the RX130L's J2 ∥ J3): the common normal is not unique,
  and for axes *nearly* parallel it runs metres away (d of ±(distance / angle)) — the classic MDH
  singularity. So they are treated as parallel, the convention d_i = 0 (frame i's origin where
  the previous normal meets axis i), X toward axis i+1. Their small relative tilt about Y_i
  (Hayati's β) is what MDH cannot express: it is dropped, and the frames after it follow the MDH
  chain, not the true axes;
- frame 0 = frame 1 at q = 0 except that X_0 is the base's x projected normal to axis 1, so
  θ_offset_1 is the angle of joint 1's zero about its axis (a rotation of the base about axis 1
  is the same thing); frame n's X keeps θ_offset_n relative to the flange's x, and d_n = 0; B and E
  carry the rest.

`residual` compares the MDH FK with the robot's own FK over sampled poses: for an exactly
parallel robot (the nominal RX130L) it is at round-off; for a calibrated one it is the β tilt's
effect, the part of the calibration the MDH table loses (state it with the table).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.model.robot import Robot


@dataclass(frozen=True)
class MdhRow:
    """One joint: α_{i−1} (rad), a_{i−1} (m), θ_offset_i (rad), d_i (m), and Hayati's β_{i−1} (rad,
    a rotation about Y after α: 0 in plain MDH; only a joint after a parallel pair may carry one)."""

    alpha_rad: float
    a_m: float
    theta_offset_rad: float
    d_m: float
    beta_rad: float = 0.0


@dataclass(frozen=True)
class Mdh:
    base: pin.SE3  # the robot's base frame → MDH frame 0
    rows: tuple[MdhRow, ...]
    tool: pin.SE3  # MDH frame n → TCP
    parallel: tuple[tuple[int, int], ...]  # joint index pairs (0-based) treated as parallel

    def fk(self, qs: np.ndarray) -> np.ndarray:
        """[N, 4, 4] TCP placements in the robot's base frame at joint angles qs [N, n] rad."""
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        t = np.broadcast_to(self.base.homogeneous, (qs.shape[0], 4, 4)).copy()
        for i, r in enumerate(self.rows):
            fixed = _rx(r.alpha_rad) @ _ry(r.beta_rad) @ _trans(r.a_m, 0.0, 0.0)
            t = t @ fixed @ _rz_batch(qs[:, i] + r.theta_offset_rad) @ _trans(0.0, 0.0, r.d_m)
        return t @ self.tool.homogeneous


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(b: float) -> np.ndarray:
    c, s = np.cos(b), np.sin(b)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _rz_batch(th: np.ndarray) -> np.ndarray:
    m = np.zeros((th.size, 4, 4))
    c, s = np.cos(th), np.sin(th)
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = c, -s, s, c
    m[:, 2, 2] = m[:, 3, 3] = 1.0
    return m


def joint_axes(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """(points [n, 3], unit directions [n, 3]) of the joint axis lines at q = 0, base frame (from the
    world-frame joint Jacobian: column j = [p × u; u] for a revolute joint)."""
    data = robot.create_data()
    pin.computeJointJacobians(robot.model, data, np.zeros(robot.model.nq))
    jac = np.asarray(data.J)[:, : robot.n]
    u = jac[3:].T / np.linalg.norm(jac[3:].T, axis=1, keepdims=True)
    p = np.cross(u, jac[:3].T)  # the foot of the perpendicular from the origin
    return p, u


def _closest_on(p: np.ndarray, u: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The point of line (p, u) closest to the non-parallel line (q, v)."""
    w = p - q
    b = u @ v
    t = (b * (v @ w) - (u @ w)) / (1.0 - b * b)
    return p + t * u


def _unit_normal(v: np.ndarray, u: np.ndarray) -> np.ndarray:
    """v's component normal to the unit vector u, normalised (zeros if none)."""
    w = v - (v @ u) * u
    n = np.linalg.norm(w)
    return w / n if n > 1e-12 else np.zeros(3)


def _frame(origin: np.ndarray, z: np.ndarray, x: np.ndarray) -> pin.SE3:
    return pin.SE3(np.column_stack([x, np.cross(z, x), z]), origin)


def mdh_from_robot(robot: Robot, parallel_tol_rad: float = 1e-6) -> Mdh:
    """The exact MDH form of a robot whose consecutive axes are either parallel (within
    `parallel_tol_rad`) or clearly not (a nominal design); see the module docstring."""
    n = robot.n
    p, u = joint_axes(robot)
    data = robot.create_data()
    pin.framesForwardKinematics(robot.model, data, np.zeros(robot.model.nq))
    tcp, flange = data.oMf[robot.tcp_frame_id], data.oMi[n]
    parallel = tuple(
        (i, i + 1)
        for i in range(n - 1)
        if np.linalg.norm(np.cross(u[i], u[i + 1])) < np.sin(parallel_tol_rad)
    )
    x0 = _unit_normal(np.array([1.0, 0.0, 0.0]), u[0])
    if not x0.any():
        x0 = _unit_normal(np.array([0.0, 1.0, 0.0]), u[0])
    frames: list[pin.SE3] = []
    for i in range(n):
        z = u[i]
        if i < n - 1 and (i, i + 1) not in parallel:  # the foot of the common normal to the next axis
            origin = _closest_on(p[i], z, p[i + 1], u[i + 1])
        elif i == 0:  # parallel to the next: the foot of the perpendicular from the base origin
            origin = p[0] + (-p[0] @ z) * z
        else:  # d_i = 0: where the previous X line meets this axis
            prev = frames[-1]
            origin = _closest_on(p[i], z, prev.translation, prev.rotation[:, 0])
        if i == n - 1:  # θ_offset_n relative to the flange's x
            x = _unit_normal(flange.rotation[:, 0], z)
            if not x.any():
                x = _unit_normal(flange.rotation[:, 1], z)
        elif (i, i + 1) in parallel:  # toward the next axis; coaxial: the previous X
            x = _unit_normal(p[i + 1] - origin, z)
            if not x.any():
                x = _unit_normal(frames[-1].rotation[:, 0] if frames else x0, z)
        else:
            x = np.cross(z, u[i + 1])
            x = x / np.linalg.norm(x)
        frames.append(_frame(origin, z, x))
    base = _frame(frames[0].translation, u[0], x0)
    prev, rows = base, []
    for i, f in enumerate(frames):
        row = _extract(prev.inverse() * f, d_zero=i == n - 1)
        rows.append(row)
        prev = prev * _row_se3(row)
    return Mdh(base=base, rows=tuple(rows), tool=prev.inverse() * tcp, parallel=parallel)


def _row_se3(r: MdhRow) -> pin.SE3:
    rz = _rz_batch(np.array([r.theta_offset_rad]))[0]
    m = _rx(r.alpha_rad) @ _trans(r.a_m, 0, 0) @ rz @ _trans(0, 0, r.d_m)
    return pin.SE3(m[:3, :3], m[:3, 3])


def _extract(rel: pin.SE3, d_zero: bool) -> MdhRow:
    """The MDH row of `rel` (frame i−1 → frame i at q = 0), exact when Z_i ⟂ X_{i−1} and the
    origin of frame i lies on X_{i−1}'s line moved along Z_i, as the construction makes them.
    `d_zero`: the last joint, whose d is carried by the tool frame."""
    r, t = rel.rotation, rel.translation
    alpha = float(np.arctan2(-r[1, 2], r[2, 2]))
    rx = _rx(alpha)[:3, :3]
    rz = rx.T @ r
    theta = float(np.arctan2(rz[1, 0], rz[0, 0]))
    d = 0.0 if d_zero else float(t @ rx[:, 2])
    return MdhRow(alpha, float(t[0]), theta, d)


FIELDS = ("alpha_rad", "a_m", "theta_offset_rad", "d_m", "beta_rad")


def free_parameters(nominal: Mdh, beta: bool) -> np.ndarray:
    """[5n] bool: the row entries (FIELDS) a fit may move. Fixed: joint 1's row (frame 0 is frame 1
    at its zero, the base frame carries the rest), joint n's θ_offset and d (the tool frame carries
    them), d_i of a joint whose next axis is parallel (the convention d_i = 0 that keeps MDH finite),
    and β except (`beta`) on the joint after a parallel pair."""
    n = len(nominal.rows)
    free = np.ones((n, 5), dtype=bool)
    free[0] = False
    free[n - 1, 2:4] = False
    free[:, 4] = False
    for i, j in nominal.parallel:
        free[i, 3] = False
        free[j, 4] = beta
    return free.ravel()


def fit_mdh(nominal: Robot, target: Robot, qs: np.ndarray, length_m: float = 1.0, beta: bool = False) -> Mdh:
    """The MDH parameters (with the nominal's convention: `free_parameters`) and base and tool frames
    whose FK best matches `target`'s over the poses qs [N, n] (least squares on position m and
    orientation rad × `length_m`), started from the nominal's exact MDH form. What remains is what
    MDH with d_i = 0 at parallel axes cannot express (`residual`)."""
    import scipy.optimize

    from rxcomm.model.geometric_errors import predict_poses

    start = mdh_from_robot(nominal)
    free = free_parameters(start, beta)
    flat0 = np.array([getattr(r, f) for r in start.rows for f in FIELDS])
    p_t, r_t = predict_poses(target, qs)

    def build(x: np.ndarray) -> Mdh:
        flat = flat0.copy()
        flat[free] = x[12:]
        rows = tuple(MdhRow(*flat[5 * i : 5 * i + 5]) for i in range(len(start.rows)))
        base = start.base * pin.exp6(pin.Motion(x[:6]))
        tool = start.tool * pin.exp6(pin.Motion(x[6:12]))
        return Mdh(base, rows, tool, start.parallel)

    def res(x: np.ndarray) -> np.ndarray:
        t = build(x).fk(qs)
        e = np.einsum("nij,nkj->nik", t[:, :3, :3], r_t)  # R_mdh · R_targetᵀ
        w = 0.5 * np.stack([e[:, 2, 1] - e[:, 1, 2], e[:, 0, 2] - e[:, 2, 0], e[:, 1, 0] - e[:, 0, 1]], 1)
        return np.concatenate([t[:, :3, 3] - p_t, w * length_m], axis=1).ravel()

    x0 = np.concatenate([np.zeros(12), flat0[free]])
    sol = scipy.optimize.least_squares(res, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return build(sol.x)


# A residual below this fraction of the arm's length (position) or in rad (orientation) is the
# fit's round-off, written as 0: where a form is exact it leaves 1e-15–1e-12 m (measured), where it
# is not 1e-6 m and up, so 1e-9 × the length is three orders from either.
ROUND_OFF_RELATIVE = 1e-9


def residual(robot: Robot, mdh: Mdh, qs: np.ndarray, length_m: float = 1.0) -> tuple[float, float]:
    """(max position error m, max orientation error rad) of the MDH FK against the robot's FK (its
    TCP in its base frame) over the poses qs [N, n]; within round-off of zero (`ROUND_OFF_RELATIVE`
    × `length_m`, × 1 rad) a figure is 0."""
    from rxcomm.model.geometric_errors import predict_poses

    p, r = predict_poses(robot, qs)
    t = mdh.fk(qs)
    dp = np.linalg.norm(t[:, :3, 3] - p, axis=1)
    rel = np.einsum("nji,njk->nik", r, t[:, :3, :3])
    w = 0.5 * np.stack(
        [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1
    )
    ang = np.arctan2(np.linalg.norm(w, axis=1), 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1))
    dp_max, ang_max = float(dp.max()), float(ang.max())
    return (
        dp_max if dp_max > ROUND_OFF_RELATIVE * length_m else 0.0,
        ang_max if ang_max > ROUND_OFF_RELATIVE else 0.0,
    )
