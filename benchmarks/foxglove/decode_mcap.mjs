// Decode every message of an MCAP file the way Foxglove does for ROS 2 channels: the schema
// (encoding "ros2msg") parsed by @foxglove/rosmsg with ros2 rules, each CDR message read by
// @foxglove/rosmsg2-serialization's MessageReader, the container read by @mcap/core.
// Usage: node decode_mcap.mjs BAG.mcap  -> one JSON object on stdout (per topic: decoded,
// failed, first error, the first message's field names, the last message decoded).
import { readFileSync } from "node:fs";
import { McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const path = process.argv[2];
if (!path) {
  console.error("usage: node decode_mcap.mjs BAG.mcap");
  process.exit(2);
}
const reader = new McapStreamReader({ validateCrcs: true });
reader.append(readFileSync(path));

// JSON-safe copy of a decoded message: typed arrays as arrays, 64-bit integers as numbers.
function plain(v) {
  if (typeof v === "bigint") return Number(v);
  if (ArrayBuffer.isView(v)) return Array.from(v, plain);
  if (Array.isArray(v)) return v.map(plain);
  if (v && typeof v === "object") return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)]));
  return v;
}

const schemas = new Map();   // schema id -> {name, encoding, data}
const channels = new Map();  // channel id -> {topic, schemaId, encoding, reader | error}
const topics = {};
let record;
while ((record = reader.nextRecord())) {
  if (record.type === "Schema") {
    schemas.set(record.id, record);
  } else if (record.type === "Channel") {
    if (channels.has(record.id)) continue;   // repeated in the summary section
    const schema = schemas.get(record.schemaId);
    const entry = { topic: record.topic, type: schema?.name, reader: null, error: null };
    try {
      if (!schema || schema.encoding !== "ros2msg" || record.messageEncoding !== "cdr") {
        throw new Error(`schema encoding ${schema?.encoding}, message encoding ${record.messageEncoding}`);
      }
      const text = new TextDecoder().decode(schema.data);
      entry.reader = new MessageReader(parse(text, { ros2: true }));
    } catch (err) {
      entry.error = `definition: ${err.message}`;
    }
    channels.set(record.id, entry);
    topics[record.topic] = { type: entry.type, decoded: 0, failed: 0, error: entry.error, fields: null,
                             last: null };
  } else if (record.type === "Message") {
    const ch = channels.get(record.channelId);
    const out = topics[ch.topic];
    if (!ch.reader) {
      out.failed += 1;
      continue;
    }
    try {
      const msg = ch.reader.readMessage(record.data);
      if (out.fields === null) out.fields = Object.keys(msg);
      out.last = plain(msg);
      out.decoded += 1;
    } catch (err) {
      out.failed += 1;
      out.error ??= `message: ${err.message}`;
    }
  }
}
const total = Object.values(topics).reduce((a, t) => a + t.decoded + t.failed, 0);
const decoded = Object.values(topics).reduce((a, t) => a + t.decoded, 0);
console.log(JSON.stringify({ bag: path, messages: total, decoded, topics }, null, 1));
process.exit(decoded === total && total > 0 ? 0 : 1);
