"""MCAP time series that Foxglove plots, with the artefact envelope inside (architecture §3): the writer.

Layout of a file written here (the format is ``rxcomm.io.mcap_format``; the reader ``mcap_read``):

- channels with ``jsonschema`` schemas and ``json`` messages; every message starts with
  ``"timestamp": {"sec", "nsec"}`` whose schema is titled ``time``; vectors are JSON arrays, so
  Foxglove plots ``/trajectory.q[0]``; fields every message repeats (``joint_names``) are declared
  once as channel constants;
- log times and stamps in epoch ns: ``time_origin_ns`` (default: when the writer opened) + sample time;
- beside each all-numeric channel, a column channel (``/columns/TOPIC``) of protobuf blocks in chunks
  of their own, which readers load without parsing the per-sample JSON;
- or, for a channel added with ``add_row_channel`` (the run log's), one fixed-layout protobuf message
  per sample instead of both (``mcap_rows``): the one copy Foxglove plots and readers view as arrays;
- the envelope as a metadata record ``rxcomm/envelope`` written right after the header (so a killed
  writer's file still says what it is) and, if the summary changed meanwhile, again at ``finish()``
  (the reader keeps the last one);
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
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

import numpy as np
from mcap.exceptions import McapError
from mcap.writer import CompressionType, Writer

from rxcomm.io.files import part_path
from rxcomm.io.mcap_format import (
    COLUMNS_DESCRIPTOR_SET,
    COLUMNS_ENCODING,
    COLUMNS_OF,
    COLUMNS_SCHEMA_TITLE,
    CONSTANTS,
    ENVELOPE_RECORD,
    NS,
    PROFILE,
    RECOVERED_RECORD,
    TIME_RECORD,
    TIME_SCHEMA,
    column_dtype,
    columns_topic,
    encode_block,
    encode_metadata,
    envelope_values,
    field_for,
    finite_or_none,
    number_field,
    time_ns,
    vector_field,
)

# Re-exported: the reader lives in mcap_read, callers import both from here.
from rxcomm.io.mcap_read import (
    McapContents,
    TopicData,
    read_mcap,
    read_mcap_envelope,
    recover_mcap,
)
from rxcomm.io.mcap_rows import (
    ROW_ENCODING,
    ROWS,
    add_fixed_messages,
    encode_rows,
    row_descriptor_set,
    row_fields,
)
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.plain import to_plain

__all__ = [
    "ENVELOPE_RECORD",
    "RECOVERED_RECORD",
    "McapContents",
    "McapWriter",
    "TopicData",
    "field_for",
    "number_field",
    "read_mcap",
    "read_mcap_envelope",
    "recover_mcap",
    "vector_field",
]

_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
BLOCK_ROWS = 2500  # samples per column block: 1 s at 2.5 kHz, ~0.5 MB for a run log's joints


@dataclass
class _Channel:
    id: int
    names: tuple[str, ...]  # per-message fields, schema order
    constants_json: str  # ',"joint_names":[...]' or ''
    dtypes: dict[str, str] | None  # column dtypes when the channel has a column channel
    columns_id: int = 0
    raw: bool = False  # a well-known schema: messages are written as given
    rows: list[list[Any]] | None = None  # a row channel (protobuf per sample): its fields
    pending: list[tuple[np.ndarray, dict[str, np.ndarray]]] = field(default_factory=list)
    written: list[tuple[int, Mapping[str, Any]]] = field(default_factory=list)


def _constant_schema(value: Any) -> dict[str, Any]:
    if isinstance(value, list | tuple):
        items = {"type": "string"} if all(isinstance(v, str) for v in value) else {"type": "number"}
        return {"type": "array", "items": items, "const": list(value)}
    kind = "string" if isinstance(value, str) else "number"
    return {"type": kind, "const": value}


class McapWriter:
    """Chunked MCAP writer for JSON-schema channels; see the module docstring for the file layout.

    ``McapWriter(path, envelope)`` opens ``path.part``; use it as a context manager or call
    :meth:`finish`. ``envelope`` is the dict from ``SomeArtefact.envelope(...)`` or an Artefact.
    ``time_origin_ns`` is the epoch time of t = 0 (default: now).
    """

    def __init__(
        self,
        path: str | Path,
        envelope: Mapping[str, Any] | Artefact,
        *,
        chunk_bytes: int = 1 << 20,
        flush_period_s: float = 1.0,
        compression: str = "zstd",
        time_origin_ns: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.part_path = part_path(self.path)
        self._envelope = envelope_values(envelope)
        self._envelope_dirty = False
        self.time_origin_ns = time.time_ns() if time_origin_ns is None else int(time_origin_ns)
        self._file: IO[bytes] = open(self.part_path, "wb")  # noqa: SIM115 - closed in finish/abort
        self._w = Writer(self._file, chunk_size=chunk_bytes, compression=_COMPRESSIONS[compression])
        self._chunk_bytes = chunk_bytes
        self._w.start(profile=PROFILE, library="rxcomm")
        self._w.add_metadata(ENVELOPE_RECORD, encode_metadata(self._envelope))
        self._w.add_metadata(TIME_RECORD, encode_metadata({"origin_ns": self.time_origin_ns}))
        self._channels: dict[str, _Channel] = {}
        self._columns_schema_id: int | None = None
        self._seq: dict[int, int] = {}
        self._period_ns = round(flush_period_s * NS)
        self._period_s = flush_period_s
        self._chunk_t0: int | None = None
        self._wall_t0 = time.monotonic()
        self._done = False

    # -- channels and messages

    def add_channel(
        self,
        topic: str,
        schema_title: str,
        fields: Mapping[str, Mapping[str, Any]],
        *,
        constants: Mapping[str, Any] | None = None,
        schema: Mapping[str, Any] | None = None,
    ) -> None:
        """Register ``topic`` with a JSON schema: the ``timestamp`` plus ``fields`` (name -> JSON schema,
        e.g. :func:`number_field`, :func:`vector_field`). ``constants`` (name -> value) are repeated in
        every message (Foxglove shows them beside the values) and declared once in the channel
        metadata. A channel whose fields are all numeric gets a column channel beside it.
        ``schema`` replaces the generated one (a Foxglove well-known schema, e.g. foxglove.FrameTransforms:
        then ``fields`` lists its top-level properties and no column channel is made)."""
        if topic in self._channels:
            raise ValueError(f"channel {topic!r} already added")
        consts = dict(constants or {})
        given = schema
        if "timestamp" in fields and schema is None:
            raise ValueError("'timestamp' is added by the writer")
        if schema is None:
            props = {"timestamp": TIME_SCHEMA, **{k: _constant_schema(v) for k, v in consts.items()}}
            schema = {
                "type": "object",
                "title": schema_title,
                "properties": {**props, **fields},
                "required": ["timestamp", *consts, *fields],
            }
        schema_id = self._w.register_schema(
            name=schema_title, encoding="jsonschema", data=json.dumps(schema, sort_keys=False).encode()
        )
        meta = {CONSTANTS: json.dumps(to_plain(consts), separators=(",", ":"))} if consts else {}
        channel_id = self._w.register_channel(
            topic=topic, message_encoding="json", schema_id=schema_id, metadata=meta
        )
        raw = given is not None  # a well-known schema: no column channel, messages as given
        dtypes = {k: column_dtype(s) for k, s in fields.items()}
        numeric = bool(dtypes) and all(dtypes.values()) and not raw
        consts_json = "".join(
            "," + json.dumps(k) + ":" + json.dumps(to_plain(v), separators=(",", ":"))
            for k, v in consts.items()
        )
        ch = _Channel(channel_id, tuple(fields), consts_json, dtypes if numeric else None, raw=raw)  # type: ignore[arg-type]
        if numeric:
            if self._columns_schema_id is None:
                self._columns_schema_id = self._w.register_schema(
                    name=COLUMNS_SCHEMA_TITLE, encoding=COLUMNS_ENCODING, data=COLUMNS_DESCRIPTOR_SET
                )
            cid = self._columns_schema_id
            ch.columns_id = self._w.register_channel(
                topic=columns_topic(topic),
                message_encoding=COLUMNS_ENCODING,
                schema_id=cid,
                metadata={COLUMNS_OF: topic},
            )
            self._seq[ch.columns_id] = 0
        self._channels[topic] = ch
        self._seq[channel_id] = 0

    def add_row_channel(
        self,
        topic: str,
        schema_title: str,
        fields: Mapping[str, tuple[str, int]],
        *,
        constants: Mapping[str, Any] | None = None,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        """Register ``topic`` as a row channel: one protobuf message ``schema_title`` per sample with
        ``fields`` (name -> (dtype ``<f4``/``<f8``/``<i8``, k values; k = 0 a scalar)), the one copy
        Foxglove plots and readers take (``mcap_format``, row messages). ``constants`` (joint names)
        and ``metadata`` (``rxcomm/grid``) go into the channel metadata; write it with ``write_arrays``."""
        if topic in self._channels:
            raise ValueError(f"channel {topic!r} already added")
        rows = row_fields(fields)
        schema_id = self._w.register_schema(
            name=schema_title, encoding=ROW_ENCODING, data=row_descriptor_set(schema_title, rows)
        )
        meta = {**(metadata or {}), ROWS: json.dumps(rows, separators=(",", ":"))}
        if constants:
            meta[CONSTANTS] = json.dumps(to_plain(dict(constants)), separators=(",", ":"))
        channel_id = self._w.register_channel(
            topic=topic, message_encoding=ROW_ENCODING, schema_id=schema_id, metadata=meta
        )
        self._channels[topic] = _Channel(channel_id, tuple(fields), "", None, rows=rows)
        self._seq[channel_id] = 0

    def write(self, topic: str, t_s: float, msg: Mapping[str, Any]) -> None:
        """Write one message at time ``t_s`` (s from the origin, >= 0); numpy values are converted,
        NaN/inf become null. On a channel with a given ``schema`` the message is written as it is
        (its stamps are the caller's: ``time_origin_ns`` + t)."""
        ch = self._channel(topic)
        if ch.rows is not None:
            self.write_arrays(topic, np.array([t_s]), {k: np.asarray(v)[None] for k, v in msg.items()})
            return
        if unknown := set(msg) - set(ch.names):
            raise ValueError(f"{topic}: fields {sorted(unknown)} are not in the channel schema")
        ns = self.time_origin_ns + time_ns(float(t_s))
        if ch.raw:  # a well-known schema carries its own stamps; plain Python values skip to_plain
            try:
                raw = json.dumps(msg, separators=(",", ":"), allow_nan=False)
            except (TypeError, ValueError):
                raw = json.dumps(finite_or_none(to_plain(dict(msg))), separators=(",", ":"))
            self._add(ch.id, ns, raw.encode())
            return
        plain = to_plain(dict(msg))
        # Keys in schema order, whatever the caller's dict order: every message has the same layout.
        values = {k: plain[k] for k in ch.names if k in plain}
        try:
            data = json.dumps(values, separators=(",", ":"), allow_nan=False)
        except ValueError:
            data = json.dumps(finite_or_none(values), separators=(",", ":"))
        head = f'{{"timestamp":{{"sec":{ns // NS},"nsec":{ns % NS}}}' + ch.constants_json
        body = head + ("," + data[1:] if len(data) > 2 else "}")
        if ch.dtypes is not None:
            ch.written.append((ns, plain))
        self._add(ch.id, ns, body.encode())

    def write_json(self, topic: str, t_s: float, data: bytes) -> None:
        """Write one message already encoded as JSON on a channel with a given ``schema``."""
        ch = self._channel(topic)
        if not ch.raw:
            raise ValueError(f"{topic}: write_json is for channels with a given schema")
        self._add(ch.id, self.time_origin_ns + time_ns(float(t_s)), data)

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

        ``digits`` significant digits per float in the JSON: 17 round-trips float64 exactly; 9 (~1e-9
        relative, far below any sensor's resolution) formats ~2x faster and makes smaller files. The
        column channel holds the exact values either way."""
        t = np.asarray(t, dtype=float)
        cols = {k: np.asarray(v) for k, v in columns.items()}
        n = t.shape[0]
        for k, c in cols.items():
            if c.ndim not in (1, 2) or c.shape[0] != n:
                raise ValueError(f"{topic}.{k}: shape {c.shape} does not match {n} time stamps")
        if topic not in self._channels:
            title = schema_title or "rxcomm." + topic.strip("/").replace("/", ".")
            self.add_channel(topic, title, {k: field_for(c) for k, c in cols.items()})
        ch = self._channel(topic)
        if unknown := set(cols) - set(ch.names):
            raise ValueError(f"{topic}: fields {sorted(unknown)} are not in the channel schema")
        if not (np.all(np.isfinite(t)) and np.all(t >= 0)):
            raise ValueError(f"{topic}: time stamps must be finite and >= 0 s")
        ns = self.time_origin_ns + np.round(t * NS).astype(np.int64)
        if ch.rows is not None:
            self._write_rows(ch, ns, cols)
            return
        fast = all(
            c.dtype.kind in "iu" or (c.dtype.kind == "f" and np.all(np.isfinite(c))) for c in cols.values()
        )
        if not fast:  # bools, NaN, strings: the general path (which also fills the column block)
            for i in range(n):
                self.write(topic, t[i], {k: c[i] for k, c in cols.items()})
            return
        if ch.dtypes is not None:
            ch.pending.append((ns, {k: c.astype(ch.dtypes[k], copy=False) for k, c in cols.items()}))
        # One %-format per message over flat per-component lists. '%.17g' round-trips float64 exactly
        # and is ~30 % faster than repr; it writes 1.0 as 1, so the reader types columns by schema.
        slots = {"f": f"%.{int(digits)}g", "i": "%d", "u": "%d"}
        tmpl = '{"timestamp":{"sec":%d,"nsec":%d}' + ch.constants_json.replace("%", "%%")
        flat: list[list[Any]] = [(ns // NS).tolist(), (ns % NS).tolist()]
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
            self._add(ch.id, log_ns, (tmpl % row).encode())

    def _write_rows(self, ch: _Channel, ns: np.ndarray, cols: Mapping[str, np.ndarray]) -> None:
        """Messages of a row channel, in chunks of their own (readers view them in one go)."""
        assert ch.rows is not None
        if self._done:
            raise ValueError("writer already finished")
        add_fixed_messages(
            self._w, ch.id, ns, encode_rows(ch.rows, cols), self._seq[ch.id], self._chunk_bytes
        )
        self._seq[ch.id] += len(ns)
        self.flush()

    def _channel(self, topic: str) -> _Channel:
        try:
            return self._channels[topic]
        except KeyError:
            raise ValueError(f"channel {topic!r} not added (add_channel first)") from None

    def _add(self, channel_id: int, log_ns: int, data: bytes, *, timed: bool = True) -> None:
        if self._done:
            raise ValueError("writer already finished")
        seq = self._seq[channel_id]
        self._seq[channel_id] = seq + 1
        self._w.add_message(channel_id, log_time=log_ns, data=data, publish_time=log_ns, sequence=seq)
        if not timed:
            return
        # Close the chunk once it spans flush_period_s (log or wall time): a killed writer loses less.
        if self._chunk_t0 is None:
            self._chunk_t0 = log_ns
        elif abs(log_ns - self._chunk_t0) >= self._period_ns or (
            time.monotonic() - self._wall_t0 >= self._period_s
        ):
            self.flush()

    def _write_blocks(self) -> bool:
        """The column blocks gathered since the last flush, as messages; True if any was written."""
        wrote = False
        for ch in self._channels.values():
            if ch.dtypes is None:
                continue
            pieces = ch.pending
            if ch.written:  # rows from write(): None (null) -> NaN in float columns
                ns = np.array([r[0] for r in ch.written], dtype=np.int64)
                cols = {}
                for k, dt in ch.dtypes.items():
                    vals = [r[1].get(k) for r in ch.written]
                    cols[k] = np.asarray(finite_or_nan(vals) if dt == "<f8" else vals, dtype=dt)
                pieces = [*pieces, (ns, cols)]
            if not pieces:
                continue
            ns = np.concatenate([p[0] for p in pieces])
            cols = {k: np.concatenate([p[1][k] for p in pieces]) for k in pieces[0][1]}
            for i in range(0, len(ns), BLOCK_ROWS):
                sl = slice(i, i + BLOCK_ROWS)
                self._add(
                    ch.columns_id,
                    int(ns[i]),
                    encode_block(ns[sl], {k: c[sl] for k, c in cols.items()}),
                    timed=False,
                )
            ch.pending, ch.written, wrote = [], [], True
        return wrote

    # -- metadata and end

    def set_summary(self, summary: Mapping[str, Any]) -> None:
        """Replace the envelope's summary; the updated envelope is written again at finish."""
        self._envelope = envelope_values({**self._envelope, "summary": to_plain(dict(summary))})
        self._envelope_dirty = True

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        """Add a free metadata record (str -> str)."""
        self._w.add_metadata(name, dict(values))

    def flush(self) -> None:
        """Close the current chunk, then write the pending column blocks to a chunk of their own, and
        hand both to the OS (survives kill -9, not a power cut)."""
        self._w.flush()
        # Column chunks uncompressed: arrays of floats gain ~14 % from zstd, and decompressing them
        # was a third of the reading time. The mcap Writer has one compression for all chunks; its
        # private attribute is switched around these chunks (if a future mcap renames it, they stay
        # compressed: slower to read, nothing else).
        mangled = "_Writer__compression"
        compression = getattr(self._w, mangled, None)
        if compression is not None:
            setattr(self._w, mangled, CompressionType.NONE)
        try:
            if self._write_blocks():
                self._w.flush()
        finally:
            if compression is not None:
                setattr(self._w, mangled, compression)
        self._chunk_t0 = None
        self._wall_t0 = time.monotonic()

    def _close_part(self) -> None:
        self.flush()
        if self._envelope_dirty:
            self._w.add_metadata(ENVELOPE_RECORD, encode_metadata(self._envelope))
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
            try:
                self.flush()
                self._done = True
                if self._envelope_dirty:
                    self._w.add_metadata(ENVELOPE_RECORD, encode_metadata(self._envelope))
                self._w.finish()
            except (OSError, ValueError, McapError):
                pass  # what reached the file stays readable by recover_mcap
            finally:
                self._done = True
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


def finite_or_nan(values: list[Any]) -> list[Any]:
    """JSON nulls (None) of a float column -> NaN, nested lists too."""
    return [float("nan") if v is None else (finite_or_nan(v) if isinstance(v, list) else v) for v in values]
