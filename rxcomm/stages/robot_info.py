"""`rxcomm robot-info --robot DIR`: what a commissioning engineer checks first about a robot description."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rxcomm import console
from rxcomm.options import RobotDir

if TYPE_CHECKING:  # the model (pinocchio, scipy) is imported where used: `--help` stays fast
    from rxcomm.model.robot import Robot

# A tracker target 50 mm off the TCP's z axis (in the TCP frame): position-only calibration needs one
# off the J6 axis, or the J6 offset and the tool's in-axis terms are invisible.
OFF_AXIS_POINT = (0.05, 0.0, 0.0)


def stretched_pose(robot: Robot) -> np.ndarray:
    """All joints at zero except J2, chosen within its limits to put the flange furthest from the J1 axis.

    For arms whose zero pose is upright (both samples) this is the arm stretched horizontally, the
    worst case for J2's gravity load.
    """
    import pinocchio as pin
    from scipy.optimize import minimize_scalar

    data = robot.create_data()

    def reach(q2: float) -> float:
        q = np.zeros(robot.n)
        q[1] = q2
        pin.framesForwardKinematics(robot.model, data, q)
        p = data.oMf[robot.flange_frame_id].translation
        return float(np.hypot(p[0], p[1]))

    grid = np.linspace(robot.q_min[1], robot.q_max[1], 721)
    i = int(np.argmax([reach(x) for x in grid]))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best = minimize_scalar(lambda x: -reach(x), bounds=(lo, hi), method="bounded", options={"xatol": 1e-9})
    q = np.zeros(robot.n)
    q[1] = best.x
    return q


def robot_facts(robot: Robot) -> dict[str, object]:
    """The figures `robot-info` prints before the catalogue limits, as a flat mapping (SI units)."""
    from rxcomm.model.dynamics import RobotDynamics, prior_parameters
    from rxcomm.model.geometric_errors import identifiable_count

    q = stretched_pose(robot)
    dyn = RobotDynamics(robot, prior_parameters(robot))
    g = dyn.gravity_torque(q, include_spring=False)
    spring = dyn.gravity_torque(q, include_spring=True) - g
    facts: dict[str, object] = {
        "name": robot.name,
        "dof": robot.n,
        "moving_mass_kg": float(sum(robot.model.inertias[i].mass for i in range(1, robot.model.njoints))),
        "reach_m": robot.reach_m,
        "stretched_pose_rad": q.tolist(),
        "stretched_gravity_torque_nm": g.tolist(),
        "stretched_spring_torque_nm": spring.tolist(),
        "stretched_net_torque_nm": (g + spring).tolist(),
        "peak_torque_nm": robot.tau_max.tolist(),
        "identifiable_geometric_full_pose": identifiable_count(robot, position_only=False),
        "identifiable_geometric_position_only": identifiable_count(
            robot, position_only=True, point=OFF_AXIS_POINT
        ),
        "identifiable_geometric_tcp_position_only": identifiable_count(robot, position_only=True),
    }
    return facts


def catalogue_facts(robot: Robot) -> dict[str, object]:
    """The catalogue limits a generic controller may use at the rated payload (model.catalogue); {}
    without a rated payload. InfeasibleError (exit 3) for a robot too weak to hold its payload."""
    from rxcomm.model.catalogue import catalogue_limits

    facts: dict[str, object] = {}
    if robot.drives.rated_payload is not None:
        cat = catalogue_limits(robot)
        facts |= {
            "rated_payload_kg": cat.payload_kg,
            "catalogue_velocity_rad_s": cat.v_max.tolist(),
            "catalogue_acceleration_rad_s2": cat.a_max.tolist(),
            "catalogue_bound_by": ", ".join(sorted(set(cat.bound_by))),
        }
    return facts


@console.stage_command
def command(robot_dir: RobotDir) -> dict[str, object]:
    """Print a robot's DOF, limits, reach, mass, the stretched-pose gravity load and identifiability."""
    from rxcomm.model.robot import load_robot

    robot = load_robot(robot_dir)
    facts = robot_facts(robot)
    out = console.out
    out.print(f"[bold]{robot.name}[/]  ({robot.urdf_path}, {robot.drives_path})")
    out.print(f"  degrees of freedom    {robot.n}")
    out.print(f"  moving mass           {facts['moving_mass_kg']:.1f} kg")
    out.print(
        f"  reach                 {facts['reach_m']:.3f} m (shoulder → TCP, links in a line: Robot.reach_m)"
    )
    out.print(f"  drive cycle           {robot.drives.cycle_s * 1e6:.0f} µs")
    out.print("")
    out.print("  joint       lower°    upper°   vmax°/s   amax rad/s²  peak N·m  cont N·m  ratio")
    for i, name in enumerate(robot.joint_names):
        out.print(
            f"  {name:<10} {np.degrees(robot.q_min[i]):8.1f} {np.degrees(robot.q_max[i]):8.1f} "
            f"{np.degrees(robot.v_max[i]):8.0f} {robot.a_max[i]:12.1f} {robot.tau_max[i]:9.0f} "
            f"{robot.tau_cont[i]:9.0f} {robot.gear_ratio[i]:6.0f}"
        )
    g = np.array(facts["stretched_gravity_torque_nm"])
    s = np.array(facts["stretched_spring_torque_nm"])
    j = int(np.argmax(np.abs(g)))
    out.print("")
    out.print(f"  arm stretched horizontally (q = {np.round(facts['stretched_pose_rad'], 3).tolist()} rad):")
    out.print(
        f"    gravity alone needs {abs(g[j]):.0f} N·m on {robot.joint_names[j]} "
        f"({abs(g[j]) / robot.tau_max[j]:.0%} of its {robot.tau_max[j]:.0f} N·m peak)"
    )
    if robot.drives.spring is not None:
        net = abs(g[j] + s[j])
        out.print(
            f"    the balancing spring gives {abs(s[j]):.0f} N·m, leaving {net:.0f} N·m "
            f"({net / robot.tau_max[j]:.0%} of peak) for the motor"
        )
    else:
        out.print("    no balancing spring")
    out.print("")
    out.print(
        f"  identifiable geometric parameters: {facts['identifiable_geometric_full_pose']} with full-pose "
        f"measurement, {facts['identifiable_geometric_position_only']} with the position of an off-axis "
        f"point ({facts['identifiable_geometric_tcp_position_only']} with the TCP position), of 48 modelled"
    )
    facts |= catalogue_facts(robot)  # after the figures: a robot too weak for its payload is exit 3
    if "catalogue_velocity_rad_s" in facts:
        out.print(
            f"  catalogue limits (rated payload {facts['rated_payload_kg']:g} kg, worst case of the prior "
            f"model, bound by {facts['catalogue_bound_by']}'s peak torque):"
        )
        v = np.degrees(facts["catalogue_velocity_rad_s"])
        out.print("    vmax°/s      " + " ".join(f"{x:7.1f}" for x in v))
        out.print("    amax rad/s²  " + " ".join(f"{x:7.2f}" for x in facts["catalogue_acceleration_rad_s2"]))
    return facts
