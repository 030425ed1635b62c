"""The one reader of run logs (``NAME.mcap``, also a stopped run's ``NAME.mcap.part``), for `run`'s
comparison plot and for `identify`; the contract itself is `rxcomm.schemas.run_log`."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rxcomm.errors import InputError
from rxcomm.io.mcap_io import TopicData, read_mcap
from rxcomm.io.validate import check_kind, validate_model
from rxcomm.io.yaml_io import check_mcap_summary
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.run_log import (
    FOXGLOVE_VIEW_TOPICS,
    GATEWAY_TOPIC,
    JOINT_FIELDS,
    JOINTS_TOPIC,
    TRACKER_TOPIC,
    RunLog,
)


@dataclass(frozen=True)
class RunLogData:
    """A run log read back: its envelope and the two topics as arrays (``joints.q_actual`` etc.)."""

    envelope: dict[str, Any]
    joints: TopicData
    gateway: TopicData | None
    tracker: TopicData | None = None  # /run/tracker, when a tracker measured during the motion

    @property
    def summary(self) -> dict[str, Any]:
        return dict(self.envelope.get("summary", {}))


def read_run_log(path: str | Path, fields: Iterable[str] = tuple(JOINT_FIELDS)) -> RunLogData:
    """Read a finished run log MCAP (also a stopped run's ``.mcap.part``) that has the joint `fields`
    (default: all the contract lists); InputError names file and field."""
    path = Path(path)
    check_mcap_summary(path)
    contents = read_mcap(path, exclude=FOXGLOVE_VIEW_TOPICS)  # the data, not the 3D panel's channels
    env = contents.envelope
    if env.get("kind") != RunLog.KIND:
        raise InputError(
            f"kind {env.get('kind')!r} is not a run log ({RunLog.KIND})", file=path, field="envelope.kind"
        )
    check_kind(env, RunLog, file=path, prefix="envelope")
    validate_model(Artefact, env, file=path, prefix="envelope")
    if JOINTS_TOPIC not in contents.topics:
        raise InputError(
            f"no {JOINTS_TOPIC} topic (has {sorted(contents.topics)})", file=path, field=JOINTS_TOPIC
        )
    joints = contents.topics[JOINTS_TOPIC]
    for name in fields if len(joints) else ():
        if name not in joints.fields:
            raise InputError("field missing", file=path, field=f"{JOINTS_TOPIC}.{name}")
    return RunLogData(env, joints, contents.topics.get(GATEWAY_TOPIC), contents.topics.get(TRACKER_TOPIC))
