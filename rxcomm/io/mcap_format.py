"""The rxcomm MCAP format, shared by the writer (``mcap_io``) and the reader (``mcap_read``).

A file holds, per logical topic, the messages Foxglove plots (``jsonschema`` + ``json``, one message
per sample, starting with ``"timestamp": {"sec", "nsec"}``, schema titled ``time``) and, for topics
whose fields are all numeric, a *column channel* beside them: one message per block of samples whose
columns are little-endian arrays in base64 (``contentEncoding: base64``, still JSON that Foxglove
opens). The column channel's metadata names the topic it mirrors (``rxcomm/columns_of``); its blocks
are written to chunks of their own, so a reader that wants arrays seeks to those chunks through the
index and never parses the per-sample JSON (docs/logs.md has the measurement behind this choice).

Time: log times and stamps are epoch nanoseconds, ``time_origin_ns`` (the run's wall clock at start,
a plan's creation time) + the sample time; the ``rxcomm/time`` metadata record holds the origin, and
readers give times in s from it. Files from before the origin existed read with origin 0.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from rxcomm.schemas.envelope import Artefact

ENVELOPE_RECORD = "rxcomm/envelope"
RECOVERED_RECORD = "rxcomm/recovered"
TIME_RECORD = "rxcomm/time"
COLUMNS_OF = "rxcomm/columns_of"  # channel metadata of a column channel: the topic it mirrors
CONSTANTS = "rxcomm/constants"  # channel metadata: JSON of the fields every message repeats
COLUMNS_SCHEMA_TITLE = "rxcomm.Columns"
PROFILE = ""  # no ROS profile: plain JSON-schema channels
NS = 1_000_000_000
TIME_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}
_DTYPES = {"number": "<f8", "integer": "<i8", "boolean": "|b1"}
_ARRAY_SCHEMA: dict[str, Any] = {
    "type": "object",
    "properties": {
        "dtype": {"type": "string", "description": "numpy dtype: <f8, <i8 or |b1"},
        "shape": {"type": "array", "items": {"type": "integer"}},
        "data": {"type": "string", "contentEncoding": "base64", "description": "C-order bytes"},
    },
    "required": ["dtype", "shape", "data"],
}


def columns_topic(topic: str) -> str:
    """The column channel beside ``topic``: ``/run/joints`` -> ``/columns/run/joints``."""
    return "/columns/" + topic.lstrip("/")


def columns_schema(fields: Mapping[str, str]) -> dict[str, Any]:
    """JSON schema of a column block; ``fields`` maps name -> description."""
    cols = {k: {**_ARRAY_SCHEMA, "description": d} for k, d in fields.items()}
    log_time = {**_ARRAY_SCHEMA, "description": "int64 log time of each sample, ns since the epoch"}
    return {
        "type": "object",
        "title": COLUMNS_SCHEMA_TITLE,
        "properties": {
            "timestamp": TIME_SCHEMA,
            "n": {"type": "integer", "minimum": 0, "description": "samples in this block"},
            "log_time_ns": log_time,
            "columns": {"type": "object", "properties": cols},
        },
        "required": ["timestamp", "n", "log_time_ns", "columns"],
    }


def column_dtype(field_schema: Mapping[str, Any]) -> str | None:
    """The block dtype of a field (scalar or array of numbers/integers/booleans); None if not numeric."""
    kind = field_schema.get("type")
    if kind == "array":
        kind = (field_schema.get("items") or {}).get("type")
    return _DTYPES.get(kind) if isinstance(kind, str) else None


def _array(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": base64.b64encode(a.data).decode()}


def _unarray(d: Mapping[str, Any]) -> np.ndarray:
    return np.frombuffer(base64.b64decode(d["data"]), dtype=np.dtype(d["dtype"])).reshape(d["shape"])


def encode_block(log_ns: np.ndarray, columns: Mapping[str, np.ndarray]) -> bytes:
    """One column-channel message: the samples' log times and each column, already in its dtype."""
    ns = int(log_ns[0]) if len(log_ns) else 0
    body = {
        "timestamp": {"sec": ns // NS, "nsec": ns % NS},
        "n": len(log_ns),
        "log_time_ns": _array(np.asarray(log_ns, dtype="<i8")),
        "columns": {k: _array(v) for k, v in columns.items()},
    }
    return json.dumps(body, separators=(",", ":")).encode()


def decode_block(data: bytes) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(log times ns [n], columns) of one column-channel message; ValueError/KeyError if malformed."""
    body = json.loads(data)
    ns = _unarray(body["log_time_ns"])
    cols = {k: _unarray(v) for k, v in body["columns"].items()}
    for k, c in cols.items():
        if c.shape[:1] != ns.shape:
            raise ValueError(f"column {k} has {c.shape[:1]} rows for {ns.shape[0]} time stamps")
    return ns, cols


# ---------------------------------------------------------------- field schemas


def number_field(description: str = "") -> dict[str, Any]:
    """JSON schema of a scalar number field (put the unit in ``description``)."""
    return {"type": "number", **({"description": description} if description else {})}


def vector_field(k: int, description: str = "") -> dict[str, Any]:
    """JSON schema of a fixed-length numeric array field (e.g. 6 joint values)."""
    d = {"type": "array", "items": {"type": "number"}, "minItems": k, "maxItems": k}
    return {**d, **({"description": description} if description else {})}


def field_for(column: np.ndarray) -> dict[str, Any]:
    """Field schema inferred from a column of ``write_arrays``: [n] scalar, [n, k] vector."""
    item = {"b": "boolean", "i": "integer", "u": "integer"}.get(column.dtype.kind, "number")
    if column.ndim == 1:
        return {"type": item}
    k = column.shape[1]
    return {"type": "array", "items": {"type": item}, "minItems": k, "maxItems": k}


def time_ns(t_s: float) -> int:
    """Sample time (s from the origin) -> ns; MCAP log times are unsigned, so t >= 0."""
    if not math.isfinite(t_s) or t_s < 0:
        raise ValueError(f"message time must be finite and >= 0 s (MCAP log times are unsigned), got {t_s}")
    return round(t_s * NS)


def finite_or_none(obj: Any) -> Any:
    """JSON has no NaN/inf: write them as null (read back as NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [finite_or_none(v) for v in obj]
    return obj


def envelope_values(envelope: Mapping[str, Any] | Artefact) -> dict[str, Any]:
    """Envelope fields validated (any kind) and JSON-able."""
    if isinstance(envelope, Artefact):
        return envelope.envelope_dict()
    return Artefact.model_validate(dict(envelope)).envelope_dict()


def encode_metadata(values: Mapping[str, Any]) -> dict[str, str]:
    """Every value JSON-encoded (strings too), so decoding is unambiguous."""
    return {k: json.dumps(v, separators=(",", ":")) for k, v in values.items()}
