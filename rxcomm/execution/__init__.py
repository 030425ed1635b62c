"""`rxcomm run`'s library: plans on a drive gateway, measured and logged (paper §2.3, architecture §7 run).

- ``plan``: resample a trajectory on the drive-cycle grid, feed-forward torque, dense limit check;
- ``approach``: jerk-limited moves (to a plan's start, between campaign poses);
- ``session``: gateway checks, interpolation ratio, enable, stream + record, stop;
- ``handover``: without feed-forward on drives just powered on, the static torque to their integrators;
- ``records``: what a stream records (``StreamLog``, ``RunResult``) and the hand-over to a record sink
  that keeps the master's memory bounded;
- ``trajectory_run``: a trajectory run (approach, stream into the log writer, tracker channel);
- ``campaign``: a pose list driven pose by pose with tracker readings, measurements written per pose;
- ``log``: the run-log MCAP written while the robot moves (the contract `identify` reads), recovery;
- ``summary``: the run summary, from the records or from running values of them;
- ``bench``: streaming figures in realtime mode.
"""
