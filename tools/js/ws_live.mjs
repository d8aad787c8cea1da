// Foxglove's own WebSocket client (@foxglove/ws-protocol) on a vesselbot live view: subscribe to every
// advertised channel, decode every message with Foxglove's ROS 2 deserializer from the channel's
// ros2msg schema, and print one JSON object when the server goes away (end of the run), after IDLE_S
// without messages, or after --max-messages N messages:
//   {"reason", "subprotocol": the one the server accepted, "capabilities": the server's,
//    "advertised": [{topic, encoding, schemaName, schemaEncoding}], "counts": {topic: n},
//    "decode_errors": {topic: "..."}, "positions": [[stamp_ns, x, z, log_time_ns], ...],   (/vesselbot/truth)
//    "log_times": {topic: [each message's timestamp (ns)]}, "times": [the server's time broadcasts (ns)],
//    "views": {"errors": [view/errors messages], "marker_namespaces": [namespaces seen on view/markers]}}
// (ns values as decimal strings, in the order received.)  JSON channels (view/errors) are parsed as JSON.
// Every non-empty sensor_msgs/msg/Image is summarised in "images": {topic: [{stamp, height, width, encoding, step,
//   n_bytes, sum, max}]}, sum and max over its samples as an Image panel reads them (32FC1: float32; 64FC2: the
//   float64 magnitudes), in the order received.
// With --scene, also "scene": the markers as a 3D panel would draw them, the last of each namespace
//   {"view": {ns: summary} (view/markers), "vessel": {ns: summary} (vessel_markers),
//    "robot": [[stamp_ns, x, y, z], ...] (each view update's robot), "truth": [[stamp_ns, x, y, z], ...]}
//   where a summary is {type, id, action, frame_id, stamp (ns), n_points, n_colors, position: [x, y, z], scale: [x, y, z],
//   color: [r, g, b, a], points_head: the first 6 points [x, y, z], points_sum: [sum x, sum y, sum z] (in order),
//   y_abs_max: max |y| of its points}; and --until-scene NS,NS,... ends it ("scene") once view/markers showed
//   every namespace NS, vessel_markers came, 5 view updates and an errors view with a tracking error were seen.
// usage: node ws_live.mjs PORT [CONNECT_TIMEOUT_S=60] [IDLE_S=20] [--subprotocol NAME] [--no-retry]
//                         [--max-messages N] [--scene] [--until-scene NS,NS,...]
// The client offers exactly one WebSocket subprotocol, NAME: by default ws-protocol's
// FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.websocket.v1" (the protocol specification's name);
// "foxglove.sdk.v1" is the name the Foxglove SDK's server uses.  Without --no-retry it retries a refused
// connection every 200 ms until CONNECT_TIMEOUT_S; with it, a failed first attempt exits 3 at once.
import wsProtocol from "@foxglove/ws-protocol";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const positional = [];
const flags = { subprotocol: FoxgloveClient.SUPPORTED_SUBPROTOCOL, retry: true, maxMessages: Infinity, scene: false,
  untilScene: null };
for (let i = 2; i < process.argv.length; i++) {
  const a = process.argv[i];
  if (a === "--subprotocol") flags.subprotocol = process.argv[++i];
  else if (a === "--no-retry") flags.retry = false;
  else if (a === "--max-messages") flags.maxMessages = Number(process.argv[++i]);
  else if (a === "--scene") flags.scene = true;
  else if (a === "--until-scene") { flags.scene = true; flags.untilScene = process.argv[++i].split(","); }
  else positional.push(a);
}
const [port, connectTimeoutS = "60", idleS = "20"] = positional;
const url = `ws://127.0.0.1:${port}`;
const deadline = Date.now() + Number(connectTimeoutS) * 1000;
const advertised = [];
const channels = new Map(); // subscription id -> {topic, reader}
const counts = {};
const decodeErrors = {};
const positions = [];
const views = { errors: [], marker_namespaces: [] };
const logTimes = {};
const times = [];
let capabilities = null;
let subprotocol = null;
let received = 0;
let lastMessage = Date.now();
let done = false;
const scene = { view: {}, vessel: {}, robot: [], truth: [] };
const images = {};

function imageSummary(m) {
  const d = m.data;
  const bytes = new DataView(d.buffer, d.byteOffset, d.byteLength);
  let sum = 0;
  let max = -Infinity;
  if (m.encoding === "32FC1") {
    for (let i = 0; i + 4 <= d.byteLength; i += 4) { const v = bytes.getFloat32(i, true); sum += v; max = Math.max(max, v); }
  } else if (m.encoding === "64FC2") {
    for (let i = 0; i + 16 <= d.byteLength; i += 16) {
      const v = Math.hypot(bytes.getFloat64(i, true), bytes.getFloat64(i + 8, true)); sum += v; max = Math.max(max, v);
    }
  }
  return { stamp: stampNs(m.header.stamp).toString(), height: m.height, width: m.width, encoding: m.encoding,
    step: m.step, n_bytes: d.byteLength, sum, max };
}
let viewUpdates = 0;

function stampNs(st) { return BigInt(st.sec) * 1000000000n + BigInt(st.nanosec); }

function summary(m) {
  const sum = [0, 0, 0];
  let yAbsMax = 0;
  for (const p of m.points) {
    sum[0] += p.x; sum[1] += p.y; sum[2] += p.z;
    yAbsMax = Math.max(yAbsMax, Math.abs(p.y));
  }
  const v = (p) => [p.x, p.y, p.z];
  return { type: m.type, id: m.id, action: m.action, frame_id: m.header.frame_id,
    stamp: stampNs(m.header.stamp).toString(), n_points: m.points.length,
    n_colors: m.colors.length, position: v(m.pose.position), scale: v(m.scale),
    color: [m.color.r, m.color.g, m.color.b, m.color.a], points_head: m.points.slice(0, 6).map(v),
    points_sum: sum, y_abs_max: yAbsMax };
}

function sceneComplete() {
  // the errors view too: on a loaded machine five marker updates could arrive before the first errors message
  return flags.untilScene !== null && viewUpdates >= 5 && Object.keys(scene.vessel).length > 0 &&
    flags.untilScene.every((ns) => ns in scene.view) &&
    views.errors.some((e) => e !== null && typeof e === "object" && "tracking_error_m" in e);
}

function finish(reason) {
  if (done) return;
  done = true;
  const out = { reason, subprotocol, capabilities, advertised, counts,
    decode_errors: decodeErrors, views, images, times: times.map(String),
    log_times: Object.fromEntries(Object.entries(logTimes).map(([k, v]) => [k, v.map(String)])),
    positions: positions.map(([t, x, z, lt]) => [t.toString(), x, z, lt.toString()]) };
  if (flags.scene) {
    const withStamp = ([t, ...xyz]) => [t.toString(), ...xyz];
    out.scene = { view: scene.view, vessel: scene.vessel, robot: scene.robot.map(withStamp),
      truth: scene.truth.map(withStamp) };
  }
  process.stdout.write(JSON.stringify(out) + "\n", () => process.exit(0));
}

function connect() {
  const ws = new WebSocket(url, [flags.subprotocol]);
  ws.binaryType = "arraybuffer";
  let opened = false;
  ws.on("open", () => { opened = true; subprotocol = ws.protocol; });
  ws.on("error", (e) => {
    if (!opened) {
      if (!flags.retry || Date.now() > deadline) {
        console.error(`no connection to ${url} offering ${flags.subprotocol}: ${e.message}`);
        process.exit(3);
      }
      setTimeout(connect, 200);
    }
  });
  ws.on("close", () => { if (opened) finish("server closed"); });
  const client = new FoxgloveClient({ ws });
  client.on("serverInfo", (info) => { capabilities = info.capabilities; });
  client.on("time", ({ timestamp }) => { times.push(timestamp); });
  client.on("advertise", (chs) => {
    for (const ch of chs) {
      advertised.push({ topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName, schemaEncoding: ch.schemaEncoding });
      const reader = ch.encoding === "json"
        ? { readMessage: (bytes) => JSON.parse(new TextDecoder().decode(bytes)) }
        : new MessageReader(parse(ch.schema, { ros2: true }));
      const sub = client.subscribe(ch.id);
      channels.set(sub, { topic: ch.topic, schemaName: ch.schemaName, reader });
      counts[ch.topic] = 0;
      logTimes[ch.topic] = [];
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    lastMessage = Date.now();
    const ch = channels.get(subscriptionId);
    if (!ch) return;
    logTimes[ch.topic].push(timestamp);
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
      if (flags.scene) {
        viewUpdates += 1;
        for (const m of msg.markers) {
          scene.view[m.ns] = summary(m);
          if (m.ns === "robot") {
            const p = m.pose.position;
            scene.robot.push([stampNs(m.header.stamp), p.x, p.y, p.z]);
          }
        }
      }
    }
    if (flags.scene && ch.topic.endsWith("/vessel_markers")) {
      for (const m of msg.markers) scene.vessel[m.ns] = summary(m);
    }
    if (ch.schemaName === "sensor_msgs/msg/Image" && msg.height > 0) {
      (images[ch.topic] ??= []).push(imageSummary(msg));
    }
    if (ch.topic.endsWith("/truth")) {
      const st = msg.header.stamp;
      positions.push([stampNs(st), msg.position.x, msg.position.z, timestamp]);
      if (flags.scene) scene.truth.push([stampNs(st), msg.position.x, msg.position.y, msg.position.z]);
    }
    received += 1;
    if (received >= flags.maxMessages) finish("max messages");
    if (sceneComplete()) finish("scene");
  });
}

connect();
setInterval(() => { if (Date.now() - lastMessage > Number(idleS) * 1000 && advertised.length) finish("idle"); }, 200);
setTimeout(() => finish("timeout"), 600000);
