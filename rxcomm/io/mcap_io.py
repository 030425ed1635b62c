"""MCAP time series that Foxglove plots, with the artefact envelope inside (architecture §3).

Layout of a file written here:

- channels with ``jsonschema`` schemas and ``json`` messages; every message starts with
  ``"timestamp": {"sec", "nsec"}`` whose schema is titled ``time``; vectors are JSON arrays, so
  Foxglove plots ``/trajectory.q[0]``;
- the envelope as a metadata record ``rxcomm/envelope`` written right after the header (so a killed
  writer's file still says what it is) and, if the summary changed meanwhile, again at ``finish()``
  (the reader keeps the last one); every value is JSON-encoded (strings too), so decoding is
  unambiguous;
- zstd chunks closed and flushed to the OS at least once per ``flush_period_s`` of log time or wall
  time, so a killed writer loses about that much.

Writing goes to ``NAME.part``; ``finish()`` (or leaving the ``with`` block normally) writes the index
and renames it to ``NAME``. If the block raises, the ``.part`` is finished as far as possible and kept,
not renamed: a run that ends in a safety stop is exactly the log one wants to look at, and keeping
the ``.part`` name means neither make nor a later stage mistakes it for a complete output.
``recover_mcap`` reads such files, including ones whose writer was killed (no footer, truncated chunk).
"""

from __future__ import annotations

import json
import math
import os
import struct
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

import numpy as np
from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.records import Channel, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_bytes, part_path
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.plain import to_plain

ENVELOPE_RECORD = "rxcomm/envelope"
RECOVERED_RECORD = "rxcomm/recovered"
PROFILE = ""  # no ROS profile: plain JSON-schema channels
TIME_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}
_NS = 1_000_000_000

_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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


def _time_ns(t_s: float) -> int:
    if not math.isfinite(t_s) or t_s < 0:
        raise ValueError(f"message time must be finite and >= 0 s (MCAP log times are unsigned), got {t_s}")
    return round(t_s * _NS)


def _finite_or_none(obj: Any) -> Any:
    """JSON has no NaN/inf: write them as null (read back as NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_none(v) for v in obj]
    return obj


def _envelope_values(envelope: Mapping[str, Any] | Artefact) -> dict[str, Any]:
    """Envelope fields validated (any kind) and JSON-able."""
    if isinstance(envelope, Artefact):
        return envelope.envelope_dict()
    return Artefact.model_validate(dict(envelope)).envelope_dict()


def _encode_metadata(values: Mapping[str, Any]) -> dict[str, str]:
    return {k: json.dumps(v, separators=(",", ":")) for k, v in values.items()}


# ---------------------------------------------------------------- writer


class McapWriter:
    """Chunked MCAP writer for JSON-schema channels; see the module docstring for the file layout.

    ``McapWriter(path, envelope)`` opens ``path.part``; use it as a context manager or call
    :meth:`finish`. ``envelope`` is the dict from ``SomeArtefact.envelope(...)`` or an Artefact.
    """

    def __init__(
        self,
        path: str | Path,
        envelope: Mapping[str, Any] | Artefact,
        *,
        chunk_bytes: int = 1 << 20,
        flush_period_s: float = 1.0,
        compression: str = "zstd",
    ) -> None:
        self.path = Path(path)
        self.part_path = part_path(self.path)
        self._envelope = _envelope_values(envelope)
        self._envelope_dirty = False
        self._file: IO[bytes] = open(self.part_path, "wb")  # noqa: SIM115 - closed in finish/abort
        self._w = Writer(self._file, chunk_size=chunk_bytes, compression=_COMPRESSIONS[compression])
        self._w.start(profile=PROFILE, library="rxcomm")
        self._w.add_metadata(ENVELOPE_RECORD, _encode_metadata(self._envelope))
        self._channels: dict[str, tuple[int, tuple[str, ...]]] = {}
        self._seq: dict[int, int] = {}
        self._period_ns = round(flush_period_s * _NS)
        self._period_s = flush_period_s
        self._chunk_t0: int | None = None
        self._wall_t0 = time.monotonic()
        self._done = False

    # -- channels and messages

    def add_channel(self, topic: str, schema_title: str, fields: Mapping[str, Mapping[str, Any]]) -> None:
        """Register ``topic`` with a JSON schema: the ``timestamp`` plus ``fields`` (name -> JSON schema,
        e.g. :func:`number_field`, :func:`vector_field`)."""
        if topic in self._channels:
            raise ValueError(f"channel {topic!r} already added")
        if "timestamp" in fields:
            raise ValueError("'timestamp' is added by the writer")
        schema = {
            "type": "object",
            "title": schema_title,
            "properties": {"timestamp": TIME_SCHEMA, **fields},
            "required": ["timestamp", *fields],
        }
        schema_id = self._w.register_schema(
            name=schema_title, encoding="jsonschema", data=json.dumps(schema, sort_keys=False).encode()
        )
        channel_id = self._w.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
        self._channels[topic] = (channel_id, tuple(fields))
        self._seq[channel_id] = 0

    def write(self, topic: str, t_s: float, msg: Mapping[str, Any]) -> None:
        """Write one message at time ``t_s`` (s, >= 0); numpy values are converted, NaN/inf become null."""
        channel_id, names = self._channel(topic)
        if unknown := set(msg) - set(names):
            raise ValueError(f"{topic}: fields {sorted(unknown)} are not in the channel schema")
        ns = _time_ns(float(t_s))
        plain = to_plain(dict(msg))
        # Keys in schema order, whatever the caller's dict order: every message has the same layout.
        body = {"timestamp": {"sec": ns // _NS, "nsec": ns % _NS}}
        body |= {k: plain[k] for k in names if k in plain}
        try:
            data = json.dumps(body, separators=(",", ":"), allow_nan=False)
        except ValueError:
            data = json.dumps(_finite_or_none(body), separators=(",", ":"))
        self._add(channel_id, ns, data.encode())

    def write_arrays(
        self,
        topic: str,
        t: np.ndarray,
        columns: Mapping[str, np.ndarray],
        *,
        schema_title: str | None = None,
        digits: int = 17,
    ) -> None:
        """Write ``len(t)`` messages at once: message i holds ``column[i]`` of every column ([n] as a
        number, [n, k] as a k-array). Registers the channel from the columns if needed.

        ``digits`` significant digits per float: 17 round-trips float64 exactly; 9 (~1e-9 relative,
        far below any sensor's resolution) formats ~2x faster and makes smaller files."""
        t = np.asarray(t, dtype=float)
        cols = {k: np.asarray(v) for k, v in columns.items()}
        n = t.shape[0]
        for k, c in cols.items():
            if c.ndim not in (1, 2) or c.shape[0] != n:
                raise ValueError(f"{topic}.{k}: shape {c.shape} does not match {n} time stamps")
        if topic not in self._channels:
            title = schema_title or "rxcomm." + topic.strip("/").replace("/", ".")
            self.add_channel(topic, title, {k: field_for(c) for k, c in cols.items()})
        channel_id, names = self._channel(topic)
        if unknown := set(cols) - set(names):
            raise ValueError(f"{topic}: fields {sorted(unknown)} are not in the channel schema")
        if not (np.all(np.isfinite(t)) and np.all(t >= 0)):
            raise ValueError(f"{topic}: time stamps must be finite and >= 0 s")
        ns = np.round(t * _NS).astype(np.int64)
        fast = all(
            c.dtype.kind in "iu" or (c.dtype.kind == "f" and np.all(np.isfinite(c))) for c in cols.values()
        )
        if not fast:  # bools, NaN, strings: the general path
            for i in range(n):
                self.write(topic, t[i], {k: c[i] for k, c in cols.items()})
            return
        # One %-format per message over flat per-component lists. '%.17g' round-trips float64 exactly
        # and is ~30 % faster than repr; it writes 1.0 as 1, so the reader types columns by schema.
        slots = {"f": f"%.{int(digits)}g", "i": "%d", "u": "%d"}
        tmpl = '{"timestamp":{"sec":%d,"nsec":%d}'
        flat: list[list[Any]] = [(ns // _NS).tolist(), (ns % _NS).tolist()]
        for k, c in cols.items():
            slot = slots[c.dtype.kind]
            key = "," + json.dumps(k).replace("%", "%%") + ":"
            if c.ndim == 1:
                tmpl += key + slot
                flat.append(c.tolist())
            else:
                tmpl += key + "[" + ",".join([slot] * c.shape[1]) + "]"
                flat.extend(c.T.tolist())
        tmpl += "}"
        for log_ns, row in zip(ns.tolist(), zip(*flat, strict=True), strict=True):
            self._add(channel_id, log_ns, (tmpl % row).encode())

    def _channel(self, topic: str) -> tuple[int, tuple[str, ...]]:
        try:
            return self._channels[topic]
        except KeyError:
            raise ValueError(f"channel {topic!r} not added (add_channel first)") from None

    def _add(self, channel_id: int, log_ns: int, data: bytes) -> None:
        if self._done:
            raise ValueError("writer already finished")
        seq = self._seq[channel_id]
        self._seq[channel_id] = seq + 1
        self._w.add_message(channel_id, log_time=log_ns, data=data, publish_time=log_ns, sequence=seq)
        # Close the chunk once it spans flush_period_s (log or wall time): a killed writer loses less.
        if self._chunk_t0 is None:
            self._chunk_t0 = log_ns
        elif abs(log_ns - self._chunk_t0) >= self._period_ns or (
            time.monotonic() - self._wall_t0 >= self._period_s
        ):
            self.flush()

    # -- metadata and end

    def set_summary(self, summary: Mapping[str, Any]) -> None:
        """Replace the envelope's summary; the updated envelope is written again at finish."""
        self._envelope = _envelope_values({**self._envelope, "summary": to_plain(dict(summary))})
        self._envelope_dirty = True

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        """Add a free metadata record (str -> str)."""
        self._w.add_metadata(name, dict(values))

    def flush(self) -> None:
        """Close the current chunk and hand it to the OS (survives kill -9, not a power cut)."""
        self._w.flush()
        self._chunk_t0 = None
        self._wall_t0 = time.monotonic()

    def _close_part(self) -> None:
        if self._envelope_dirty:
            self._w.add_metadata(ENVELOPE_RECORD, _encode_metadata(self._envelope))
        self._w.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self._done = True

    def finish(self, *, before_rename: Callable[[Path], None] | None = None) -> Path:
        """Write index and footer, then rename ``NAME.part`` to ``NAME``. ``before_rename(part_path)``
        runs on the finished ``.part`` first (e.g. to hash it and write the summary YAML)."""
        if self._done:
            raise ValueError("writer already finished")
        try:
            self._close_part()
            if before_rename is not None:
                before_rename(self.part_path)
        except BaseException:
            self.abort()
            raise
        os.replace(self.part_path, self.path)
        return self.path

    def abort(self) -> Path:
        """Finish the ``.part`` as far as possible and keep it (not renamed); returns its path."""
        if not self._done:
            self._done = True
            try:
                if self._envelope_dirty:
                    self._w.add_metadata(ENVELOPE_RECORD, _encode_metadata(self._envelope))
                self._w.finish()
            except (OSError, ValueError, McapError):
                pass  # what reached the file stays readable by recover_mcap
            finally:
                self._file.close()
        return self.part_path

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self.abort()
        elif not self._done:
            self.finish()


# ---------------------------------------------------------------- reader


@dataclass(frozen=True)
class TopicData:
    """One channel's messages as arrays: ``t`` [n] s and each field [n] or [n, k] (``td.q``, ``td["q"]``).

    Numbers become float64 (null -> NaN), integers int64, booleans bool.
    """

    topic: str
    schema_title: str
    t: np.ndarray
    fields: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    def __getattr__(self, name: str) -> np.ndarray:
        fields = self.__dict__.get("fields", {})
        if name in fields:
            return fields[name]
        raise AttributeError(name)

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class McapContents:
    """What :func:`read_mcap` / :func:`recover_mcap` found.

    ``complete`` is False when the file had no footer (a killed writer); ``stopped_because`` then says
    where reading stopped.
    """

    envelope: dict[str, Any]
    topics: dict[str, TopicData]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = True
    stopped_because: str | None = None

    @property
    def n_messages(self) -> int:
        return sum(len(td) for td in self.topics.values())


class _ExactReader:
    """File wrapper whose short read raises EndOfFile, so a truncated record stops the stream reader
    cleanly instead of being parsed from too few bytes."""

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        if n > 0 and len(data) < n:
            raise EndOfFile()
        return data


@dataclass
class _Raw:
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: dict[int, list[McapMessage]] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    complete: bool = False
    stopped_because: str | None = None


def _scan(path: Path, *, strict: bool) -> _Raw:
    """Read records in file order (no seeking, no index needed); in strict mode any defect is an
    InputError, otherwise reading stops at the first truncated or corrupt record."""
    raw = _Raw()
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed below
    except FileNotFoundError as e:
        raise InputError("file not found", file=path) from e
    except OSError as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    with f:
        reader = StreamReader(_ExactReader(f), validate_crcs=True)
        records = reader.records
        try:
            for rec in records:
                if isinstance(rec, Schema):
                    raw.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    raw.channels[rec.id] = rec
                    raw.messages.setdefault(rec.id, [])
                elif isinstance(rec, McapMessage):
                    raw.messages.setdefault(rec.channel_id, []).append(rec)
                elif isinstance(rec, Metadata):
                    raw.metadata.append(rec)
            raw.complete = True  # the stream reader stops only after the footer and closing magic
        except EndOfFile as e:
            if f.tell() <= 8:
                raise InputError("not an MCAP file (too short)", file=path) from e
            raw.stopped_because = f"file ends inside a record or before the footer at byte {f.tell()}"
        except (McapError, ValueError, struct.error) as e:
            if isinstance(e, InvalidMagic) and f.tell() <= 8:
                raise InputError(f"not an MCAP file: {e}", file=path) from e
            raw.stopped_because = f"unreadable record near byte {f.tell()}: {e}"
    if strict and not raw.complete:
        raise InputError(
            f"incomplete MCAP ({raw.stopped_because}); a killed writer's file can be read with "
            "rxcomm.io.mcap_io.recover_mcap",
            file=path,
        )
    return raw


def _number_fields(schema: Schema | None) -> set[str]:
    """Fields a JSON schema declares as numbers or arrays of numbers (read as float64)."""
    if schema is None or schema.encoding != "jsonschema":
        return set()
    try:
        props = json.loads(schema.data).get("properties", {})
    except (json.JSONDecodeError, AttributeError):
        return set()
    out = set()
    for k, p in props.items():
        if isinstance(p, dict) and "number" in (p.get("type"), (p.get("items") or {}).get("type")):
            out.add(k)
    return out


def _column(values: list[Any], file: Path, name: str, number: bool) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float if number else None)
        if arr.dtype == object:  # nulls among numbers
            arr = np.asarray(values, dtype=float)
    except (ValueError, TypeError) as e:
        raise InputError(f"values are ragged or mixed: {e}", file=file, field=name) from e
    return arr


def _decode(raw: _Raw, path: Path, *, need_envelope: bool) -> McapContents:
    metadata: dict[str, dict[str, str]] = {}
    for m in raw.metadata:  # later records of the same name win (the envelope is rewritten at finish)
        metadata[m.name] = dict(m.metadata)
    envelope: dict[str, Any] = {}
    if ENVELOPE_RECORD in metadata:
        try:
            envelope = {k: json.loads(v) for k, v in metadata[ENVELOPE_RECORD].items()}
        except json.JSONDecodeError as e:
            raise InputError(f"not JSON: {e}", file=path, field=ENVELOPE_RECORD) from e
    elif need_envelope:
        raise InputError("no rxcomm envelope metadata record; not an rxcomm artefact", file=path)

    topics: dict[str, TopicData] = {}
    for cid, msgs in raw.messages.items():
        if (ch := raw.channels.get(cid)) is None:
            raise InputError(f"messages on channel id {cid}, which is never defined", file=path)
        if ch.message_encoding != "json":
            raise InputError(
                f"message encoding {ch.message_encoding!r} is not json", file=path, field=ch.topic
            )
        schema = raw.schemas.get(ch.schema_id)
        log_ns = np.fromiter((m.log_time for m in msgs), dtype=np.int64, count=len(msgs))
        if np.any(np.diff(log_ns) < 0):  # file order is write order; present in time order
            order = np.argsort(log_ns, kind="stable")
            msgs = [msgs[i] for i in order]
            log_ns = log_ns[order]
        try:
            decoded = json.loads(b"[" + b",".join(m.data for m in msgs) + b"]")
        except json.JSONDecodeError as e:
            raise InputError(f"message is not JSON: {e}", file=path, field=ch.topic) from e
        names: dict[str, None] = {}  # ordered union of the messages' keys
        for d in decoded:
            if d.keys() != names.keys():
                names.update(dict.fromkeys(d))
        names.pop("timestamp", None)
        numbers = _number_fields(schema)
        fields = {
            k: _column([d.get(k) for d in decoded], path, f"{ch.topic}.{k}", k in numbers) for k in names
        }
        topics[ch.topic] = TopicData(ch.topic, schema.name if schema else "", log_ns / _NS, fields)
    return McapContents(envelope, topics, metadata, raw.complete, raw.stopped_because)


def read_mcap_envelope(path: str | Path) -> dict[str, Any]:
    """The envelope alone, from the metadata record written right after the header: what the file
    is (its ``kind``), without reading its data. InputError if it is no rxcomm MCAP."""
    path = Path(path)
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed below
    except FileNotFoundError as e:
        raise InputError("file not found", file=path) from e
    except OSError as e:
        raise InputError(f"cannot read: {e}", file=path) from e
    with f:
        try:
            for rec in StreamReader(_ExactReader(f), validate_crcs=True).records:
                if isinstance(rec, Metadata) and rec.name == ENVELOPE_RECORD:
                    try:
                        return {k: json.loads(v) for k, v in rec.metadata.items()}
                    except json.JSONDecodeError as e:
                        raise InputError(f"not JSON: {e}", file=path, field=ENVELOPE_RECORD) from e
        except (EndOfFile, McapError, ValueError, struct.error) as e:
            raise InputError(f"not a readable MCAP file: {e or type(e).__name__}", file=path) from e
    raise InputError("no rxcomm envelope metadata record; not an rxcomm artefact", file=path)


def read_mcap(path: str | Path) -> McapContents:
    """Read a finished rxcomm MCAP completely; anything unfinished or unreadable is an InputError."""
    path = Path(path)
    return _decode(_scan(path, strict=True), path, need_envelope=True)


def recover_mcap(part_path: str | Path, out_path: str | Path | None = None) -> McapContents:
    """Read what a killed or failed writer left in ``NAME.part`` (up to the last complete chunk) and,
    with ``out_path``, write it as a finished MCAP (schemas, channels, messages, metadata, plus a
    ``rxcomm/recovered`` record saying from where and why reading stopped)."""
    part_path = Path(part_path)
    raw = _scan(part_path, strict=False)
    contents = _decode(raw, part_path, need_envelope=False)
    if out_path is not None:
        out_path = Path(out_path)
        if out_path.resolve() == part_path.resolve():
            raise ValueError("out_path must differ from the file being recovered")
        buf = BytesIO()
        w = Writer(buf, compression=CompressionType.ZSTD)
        w.start(profile=PROFILE, library="rxcomm")
        for m in raw.metadata:
            w.add_metadata(m.name, dict(m.metadata))
        w.add_metadata(
            RECOVERED_RECORD,
            {
                "from": part_path.name,
                "complete": json.dumps(raw.complete),
                "stopped_because": str(raw.stopped_because),
            },
        )
        schema_ids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in raw.schemas.items()}
        channel_ids = {
            cid: w.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata)
            )
            for cid, c in raw.channels.items()
        }
        for cid, msgs in raw.messages.items():
            for m in msgs:
                w.add_message(channel_ids[cid], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()
        atomic_write_bytes(out_path, buf.getvalue(), part_suffix=".recover.part")
    return contents
