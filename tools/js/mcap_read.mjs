// Read a rosbag2 MCAP with Foxglove's own MCAP reader (@mcap/core), through its index, and decode
// every message with Foxglove's ROS 2 deserializer (@foxglove/rosmsg2-serialization) from the
// ros2msg schema embedded in the file.  Prints one JSON object:
//   {"counts": {topic: n}, "chunk_compression": [...], "decoded": n, "positions": [[stamp_ns, x, z], ...]}
// where positions are /vesselbot/truth's header stamps and robot positions.
// usage: node mcap_read.mjs FILE.mcap [TRUTH_TOPIC]
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import zstd from "@foxglove/wasm-zstd";

const [file, truthTopic = "/vesselbot/truth"] = process.argv.slice(2);
const fh = await open(file, "r");
const size = BigInt((await fh.stat()).size);
const readable = {
  size: async () => size,
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await fh.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
await zstd.isLoaded;
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: { zstd: (data, decompressedSize) => zstd.decompress(data, Number(decompressedSize)) },
});
const readers = new Map();
for (const [id, ch] of reader.channelsById) {
  const schema = reader.schemasById.get(ch.schemaId);
  if (schema.encoding !== "ros2msg" || ch.messageEncoding !== "cdr") {
    throw new Error(`${ch.topic}: schema ${schema.encoding}, encoding ${ch.messageEncoding}`);
  }
  readers.set(id, new MessageReader(parse(new TextDecoder().decode(schema.data), { ros2: true })));
}
const counts = {};
const positions = [];
let decoded = 0;
for await (const m of reader.readMessages()) {
  const ch = reader.channelsById.get(m.channelId);
  const msg = readers.get(m.channelId).readMessage(m.data);
  decoded += 1;
  counts[ch.topic] = (counts[ch.topic] ?? 0) + 1;
  if (ch.topic === truthTopic) {
    const st = msg.header.stamp;
    positions.push([BigInt(st.sec) * 1000000000n + BigInt(st.nanosec), msg.position.x, msg.position.z]);
  }
}
await fh.close();
const chunkCompression = [...new Set(reader.chunkIndexes.map((c) => c.compression || "none"))];
process.stdout.write(JSON.stringify({ counts, chunk_compression: chunkCompression, decoded, chunks: reader.chunkIndexes.length,
  positions: positions.map(([t, x, z]) => [t.toString(), x, z]) }) + "\n");
