"""Trajectory planning: Cartesian paths and their time/energy-optimal timing (paper §5).

- ``paths``: arc-length parametrised TCP paths and the ISO 9283 test paths;
- ``path_ik``: IK along a path on one branch, as a C² joint spline;
- ``topp``, ``path_dynamics``, ``path_nlp``, ``path_profile``: the timing along a fixed path
  (toppra's time-optimal profile, the energy-weighted NLP) (§5.1–5.3);
- ``timing``, ``cp_grid``: one solver interface over both timings and the grids they run on;
- ``cp``: continuous-path planning that chains them;
- ``ptp_problem``, ``ptp_ocp``, ``ptp``, ``ptp_shooting``, ``warm_start``: point-to-point optimal control
  (§5.4): its inputs, the OCP transcription, planning with the dense check, the shooting peer.

May import: `rxcomm.model`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`. Independent of
calibration and identification (see docs/architecture.md).
"""
