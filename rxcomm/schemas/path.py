"""`PATH.yaml`: a Cartesian TCP path for `plan-cp` (architecture §7 plan-cp, paper §5.1).

A config file written by hand or by the ISO 9283 generator (`rxcomm.planning.paths.iso9283_paths`): no
envelope, but `kind`/`schema_version` so a wrong file is refused by name. Every position and
orientation is of the robot's TCP (drives.yaml `tcp`) in the robot's **base frame** (URDF root), SI
units. The path parameter σ is the TCP arc length in m, from 0 at the start to the path length.

Geometry (one per file, `geometry.type`):
- `line`: `start_m` → `end_m`;
- `circle`: three points (`points_m`: arc from the first through the second to the third, or the full
  circle through them with `full: true`), or `centre_m` + `normal` + `radius_m` with the start
  direction `start_direction` and the swept angle `sweep_rad` (right-handed about `normal`);
- `polyline`: straight segments through `points_m`, each corner rounded by a blend that leaves and
  rejoins the segments `blend_radius_m` from the corner (a zone, as robot controllers define it), with
  continuous curvature (0: sharp corners, which no finite acceleration can follow);
- `spline`: a C² cubic spline through `points_m` (chord-length knots, not-a-knot ends).

Orientation: `hold` keeps `rpy` along the path; `slerp` turns at a constant rate (per metre) from
`rpy` to `end_rpy`. Angles are URDF roll-pitch-yaw, R = Rz(yaw)·Ry(pitch)·Rx(roll), given in rad
(`rpy_rad`) or degrees (`rpy_deg`), exactly one of them.

IK branch: `branch` picks the start configuration by shoulder (`front`: wrist centre in front of the
J1 axis), elbow (`up`: elbow above the shoulder–wrist line) and wrist (`positive`: J5 > 0); or give
`q_start_rad` to start from the IK solution nearest to it. The branch is then followed continuously.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import ConfigDict, Field, model_validator

from rxcomm.schemas.strict import Strict

Vec3 = tuple[float, float, float]


class _Finite(Strict):
    # NaN and inf are refused by name (YAML reads `.nan`, `.inf` as floats): a path file is bad input,
    # not an IK failure at "σ = nan m"
    model_config = ConfigDict(allow_inf_nan=False)


class Line(_Finite):
    type: Literal["line"]
    start_m: Vec3
    end_m: Vec3


class Circle(_Finite):
    """A circular arc or full circle: three points, or centre + normal + radius."""

    type: Literal["circle"]
    points_m: tuple[Vec3, Vec3, Vec3] | None = Field(
        None, description="start, a point on the way, end (or three points of the full circle)"
    )
    full: bool = Field(
        False, description="with points_m: the whole circle from the first point, via the others"
    )
    centre_m: Vec3 | None = None
    normal: Vec3 | None = Field(None, description="plane normal; the arc turns right-handed about it")
    radius_m: float | None = Field(None, gt=0)
    start_direction: Vec3 | None = Field(
        None, description="from the centre towards the start point (projected onto the plane)"
    )
    sweep_rad: float = Field(2 * math.pi, description="swept angle with centre_m (2π: full circle)")

    @model_validator(mode="after")
    def _one_form(self) -> Circle:
        by_centre = (self.centre_m, self.normal, self.radius_m, self.start_direction)
        if self.points_m is not None:
            if any(v is not None for v in by_centre):
                raise ValueError("give either points_m or centre_m/normal/radius_m/start_direction, not both")
        elif any(v is None for v in by_centre):
            raise ValueError(
                "give points_m (three points) or all of centre_m, normal, radius_m, start_direction"
            )
        elif self.sweep_rad == 0:
            raise ValueError("sweep_rad must not be 0")
        return self


class Polyline(_Finite):
    type: Literal["polyline"]
    points_m: list[Vec3] = Field(min_length=2)
    blend_radius_m: float = Field(
        0.0,
        ge=0,
        description="corner zone: the blend leaves and rejoins the segments this far from the corner",
    )


class Spline(_Finite):
    type: Literal["spline"]
    points_m: list[Vec3] = Field(min_length=2)


Geometry = Annotated[Line | Circle | Polyline | Spline, Field(discriminator="type")]


class Orientation(_Finite):
    """TCP orientation along the path (URDF rpy, base frame)."""

    mode: Literal["hold", "slerp"] = "hold"
    rpy_rad: Vec3 | None = None
    rpy_deg: Vec3 | None = None
    end_rpy_rad: Vec3 | None = Field(None, description="slerp: orientation at the end of the path")
    end_rpy_deg: Vec3 | None = None

    @model_validator(mode="after")
    def _angles(self) -> Orientation:
        if (self.rpy_rad is None) == (self.rpy_deg is None):
            raise ValueError("give exactly one of rpy_rad or rpy_deg")
        has_end = self.end_rpy_rad is not None or self.end_rpy_deg is not None
        if self.end_rpy_rad is not None and self.end_rpy_deg is not None:
            raise ValueError("give at most one of end_rpy_rad or end_rpy_deg")
        if self.mode == "slerp" and not has_end:
            raise ValueError("mode slerp needs end_rpy_rad or end_rpy_deg")
        if self.mode == "hold" and has_end:
            raise ValueError("mode hold takes no end orientation (use mode: slerp)")
        return self

    @property
    def start(self) -> Vec3:
        return self.rpy_rad if self.rpy_rad is not None else tuple(math.radians(a) for a in self.rpy_deg)

    @property
    def end(self) -> Vec3:
        if self.mode == "hold":
            return self.start
        if self.end_rpy_rad is not None:
            return self.end_rpy_rad
        return tuple(math.radians(a) for a in self.end_rpy_deg)


class Branch(_Finite):
    """Which IK solution to start from (each None: either)."""

    shoulder: Literal["front", "back"] | None = "front"
    elbow: Literal["up", "down"] | None = "up"
    wrist: Literal["positive", "negative"] | None = "positive"


class PathLimits(_Finite):
    """Optional Cartesian limits that belong to the path (e.g. ISO 9283 tests at 1 m/s, 5 m/s²)."""

    tcp_speed_max_m_s: float | None = Field(None, gt=0)
    tcp_acceleration_max_m_s2: float | None = Field(None, gt=0)


class PathSpec(_Finite):
    """One TCP path in the robot base frame."""

    KIND: ClassVar[str] = "rxcomm/Path"
    SCHEMA_VERSION: ClassVar[int] = 1

    kind: Literal["rxcomm/Path"]
    schema_version: Literal[1]
    name: str = ""
    description: str = ""
    frame: Literal["base"] = Field(
        "base", description="positions and orientations are in the robot base frame"
    )
    tcp_xyz_m: Vec3 | None = Field(
        None,
        description="the TCP offset from the drives.yaml tcp parent frame this path was written for; "
        "checked against the robot when given",
    )
    geometry: Geometry
    orientation: Orientation
    branch: Branch = Branch()
    q_start_rad: list[float] | None = Field(
        None, description="start from the IK solution nearest to this (overrides branch)"
    )
    limits: PathLimits = PathLimits()
