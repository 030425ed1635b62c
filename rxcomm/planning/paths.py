"""Cartesian TCP paths parametrised by arc length σ (m) (paper §5.1).

A `CartesianPath` is a curve (position of the TCP in the base frame) and an orientation law, both
functions of σ ∈ [0, length_m]. Curves are small objects with one method, `eval(s, order)`, giving the
position (order 0) or its first/second derivative w.r.t. σ; because σ is arc length, |p'(σ)| = 1 and
the TCP speed is σ̇. `build_path(spec)` turns a `rxcomm.schemas.path.PathSpec` into one, refusing
zero-length segments, collinear circle points and blends that do not fit with `InputError` naming the
field; `load_path` reads a path file and checks it is within the robot's reach.

The ISO 9283 test cube and its paths are in `rxcomm.planning.iso9283`, which builds on `rpy_matrix`
and `unit_vector` here.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import pinocchio as pin
from scipy.interpolate import CubicSpline

from rxcomm.errors import InputError
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.io.yaml_io import load_yaml
from rxcomm.model.robot import Robot
from rxcomm.schemas.path import (
    Circle,
    Line,
    Orientation,
    PathSpec,
    Polyline,
    Spline,
)

MIN_SEGMENT_M = 1e-6  # shorter segments are "zero length": σ by arc length is undefined on them


class Curve(Protocol):
    """A TCP position curve parametrised by arc length: eval(s [N], order 0/1/2) -> [N, 3]."""

    length_m: float

    def eval(self, s: np.ndarray, order: int = 0) -> np.ndarray: ...


def unit_vector(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@dataclass(frozen=True, eq=False)
class LineCurve:
    start: np.ndarray
    end: np.ndarray

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def eval(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        u = (self.end - self.start) / self.length_m
        if order == 0:
            return self.start + s[:, None] * u
        if order == 1:
            return np.broadcast_to(u, (len(s), 3)).copy()
        return np.zeros((len(s), 3))


@dataclass(frozen=True, eq=False)
class ArcCurve:
    """p(φ) = centre + r·(cos φ·e1 + sin φ·e2), φ = σ/r ∈ [0, sweep], sweep > 0."""

    centre: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    radius: float
    sweep: float

    @property
    def length_m(self) -> float:
        return float(self.radius * self.sweep)

    def eval(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        phi = np.atleast_1d(np.asarray(s, dtype=float))[:, None] / self.radius
        c, sn = np.cos(phi), np.sin(phi)
        if order == 0:
            return self.centre + self.radius * (c * self.e1 + sn * self.e2)
        if order == 1:
            return -sn * self.e1 + c * self.e2
        return -(c * self.e1 + sn * self.e2) / self.radius


@dataclass(frozen=True, eq=False)
class ChainCurve:
    """Curves joined end to end (tangent continuity is the builder's business)."""

    parts: tuple
    breaks: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "breaks", np.concatenate([[0.0], np.cumsum([p.length_m for p in self.parts])])
        )

    @property
    def length_m(self) -> float:
        return float(self.breaks[-1])

    def eval(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        idx = np.clip(np.searchsorted(self.breaks, s, side="right") - 1, 0, len(self.parts) - 1)
        out = np.empty((len(s), 3))
        for i in np.unique(idx):
            sel = idx == i
            out[sel] = self.parts[i].eval(s[sel] - self.breaks[i], order)
        return out


class _ArcLengthCurve(ABC):
    """A parametric curve P(u) re-parametrised by arc length: u(σ) is tabulated by Gauss–Legendre
    quadrature on a fine sub-grid of `breaks` and refined by Newton steps, so |p'(σ)| = 1 to ~1e-9.
    Subclasses give `_p(u, order)` and the parameter breaks."""

    def _setup(self, breaks: np.ndarray) -> None:
        sub = np.linspace(0, 1, 65)
        uu = np.concatenate(
            [breaks[i] + (breaks[i + 1] - breaks[i]) * sub[:-1] for i in range(len(breaks) - 1)]
            + [[breaks[-1]]]
        )
        xg, wg = np.polynomial.legendre.leggauss(5)
        a, b = uu[:-1, None], uu[1:, None]
        nodes = (a + b) / 2 + (b - a) / 2 * xg
        speed = np.linalg.norm(self._p(nodes.ravel(), 1), axis=1).reshape(nodes.shape)
        seg = ((b - a) / 2 * (speed * wg)).sum(axis=1)
        object.__setattr__(self, "_s_tab", np.concatenate([[0.0], np.cumsum(seg)]))
        object.__setattr__(self, "_u_tab", uu)

    @abstractmethod
    def _p(self, u: np.ndarray, order: int) -> np.ndarray:
        """The `order`-th derivative of P at parameters `u`, [len(u), 3]."""

    @property
    def length_m(self) -> float:
        return float(self._s_tab[-1])

    def _u(self, s: np.ndarray) -> np.ndarray:
        u = np.interp(s, self._s_tab, self._u_tab)
        i = np.clip(np.searchsorted(self._s_tab, s, side="right") - 1, 0, len(self._s_tab) - 2)
        # Newton on s(u) = s_tab[i] + ∫_{u_i}^{u} |P'| du (3-point Gauss per step is plenty on the sub-grid).
        xg, wg = np.polynomial.legendre.leggauss(3)
        for _ in range(3):
            a = self._u_tab[i]
            nodes = (a + u)[:, None] / 2 + ((u - a) / 2)[:, None] * xg
            sp = np.linalg.norm(self._p(nodes.ravel(), 1), axis=1).reshape(nodes.shape)
            s_u = self._s_tab[i] + (u - a) / 2 * (sp * wg).sum(axis=1)
            u = u - (s_u - s) / np.linalg.norm(self._p(u, 1), axis=1)
        return u

    def eval(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        u = self._u(s)
        if order == 0:
            return self._p(u, 0)
        d1, d2 = self._p(u, 1), self._p(u, 2)
        n1 = np.linalg.norm(d1, axis=1)[:, None]
        if order == 1:
            return d1 / n1
        # p'' = P''·u'² + P'·u'', u' = 1/|P'|, u'' = −(P'·P'')/|P'|⁴
        dot = (d1 * d2).sum(axis=1)[:, None]
        return d2 / n1**2 - d1 * dot / n1**4


@dataclass(frozen=True, eq=False)
class SplineCurve(_ArcLengthCurve):
    """C² cubic spline through waypoints (chord-length knots, not-a-knot), by arc length."""

    points: np.ndarray
    _spline: CubicSpline = field(init=False, repr=False)

    def __post_init__(self) -> None:
        chord = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        u = np.concatenate([[0.0], np.cumsum(chord)])
        bc = "not-a-knot" if len(self.points) > 3 else "natural"
        object.__setattr__(self, "_spline", CubicSpline(u, self.points, bc_type=bc))
        self._setup(u)

    def _p(self, u: np.ndarray, order: int) -> np.ndarray:
        return self._spline(u, order)


@dataclass(frozen=True, eq=False)
class BlendCurve(_ArcLengthCurve):
    """A corner blend with continuous curvature: the quintic Bézier whose control points lie a third,
    two thirds and all of `zone` along each segment from the corner. Its first three control points are
    on the incoming line and its last three on the outgoing one, so tangent and curvature (zero) match
    the straight segments at both ends: no curvature step, hence no joint-acceleration step, at the
    junctions (a circular blend has one, which no finite torque rate can follow at speed)."""

    corner: np.ndarray
    d_in: np.ndarray
    d_out: np.ndarray
    zone: float
    _ctrl: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        f = np.array([1.0, 2 / 3, 1 / 3])
        ctrl = np.vstack(
            [
                self.corner - self.zone * f[:, None] * self.d_in,
                self.corner + self.zone * f[::-1, None] * self.d_out,
            ]
        )
        object.__setattr__(self, "_ctrl", ctrl)
        self._setup(np.linspace(0.0, 1.0, 5))

    def _p(self, u: np.ndarray, order: int) -> np.ndarray:
        u = np.atleast_1d(np.asarray(u, dtype=float))[:, None]
        c = self._ctrl
        n = len(c) - 1
        for _ in range(order):  # derivative control points
            c = n * np.diff(c, axis=0)
            n -= 1
        from math import comb

        basis = np.hstack([comb(n, k) * u**k * (1 - u) ** (n - k) for k in range(n + 1)])
        return basis @ c


@dataclass(frozen=True, eq=False)
class OrientationLaw:
    """R(σ) = R0·exp(w·σ/L): held (w = 0) or slerped at a constant rate from R0 to R1 over length L."""

    r0: np.ndarray
    w: np.ndarray  # body-frame rotation vector over the whole path, rad
    length_m: float

    @classmethod
    def slerp(cls, r0: np.ndarray, r1: np.ndarray, length_m: float) -> OrientationLaw:
        return cls(r0, pin.log3(r0.T @ r1), length_m)

    def rotation(self, s: np.ndarray) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return np.array([self.r0 @ pin.exp3(self.w * si / self.length_m) for si in s])

    def angular_rate(self, s: np.ndarray) -> np.ndarray:
        """dθ/dσ in the base frame, rad/m (constant: exp(w·σ/L) leaves w unchanged)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return np.broadcast_to(self.r0 @ self.w / self.length_m, (len(s), 3)).copy()


@dataclass(frozen=True, eq=False)
class CartesianPath:
    """TCP pose along σ ∈ [0, length_m] (base frame). `spec` is what it was built from (or None)."""

    curve: Curve
    orientation: OrientationLaw
    name: str = ""
    spec: PathSpec | None = None

    @property
    def length_m(self) -> float:
        return float(self.curve.length_m)

    def position(self, s, order: int = 0) -> np.ndarray:
        return self.curve.eval(s, order)

    def rotation(self, s) -> np.ndarray:
        return self.orientation.rotation(s)

    def twist_rate(self, s) -> np.ndarray:
        """[p'(σ); ω'(σ)]: TCP velocity per unit σ̇ (m/m and rad/m, base frame), shape [N, 6]."""
        return np.hstack([self.curve.eval(s, 1), self.orientation.angular_rate(s)])

    def poses(self, s) -> list[pin.SE3]:
        p, r = self.position(s), self.rotation(s)
        return [pin.SE3(ri, pi) for pi, ri in zip(p, r, strict=True)]


# ---------------------------------------------------------------------------------------------------
# Building paths from specs


def rpy_matrix(v) -> np.ndarray:
    """Rotation matrix of roll-pitch-yaw angles (rad, fixed axes x-y-z), as Pinocchio defines them."""
    return pin.rpy.rpyToMatrix(np.asarray(v, dtype=float))


def _circle_from_points(p1, p2, p3, full: bool, field_name: str) -> ArcCurve:
    a, b = p2 - p1, p3 - p1
    n = np.cross(a, b)
    if min(np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(p3 - p2)) < MIN_SEGMENT_M:
        raise InputError("two of the three circle points coincide (zero-length arc)", field=field_name)
    if np.linalg.norm(n) < 1e-9 * np.linalg.norm(a) * np.linalg.norm(b):
        raise InputError(
            "the three circle points are collinear: no circle passes through them", field=field_name
        )
    # Circumcentre: p1 + (|a|²·(b×n) + |b|²·(n×a)) / (2|n|²)
    centre = p1 + (np.dot(a, a) * np.cross(b, n) + np.dot(b, b) * np.cross(n, a)) / (2 * np.dot(n, n))
    radius = float(np.linalg.norm(p1 - centre))
    e1 = (p1 - centre) / radius
    e2 = np.cross(unit_vector(n), e1)
    d3 = p3 - centre
    sweep = 2 * np.pi if full else float(np.mod(np.arctan2(d3 @ e2, d3 @ e1), 2 * np.pi))
    return ArcCurve(centre, e1, e2, radius, sweep)


def _circle_from_centre(c: Circle) -> ArcCurve:
    n = np.asarray(c.normal, dtype=float)
    if np.linalg.norm(n) < 1e-12:
        raise InputError("normal must not be zero", field="geometry.normal")
    n = unit_vector(n)
    d = np.asarray(c.start_direction, dtype=float)
    d = d - (d @ n) * n
    if np.linalg.norm(d) < 1e-9:
        raise InputError("start_direction is parallel to the normal", field="geometry.start_direction")
    e1 = unit_vector(d)
    e2 = np.cross(n, e1)
    sweep = c.sweep_rad
    if sweep < 0:
        e2, sweep = -e2, -sweep
    return ArcCurve(np.asarray(c.centre_m, dtype=float), e1, e2, float(c.radius_m), float(sweep))


def _polyline(points: np.ndarray, zone: float) -> ChainCurve:
    """Straight segments through `points`; each interior corner rounded by a `BlendCurve` that leaves
    and joins the segments `zone` metres from the corner (0: sharp corners)."""
    seg = np.diff(points, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    for i, length in enumerate(lengths):
        if length < MIN_SEGMENT_M:
            raise InputError(
                f"zero-length segment: point {i + 1} equals point {i}", field=f"geometry.points_m[{i + 1}]"
            )
    dirs = seg / lengths[:, None]
    cut = np.zeros(len(points))
    for i in range(1, len(points) - 1):
        turn = np.arccos(float(np.clip(dirs[i - 1] @ dirs[i], -1, 1)))
        if turn > np.pi - 1e-6:
            raise InputError(
                f"the path reverses at point {i}: no blend can round it", field=f"geometry.points_m[{i}]"
            )
        if zone > 0 and turn > 1e-9:
            cut[i] = zone
    for i, length in enumerate(lengths):
        if cut[i] + cut[i + 1] > length + 1e-12:
            raise InputError(
                f"blend_radius_m too large: the blends at points {i} and {i + 1} need "
                f"{cut[i] + cut[i + 1]:.4g} m of a {length:.4g} m segment",
                field="geometry.blend_radius_m",
            )
    parts: list = []
    for i in range(len(lengths)):
        a = points[i] + dirs[i] * cut[i]
        b = points[i + 1] - dirs[i] * cut[i + 1]
        if np.linalg.norm(b - a) > MIN_SEGMENT_M:
            parts.append(LineCurve(a, b))
        corner = i + 1
        if corner < len(points) - 1 and cut[corner] > 0:
            parts.append(BlendCurve(points[corner], dirs[corner - 1], dirs[corner], cut[corner]))
    return ChainCurve(tuple(parts))


def build_curve(geometry) -> Curve:
    if isinstance(geometry, Line):
        a, b = np.asarray(geometry.start_m, float), np.asarray(geometry.end_m, float)
        if np.linalg.norm(b - a) < MIN_SEGMENT_M:
            raise InputError("zero-length segment: end_m equals start_m", field="geometry.end_m")
        return LineCurve(a, b)
    if isinstance(geometry, Circle):
        if geometry.points_m is not None:
            p1, p2, p3 = (np.asarray(p, float) for p in geometry.points_m)
            return _circle_from_points(p1, p2, p3, geometry.full, "geometry.points_m")
        return _circle_from_centre(geometry)
    if isinstance(geometry, Polyline):
        return _polyline(np.asarray(geometry.points_m, float), geometry.blend_radius_m)
    if isinstance(geometry, Spline):
        pts = np.asarray(geometry.points_m, float)
        for i in range(1, len(pts)):
            if np.linalg.norm(pts[i] - pts[i - 1]) < MIN_SEGMENT_M:
                raise InputError(
                    f"zero-length segment: point {i} equals point {i - 1}", field=f"geometry.points_m[{i}]"
                )
        return SplineCurve(pts)
    raise TypeError(f"unknown geometry {type(geometry).__name__}")


def _positions(geometry) -> list[tuple[str, np.ndarray, bool]]:
    """(field, value, is a distance from the base origin) of every length in a path geometry."""
    g = geometry
    out: list[tuple[str, np.ndarray, bool]] = []
    for name in ("start_m", "end_m", "centre_m"):
        if getattr(g, name, None) is not None:
            out.append((name, np.asarray(getattr(g, name), float), True))
    points = getattr(g, "points_m", None)
    if points is not None:
        out += [(f"points_m.{i}", np.asarray(p, float), True) for i, p in enumerate(points)]
    if getattr(g, "radius_m", None) is not None:
        out.append(("radius_m", np.asarray(g.radius_m, float), False))
    return out


def check_within_reach(spec: PathSpec, robot: Robot) -> None:
    """Refuse a path with a position no configuration of `robot` can reach, whatever the IK: farther
    from the base origin than `Robot.reach_from_base_m` (a circle: a radius above it). Such a file is not in
    this robot's base frame or not in metres (millimetres, typically): bad input (InputError naming
    the field, exit 2), not an unreachable stretch (exit 3)."""
    reach = robot.reach_from_base_m
    for name, v, is_point in _positions(spec.geometry):
        dist = float(np.linalg.norm(v))
        if dist <= reach:
            continue
        what = "is" if is_point else "radius"
        unit = ""
        if dist / 1000 <= reach:
            unit = f"; positions are in metres: millimetres? ({dist / 1000:.4g} m as mm)"
        raise InputError(
            f"{np.round(v, 6).tolist()} {what} {dist:.4g} m from the base origin, beyond the "
            f"{reach:.3f} m {robot.name} can reach in any configuration{unit}",
            field=f"geometry.{name}",
        )


def build_path(spec: PathSpec) -> CartesianPath:
    """The `CartesianPath` of a path spec; InputError (field named) on degenerate geometry."""
    curve = build_curve(spec.geometry)
    if curve.length_m < MIN_SEGMENT_M:
        raise InputError("zero-length path", field="geometry")
    o: Orientation = spec.orientation
    r0 = rpy_matrix(o.start)
    law = OrientationLaw.slerp(r0, rpy_matrix(o.end), curve.length_m)
    return CartesianPath(curve, law, name=spec.name, spec=spec)


def load_path(path: Path, robot: Robot) -> tuple[PathSpec, CartesianPath]:
    """A path file (`rxcomm/Path`) for `robot` as spec and `CartesianPath`; InputError names the file
    and the field (a TCP other than the robot's, a joint count, a geometry that cannot be built)."""
    data = load_yaml(path)
    check_kind(data, PathSpec, file=path)
    spec = validate_model(PathSpec, data, file=path)
    if spec.tcp_xyz_m is not None and not np.allclose(spec.tcp_xyz_m, robot.drives.tcp.xyz_m, atol=1e-6):
        raise InputError(
            f"the path was written for a TCP at {list(spec.tcp_xyz_m)} m from "
            f"{robot.drives.tcp.parent_frame}; the robot's TCP is at {list(robot.drives.tcp.xyz_m)} m",
            file=path,
            field="tcp_xyz_m",
        )
    if spec.q_start_rad is not None and len(spec.q_start_rad) != robot.n:
        raise InputError(f"expected {robot.n} joint angles", file=path, field="q_start_rad")
    try:
        check_within_reach(spec, robot)
        return spec, build_path(spec)
    except InputError as e:
        raise InputError(e.reason, file=path, field=e.field) from e
