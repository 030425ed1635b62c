"""A real tracker's export joins a finished run log: a copy of ``NAME.mcap`` with ``/run/tracker``
(docs/tracker-csv.md). The alignment (`rxcomm.acceptance.alignment`) is the caller's."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.execution.log import gateway_rows, joint_rows, tracker_topic, write_tracker_channel
from rxcomm.execution.log_grid import joint_grid_steps, on_grid
from rxcomm.io.mcap_io import McapWriter, read_mcap
from rxcomm.io.mcap_rows import GRID
from rxcomm.io.yaml_io import read_yaml_artefact, summary_yaml_path, write_mcap_summary
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.run_log import GATEWAY_TOPIC, JOINTS_TOPIC, TRACKER_TOPIC, RunLog, TrackerChannel


def attach_tracker(
    src: str | Path,
    out: str | Path,
    t_tracker_s: np.ndarray,
    position_m: np.ndarray,
    quaternion_wxyz: np.ndarray,
    channel: TrackerChannel,
    inputs: Mapping[str, str | Path],
) -> Path:
    """A copy of the finished run log `src` (``NAME.mcap`` + ``NAME.yaml``) as `out` (+ its YAML) with
    a ``/run/tracker`` channel: how a real tracker's export enters the log after the run. `inputs`
    (name → file, e.g. the CSV) join the envelope's."""
    src, out = Path(src), Path(out)
    summary_yaml_path(out)
    meta = read_yaml_artefact(summary_yaml_path(src), RunLog)
    if meta.tracker is not None:
        raise InputError("the log has a tracker channel already", file=src, field="tracker")
    contents = read_mcap(src)
    env = dict(contents.envelope)
    env["inputs"] = {**env.get("inputs", {}), **{k: sha256_file(p) for k, p in inputs.items()}}
    # written in the row layout whatever the source's (docs/logs.md §1)
    rows = {JOINTS_TOPIC: joint_rows(len(meta.joint_names)), GATEWAY_TOPIC: gateway_rows()}
    titles = {JOINTS_TOPIC: "rxcomm.RunJoints", GATEWAY_TOPIC: "rxcomm.RunGateway"}
    names = {JOINTS_TOPIC: {"joint_names": list(meta.joint_names)}, GATEWAY_TOPIC: None}
    grid = {JOINTS_TOPIC: {GRID: json.dumps(joint_grid_steps())}, GATEWAY_TOPIC: None}
    w = McapWriter(out, env)
    try:
        for topic, fields in rows.items():
            w.add_row_channel(topic, titles[topic], fields, constants=names[topic], metadata=grid[topic])
            if topic in contents.topics:
                td = contents.topics[topic]  # the joints on their grids, as the run writes them
                w.write_arrays(topic, td.t, on_grid(td.fields) if topic == JOINTS_TOPIC else td.fields)
        kept = write_tracker_channel(w, t_tracker_s, position_m, quaternion_wxyz, channel)
    except BaseException:
        w.abort()
        raise
    topics = [t for t in meta.topics if t.topic != TRACKER_TOPIC] + [tracker_topic(kept)]
    data = {**meta.model_dump(mode="json"), "inputs": env["inputs"], "topics": topics, "tracker": kept}
    return w.finish(before_rename=lambda part: write_mcap_summary(RunLog, data, out, part))
