// A Foxglove WebSocket client made of Foxglove's own libraries (@foxglove/ws-protocol, @foxglove/rosmsg,
// @foxglove/rosmsg2-serialization) and the `ws` WebSocket: it connects to URL, subscribes to the TOPICs, decodes
// each message by the ros2msg schema its channel advertises, and prints one JSON object for the first stamp that
// all TOPICs carried: each topic's channel (encoding, schema name and encoding) and decoded message, byte arrays
// as base64. A message with no header of its own (tf2_msgs/TFMessage, as on /tf_static) counts for every stamp.
// Exits 1 with a message on stderr if none comes within TIMEOUT_S.
//
//   node subscribe.mjs URL TIMEOUT_S TOPIC...
import wsProtocol from "@foxglove/ws-protocol";
import rosmsg from "@foxglove/rosmsg";
import rosmsg2 from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol; // CommonJS packages: their exports through the default
const { parse } = rosmsg;
const { MessageReader } = rosmsg2;

const [url, timeoutS, ...topics] = process.argv.slice(2);
const fail = (why) => {
  process.stderr.write(`${why}\n`);
  process.exit(1);
};
setTimeout(() => fail(`no stamp on all of ${topics.join(", ")} within ${timeoutS} s`), Number(timeoutS) * 1000);

const plain = (value) => {
  if (value instanceof Uint8Array) return { base64: Buffer.from(value).toString("base64") };
  if (ArrayBuffer.isView(value)) return Array.from(value);
  if (Array.isArray(value)) return value.map(plain);
  if (typeof value === "bigint") return Number(value);
  if (value && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
};

// The server (foxglove-sdk) speaks foxglove.sdk.v1, the successor of the foxglove.websocket.v1 that this client's
// library names; their messages are the same, so the library's parser reads it.
const client = new FoxgloveClient({ ws: new WebSocket(url, ["foxglove.sdk.v1"]) });
const channels = new Map(); // subscription id -> { channel, reader }
const byStamp = new Map(); // "sec.nanosec" -> { topic: { channel, message } }
client.on("error", (error) => fail(`client error: ${error}`));
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    if (!topics.includes(channel.topic)) continue;
    if (channel.schemaEncoding !== "ros2msg") fail(`${channel.topic}: schema encoding ${channel.schemaEncoding}`);
    const reader = new MessageReader(parse(channel.schema, { ros2: true }));
    channels.set(client.subscribe(channel.id), { channel, reader });
  }
});
const unstamped = {}; // topic -> { channel, message }, for messages with no header
client.on("message", ({ subscriptionId, data }) => {
  const { channel, reader } = channels.get(subscriptionId);
  const message = reader.readMessage(data);
  const entry = {
    channel: { encoding: channel.encoding, schemaName: channel.schemaName, schemaEncoding: channel.schemaEncoding },
    message: plain(message),
  };
  if (message.header === undefined) {
    unstamped[channel.topic] = entry;
  } else {
    const stamp = `${message.header.stamp.sec}.${message.header.stamp.nanosec}`;
    byStamp.set(stamp, { ...(byStamp.get(stamp) ?? {}), [channel.topic]: entry });
  }
  for (const seen of byStamp.values()) {
    const all = { ...unstamped, ...seen };
    if (topics.every((topic) => topic in all)) {
      process.stdout.write(JSON.stringify(all), () => process.exit(0));
      return;
    }
  }
});
