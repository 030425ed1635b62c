"""The ISO 9283 performance criteria of one robot state (`rxcomm iso9283` → ``iso9283.yaml``).

One entry per criterion and test position or path, as ISO 9283:1998 defines them (§7.2 pose
accuracy/repeatability, §7.6 corner overshoot, §8 path accuracy/repeatability, §8.7 path velocity):

- ``AP_p`` (m) distance of the barycentre of the attained positions from the command position;
  ``AP_a``, ``AP_b``, ``AP_c`` (rad) mean attained minus command orientation about x, y, z;
- ``RP_l`` (m) = l̄ + 3 S_l, l the distances of the attained positions to their barycentre;
  ``RP_a``, ``RP_b``, ``RP_c`` (rad) = 3 S of the attained angles;
- ``AT_p`` (m) max over the path's normal planes of |barycentre of the cycles' crossings − command|;
  ``RT_p`` (m) max over the planes of l̄ + 3 S_l of the crossings about their barycentre;
- ``CO`` (m) corner overshoot: the farthest the attained path leaves the command path after a corner;
- ``AV`` (1, a fraction of the command speed) (mean attained − command speed) / command speed;
  ``RV`` (1) 3 S of the attained speed / command speed.

``value: null`` means "not measured" (no log given, too few cycles, no tracker channel); ``note`` says
why. Positions are in the robot's base frame (the tracker frame mapped by ``base_frame``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict

CriterionKey = Literal[
    "AP_p", "AP_a", "AP_b", "AP_c", "RP_l", "RP_a", "RP_b", "RP_c", "AT_p", "RT_p", "CO", "AV", "RV"
]
CRITERIA_UNITS: dict[str, str] = {
    "AP_p": "m",
    "AP_a": "rad",
    "AP_b": "rad",
    "AP_c": "rad",
    "RP_l": "m",
    "RP_a": "rad",
    "RP_b": "rad",
    "RP_c": "rad",
    "AT_p": "m",
    "RT_p": "m",
    "CO": "m",
    "AV": "1",
    "RV": "1",
}
POSE_CRITERIA = ("AP_p", "AP_a", "AP_b", "AP_c", "RP_l", "RP_a", "RP_b", "RP_c")
PATH_CRITERIA = ("AT_p", "RT_p", "AV", "RV")
POSES = ("P1", "P2", "P3", "P4", "P5")
PATHS = ("iso9283-line", "iso9283-circle-large", "iso9283-circle-small", "iso9283-rectangle")


class Criterion(Strict):
    """One criterion at one test pose or on one test path."""

    key: CriterionKey
    target: str = Field(description="test pose P1..P5 or test path (iso9283-line, ...)")
    value: float | None = Field(description="in `unit`; null = not measured")
    unit: Literal["m", "rad", "1"]
    cycles: int | None = Field(description="cycles the value is computed over (ISO: 30 poses, 10 paths)")
    command_speed_m_per_s: float | None = Field(description="TCP speed commanded on the path, m/s")
    log: str | None = Field(description="the run log it came from (file name)")
    note: str = Field("", description="why not measured, or what the value rests on")


class CubeDefinition(Strict):
    """The ISO 9283 test cube (base frame) and its inclined plane's points."""

    centre_m: tuple[float, float, float]
    side_m: float = Field(gt=0)
    rpy_rad: tuple[float, float, float] = Field(description="command TCP orientation, URDF roll-pitch-yaw")
    plane_corners_m: list[tuple[float, float, float]] = Field(description="C1..C4 of the inclined plane")
    points_m: dict[str, tuple[float, float, float]] = Field(description="P1..P5")


class BaseFrame(Strict):
    """The robot base in the tracker frame the attained poses were mapped with."""

    xyz_m: tuple[float, float, float]
    rpy_rad: tuple[float, float, float]
    source: Literal["calibration", "cell"] = Field(
        description="the calibration's measured base frame, or the cell layout's nominal one"
    )


class EvaluationSettings(Strict):
    """How attained poses and paths are taken from the logs for the ISO 9283 criteria (not to be confused
    with `rxcomm.execution.campaign.CampaignSettings`, how a pose campaign is measured)."""

    min_dwell_s: float = Field(0.2, gt=0, description="a dwell: zero commanded velocity at least this, s")
    measure_fraction: float = Field(
        0.5, gt=0, le=1, description="the attained pose: mean of the dwell's last fraction of samples"
    )
    match_m: float = Field(0.02, gt=0, description="a dwell is at Pi when its command TCP is this near, m")
    n_points: int = Field(200, ge=10, description="command points along a path (normal planes)")
    corner_zone_m: float = Field(0.1, gt=0, description="corner overshoot zone after each corner, m")
    velocity_window_s: float = Field(0.01, gt=0, description="tracker speed: central difference ±, s")
    skip_first_dwell: bool = Field(
        True, description="the plan's first dwell (at P1, before cycle 1) is the start, not a cycle"
    )


class Iso9283Settings(EvaluationSettings):
    """The evaluation settings as recorded, with the test paths' directory."""

    paths: str = Field(description="the directory of the ISO 9283 test paths (`rxcomm plan-cp --iso9283`)")


class Iso9283Summary(Strict):
    """What a rxcomm/Iso9283 summary holds (units in the names; None: not measured)."""

    n_criteria: int
    n_measured: int
    pose_dwell_s: float | None = None
    measuring_window_s: float | None = None


class Iso9283(Artefact[Iso9283Settings, Iso9283Summary], kind="rxcomm/Iso9283", schema_version=1):
    """ISO 9283 criteria measured by the tracker on one state of the robot."""

    robot: str
    cube: CubeDefinition
    base_frame: BaseFrame
    criteria: list[Criterion]
