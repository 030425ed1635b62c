"""Reading rxcomm MCAP files (format: ``rxcomm.io.mcap_format``): whole, by topic, or what a killed
writer left.

A finished file is read through its index: a row channel (run logs since issue 32, ``mcap_rows``)
with one np.frombuffer per chunk; a topic with a complete column channel from its blocks (protobuf,
arrays as bytes, no per-sample JSON parsed); any other from its messages. A file without a usable
index (a ``.part`` of a killed writer, through :func:`recover_mcap`) is read record by record in file
order, from the per-sample messages, which are never behind the blocks.
"""

from __future__ import annotations

import contextlib
import json
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_bytes
from rxcomm.io.mcap_format import (
    COLUMNS_OF,
    CONSTANTS,
    ENVELOPE_RECORD,
    NS,
    PROFILE,
    RECOVERED_RECORD,
    TIME_RECORD,
    decode_block,
)
from rxcomm.io.mcap_rows import (
    _MESSAGE_HEAD,
    _OP_MESSAGE,
    _RECORD_HEAD,
    ROWS,
    chunk_records,
    chunk_rows,
    decode_rows,
    parse_rows,
    row_dtype,
)


@dataclass(frozen=True)
class TopicData:
    """One channel's messages as arrays: ``t`` [n] s from the file's time origin and each field [n] or
    [n, k] (``td.q``, ``td["q"]``); ``constants`` the values every message repeats (``joint_names``).

    Numbers become float64 (null -> NaN), integers int64, booleans bool.
    """

    topic: str
    schema_title: str
    t: np.ndarray
    fields: dict[str, np.ndarray]
    constants: dict[str, Any] = field(default_factory=dict)
    backwards_at_s: float | None = None  # the first log time that went backwards in file order (re-sorted)

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
    where reading stopped. ``time_origin_ns``: epoch ns of t = 0 (0 for files written before it).
    """

    envelope: dict[str, Any]
    topics: dict[str, TopicData]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = True
    stopped_because: str | None = None
    time_origin_ns: int = 0

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


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")  # noqa: SIM115 - the callers close it
    except FileNotFoundError as e:
        raise InputError("file not found", file=path) from e
    except OSError as e:
        raise InputError(f"cannot read: {e}", file=path) from e


def _scan(path: Path, *, strict: bool) -> _Raw:
    """Read records in file order (no seeking, no index needed); in strict mode any defect is an
    InputError, otherwise reading stops at the first truncated or corrupt record."""
    raw = _Raw()
    with _open(path) as f:
        records = StreamReader(_ExactReader(f), validate_crcs=True).records
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
    except (ValueError, TypeError) as e:
        raise InputError(f"values are ragged or mixed: {e}", file=file, field=name) from e
    if arr.dtype == object:  # nulls among numbers -> NaN; structured values (Foxglove messages) stay
        with contextlib.suppress(ValueError, TypeError):
            arr = np.asarray(values, dtype=float)
    return arr


def _metadata(records: Iterable[Metadata], path: Path, *, need_envelope: bool) -> tuple[dict, dict, int]:
    """(metadata by name, envelope, time origin ns); later records of a name win (the envelope is
    rewritten at finish)."""
    metadata: dict[str, dict[str, str]] = {}
    for m in records:
        metadata[m.name] = dict(m.metadata)
    envelope: dict[str, Any] = {}
    if ENVELOPE_RECORD in metadata:
        try:
            envelope = {k: json.loads(v) for k, v in metadata[ENVELOPE_RECORD].items()}
        except json.JSONDecodeError as e:
            raise InputError(f"not JSON: {e}", file=path, field=ENVELOPE_RECORD) from e
    elif need_envelope:
        raise InputError("no rxcomm envelope metadata record; not an rxcomm artefact", file=path)
    try:
        origin = int(json.loads(metadata.get(TIME_RECORD, {}).get("origin_ns", "0")))
    except (json.JSONDecodeError, TypeError, ValueError) as e:
        raise InputError(f"not an integer: {e}", file=path, field=f"{TIME_RECORD}.origin_ns") from e
    return metadata, envelope, origin


def _constants(ch: Channel, path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(ch.metadata[CONSTANTS])) if CONSTANTS in ch.metadata else {}
    except (json.JSONDecodeError, TypeError, ValueError) as e:
        raise InputError(f"channel constants are not JSON: {e}", file=path, field=ch.topic) from e


def _messages_topic(
    ch: Channel, schema: Schema | None, msgs: list[McapMessage], path: Path, origin: int
) -> TopicData:
    """A topic from its per-sample messages (JSON, or the protobuf messages of a row channel)."""
    if ROWS in ch.metadata:
        return _rows_topic(
            ch, schema, [m.log_time for m in msgs], b"".join(m.data for m in msgs), path, origin
        )
    if ch.message_encoding != "json":
        raise InputError(f"message encoding {ch.message_encoding!r} is not json", file=path, field=ch.topic)
    log_ns = np.fromiter((m.log_time for m in msgs), dtype=np.int64, count=len(msgs))
    back = _backwards_at(log_ns, origin)
    if back is not None:  # file order is write order; present in time order
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
    constants = _constants(ch, path)
    for k in ("timestamp", *constants):
        names.pop(k, None)
    numbers = _number_fields(schema)
    fields = {k: _column([d.get(k) for d in decoded], path, f"{ch.topic}.{k}", k in numbers) for k in names}
    t = (log_ns - origin) / NS
    return TopicData(ch.topic, schema.name if schema else "", t, fields, constants, back)


def _backwards_at(log_ns: np.ndarray, origin: int) -> float | None:
    """The first log time (s from the origin) smaller than the one before it, None if in order."""
    back = np.flatnonzero(np.diff(log_ns) < 0)
    return float((log_ns[back[0] + 1] - origin) / NS) if back.size else None


def _row_layout(ch: Channel, path: Path) -> list[list[Any]]:
    try:
        return parse_rows(ch.metadata[ROWS])
    except ValueError as e:
        raise InputError(f"row layout {ROWS} unreadable: {e}", file=path, field=ch.topic) from e


def _rows_topic(
    ch: Channel, schema: Schema | None, log_ns: Iterable[int], data: bytes, path: Path, origin: int
) -> TopicData:
    """A row channel's topic from its messages' bytes, concatenated in file order: one np.frombuffer."""
    ns = np.fromiter(log_ns, dtype=np.int64) if not isinstance(log_ns, np.ndarray) else log_ns
    back = _backwards_at(ns, origin)
    try:
        ns, fields = decode_rows(_row_layout(ch, path), ns, data)  # in time order
    except ValueError as e:
        raise InputError(str(e), file=path, field=ch.topic) from e
    title = schema.name if schema else ""
    return TopicData(ch.topic, title, (ns - origin) / NS, fields, _constants(ch, path), backwards_at_s=back)


def _block_topic(
    ch: Channel, schema: Schema | None, blocks: list[McapMessage], path: Path, origin: int
) -> TopicData:
    """A topic from the blocks of its column channel."""
    try:
        decoded = [decode_block(m.data) for m in blocks]
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"unreadable column block: {e}", file=path, field=ch.topic) from e
    log_ns = np.concatenate([d[0] for d in decoded]) if decoded else np.zeros(0, dtype=np.int64)
    names = list(decoded[0][1]) if decoded else []
    fields = {k: np.concatenate([d[1][k] for d in decoded]).astype(_native(decoded[0][1][k])) for k in names}
    back = _backwards_at(log_ns, origin)
    if back is not None:
        order = np.argsort(log_ns, kind="stable")
        log_ns, fields = log_ns[order], {k: v[order] for k, v in fields.items()}
    t = (log_ns - origin) / NS
    return TopicData(ch.topic, schema.name if schema else "", t, fields, _constants(ch, path), back)


def _native(a: np.ndarray) -> np.dtype:
    return np.dtype({"f": np.float64, "i": np.int64, "u": np.int64, "b": bool}[a.dtype.kind])


def _decode(
    raw: _Raw, path: Path, *, need_envelope: bool, topics: Iterable[str] | None = None
) -> McapContents:
    """A scanned file's topics from their per-sample messages (column channels are skipped)."""
    metadata, envelope, origin = _metadata(raw.metadata, path, need_envelope=need_envelope)
    want = None if topics is None else set(topics)
    out: dict[str, TopicData] = {}
    for cid, msgs in raw.messages.items():
        if (ch := raw.channels.get(cid)) is None:
            raise InputError(f"messages on channel id {cid}, which is never defined", file=path)
        if COLUMNS_OF in ch.metadata or (want is not None and ch.topic not in want):
            continue
        out[ch.topic] = _messages_topic(ch, raw.schemas.get(ch.schema_id), msgs, path, origin)
    return McapContents(envelope, out, metadata, raw.complete, raw.stopped_because, origin)


def _summary(f: IO[bytes]) -> tuple[SeekingReader, Summary] | None:
    """The index of a finished file with chunk indexes and statistics; None if there is none."""
    try:
        reader = SeekingReader(f, validate_crcs=True)
        summary = reader.get_summary()
    except (EndOfFile, McapError, ValueError, struct.error, OSError):
        return None
    if summary is None or not summary.chunk_indexes or summary.statistics is None:
        return None
    return reader, summary


def _chunk_messages(f: IO[bytes], offset: int, channel_ids: set[int]) -> list[tuple[int, int, memoryview]]:
    """(channel id, log time, data) of the messages of ``channel_ids`` in the chunk at ``offset``,
    sliced from the chunk's records (decompressed and CRC-checked by ``chunk_records``)."""
    records = chunk_records(f, offset)
    out = []
    j = 0
    while j < len(records):
        op, length = _RECORD_HEAD.unpack_from(records, j)
        j += _RECORD_HEAD.size
        if op == _OP_MESSAGE:
            cid, _, log_time, _ = _MESSAGE_HEAD.unpack_from(records, j)
            if cid in channel_ids:
                out.append((cid, log_time, records[j + _MESSAGE_HEAD.size : j + length]))
        j += length
    return out


def _read_indexed(
    f: IO[bytes], reader: SeekingReader, summary: Summary, path: Path, topics: Iterable[str] | None
) -> McapContents:
    metadata, envelope, origin = _metadata(reader.iter_metadata(), path, need_envelope=True)
    columns = {c.metadata[COLUMNS_OF]: c for c in summary.channels.values() if COLUMNS_OF in c.metadata}
    plain = {c.topic: c for c in summary.channels.values() if COLUMNS_OF not in c.metadata}
    want = list(plain) if topics is None else [t for t in topics if t in plain]
    counts = summary.statistics.channel_message_counts

    def messages(names: list[str]) -> dict[str, list[McapMessage]]:
        got: dict[str, list[McapMessage]] = {n: [] for n in names}
        ids = {c.id for c in summary.channels.values() if c.topic in got}
        for ci in summary.chunk_indexes:
            if ids & set(ci.message_index_offsets):
                for cid, log_time, data in _chunk_messages(f, ci.chunk_start_offset, ids):
                    msg = McapMessage(
                        channel_id=cid, sequence=0, log_time=log_time, publish_time=log_time, data=data
                    )  # type: ignore[arg-type]
                    got[summary.channels[cid].topic].append(msg)
        return got

    out: dict[str, TopicData] = {}
    for t in [t for t in want if ROWS in plain[t].metadata]:
        ch = plain[t]
        size = row_dtype(_row_layout(ch, path)).itemsize
        parts = [
            chunk_rows(f, ci.chunk_start_offset, ch.id, size)
            for ci in summary.chunk_indexes
            if ch.id in ci.message_index_offsets or not ci.message_index_offsets
        ]
        ns = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
        data = b"".join(b for p in parts for b in p[1])
        out[t] = _rows_topic(ch, summary.schemas.get(ch.schema_id), ns, data, path, origin)
    by_blocks = [t for t in want if t in columns and t not in out]
    blocks = messages([columns[t].topic for t in by_blocks])
    rest = [t for t in want if t not in columns and t not in out]
    for t in by_blocks:
        ch = plain[t]
        td = _block_topic(ch, summary.schemas.get(ch.schema_id), blocks[columns[t].topic], path, origin)
        if len(td) == counts.get(ch.id, 0):
            out[t] = td
        else:  # blocks behind the messages (a recovered file): the messages are the record
            rest.append(t)
    for t, msgs in messages(rest).items():
        ch = plain[t]
        out[t] = _messages_topic(ch, summary.schemas.get(ch.schema_id), msgs, path, origin)
    return McapContents(envelope, {t: out[t] for t in want}, metadata, True, None, origin)


def read_mcap_envelope(path: str | Path) -> dict[str, Any]:
    """The envelope alone, from the metadata record written right after the header: what the file
    is (its ``kind``), without reading its data. InputError if it is no rxcomm MCAP."""
    path = Path(path)
    with _open(path) as f:
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


def read_mcap(
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    exclude: Iterable[str] = (),
    columns: bool = True,
) -> McapContents:
    """Read a finished rxcomm MCAP (all topics, or only ``topics``, less ``exclude``; column channels are
    never topics of their own); anything unfinished or unreadable is an InputError. ``columns=False``
    reads the per-sample messages instead of the column blocks (slow; to cross-check the two)."""
    path = Path(path)
    topics = None if topics is None else list(topics)
    with _open(path) as f:
        indexed = _summary(f) if columns else None
        if indexed is not None and exclude:
            skip = set(exclude)
            names = [c.topic for c in indexed[1].channels.values() if COLUMNS_OF not in c.metadata]
            topics = [t for t in (names if topics is None else topics) if t not in skip]
        if indexed is not None:
            try:
                return _read_indexed(f, *indexed, path, topics)
            except (EndOfFile, McapError, struct.error) as e:
                raise InputError(f"unreadable MCAP: {e or type(e).__name__}", file=path) from e
    raw = _scan(path, strict=True)
    if exclude:
        skip = set(exclude)
        names = [c.topic for c in raw.channels.values() if COLUMNS_OF not in c.metadata]
        topics = [t for t in (names if topics is None else topics) if t not in skip]
    return _decode(raw, path, need_envelope=True, topics=topics)


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
