"""`rxcomm run`'s library: plans on a drive gateway, measured and logged (paper §2.3, architecture §7 run).

- ``plan``: resample a trajectory on the drive-cycle grid, feed-forward torque, dense limit check;
- ``approach``: jerk-limited moves (to a plan's start, between campaign poses);
- ``session``: gateway checks, interpolation ratio, enable, stream + record, stop;
- ``campaign``: a pose list driven pose by pose with tracker readings;
- ``log``: the run-log summary and MCAP (the contract `identify` reads);
- ``bench``: streaming figures in realtime mode.
"""
