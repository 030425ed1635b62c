"""Row messages: one protobuf message per sample, the run log's channels (issue 32), written and read
in blocks.

A row channel (run logs from issue 32 on) holds one protobuf message per sample, the one copy that
both Foxglove plots (``/run/joints.q_actual[0]``: its schema is the FileDescriptorSet below) and
rxcomm reads. Every field is always written, in field-number order, with a fixed width: a vector as
a packed repeated field (tag, byte length, values), a scalar as a fixed32/fixed64 field (tag, value).
So every message of a channel has the same bytes layout, and a block of messages is one numpy
structured array: writing is one ``tobytes``, reading one ``np.frombuffer`` per chunk.
The channel metadata ``rxcomm/rows`` lists the fields as [name, dtype, k] (k = 0: a scalar).

Writing (:func:`add_fixed_messages`): the mcap package adds a message in ~4 µs of Python (a record
builder call per field); a 60 s run log at 2.5 kHz has 150 000 joint messages. Here a block of them
is one numpy array of whole MCAP message records (opcode, length, channel, sequence, log and publish
time, data) handed to the writer's open chunk in one write, with its message index as one array. This
reaches into the Writer's private state (``_Writer__chunk_builder``, ``_Writer__statistics``, as
``mcap_io`` already does for the chunk compression); if a future mcap renames it, the messages are
added one by one: slower, the same file. Reading (:func:`chunk_rows`): a chunk of one row channel's
messages is one ``np.frombuffer``; any other chunk is walked record by record.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Mapping
from typing import IO, Any

import lz4.frame
import numpy as np
import zstandard
from mcap.exceptions import EndOfFile, McapError
from mcap.records import MessageIndex
from mcap.writer import Writer

from rxcomm.io.mcap_format import _field_descriptor, _ld

ROWS = "rxcomm/rows"  # channel metadata of a row channel: JSON [[name, dtype, k], ...]
GRID = "rxcomm/grid"  # optional channel metadata: JSON {name: step}, the grid the values were rounded to
ROW_ENCODING = "protobuf"
_PROTO_TYPES = {"<f4": (2, 5), "<f8": (1, 1), "<i8": (16, 1)}  # dtype -> (FieldDescriptorProto type, wire)


def row_fields(fields: Mapping[str, tuple[str, int]]) -> list[list[Any]]:
    """The ``rxcomm/rows`` list of ``fields`` (name -> (dtype, k)); ValueError for a field that cannot
    be a row field."""
    if not 0 < len(fields) <= 15:
        raise ValueError(f"a row message has 1..15 fields (one-byte tags), got {len(fields)}")
    out = []
    for name, (dtype, k) in fields.items():
        if dtype not in _PROTO_TYPES:
            raise ValueError(f"row field {name}: dtype {dtype} is not one of {sorted(_PROTO_TYPES)}")
        if not 0 <= k * np.dtype(dtype).itemsize < 128:
            raise ValueError(f"row field {name}: {k} values do not fit a one-byte length")
        out.append([name, dtype, int(k)])
    return out


def row_dtype(rows: list[list[Any]]) -> np.dtype:
    """The numpy structured dtype of one row message (tags and lengths included)."""
    parts: list[tuple[Any, ...]] = []
    for number, (name, dtype, k) in enumerate(rows, start=1):
        parts.append((f"_tag{number}", "u1"))
        if k:
            parts += [(f"_len{number}", "u1"), (name, dtype, (k,))]
        else:
            parts.append((name, dtype))
    return np.dtype(parts)


def row_header(rows: list[list[Any]], n: int) -> np.ndarray:
    """``n`` row messages with their tags and lengths set and zero values, to be filled field by field."""
    a = np.zeros(n, dtype=row_dtype(rows))
    for number, (_, dtype, k) in enumerate(rows, start=1):
        a[f"_tag{number}"] = number << 3 | (2 if k else _PROTO_TYPES[dtype][1])
        if k:
            a[f"_len{number}"] = k * np.dtype(dtype).itemsize
    return a


def check_rows(a: np.ndarray, rows: list[list[Any]]) -> None:
    """ValueError unless every message of ``a`` has the tags and lengths of ``rows``."""
    ref = row_header(rows, 1)
    keys = [k for k in ref.dtype.names or () if k.startswith("_")]
    at = [ref.dtype.fields[k][1] for k in keys]  # byte offsets of the tags and lengths
    raw = a.view(np.uint8).reshape(len(a), a.dtype.itemsize)[:, at]
    bad = np.flatnonzero(np.any(raw != ref.view(np.uint8)[at], axis=0))
    if len(a) and len(bad):
        raise ValueError(f"row messages with another layout ({keys[bad[0]]})")


def parse_rows(text: str) -> list[list[Any]]:
    """The ``rxcomm/rows`` list from its channel metadata text; ValueError if it is no valid layout."""
    try:
        rows = json.loads(text)
        row_fields({name: (dtype, k) for name, dtype, k in rows})
    except (json.JSONDecodeError, TypeError, ValueError) as e:
        raise ValueError(f"not a row layout: {e}") from e
    return rows


def encode_rows(rows: list[list[Any]], cols: Mapping[str, np.ndarray]) -> np.ndarray:
    """The row messages of ``cols`` (name -> [n] or [n, k]) as one structured array."""
    if missing := {r[0] for r in rows} - set(cols):
        raise ValueError(f"row channel: fields {sorted(missing)} missing")
    n = len(next(iter(cols.values())))
    a = row_header(rows, n)
    for name, _, k in rows:
        c = np.asarray(cols[name])
        if c.shape != ((n, k) if k else (n,)):
            raise ValueError(f"{name}: shape {c.shape}, expected {(n, k) if k else (n,)}")
        a[name] = c
    return a


def decode_rows(
    rows: list[list[Any]], log_ns: np.ndarray, data: bytes
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(log times in time order, fields as float64/int64 arrays) of concatenated row messages;
    ValueError if their size or layout is not the channel's."""
    dtype = row_dtype(rows)
    if len(data) != len(log_ns) * dtype.itemsize:
        raise ValueError(f"{len(data)} bytes for {len(log_ns)} row messages of {dtype.itemsize} bytes")
    a = np.frombuffer(data, dtype=dtype)
    check_rows(a, rows)
    if np.any(np.diff(log_ns) < 0):
        order = np.argsort(log_ns, kind="stable")
        log_ns, a = log_ns[order], a[order]
    native = {"<f4": np.float64, "<f8": np.float64, "<i8": np.int64}
    return log_ns, {name: a[name].astype(native[dtype]) for name, dtype, _ in rows}


def row_descriptor_set(message: str, rows: list[list[Any]]) -> bytes:
    """The FileDescriptorSet (proto3) of the row message ``package.Name`` ``message``."""
    package, _, name = message.rpartition(".")
    fields = b"".join(
        _ld(2, _field_descriptor(fname, number, 3 if k else 1, _PROTO_TYPES[dtype][0]))
        for number, (fname, dtype, k) in enumerate(rows, start=1)
    )
    file = _ld(1, f"{message.replace('.', '/')}.proto".encode()) + _ld(2, package.encode())
    return _ld(1, file + _ld(4, _ld(1, name.encode()) + fields) + _ld(12, b"proto3"))


_OP_MESSAGE = 0x05
_HEAD = 22  # channel id u16, sequence u32, log time u64, publish time u64


class _ArrayIndex(MessageIndex):
    """A MessageIndex whose entries are written as one array (the mcap writer loops per entry)."""

    def write(self, stream: Any) -> None:
        stream.start_record(0x07)  # MESSAGE_INDEX
        stream.write2(self.channel_id)
        entries = np.asarray(self.records, dtype="<u8").reshape(-1, 2)
        stream.write4(entries.nbytes)
        stream.write(entries.tobytes())
        stream.finish_record()


def _record_dtype(size: int) -> np.dtype:
    return np.dtype(
        [
            ("op", "u1"),
            ("len", "<u8"),
            ("ch", "<u2"),
            ("seq", "<u4"),
            ("log", "<u8"),
            ("pub", "<u8"),
            ("data", f"V{size}"),
        ]  # fmt: skip
    )


def add_fixed_messages(
    w: Writer, channel_id: int, log_ns: np.ndarray, data: np.ndarray, seq0: int, chunk_bytes: int
) -> None:
    """Add ``len(log_ns)`` messages of ``channel_id``: message i is the bytes of ``data[i]`` (a
    structured array), sequence ``seq0 + i``. Closes the open chunk first and each chunk of about
    ``chunk_bytes``, so the messages are in chunks of their own."""
    n, size = len(log_ns), data.dtype.itemsize
    cb = getattr(w, "_Writer__chunk_builder", None)
    stats = getattr(w, "_Writer__statistics", None)
    if cb is None or stats is None or not hasattr(cb, "record_writer"):
        raw = memoryview(data.tobytes())
        for i, t in enumerate(log_ns.tolist()):
            w.add_message(channel_id, t, raw[i * size : (i + 1) * size], t, seq0 + i)
        return
    w.flush()
    rec = np.zeros(n, dtype=_record_dtype(size))
    rec["op"], rec["len"], rec["ch"] = _OP_MESSAGE, _HEAD + size, channel_id
    rec["seq"] = (seq0 + np.arange(n)) % (1 << 32)
    rec["log"] = rec["pub"] = log_ns
    rec["data"] = data.view(f"V{size}")
    per_chunk = max(1, chunk_bytes // rec.dtype.itemsize)
    for i in range(0, n, per_chunk):
        part = rec[i : i + per_chunk]
        times = part["log"]
        first = cb.num_messages == 0
        offsets = cb.count + np.arange(len(part), dtype=np.uint64) * rec.dtype.itemsize
        cb.record_writer.write(part.tobytes())
        index = cb.message_indices.get(channel_id)
        entries = np.stack([times, offsets], axis=1).tolist()
        if index is None:
            cb.message_indices[channel_id] = _ArrayIndex(channel_id, entries)
        else:
            index.records.extend(map(tuple, entries))
        lo, hi = int(times.min()), int(times.max())
        cb.message_start_time = lo if first else min(cb.message_start_time, lo)
        cb.message_end_time = max(cb.message_end_time, hi)
        cb.num_messages += len(part)
        stats.message_start_time = lo if stats.message_count == 0 else min(stats.message_start_time, lo)
        stats.message_end_time = max(stats.message_end_time, hi)
        stats.channel_message_counts[channel_id] += len(part)
        stats.message_count += len(part)
        w.flush()


_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_OP_CHUNK = 0x06


def chunk_records(f: IO[bytes], offset: int) -> memoryview:
    """The decompressed, CRC-checked records of the chunk at ``offset``."""
    f.seek(offset)
    op, length = _RECORD_HEAD.unpack(f.read(_RECORD_HEAD.size))
    if op != _OP_CHUNK:
        raise McapError(f"no chunk record at byte {offset}")
    body = memoryview(f.read(length))
    if len(body) != length:
        raise EndOfFile()
    _, _, size, crc, clen = _CHUNK_HEAD.unpack_from(body)
    i = _CHUNK_HEAD.size
    compression = bytes(body[i : i + clen]).decode()
    i += clen
    (n,) = struct.unpack_from("<Q", body, i)
    data = body[i + 8 : i + 8 + n]
    if compression == "zstd":
        records = memoryview(zstandard.ZstdDecompressor().decompress(data, max_output_size=size))
    elif compression == "lz4":
        records = memoryview(lz4.frame.decompress(data))
    elif compression:
        raise McapError(f"chunk at byte {offset}: unknown compression {compression!r}")
    else:
        records = data
    if len(records) != size or (crc and zlib.crc32(records) != crc):
        raise McapError(f"chunk at byte {offset}: size or CRC mismatch")
    return records


def chunk_rows(f: IO[bytes], offset: int, channel_id: int, size: int) -> tuple[np.ndarray, list[bytes]]:
    """(log times, message bytes) of the row channel ``channel_id`` (messages of ``size`` bytes) in the
    chunk at ``offset``. A chunk of that channel's messages alone (after any schema and channel
    records) is one np.frombuffer; any other is walked record by record."""
    records = chunk_records(f, offset)
    j, n = 0, len(records)
    ns: list[int] = []
    out: list[bytes] = []
    record = np.dtype([("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("log", "<u8"),
                       ("pub", "<u8"), ("data", f"V{size}")])  # fmt: skip
    tried = False
    while j < n:
        op, length = _RECORD_HEAD.unpack_from(records, j)
        if op == _OP_MESSAGE and not tried and (n - j) % record.itemsize == 0:
            tried = True
            view = np.frombuffer(records[j:], dtype=record)
            same = np.all(view["op"] == _OP_MESSAGE) and np.all(view["len"] == record.itemsize - 9)
            if same and np.all(view["ch"] == channel_id):
                return np.concatenate([np.array(ns, dtype=np.int64), view["log"].astype(np.int64)]), [
                    *out,
                    view["data"].tobytes(),
                ]
        j += _RECORD_HEAD.size
        if op == _OP_MESSAGE:
            cid, _, log_time, _ = _MESSAGE_HEAD.unpack_from(records, j)
            if cid == channel_id:
                if length - _MESSAGE_HEAD.size != size:
                    raise McapError(f"row message of {length - _MESSAGE_HEAD.size} bytes, expected {size}")
                ns.append(log_time)
                out.append(bytes(records[j + _MESSAGE_HEAD.size : j + length]))
        j += length
    return np.array(ns, dtype=np.int64), out
