// The unmodified npm client @foxglove/ws-protocol (FoxgloveClient) against the live view, under Node.
//
//   node foxglove_ws_client.js ws://127.0.0.1:PORT TOPIC [TOPIC ...]
//
// Connects offering only the subprotocol FoxgloveClient.SUPPORTED_SUBPROTOCOL ("foxglove.websocket.v1", as
// Lichtblick and older Foxglove Studio do), waits for serverInfo and the advertised channels, subscribes to
// TOPICs and decodes the first message of each: protobuf with protobufjs from the FileDescriptorSet the server
// advertised (as Lichtblick does), JSON with JSON.parse. Prints one JSON object to stdout and exits 0; on any
// error or after 20 s, prints the reason to stderr and exits 1. NODE_PATH names the node_modules to use.
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const [url, ...topics] = process.argv.slice(2);
const fail = (why) => { process.stderr.write(`foxglove_ws_client: ${why}\n`); process.exit(1); };
if (!url || topics.length === 0) fail("usage: foxglove_ws_client.js URL TOPIC [TOPIC ...]");
setTimeout(() => fail(`timed out; got ${JSON.stringify(Object.keys(out.messages))}`), 20000).unref();

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const out = { offered: [FoxgloveClient.SUPPORTED_SUBPROTOCOL], subprotocol: null, serverInfo: null, channels: [],
              messages: {} };
const bySubscription = new Map();      // subscription id -> { channel, decode }

function decoder(channel) {
  if (channel.encoding === "json") return (bytes) => JSON.parse(new TextDecoder().decode(bytes));
  if (channel.encoding !== "protobuf") fail(`unexpected encoding ${channel.encoding} on ${channel.topic}`);
  const fds = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
  const type = protobuf.Root.fromDescriptor(fds).lookupType(channel.schemaName);
  return (bytes) => type.toObject(type.decode(bytes), { longs: Number, defaults: true });
}

client.on("open", () => { out.subprotocol = ws.protocol; });
client.on("error", (e) => fail(`client error: ${e && e.message}`));
let done = false;
client.on("close", (e) => { if (!done) fail(`closed before all messages arrived (code ${e && e.code})`); });
client.on("serverInfo", (info) => { out.serverInfo = info; });
client.on("advertise", (channels) => {
  for (const ch of channels) {
    out.channels.push({ id: ch.id, topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName,
                        schemaEncoding: ch.schemaEncoding });
    if (topics.includes(ch.topic)) bySubscription.set(client.subscribe(ch.id), { channel: ch, decode: decoder(ch) });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  if (done) return;
  const sub = bySubscription.get(subscriptionId);
  if (!sub) fail(`message for unknown subscription ${subscriptionId}`);
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  if (!(sub.channel.topic in out.messages)) {
    out.messages[sub.channel.topic] = { logTime: timestamp.toString(), message: sub.decode(bytes) };
  }
  if (topics.every((t) => t in out.messages)) {
    done = true;
    process.stdout.write(JSON.stringify(out) + "\n", () => {
      client.close();
      process.exit(0);
    });
  }
});
