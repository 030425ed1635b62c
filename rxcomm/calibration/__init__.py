"""Geometric calibration: which poses to measure and what the measurements say (paper §3).

- ``pose_selection``: the workspace grid, candidate poses and the observability-optimal subset (§3.3);
- ``fit``: tracker measurements → identifiable geometric errors by Levenberg–Marquardt, the
  held-out validation, the calibrated URDF (§3.2).

May import: `rxcomm.model`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`. Independent of
identification and planning (see docs/architecture.md).
"""
