"""Log encodings measured side by side (docs/logs.md): rxcomm's writer (per-sample JSON for Foxglove +
protobuf column blocks) beside the official foxglove-sdk writer (Rust; JSON channels, well-known
schemas in protobuf), for a 60 s 2.5 kHz run log's joints and for the 3D view's frame transforms.

Not a `make bench` section: foxglove-sdk is no dependency of rxcomm. Run it in an environment that has
both (`pip install foxglove-sdk protobuf` beside rxcomm): ``python -m bench.log_encodings``. The
protobuf package also checks that the column schema rxcomm writes is a valid FileDescriptorSet that
decodes the blocks.
"""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
from mcap.reader import make_reader

import rxcomm
from rxcomm.execution.frames import link_transforms, link_tree
from rxcomm.io.foxglove import FRAME_TRANSFORMS, FRAME_TRANSFORMS_SCHEMA, frame_transforms
from rxcomm.io.mcap_format import COLUMNS_DESCRIPTOR_SET, decode_block
from rxcomm.io.mcap_io import McapWriter, read_mcap
from rxcomm.model.robot import load_robot

N = 150_000  # 60 s at 2.5 kHz
N_TF = 15_000  # 6 s of transforms at 2.5 kHz (the log writes them at 50 Hz)
FIELDS = ("q_demand", "qd_demand", "qdd_demand", "q_actual", "tau_actual", "tau_ff", "following_error")


def _env() -> dict:
    return {
        "kind": "rxcomm/RunLog",
        "schema_version": 1,
        "created": datetime.now(UTC),
        "rxcomm_version": rxcomm.__version__,
        "inputs": {},
        "settings": {},
        "summary": {},
    }


def _columns() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = np.arange(N) / 2500.0
    w = np.linspace(1.0, 2.5, 6)
    base = np.sin(np.outer(t, w))
    rng = np.random.default_rng(0)
    cols = {k: base * (i + 1) + 1e-6 * rng.standard_normal(base.shape) for i, k in enumerate(FIELDS)}
    return t, cols | {"tcp_error_m": np.abs(base[:, 0]) * 1e-4, "tcp_speed_m_s": np.abs(base[:, 1])}


def _json_rows(t: np.ndarray, cols: dict[str, np.ndarray], t0_ns: int) -> list[tuple[int, bytes]]:
    ns = t0_ns + np.round(t * 1e9).astype(np.int64)
    out = []
    for i in range(len(t)):
        body = {"timestamp": {"sec": int(ns[i] // 10**9), "nsec": int(ns[i] % 10**9)}}
        body |= {k: (c[i].tolist() if c.ndim == 2 else float(c[i])) for k, c in cols.items()}
        out.append((int(ns[i]), json.dumps(body, separators=(",", ":")).encode()))
    return out


def _scan_json(path: Path, topic: str) -> float:
    t0 = time.perf_counter()
    with open(path, "rb") as f:
        msgs = [m.data for _, _, m in make_reader(f).iter_messages(topics=[topic])]
    json.loads(b"[" + b",".join(msgs) + b"]")
    return time.perf_counter() - t0


def joints(tmp: Path) -> list[tuple[str, float, float, float]]:
    import foxglove

    t, cols = _columns()
    rows = []
    ours = tmp / "ours.mcap"
    t0 = time.perf_counter()
    with McapWriter(ours, _env()) as w:
        w.write_arrays("/run/joints", t, cols, digits=10)
    write_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    read_mcap(ours, ["/run/joints"])
    read_s = time.perf_counter() - t0
    rows.append(("rxcomm: JSON per sample + protobuf columns", write_s, ours.stat().st_size / 1e6, read_s))
    # the column schema is a real FileDescriptorSet that protobuf decodes the blocks with
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(COLUMNS_DESCRIPTOR_SET)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("rxcomm.Columns"))
    with open(ours, "rb") as f:
        _, _, block = next(make_reader(f).iter_messages(topics=["/columns/run/joints"]))
    pb = cls.FromString(block.data)
    ns, ref = decode_block(block.data)
    assert pb.n == len(ns) and list(pb.log_time_ns) == ns.tolist()
    col = next(c for c in pb.columns if c.name == "q_actual")
    assert np.array_equal(np.frombuffer(col.data, dtype=col.dtype).reshape(col.shape), ref["q_actual"])

    schema = {"type": "object", "properties": {k: {"type": "array"} for k in cols}}
    for label, pre in (
        ("foxglove-sdk: JSON dicts (json.dumps)", False),
        ("foxglove-sdk: json.dumps bytes, then log", True),
    ):
        path = tmp / f"sdk{pre}.mcap"
        t0_ns = time.time_ns()
        t0 = time.perf_counter()
        data = _json_rows(t, cols, t0_ns) if pre else None
        with foxglove.open_mcap(path, allow_overwrite=True):
            ch = foxglove.Channel("/run/joints", schema=schema)
            if data is not None:
                for ns_i, body in data:
                    ch.log(body, log_time=ns_i)
            else:
                ns = t0_ns + np.round(t * 1e9).astype(np.int64)
                lists = {k: c.tolist() for k, c in cols.items()}
                for i in range(len(t)):
                    msg = {"timestamp": {"sec": int(ns[i]) // 10**9, "nsec": int(ns[i]) % 10**9}}
                    ch.log(msg | {k: v[i] for k, v in lists.items()}, log_time=int(ns[i]))
        rows.append(
            (label, time.perf_counter() - t0, path.stat().st_size / 1e6, _scan_json(path, "/run/joints"))
        )
    return rows


def transforms(tmp: Path) -> list[tuple[str, float, float, float]]:
    import foxglove
    from foxglove.channels import FrameTransformsChannel
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    robot = load_robot("samples/rx130l")
    tree = link_tree(robot)
    q = 0.3 * np.sin(np.outer(np.arange(N_TF) / 2500.0, np.linspace(1, 3, 6)))
    trans, rot = link_transforms(robot, tree, q)
    t0_ns = time.time_ns()
    ns = t0_ns + np.arange(N_TF) * 400_000
    rows = []
    ours = tmp / "tf-ours.mcap"
    t0 = time.perf_counter()
    with McapWriter(ours, _env(), time_origin_ns=t0_ns) as w:
        w.add_channel("/run/tf", FRAME_TRANSFORMS, {"transforms": {}}, schema=FRAME_TRANSFORMS_SCHEMA)
        for i in range(N_TF):
            w.write("/run/tf", i * 400e-6, frame_transforms(int(ns[i]), list(tree.pairs), trans[i], rot[i]))
    rows.append(
        (
            "rxcomm: foxglove.FrameTransforms, JSON",
            time.perf_counter() - t0,
            ours.stat().st_size / 1e6,
            _scan_json(ours, "/run/tf"),
        )
    )
    path = tmp / "tf-sdk.mcap"
    t0 = time.perf_counter()
    with foxglove.open_mcap(path, allow_overwrite=True):
        ch = FrameTransformsChannel("/run/tf")
        for i in range(N_TF):
            ts = Timestamp(sec=int(ns[i]) // 10**9, nsec=int(ns[i]) % 10**9)
            tfs = [
                FrameTransform(
                    timestamp=ts,
                    parent_frame_id=a,
                    child_frame_id=b,
                    translation=Vector3(
                        x=float(trans[i, j, 0]), y=float(trans[i, j, 1]), z=float(trans[i, j, 2])
                    ),
                    rotation=Quaternion(
                        x=float(rot[i, j, 0]),
                        y=float(rot[i, j, 1]),
                        z=float(rot[i, j, 2]),
                        w=float(rot[i, j, 3]),
                    ),
                )
                for j, (a, b) in enumerate(tree.pairs)
            ]
            ch.log(FrameTransforms(transforms=tfs), log_time=int(ns[i]))
    rows.append(
        (
            "foxglove-sdk: foxglove.FrameTransforms, protobuf",
            time.perf_counter() - t0,
            path.stat().st_size / 1e6,
            float("nan"),
        )
    )
    return rows  # fmt: skip


def main() -> None:
    with TemporaryDirectory() as tmp:
        print(f"| {N} joint samples (60 s at 2.5 kHz), 9 fields | write s | MB | read s |")
        print("|---|---|---|---|")
        for label, w, mb, r in joints(Path(tmp)):
            print(f"| {label} | {w:.2f} | {mb:.1f} | {r:.2f} |")
        links = len(link_tree(load_robot("samples/rx130l")).pairs)
        print(f"\n| {N_TF} FrameTransforms messages, {links} links | write s | MB | read s |")
        print("|---|---|---|---|")
        for label, w, mb, r in transforms(Path(tmp)):
            read = "no reader in the SDK" if np.isnan(r) else f"{r:.2f}"
            print(f"| {label} | {w:.2f} | {mb:.1f} | {read} |")


if __name__ == "__main__":
    main()
