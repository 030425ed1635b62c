"""The closed form of the one IK: a spherical-wrist 6R arm (the OPW class), detected and read from the
model itself, every branch of a pose (`analytic_solutions`); `rxcomm.model.ik` refines and selects.

The closed form (`SphericalWrist`) is read from the model at q = 0, so it holds for any arm of the
OPW class (Brandstötter et al. 2014: joint 1 any axis, joints 2 and 3 parallel and perpendicular to
it, a shoulder offset allowed — the m900 — a lateral offset b, and three wrist axes through one
point), whatever its URDF conventions: the joint axes and points on them, the wrist centre and the
TCP's offset from it. Position: the wrist centre fixes q1 (two shoulder solutions, b kept), then q2,
q3 from the planar two-link triangle in the arm plane (two elbow solutions). Orientation: product of
exponentials at q_ref = (q1, q2, q3, 0, 0, 0), R(q) = Rot(u4, q4)·Rot(u5, q5)·Rot(u6, q6)·R(q_ref)
with the world axes u_i at q_ref; Paden–Kahan subproblem 2 gives (q4, q5) (two wrist solutions) and
subproblem 1 gives q6. At the wrist singularity (q5 = 0: u4 ∥ u6) only q4 + q6 is fixed; q4 is kept
at the reference's (else 0); near it (q5 → 0) the solutions stay exact, q4 and q6 each
ill-conditioned (their sum is not). At the shoulder singularity (wrist centre on axis 1, b = 0) q1
is free and kept at the reference's.

The form is `exact` when the model is of the class to `EXACT_TOL` (a nominal URDF: every closed-form
solution exact to rounding). A calibrated model's joint offsets and link errors make its wrist only
nearly spherical: its form, read from that model, is approximate (its solutions off by millimetres,
Newton on the model closes the rest), and only there does a triangle just out of the form's reach
(`REACH_SLACK`) still give a start. A model outside the class (axes 2 and 3 not parallel, wrist axes
more than `WRIST_TOL_M` apart) gets `None` from `spherical_wrist`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pinocchio as pin

from rxcomm.model.robot import Robot

WRIST_TOL_M = 2e-3  # wrist axes farther apart than this: no closed form
PARALLEL_TOL = 2e-2  # rad: axes 2 and 3 parallel, axis 2 ⟂ axis 1
REACH_SLACK = 0.02  # an approximate form: a triangle just out of reach still seeds Newton
EXACT_TOL = 1e-9  # wrist axes this close, axes 2 ∥ 3 ⟂ 1 to this: the closed form is exact (m, rad)
_AXES = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}


def _local_axis(joint: pin.JointModel) -> np.ndarray | None:
    name = joint.shortname()
    for key, axis in _AXES.items():
        if name == "JointModel" + key:
            return np.array(axis)
    if name == "JointModelRevoluteUnaligned":
        return np.asarray(joint.extract().axis, dtype=float)
    return None


@dataclass(frozen=True)
class SphericalWrist:
    """The closed form's constants, read from the model at q = 0 (world frame = base frame)."""

    axes: np.ndarray  # [6, 3] local joint axes
    o1: np.ndarray  # a point on axis 1
    w1: np.ndarray  # axis 1
    w2: np.ndarray  # axis 2 at q = 0
    e0: np.ndarray  # w1 × w2
    b: float  # the wrist centre's constant component along w2 from o1 (shoulder offset)
    o2: np.ndarray
    l1: tuple[float, float]  # joint 2 → joint 3, in the arm plane (e0, w1)
    l2: tuple[float, float]  # joint 3 → wrist centre, in the arm plane
    s3: float  # +1 if axis 3 points as axis 2, −1 if opposite
    delta: float  # the elbow angle β = s3·q3 of the straight arm is −delta (mod π)
    centre_in_tcp: np.ndarray  # the wrist centre in the TCP frame (constant)
    exact: bool  # the model is of the class to EXACT_TOL (else, e.g. calibrated: Newton finishes)


def _closest_point(points: list[np.ndarray], dirs: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The point nearest to the lines (point, unit direction) in least squares, and its largest distance."""
    a = sum(np.eye(3) - np.outer(d, d) for d in dirs)
    rhs = sum((np.eye(3) - np.outer(d, d)) @ p for p, d in zip(points, dirs, strict=True))
    c = np.linalg.lstsq(a, rhs, rcond=None)[0]
    dist = max(
        float(np.linalg.norm((np.eye(3) - np.outer(d, d)) @ (c - p)))
        for p, d in zip(points, dirs, strict=True)
    )
    return c, dist


def _plane(v: np.ndarray, e0: np.ndarray, w1: np.ndarray) -> tuple[float, float]:
    return float(v @ e0), float(v @ w1)


@lru_cache(maxsize=32)
def _wrist_cached(model_id: int, robot: Robot) -> SphericalWrist | None:
    m = robot.model
    if m.nq != 6 or m.nv != 6 or m.njoints != 7 or any(m.parents[j] != j - 1 for j in range(1, 7)):
        return None
    axes = [_local_axis(m.joints[j]) for j in range(1, 7)]
    if any(a is None for a in axes):
        return None
    data = m.createData()
    q0 = np.zeros(6)
    pin.framesForwardKinematics(m, data, q0)
    pts = [data.oMi[j].translation.copy() for j in range(1, 7)]
    dirs = [data.oMi[j].rotation @ axes[j - 1] for j in range(1, 7)]
    dirs = [d / np.linalg.norm(d) for d in dirs]
    w1, w2, w3 = dirs[0], dirs[1], dirs[2]
    if abs(w1 @ w2) > PARALLEL_TOL or np.linalg.norm(np.cross(w2, w3)) > PARALLEL_TOL:
        return None
    centre, dist = _closest_point(pts[3:], dirs[3:])
    if dist > WRIST_TOL_M:
        return None
    tcp = data.oMf[robot.tcp_frame_id]
    e0 = np.cross(w1, w2)
    e0 /= np.linalg.norm(e0)
    o1, o2, o3 = pts[0], pts[1], pts[2]
    return SphericalWrist(
        axes=np.array(axes),
        o1=o1,
        w1=w1,
        w2=w2,
        e0=e0,
        b=float((centre - o1) @ w2),
        o2=o2,
        l1=_plane(o3 - o2, e0, w1),
        l2=_plane(centre - o3, e0, w1),
        s3=1.0 if w2 @ w3 > 0 else -1.0,
        delta=math.atan2(*reversed(_plane(centre - o3, e0, w1)))
        - math.atan2(*reversed(_plane(o3 - o2, e0, w1))),
        centre_in_tcp=tcp.rotation.T @ (centre - tcp.translation),
        exact=max(dist, abs(w1 @ w2), float(np.linalg.norm(np.cross(w2, w3)))) < EXACT_TOL,
    )


def spherical_wrist(robot: Robot) -> SphericalWrist | None:
    """The closed form of ``robot`` (cached per model), or None if it is not of the OPW class."""
    return _wrist_cached(id(robot.model), robot)


def wrap_angle(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _cross(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _sp1(w: tuple[float, ...], p: tuple[float, ...], q: tuple[float, ...]) -> float:
    """Paden–Kahan 1: the angle about unit ``w`` turning ``p`` onto ``q`` (their parts ⟂ w)."""
    wp, wq = _dot(w, p), _dot(w, q)
    pp = (p[0] - w[0] * wp, p[1] - w[1] * wp, p[2] - w[2] * wp)
    qq = (q[0] - w[0] * wq, q[1] - w[1] * wq, q[2] - w[2] * wq)
    return math.atan2(_dot(w, _cross(pp, qq)), _dot(pp, qq))


def _sp2(
    w1: tuple[float, ...], w2: tuple[float, ...], p: tuple[float, ...], q: tuple[float, ...]
) -> list[tuple[float, float]]:
    """Paden–Kahan 2: (θ1, θ2) with Rot(w1, θ1)·Rot(w2, θ2)·p = q (axes through one point)."""
    c = _dot(w1, w2)
    den = c * c - 1.0
    if abs(den) < 1e-12:
        return []
    alpha = (c * _dot(w2, p) - _dot(w1, q)) / den
    beta = (c * _dot(w1, q) - _dot(w2, p)) / den
    cross = _cross(w1, w2)
    g2 = (_dot(p, p) - alpha**2 - beta**2 - 2 * alpha * beta * c) / _dot(cross, cross)
    if g2 < -1e-9:
        return []
    out = []
    for g in (math.sqrt(max(g2, 0.0)), -math.sqrt(max(g2, 0.0))):
        z = tuple(alpha * w1[i] + beta * w2[i] + g * cross[i] for i in range(3))
        out.append((_sp1(w1, z, q), _sp1(w2, p, z)))
    return out


def _rot(w: tuple[float, ...], a: float, v: tuple[float, ...]) -> tuple[float, ...]:
    """Rodrigues: ``v`` turned by ``a`` about unit ``w``."""
    c, s = math.cos(a), math.sin(a)
    k = _cross(w, v)
    d = _dot(w, v) * (1 - c)
    return tuple(v[i] * c + k[i] * s + w[i] * d for i in range(3))


def _arm(sw: SphericalWrist, centre: np.ndarray, q1_singular: float) -> list[tuple[float, float, float]]:
    """(q1, q2, q3) placing the wrist centre at ``centre``: up to 2 shoulders × 2 elbows. On axis 1
    (the shoulder singularity of an arm without offset) q1 is free: ``q1_singular`` is taken. An
    approximate form (not ``exact``) also gives starts for triangles just out of its reach."""
    slack = 0.0 if sw.exact else REACH_SLACK
    d = centre - sw.o1
    x, y, h = float(d @ sw.w2), float(d @ sw.e0), float(d @ sw.w1)
    rho = math.hypot(x, y)
    if rho < 1e-9 and abs(sw.b) < 1e-9:
        phi, dphi = q1_singular - math.pi / 2, math.pi / 2  # the q1 that keeps the seed's
    elif rho < abs(sw.b) * (1 - slack):
        return []
    else:
        phi, dphi = math.atan2(y, x), math.acos(max(-1.0, min(1.0, sw.b / rho)))
    out = []
    l1, l2 = sw.l1, sw.l2
    n1, n2 = math.hypot(*l1), math.hypot(*l2)
    delta = math.atan2(l2[1], l2[0]) - math.atan2(l1[1], l1[0])
    for q1 in (phi + dphi, phi - dphi):
        # the wrist centre in the arm plane at q1 = 0, from joint 2
        r = -x * math.sin(q1) + y * math.cos(q1)  # component along e(q1)
        t = sw.o1 + r * sw.e0 + h * sw.w1 - sw.o2
        tx, ty = _plane(t, sw.e0, sw.w1)
        c = (tx * tx + ty * ty - n1 * n1 - n2 * n2) / (2 * n1 * n2)
        if abs(c) > 1.0 + slack:  # an approximate form (a calibrated model): Newton decides
            continue
        a = math.acos(max(-1.0, min(1.0, c)))
        if abs(c) > 1.0:  # just out of reach on the closed form: start both elbows off the straight arm
            a = 0.2 if c > 0 else math.pi - 0.2
        for beta in (-delta + a, -delta - a):
            vx = l1[0] + math.cos(beta) * l2[0] - math.sin(beta) * l2[1]
            vy = l1[1] + math.sin(beta) * l2[0] + math.cos(beta) * l2[1]
            q2 = math.atan2(ty, tx) - math.atan2(vy, vx)
            out.append((wrap_angle(q1), wrap_angle(q2), wrap_angle(sw.s3 * beta)))
    return out


def analytic_solutions(
    robot: Robot, target: pin.SE3, data: pin.Data | None = None, near: np.ndarray | None = None
) -> list[np.ndarray]:
    """Every closed-form solution of ``target`` (up to 8; joint angles in (−π, π], limits not applied),
    on the closed form of the model (exact for a nominal OPW arm). [] if the arm has no closed form
    or the pose is out of reach. At a singularity the free joint (q1 with the wrist centre on axis
    1, q4 with q5 = 0) keeps its value in ``near`` (default 0)."""
    ref = np.zeros(6) if near is None else np.asarray(near, dtype=float)
    sw = spherical_wrist(robot)
    if sw is None:
        return []
    m = robot.model
    data = m.createData() if data is None else data
    centre = target.translation + target.rotation @ sw.centre_in_tcp
    out = []
    fid = robot.tcp_frame_id
    for q1, q2, q3 in _arm(sw, centre, float(ref[0])):
        pin.framesForwardKinematics(m, data, np.array([q1, q2, q3, 0.0, 0.0, 0.0]))
        u4, u5, u6 = (tuple((data.oMi[j].rotation @ sw.axes[j - 1]).tolist()) for j in (4, 5, 6))
        w = target.rotation @ data.oMf[fid].rotation.T  # = Rot(u4, q4)·Rot(u5, q5)·Rot(u6, q6)
        wl = w.tolist()
        q = tuple(_dot(row, u6) for row in wl)
        if _dot(u4, u6) ** 2 > 1 - 1e-12 and _dot(_cross(u6, q), _cross(u6, q)) < 1e-18:
            # wrist singular: u6 stays where it was, q5 = 0 (or π if u4 and u6 are opposed): q4 free
            pairs = [(float(ref[3]), 0.0 if _dot(u6, q) > 0 else math.pi)]
        else:
            pairs = _sp2(u4, u5, u6, q)
        v = _cross(u6, (1.0, 0.0, 0.0) if abs(u6[0]) < 0.9 else (0.0, 1.0, 0.0))
        wv = tuple(_dot(row, v) for row in wl)
        for q4, q5 in pairs:
            # Rot(u6, q6)·v = Rot(u5, −q5)·Rot(u4, −q4)·W·v
            target_v = _rot(u5, -q5, _rot(u4, -q4, wv))
            q6 = _sp1(u6, v, target_v)
            out.append(np.array([q1, q2, q3, wrap_angle(q4), wrap_angle(q5), wrap_angle(q6)]))
    return out


def same_branch(robot: Robot, a: np.ndarray, b: np.ndarray, eps: float = 1e-3) -> bool:
    """Whether ``a`` and ``b`` are on the same elbow and wrist branch of the closed form (the sign of
    the elbow angle from the straight arm, of q5); True without a closed form, or where ``a`` is
    within ``eps`` of the straight arm or wrist (both branches meet there)."""
    sw = spherical_wrist(robot)
    if sw is None:
        return True
    delta = sw.delta
    for x, y in ((sw.s3 * a[2] + delta, sw.s3 * b[2] + delta), (a[4], b[4])):
        sa = math.sin(x)
        if abs(sa) > eps and sa * math.sin(y) < 0:
            return False
    return True
