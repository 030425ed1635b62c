"""Acceptance measurement: tracker data on the run log's time axis and the ISO 9283 criteria.

- ``alignment``: a tracker's samples (simulated cell or a real tracker's CSV) put on the joint log's
  time axis, by the stream-start trigger and/or by cross-correlating the TCP speed profiles;
- ``criteria``: ISO 9283:1998 pose, path, corner and velocity criteria on attained poses and paths
  (vectorised numpy, no robot);
- ``campaign``: from run logs with a tracker channel to the criteria of one robot state.

The package sits beside ``execution`` (above planning, whose ISO 9283 cube and paths it reads).
"""
