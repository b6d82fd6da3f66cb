// Checks MCAP files with the official MCAP TypeScript reader (@mcap/core), not our Python
// code: usage `node validate.mjs FILE.mcap...`. Prints one JSON line per file
// ({"file", "ok", "errors", "messages", ...}) and exits 1 if any file fails.
//
// Checked, for each file:
//  * a streaming pass over every record (McapStreamReader, validateCrcs): record framing,
//    chunk CRCs of the decompressed chunks, attachment CRCs, a closing footer;
//  * the data-section CRC stored in DataEnd, recomputed here over the bytes from the magic
//    up to DataEnd (the stream reader skips it), and required to be present (non-zero);
//  * the indexed read (McapIndexedReader): footer and summary CRC, the chunk indexes and
//    message indexes lead to as many messages as the stream pass saw and as the Statistics
//    record counts, every message names a known channel and every channel a known schema,
//    and every attachment read through its index passes its CRC.
import { readFile } from "node:fs/promises";

import { crc32 } from "@foxglove/crc";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";

const decompressHandlers = await loadDecompressHandlers();

async function check(file) {
  const out = { file, ok: false, errors: [] };
  const bytes = new Uint8Array(await readFile(file));

  // 1. Streaming pass.
  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(bytes);
  const channels = new Map();
  const schemas = new Set();
  let messages = 0;
  let attachments = 0;
  let dataEnd;
  for (let rec; (rec = stream.nextRecord()); ) {
    switch (rec.type) {
      case "Schema": schemas.add(rec.id); break;
      case "Channel":
        if (rec.schemaId !== 0 && !schemas.has(rec.schemaId)) {
          out.errors.push(`channel ${rec.id} (${rec.topic}) names unknown schema ${rec.schemaId}`);
        }
        channels.set(rec.id, rec.topic);
        break;
      case "Message":
        if (!channels.has(rec.channelId)) {
          out.errors.push(`message on unknown channel ${rec.channelId}`);
        }
        messages += 1;
        break;
      case "Attachment": attachments += 1; break;
      case "DataEnd": dataEnd = rec; break;
      default: break;
    }
  }
  if (!stream.done()) {
    out.errors.push(`stream reader: file ends without a complete footer (${stream.bytesRemaining()} bytes unparsed)`);
  }
  out.messages = messages;
  out.attachments = attachments;

  // 2. Indexed read: summary CRC, indexes, data-section CRC.
  const readable = {
    size: async () => BigInt(bytes.byteLength),
    read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const stored = reader.dataSectionCrc ?? dataEnd?.dataSectionCrc ?? 0;
  if (!stored) {
    out.errors.push("no data-section CRC (DataEnd.data_section_crc is 0)");
  } else {
    const actual = crc32(bytes.subarray(0, Number(reader.dataEndOffset)));
    if (actual !== stored) {
      out.errors.push(`data-section CRC ${actual} != stored ${stored}`);
    }
  }
  out.dataSectionCrc = stored;
  let indexed = 0;
  for await (const msg of reader.readMessages({ validateCrcs: true })) {
    if (!reader.channelsById.has(msg.channelId)) {
      out.errors.push(`indexed message on unknown channel ${msg.channelId}`);
    }
    indexed += 1;
  }
  if (indexed !== messages) {
    out.errors.push(`indexed read found ${indexed} messages, the stream ${messages}`);
  }
  if (reader.statistics && Number(reader.statistics.messageCount) !== messages) {
    out.errors.push(`Statistics count ${reader.statistics.messageCount} messages, the stream ${messages}`);
  }
  let indexedAttachments = 0;
  for await (const _ of reader.readAttachments({ validateCrcs: true })) indexedAttachments += 1;
  if (indexedAttachments !== attachments) {
    out.errors.push(`attachment index lists ${indexedAttachments}, the stream has ${attachments}`);
  }
  for (const [id, channel] of reader.channelsById) {
    if (channel.schemaId !== 0 && !reader.schemasById.has(channel.schemaId)) {
      out.errors.push(`summary: channel ${id} names unknown schema ${channel.schemaId}`);
    }
  }
  out.ok = out.errors.length === 0;
  return out;
}

let failed = 0;
for (const file of process.argv.slice(2)) {
  let result;
  try {
    result = await check(file);
  } catch (err) {
    result = { file, ok: false, errors: [String(err?.message ?? err)] };
  }
  if (!result.ok) failed += 1;
  console.log(JSON.stringify(result));
}
process.exit(failed ? 1 : 0);
