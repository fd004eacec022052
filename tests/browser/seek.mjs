#!/usr/bin/env node
// Seek into a drive the way the Foxglove app does: @mcap/core's McapIndexedReader (summary,
// chunk indexes, message indexes), messages from a start time on.
//
//   node tests/browser/seek.mjs DRIVE.mcap START_NS
//
// Prints one JSON object on stdout: {"messages": [[topic, logTimeNs, sha256(data)], ...]} in the
// order the reader gives them (log time), or {"error": "..."} when the reader refuses the file
// (exit status 1). tests/test_archive_size.py compares it with what mcap's Python reader gives.
// The packages come from tests/browser (npm ci there): @mcap/core, @mcap/support.

import { createHash } from "node:crypto";
import { createRequire } from "node:module";
import fs from "node:fs/promises";
import path from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

const HERE = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(HERE, "package.json"));
const load = async (name) => await import(pathToFileURL(require.resolve(name)).href);

const [file, start] = process.argv.slice(2);
if (!file || start === undefined) {
  console.error("usage: node seek.mjs DRIVE.mcap START_NS");
  process.exit(2);
}
const { McapIndexedReader } = await load("@mcap/core");
const { loadDecompressHandlers } = await load("@mcap/support");
const handle = await fs.open(file, "r");
const size = (await handle.stat()).size;
const readable = {
  size: async () => BigInt(size),
  read: async (offset, length) => {
    const buffer = Buffer.alloc(Number(length));
    await handle.read(buffer, 0, Number(length), Number(offset));
    return new Uint8Array(buffer.buffer, buffer.byteOffset, buffer.byteLength);
  },
};
try {
  const reader = await McapIndexedReader.Initialize({
    readable, decompressHandlers: await loadDecompressHandlers() });
  const messages = [];
  for await (const message of reader.readMessages({ startTime: BigInt(start) })) {
    const topic = reader.channelsById.get(message.channelId)?.topic;
    const digest = createHash("sha256").update(message.data).digest("hex");
    messages.push([topic, String(message.logTime), digest]);
  }
  console.log(JSON.stringify({ messages }));
} catch (error) {
  console.log(JSON.stringify({ error: String(error?.message ?? error) }));
  process.exitCode = 1;
} finally {
  await handle.close();
}
