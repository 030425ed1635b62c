"""Dynamic identification: how to excite the robot and what its joint logs say (paper §4).

- ``excitation``: the Fourier-series exciting trajectory, optimised for the regressor's condition (§4.2);
  its parts in ``excitation_trajectory``, ``excitation_limits`` and ``excitation_problem``;
- ``fit``: joint logs → filtered, decimated regressor rows → base parameters by weighted least
  squares, with validation and physical consistency (§4.1, §4.3); its steps in ``settings``, ``logs``,
  ``processing``, ``estimation``, ``consistency`` and ``validation``.

May import: `rxcomm.model`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`. Independent of
calibration and planning (see docs/architecture.md).
"""
