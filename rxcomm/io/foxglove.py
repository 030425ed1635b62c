"""Foxglove's well-known message schemas in their JSON encoding, and the messages rxcomm writes in them.

Foxglove recognises a channel by the schema *name* (``foxglove.FrameTransforms``, ``foxglove.PoseInFrame``;
docs.foxglove.dev, "message schemas"); the JSON schemas below follow the published definitions
(time as ``{sec, nsec}``, ``foxglove.Vector3``, ``foxglove.Quaternion`` x-y-z-w). The 3D panel
builds its transform tree from every FrameTransforms channel, so a URDF whose link names match the
``child_frame_id`` values moves with the logged joints.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

from rxcomm.io.mcap_format import NS, TIME_SCHEMA
from rxcomm.schemas.run_log import ROBOT_DESCRIPTION_TOPIC

if TYPE_CHECKING:
    from rxcomm.io.mcap_io import McapWriter

FRAME_TRANSFORMS = "foxglove.FrameTransforms"
POSE_IN_FRAME = "foxglove.PoseInFrame"


def _xyz(title: str, keys: str) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": {k: {"type": "number"} for k in keys}}


_VECTOR3 = _xyz("foxglove.Vector3", "xyz")
_QUATERNION = _xyz("foxglove.Quaternion", "xyzw")

FRAME_TRANSFORMS_SCHEMA: dict[str, Any] = {
    "title": FRAME_TRANSFORMS,
    "description": "An array of FrameTransform messages",
    "type": "object",
    "properties": {
        "transforms": {
            "type": "array",
            "items": {
                "title": "foxglove.FrameTransform",
                "type": "object",
                "properties": {
                    "timestamp": TIME_SCHEMA,
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": _VECTOR3,
                    "rotation": _QUATERNION,
                },
            },
        }
    },
}

POSE_IN_FRAME_SCHEMA: dict[str, Any] = {
    "title": POSE_IN_FRAME,
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {
        "timestamp": TIME_SCHEMA,
        "frame_id": {"type": "string"},
        "pose": {
            "title": "foxglove.Pose",
            "type": "object",
            "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
        },
    },
}


STRING_SCHEMA: dict[str, Any] = {
    "title": "std_msgs/String",
    "type": "object",
    "properties": {"data": {"type": "string", "description": "the robot's URDF (XML)"}},
}


def add_frame_transforms_channel(w: McapWriter, topic: str) -> None:
    """Register a foxglove.FrameTransforms channel (part of the 3D panel's transform tree)."""
    w.add_channel(topic, FRAME_TRANSFORMS, {"transforms": {}}, schema=FRAME_TRANSFORMS_SCHEMA)


def add_pose_channel(w: McapWriter, topic: str) -> None:
    """Register a foxglove.PoseInFrame channel (messages: :func:`pose_in_frame`)."""
    fields = {"timestamp": {}, "frame_id": {}, "pose": {}}
    w.add_channel(topic, POSE_IN_FRAME, fields, schema=POSE_IN_FRAME_SCHEMA)


def write_robot_description(w: McapWriter, t: float, urdf_text: str) -> None:
    """The URDF itself on ``/robot_description``, so the 3D panel's URDF layers (source: topic) need no
    file of their own."""
    w.add_channel(ROBOT_DESCRIPTION_TOPIC, "std_msgs/String", {"data": {}}, schema=STRING_SCHEMA)
    w.write(ROBOT_DESCRIPTION_TOPIC, t, {"data": urdf_text})


def stamp(ns: int) -> dict[str, int]:
    """Foxglove time of an epoch time in ns."""
    return {"sec": ns // NS, "nsec": ns % NS}


def _vec(v: np.ndarray, decimals: int | None = None) -> dict[str, float]:
    x = [float(a) if decimals is None else round(float(a), decimals) for a in v[:3]]
    return dict(zip("xyz", x, strict=True))


def _quat_xyzw(q: np.ndarray, decimals: int | None = None) -> dict[str, float]:
    x = [float(a) if decimals is None else round(float(a), decimals) for a in q[:4]]
    return dict(zip("xyzw", x, strict=True))


def frame_transforms(
    ns: int, pairs: list[tuple[str, str]], translation: np.ndarray, rotation_xyzw: np.ndarray
) -> dict[str, Any]:
    """One foxglove.FrameTransforms message: ``pairs`` (parent, child) with ``translation`` [m, 3] (m)
    and ``rotation_xyzw`` [m, 4] of each child in its parent."""
    ts = stamp(ns)
    return {
        "transforms": [
            {
                "timestamp": ts,
                "parent_frame_id": parent,
                "child_frame_id": child,
                "translation": _vec(translation[i]),
                "rotation": _quat_xyzw(rotation_xyzw[i]),
            }
            for i, (parent, child) in enumerate(pairs)
        ]
    }


def pose_in_frame(
    ns: int, frame_id: str, position: np.ndarray, orientation_xyzw: np.ndarray, decimals: int | None = None
) -> dict[str, Any]:
    """One foxglove.PoseInFrame message (position in m); values rounded to ``decimals`` if given."""
    pose = {"position": _vec(position, decimals), "orientation": _quat_xyzw(orientation_xyzw, decimals)}
    return {"timestamp": stamp(ns), "frame_id": frame_id, "pose": pose}


def frame_transforms_template(pairs: list[tuple[str, str]], decimals: int | None = None) -> str:
    """A %-template of the FrameTransforms JSON for ``pairs``: fill it with :func:`frame_transforms_json`.
    The same text as ``json.dumps(frame_transforms(...))`` without building the dicts (the writer does
    this while the robot moves); with ``decimals``, the values in fixed point with that many decimals
    (shorter text that compresses better: a run log's views, docs/logs.md §2)."""
    v = "%r" if decimals is None else f"%.{int(decimals)}f"
    items = []
    for parent, child in pairs:
        ids = f'"parent_frame_id":{json.dumps(parent)},"child_frame_id":{json.dumps(child)},'
        items.append(
            '{"timestamp":{"sec":%d,"nsec":%d},'
            + ids.replace("%", "%%")
            + f'"translation":{{"x":{v},"y":{v},"z":{v}}},'
            f'"rotation":{{"x":{v},"y":{v},"z":{v},"w":{v}}}}}'
        )
    return '{"transforms":[' + ",".join(items) + "]}"


def frame_transforms_json(
    template: str, ns: int, translation: np.ndarray, rotation_xyzw: np.ndarray
) -> bytes:
    """The FrameTransforms message of :func:`frame_transforms_template` at epoch ``ns``."""
    sec, nsec = ns // NS, ns % NS
    values: list[Any] = []
    for t, r in zip(translation.tolist(), rotation_xyzw.tolist(), strict=True):
        values += [sec, nsec, *t, *r]
    return (template % tuple(values)).encode()
