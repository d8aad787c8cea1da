// Foxglove's own WebSocket client (@foxglove/ws-protocol) on a vesselbot live view: subscribe to every
// advertised channel, decode every message with Foxglove's ROS 2 deserializer from the channel's
// ros2msg schema, and print one JSON object when the server goes away (end of the run) or after
// IDLE_S without messages:
//   {"advertised": [{topic, encoding, schemaName, schemaEncoding}], "counts": {topic: n},
//    "decode_errors": {topic: "..."}, "positions": [[stamp_ns, x, z], ...],   (positions: /vesselbot/truth)
//    "views": {"errors": [view/errors messages], "marker_namespaces": [namespaces seen on view/markers]}}
// JSON channels (the derived view/errors) are parsed as JSON.
// usage: node ws_live.mjs PORT [CONNECT_TIMEOUT_S=60] [IDLE_S=20]
// The client offers ws-protocol's "foxglove.websocket.v1" and "foxglove.sdk.v1", the name the SDK's server
// (foxglove-sdk 0.30) accepts for the same protocol.
import wsProtocol from "@foxglove/ws-protocol";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [port, connectTimeoutS = "60", idleS = "20"] = process.argv.slice(2);
const url = `ws://127.0.0.1:${port}`;
const deadline = Date.now() + Number(connectTimeoutS) * 1000;
const advertised = [];
const channels = new Map(); // subscription id -> {topic, reader}
const counts = {};
const decodeErrors = {};
const positions = [];
const views = { errors: [], marker_namespaces: [] };
let lastMessage = Date.now();
let done = false;

function finish(reason) {
  if (done) return;
  done = true;
  process.stdout.write(JSON.stringify({ reason, advertised, counts, decode_errors: decodeErrors, views,
    positions: positions.map(([t, x, z]) => [t.toString(), x, z]) }) + "\n", () => process.exit(0));
}

function connect() {
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
  ws.binaryType = "arraybuffer";
  let opened = false;
  ws.on("open", () => { opened = true; });
  ws.on("error", () => {
    if (!opened) {
      if (Date.now() > deadline) { console.error(`no server at ${url}`); process.exit(3); }
      setTimeout(connect, 200);
    }
  });
  ws.on("close", () => { if (opened) finish("server closed"); });
  const client = new FoxgloveClient({ ws });
  client.on("advertise", (chs) => {
    for (const ch of chs) {
      advertised.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName, schemaEncoding: ch.schemaEncoding });
      const reader = ch.encoding === "json"
        ? { readMessage: (bytes) => JSON.parse(new TextDecoder().decode(bytes)) }
        : new MessageReader(parse(ch.schema, { ros2: true }));
      const sub = client.subscribe(ch.id);
      channels.set(sub, { topic: ch.topic, reader });
      counts[ch.topic] = 0;
    }
  });
  client.on("message", ({ subscriptionId, data }) => {
    lastMessage = Date.now();
    const ch = channels.get(subscriptionId);
    if (!ch) return;
    let msg;
    try {
      msg = ch.reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
    } catch (e) {
      decodeErrors[ch.topic] = String(e);
      return;
    }
    counts[ch.topic] += 1;
    if (ch.topic.endsWith("/view/errors")) views.errors.push(msg);
    if (ch.topic.endsWith("/view/markers")) {
      for (const m of msg.markers) if (!views.marker_namespaces.includes(m.ns)) views.marker_namespaces.push(m.ns);
    }
    if (ch.topic.endsWith("/truth")) {
      const st = msg.header.stamp;
      positions.push([BigInt(st.sec) * 1000000000n + BigInt(st.nanosec), msg.position.x, msg.position.z]);
    }
  });
}

connect();
setInterval(() => { if (Date.now() - lastMessage > Number(idleS) * 1000 && advertised.length) finish("idle"); }, 200);
setTimeout(() => finish("timeout"), 600000);
