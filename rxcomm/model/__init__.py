"""The robot model: what the robot is, independent of any measurement or plan.

Owns the immutable `Robot` (Pinocchio model + drives data) and everything computed from it alone:
kinematics and the one IK, rigid-body dynamics and its symbolic (CasADi) form, the gravity spring,
the geometric error model and its identifiable subset, base inertial parameters, and joint/motor
limit checks. Paper §2 (models), §3.1 (geometric errors), §4.1 (dynamic model and base parameters).

May import: `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`. Nothing above (see docs/architecture.md).
"""
