"""Geometric calibration: which poses to measure and what the measurements say (paper §3).

- ``workspace``, ``pose_selection``, ``baselines``: the workspace grid, candidate poses, the
  observability-optimal subset and the naive references (linear scan, evenly spaced) (§3.3);
- ``fit``: tracker measurements → identifiable geometric errors (§3.2), the steps in order, from
  ``measurements`` (reading, checks), ``frames`` (closed-form base and tool), ``residuals``
  (weighted residual, Table 2), ``lm`` (Levenberg–Marquardt, covariance, outliers, noise,
  cross-validation), ``selection`` (candidate models), ``compliance`` (holding torques),
  ``plausibility`` (checks and notes), ``settings``;
- ``artefact``: the Calibration artefact from a result; ``urdf``, ``exports``: the calibrated URDF with
  the TCP frame, MDH parameters and zero offsets;
  ``loading``: a calibration artefact back as an error model or a calibrated robot.

May import: `rxcomm.model`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`. Independent of
identification and planning (see docs/architecture.md).
"""
