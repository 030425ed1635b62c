// Reads a run log with @mcap/core (the reader Foxglove is built on) and decodes every protobuf message
// with protobufjs from the schema's FileDescriptorSet, as Foxglove does (docs/logs.md §2). Not part of CI:
//   npm install @mcap/core protobufjs fzstd && node docs/foxglove/check-mcap-core.mjs LOG.mcap
import { McapIndexedReader } from "@mcap/core";
import { open } from "node:fs/promises";
import { decompress } from "fzstd";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const fh = await open(process.argv[2], "r");
const readable = {
  size: async () => BigInt((await fh.stat()).size),
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await fh.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: { zstd: (buf, size) => decompress(buf, new Uint8Array(Number(size))) },
});
const types = new Map();
for (const [id, ch] of reader.channelsById) {
  const schema = reader.schemasById.get(ch.schemaId);
  if (ch.messageEncoding === "protobuf") {
    const fds = descriptor.FileDescriptorSet.decode(schema.data);
    const root = protobuf.Root.fromDescriptor(fds);
    types.set(id, root.lookupType(schema.name));
  }
}
const counts = {};
let first = null, last = null;
for await (const msg of reader.readMessages()) {
  const ch = reader.channelsById.get(msg.channelId);
  counts[ch.topic] = (counts[ch.topic] ?? 0) + 1;
  const t = types.get(msg.channelId);
  if (t) {
    const m = t.toObject(t.decode(msg.data));
    if (ch.topic === "/run/joints") { if (!first) first = m; last = m; }
  } else if (ch.messageEncoding === "json") {
    JSON.parse(new TextDecoder().decode(msg.data));
  }
}
console.log(JSON.stringify(counts));
console.log("first /run/joints q_actual", first.q_actual, "tcp_speed_m_s", first.tcp_speed_m_s);
console.log("last  /run/joints q_actual", last.q_actual, "n fields", Object.keys(last).length);
