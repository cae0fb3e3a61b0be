// Reads a capm-field run log with the JavaScript stack Foxglove uses (@mcap/core, protobufjs with
// its descriptor extension): every record CRC-checked, every message decoded through the schema
// the file carries. Prints one JSON object: per topic its count, schema, encoding and first
// message (bytes fields as their length and first 4 bytes). Usage: node read.mjs RUN.mcap
import fs from "node:fs";
import { McapStreamReader } from "@mcap/core";
import * as fzstd from "fzstd";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const reader = new McapStreamReader({
  validateCrcs: true,
  decompressHandlers: { zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))) },
});
reader.append(fs.readFileSync(process.argv[2]));
const schemas = new Map(), channels = new Map(), types = new Map(), topics = {}, metadata = {};
const bytes = (k, v) => (v instanceof Uint8Array ? { bytes: v.length, head: Array.from(v.subarray(0, 4)) } : v);
for (let rec; (rec = reader.nextRecord()) !== undefined; ) {
  if (rec.type === "Schema") schemas.set(rec.id, rec);
  else if (rec.type === "Channel") channels.set(rec.id, rec);
  else if (rec.type === "Metadata") metadata[rec.name] = Object.fromEntries(rec.metadata);
  else if (rec.type === "Message") {
    const ch = channels.get(rec.channelId), sc = schemas.get(ch.schemaId);
    let msg;
    if (ch.messageEncoding === "protobuf") {
      if (!types.has(sc.id)) types.set(sc.id, protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(sc.data)).lookupType(sc.name));
      const T = types.get(sc.id);
      msg = T.toObject(T.decode(rec.data), { longs: Number, defaults: true });
    } else if (ch.messageEncoding === "cdr" && sc.name === "std_msgs/msg/String") {
      const n = new DataView(rec.data.buffer, rec.data.byteOffset + 4, 4).getUint32(0, true);
      msg = { data: new TextDecoder("utf-8", { fatal: true }).decode(rec.data.subarray(8, 8 + n - 1)) };
    } else throw new Error(`${ch.topic}: no decoder for ${ch.messageEncoding} / ${sc.name}`);
    const t = (topics[ch.topic] ??= { count: 0, schema: sc.name, encoding: ch.messageEncoding, first: JSON.parse(JSON.stringify(msg, bytes)) });
    t.count += 1;
  }
}
console.log(JSON.stringify({ topics, metadata }));
