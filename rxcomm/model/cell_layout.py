"""A stated default cell for a robot that comes without one (`import-robot`): the layout scaled by reach.

`cell.yaml` holds what a robot model does not: where the floor and the tracker are, what the arm must
not hit, where excitation may take it. For an imported robot none of it is known, so `default_cell`
lays out the samples' cell scaled to the robot's reach R (shoulder → TCP stretched) and shoulder
height h, and `layout_notes` says each choice, for the file's header and the console:

- floor at the base origin's height (a robot bolted to its mounting plate), clearance 0.05 m;
- workspace box ±(R_base + 0.2) m around the base (R_base: base origin → TCP stretched), up to
  h + R + 0.2 m;
- self-collision capsules of radius 0.16·R (base to shoulder) and 0.09·R (upper arm), margin 0.04 m:
  the M900 sample's 0.15 / 0.08 m at its 0.93 m reach;
- a 6D tracker 2.2·R in front of the base (+x), at the base's height, looking at (0.5·R, 0, h), its
  datasheet noise 50 µm / 0.1 mrad, field of view ±0.7 rad, probe facing it within ±1.05 rad;
- the excitation's allowed region: tool and wrist centre within R of the base, the elbow within
  0.75·R, all above twice the floor clearance.
"""

from __future__ import annotations

import numpy as np

from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import (
    AllowedRegion,
    Box,
    Cell,
    GatewayDefaults,
    Placement,
    SelfCollision,
    TrackerSpec,
    Workspace,
)

FLOOR_CLEARANCE_M = 0.05


def _mm(x: float) -> float:
    return round(float(x), 3) + 0.0  # + 0.0: no -0.0 in the file


TRACKER_DISTANCE_REACHES = 2.2


def default_cell(robot: Robot) -> Cell:
    """The module's stated layout for `robot` (base frame, m, rad)."""
    reach, h = _mm(robot.reach_m), _mm(robot.shoulder_height_m)
    side = _mm(robot.reach_from_base_m + 0.2)
    low = 2 * FLOOR_CLEARANCE_M

    def box(xy: float, z_lo: float, z_hi: float) -> Box:
        return Box(min_m=(-xy, -xy, z_lo), max_m=(xy, xy, z_hi))

    tracker_at = np.array([_mm(TRACKER_DISTANCE_REACHES * reach), 0.0, 0.0])
    target = np.array([0.5 * reach, 0.0, h])
    view = target - tracker_at
    return Cell(
        kind="rxcomm/Cell",
        schema_version=1,
        robot=".",
        workspace=Workspace(
            box=box(side, 0.0, _mm(h + reach + 0.2)), floor_z_m=0.0, floor_clearance_m=FLOOR_CLEARANCE_M
        ),
        self_collision=SelfCollision(
            margin_m=0.04, base_radius_m=_mm(0.16 * reach), upper_arm_radius_m=_mm(0.09 * reach)
        ),
        tracker=TrackerSpec(
            tracker_to_base=Placement(xyz_m=tuple(_mm(-x) for x in tracker_at)),
            view_axis_in_tracker=tuple(round(float(x), 6) + 0.0 for x in view / np.linalg.norm(view)),
            half_angle_rad=0.7,
            range_min_m=0.3,
            range_max_m=_mm(tracker_at[0] + side + h + reach),
            probe_half_angle_rad=1.05,
            measures="pose",
            position_sigma_m=5e-5,
            orientation_sigma_rad=1e-4,
        ),
        gateway=GatewayDefaults(),
        allowed_region=AllowedRegion(
            tool=box(reach, low, _mm(h + reach)),
            wrist_centre=box(reach, low, _mm(h + reach)),
            elbow=box(_mm(0.75 * reach), low, _mm(h + 0.75 * reach)),
        ),
    )


def layout_notes(robot: Robot) -> list[str]:
    """What `default_cell` assumed, in words with this robot's numbers."""
    reach, h = robot.reach_m, robot.shoulder_height_m
    return [
        f"floor at the base origin (z = 0), clearance {FLOOR_CLEARANCE_M} m; workspace box "
        f"±{robot.reach_from_base_m + 0.2:.3f} m, up to {h + reach + 0.2:.3f} m",
        f"6D tracker {TRACKER_DISTANCE_REACHES * reach:.3f} m in front of the base (+x, base height), "
        f"50 µm / 0.1 mrad, looking at ({0.5 * reach:.3f}, 0, {h:.3f}) m",
        f"self-collision radii {0.16 * reach:.3f} m (base) / {0.09 * reach:.3f} m (upper arm); "
        f"excitation: tool and wrist within {reach:.3f} m, elbow within {0.75 * reach:.3f} m",
    ]
