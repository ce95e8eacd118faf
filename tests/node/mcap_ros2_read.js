// An MCAP recording read as Foxglove and Lichtblick read one, under Node: the npm packages @mcap/core
// (McapIndexedReader: the summary, chunk indexes and message indexes), @mcap/nodejs (FileHandleReadable),
// @mcap/support (the zstd/lz4 chunk decompressors) and ROS 2 CDR decoding with @foxglove/rosmsg (parse, ros2) and
// @foxglove/rosmsg2-serialization (MessageReader).
//
//   node mcap_ros2_read.js FILE EVERY
//
// Prints one JSON object: the summary (statistics, chunk index count, channels with their schema names, metadata
// index names) and, per topic, the messages in log-time order as the indexed reader yields them: their count, every
// log time, and the decoded values of messages 0, EVERY, 2 x EVERY, ... and of the last one. Decoded values as
// JSON: int64/uint64 (BigInt) as numbers when exact, else strings; typed arrays as arrays. Exits 1 with the reason
// on stderr on any error (a message that does not decode, or leaves more than CDR's padding over, is one). NODE_PATH names the
// node_modules to use.
"use strict";
const fs = require("node:fs/promises");
const { McapIndexedReader } = require("@mcap/core");
const { FileHandleReadable } = require("@mcap/nodejs");
const { loadDecompressHandlers } = require("@mcap/support");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

const fail = (why) => { process.stderr.write(`mcap_ros2_read: ${why}\n`); process.exit(1); };
const [file, everyArg] = process.argv.slice(2);
if (!file || !everyArg) fail("usage: mcap_ros2_read.js FILE EVERY");
const every = Number(everyArg);

function plain(v) {
  if (typeof v === "bigint") return Number.isSafeInteger(Number(v)) ? Number(v) : v.toString();
  if (ArrayBuffer.isView(v)) return Array.from(v, plain);
  if (Array.isArray(v)) return v.map(plain);
  if (v !== null && typeof v === "object") {
    const o = {};
    for (const [k, x] of Object.entries(v)) o[k] = plain(x);
    return o;
  }
  return v;
}

async function main() {
  const handle = await fs.open(file, "r");
  try {
    const reader = await McapIndexedReader.Initialize({ readable: new FileHandleReadable(handle),
                                                        decompressHandlers: await loadDecompressHandlers() });
    const decoders = new Map();            // channel id -> MessageReader
    const channels = {};
    for (const [id, ch] of reader.channelsById) {
      const schema = reader.schemasById.get(ch.schemaId);
      if (!schema || schema.encoding !== "ros2msg" || ch.messageEncoding !== "cdr") {
        fail(`channel ${ch.topic}: schema encoding ${schema && schema.encoding}, message encoding ${ch.messageEncoding}`);
      }
      decoders.set(id, new MessageReader(parse(new TextDecoder().decode(schema.data), { ros2: true })));
      channels[id] = { topic: ch.topic, schema: schema.name };
    }
    const s = reader.statistics;
    const out = {
      profile: reader.header.profile,
      statistics: s && { messageCount: Number(s.messageCount), chunkCount: s.chunkCount,
                         channelCount: s.channelCount, schemaCount: s.schemaCount,
                         messageStartTime: s.messageStartTime.toString(), messageEndTime: s.messageEndTime.toString(),
                         channelMessageCounts: Object.fromEntries(
                           [...s.channelMessageCounts].map(([id, n]) => [channels[id].topic, Number(n)])) },
      chunkIndexes: reader.chunkIndexes.length,
      metadataIndexes: reader.metadataIndexes.map((m) => m.name),
      channels: Object.fromEntries(Object.values(channels).map((c) => [c.topic, c.schema])),
      topics: {},
    };
    const pending = {};                    // topic -> the last message seen (decoded at the end if not sampled)
    for await (const msg of reader.readMessages({ validateCrcs: true })) {
      const topic = channels[msg.channelId].topic;
      const t = out.topics[topic] || (out.topics[topic] = { count: 0, logTimes: [], sampled: {} });
      const k = t.count++;
      t.logTimes.push(msg.logTime.toString());
      const dec = decoders.get(msg.channelId);
      const value = dec.readMessage(msg.data);
      // Fast DDS pads a serialized message to a multiple of 4 bytes (the CDR header's options say how much):
      // up to 3 zero bytes may follow the data, nothing else
      const over = msg.data.subarray(dec.lastReadByteLength());
      if (over.length > 3 || over.some((x) => x !== 0)) {
        fail(`${topic} message ${k}: ${over.length} bytes left over after decoding`);
      }
      if (k % every === 0) t.sampled[k] = plain(value);
      pending[topic] = [k, value];
    }
    for (const [topic, [k, value]] of Object.entries(pending)) out.topics[topic].sampled[k] = plain(value);
    process.stdout.write(JSON.stringify(out));
  } finally {
    await handle.close();
  }
}

main().catch((e) => fail(e && e.stack ? e.stack : String(e)));
