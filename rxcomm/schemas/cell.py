"""`cell.yaml`: the robot cell around one robot (architecture §1: workspace, tracker, gateway).

A config file, not a stage output: no envelope, but a `kind`/`schema_version` so a wrong file is
refused by name. Frames: everything geometric is in the robot's nominal **base frame** (the URDF
root) unless the field says `_in_tracker` / `_in_tcp`. SI units, named in the fields.

Extensible: stages that need more cell data (e.g. excitation settings) add a sub-model field here
with a default, so older cell files stay valid.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from rxcomm.schemas.strict import Strict

Vec3 = tuple[float, float, float]


class Placement(Strict):
    """A rigid placement: translation (m) then URDF-style rpy (rad; R = Rz(yaw)·Ry(pitch)·Rx(roll))."""

    xyz_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_rad: Vec3 = (0.0, 0.0, 0.0)


class Box(Strict):
    """An axis-aligned box in the base frame."""

    min_m: Vec3
    max_m: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if any(lo >= hi for lo, hi in zip(self.min_m, self.max_m, strict=True)):
            raise ValueError(f"min_m {self.min_m} must be below max_m {self.max_m} on every axis")
        return self


class Workspace(Strict):
    """Where the arm may be: TCP, wrist centre and elbow inside `box` and above the floor."""

    box: Box
    floor_z_m: float = Field(0.0, description="floor height in the base frame, m")
    floor_clearance_m: float = Field(
        0.05, ge=0, description="minimum height of TCP/wrist/elbow above the floor"
    )

    def box_above_floor(self) -> Box:
        """`box` with its bottom raised to the floor plus the clearance."""
        lo = list(self.box.min_m)
        lo[2] = max(lo[2], self.floor_z_m + self.floor_clearance_m)
        return Box(min_m=(lo[0], lo[1], lo[2]), max_m=self.box.max_m)


class SelfCollision(Strict):
    """A simple self-collision check with two capsules (segments with a radius) of the arm.

    - base capsule: from the base origin to the shoulder (origin of joint 2);
    - upper-arm capsule: from the shoulder to the elbow (origin of joint 3).
    A configuration is refused when the TCP or the wrist centre (origin of joint 5) comes closer than
    radius + `margin_m` to the base capsule, or the TCP closer than radius + `margin_m` to the upper
    arm. The forearm/wrist against the upper arm is left to the joint-3 limits.
    """

    margin_m: float = Field(0.05, ge=0)
    base_radius_m: float = Field(gt=0)
    upper_arm_radius_m: float = Field(gt=0)


class TrackerSpec(Strict):
    """The measuring device (laser tracker / stereo camera) and its probe on the TCP.

    `tracker_to_base` is the *nominal* pose of the robot base in the tracker frame (from the cell
    layout); calibration estimates the real one (`base.*` errors). A TCP is visible when its distance
    to the tracker is within the range, the direction to it is within `half_angle_rad` of `view_axis`,
    and the probe axis points at the tracker within `probe_half_angle_rad`. Pose selection keeps its
    candidates `visibility_margin_rad` inside both cones: the real robot's geometric errors turn the
    probe by milliradians, enough to take a pose chosen on the nominal cone's edge out of view.
    """

    tracker_to_base: Placement
    view_axis_in_tracker: Vec3 = Field(description="direction the tracker looks, tracker frame (normalised)")
    half_angle_rad: float = Field(gt=0, le=math.pi)
    range_min_m: float = Field(ge=0)
    range_max_m: float = Field(gt=0)
    probe_axis_in_tcp: Vec3 = Field((0.0, 0.0, 1.0), description="probe normal in the TCP frame")
    probe_half_angle_rad: float = Field(math.pi / 3, gt=0, le=math.pi)
    visibility_margin_rad: float = Field(
        0.02, ge=0, description="pose selection stays this far inside the view and probe cones, rad"
    )
    measures: Literal["pose", "position"] = Field("pose", description="6D probe (pose) or position only")
    position_sigma_m: float = Field(5e-5, gt=0, description="datasheet position noise (1σ), m")
    orientation_sigma_rad: float = Field(1e-4, gt=0, description="datasheet orientation noise (1σ), rad")
    sample_rate_hz: float = Field(
        1000.0, gt=0, le=10000, description="rate of the tracker's samples while the robot moves, Hz"
    )

    @model_validator(mode="after")
    def _check(self) -> TrackerSpec:
        if self.range_min_m >= self.range_max_m:
            raise ValueError("range_min_m must be below range_max_m")
        if self.visibility_margin_rad >= min(self.half_angle_rad, self.probe_half_angle_rad):
            raise ValueError("visibility_margin_rad must be smaller than both cone half-angles")
        for name in ("view_axis_in_tracker", "probe_axis_in_tcp"):
            if math.hypot(*getattr(self, name)) < 1e-9:
                raise ValueError(f"{name} must not be zero")
        return self


class GatewayDefaults(Strict):
    """Where `run` finds the drive gateway when `--gateway` is not given (architecture §6)."""

    host: str = "127.0.0.1"
    port: int = Field(1502, ge=1, le=65535)
    timeout_s: float = Field(1.0, gt=0)


class AllowedRegion(Strict):
    """Where excitation trajectories may take the arm (paper eq. 30: r_E ⊂ R³_allowed), base frame."""

    tool: Box
    wrist_centre: Box
    elbow: Box


class Cell(Strict):
    kind: Literal["rxcomm/Cell"]
    schema_version: Literal[1]
    robot: str | None = Field(None, description="robot directory this cell was laid out for (informative)")
    workspace: Workspace
    self_collision: SelfCollision
    tracker: TrackerSpec
    gateway: GatewayDefaults = GatewayDefaults()
    allowed_region: AllowedRegion
