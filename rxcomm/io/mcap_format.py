"""The rxcomm MCAP format, shared by the writer (``mcap_io``) and the reader (``mcap_read``).

A file holds, per logical topic, the messages Foxglove plots (``jsonschema`` + ``json``, one message
per sample, starting with ``"timestamp": {"sec", "nsec"}``, schema titled ``time``) and, for topics
whose fields are all numeric, a *column channel* beside them: one protobuf message per block of
samples whose columns are the little-endian arrays as bytes (a schema Foxglove decodes too). The
column channel's metadata names the topic it mirrors (``rxcomm/columns_of``); its blocks are
written to chunks of their own, so a reader that wants arrays seeks to those chunks through the
index and never parses the per-sample JSON (docs/logs.md has the measurement behind this choice).

Time: log times and stamps are epoch nanoseconds, ``time_origin_ns`` (the run's wall clock at start,
a plan's creation time) + the sample time; the ``rxcomm/time`` metadata record holds the origin, and
readers give times in s from it. Files from before the origin existed read with origin 0.
"""

from __future__ import annotations

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


def columns_topic(topic: str) -> str:
    """The column channel beside ``topic``: ``/run/joints`` -> ``/columns/run/joints``."""
    return "/columns/" + topic.lstrip("/")


def column_dtype(field_schema: Mapping[str, Any]) -> str | None:
    """The block dtype of a field (scalar or array of numbers/integers/booleans); None if not numeric."""
    kind = field_schema.get("type")
    if kind == "array":
        kind = (field_schema.get("items") or {}).get("type")
    return _DTYPES.get(kind) if isinstance(kind, str) else None


# ---------------------------------------------------------------- column blocks (protobuf)
#
# A block is the protobuf message (proto3, package rxcomm) that Foxglove decodes from the schema's
# FileDescriptorSet:
#   message Column  { string name = 1; string dtype = 2; repeated uint32 shape = 3; bytes data = 4; }
#   message Columns { uint32 n = 1; repeated sfixed64 log_time_ns = 2; repeated Column columns = 3; }
# Packed sfixed64 and bytes are the arrays' little-endian bytes as they are: encoding is a join, decoding
# a np.frombuffer per column, with no per-value work. Encoded here by hand: no protobuf dependency.

COLUMNS_ENCODING = "protobuf"


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _ld(number: int, payload: bytes) -> bytes:
    """A length-delimited field (strings, bytes, sub-messages, packed repeated)."""
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def _vi(number: int, value: int) -> bytes:
    return _varint(number << 3) + _varint(value)


def _read_varint(buf: memoryview, i: int) -> tuple[int, int]:
    shift = n = 0
    while True:
        b = buf[i]
        i += 1
        n |= (b & 0x7F) << shift
        if not b & 0x80:
            return n, i
        shift += 7


def _fields(buf: memoryview) -> list[tuple[int, int | memoryview]]:
    """(field number, varint value or length-delimited payload) of a protobuf message."""
    out: list[tuple[int, int | memoryview]] = []
    i = 0
    while i < len(buf):
        key, i = _read_varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _read_varint(buf, i)
            out.append((number, value))
        elif wire == 2:
            size, i = _read_varint(buf, i)
            if i + size > len(buf):
                raise ValueError("truncated field")
            out.append((number, buf[i : i + size]))
            i += size
        else:
            raise ValueError(f"unexpected wire type {wire}")
    return out


def _field_descriptor(name: str, number: int, label: int, kind: int, type_name: str = "") -> bytes:
    # FieldDescriptorProto: name 1, number 3, label 4 (1 optional, 3 repeated), type 5, type_name 6
    body = _ld(1, name.encode()) + _vi(3, number) + _vi(4, label) + _vi(5, kind)
    return body + (_ld(6, type_name.encode()) if type_name else b"")


def _columns_descriptor_set() -> bytes:
    string, bytes_, uint32, sfixed64, message = 9, 12, 13, 16, 11
    column = _ld(1, b"Column") + b"".join(
        _ld(2, f)
        for f in (
            _field_descriptor("name", 1, 1, string),
            _field_descriptor("dtype", 2, 1, string),
            _field_descriptor("shape", 3, 3, uint32),
            _field_descriptor("data", 4, 1, bytes_),
        )
    )
    columns = _ld(1, COLUMNS_SCHEMA_TITLE.split(".")[-1].encode()) + b"".join(
        _ld(2, f)
        for f in (
            _field_descriptor("n", 1, 1, uint32),
            _field_descriptor("log_time_ns", 2, 3, sfixed64),
            _field_descriptor("columns", 3, 3, message, ".rxcomm.Column"),
        )
    )
    # FileDescriptorProto: name 1, package 2, message_type 4, syntax 12; FileDescriptorSet: file 1
    file = _ld(1, b"rxcomm/columns.proto") + _ld(2, b"rxcomm") + _ld(4, column) + _ld(4, columns)
    return _ld(1, file + _ld(12, b"proto3"))


COLUMNS_DESCRIPTOR_SET = _columns_descriptor_set()


def encode_block(log_ns: np.ndarray, columns: Mapping[str, np.ndarray]) -> bytes:
    """One column-channel message: the samples' log times and each column, already in its dtype."""
    parts = [_vi(1, len(log_ns)), _ld(2, np.ascontiguousarray(log_ns, dtype="<i8").tobytes())]
    for name, a in columns.items():
        a = np.ascontiguousarray(a)
        shape = b"".join(_varint(int(d)) for d in a.shape)
        col = _ld(1, name.encode()) + _ld(2, a.dtype.str.encode()) + _ld(3, shape) + _ld(4, a.tobytes())
        parts.append(_ld(3, col))
    return b"".join(parts)


def decode_block(data: bytes) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(log times ns [n], columns) of one column-channel message; ValueError if malformed."""
    ns = np.zeros(0, dtype="<i8")
    cols: dict[str, np.ndarray] = {}
    for number, value in _fields(memoryview(data)):
        if number == 2 and isinstance(value, memoryview):
            ns = np.frombuffer(value, dtype="<i8")
        elif number == 3 and isinstance(value, memoryview):
            col = dict(_fields(value))
            shape_buf = col.get(3, memoryview(b""))
            shape, i = [], 0
            while isinstance(shape_buf, memoryview) and i < len(shape_buf):
                d, i = _read_varint(shape_buf, i)
                shape.append(d)
            name, dtype, raw = (
                bytes(col[k]) if isinstance(col.get(k), memoryview) else None for k in (1, 2, 4)
            )
            if name is None or dtype is None or raw is None:
                raise ValueError("column without name, dtype or data")
            cols[name.decode()] = np.frombuffer(raw, dtype=np.dtype(dtype.decode())).reshape(shape)
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
