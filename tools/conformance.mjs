#!/usr/bin/env node
// Conformance of tankviz's output with Foxglove's own client libraries.
//
//   node tools/conformance.mjs live ws://127.0.0.1:8765 [--seconds 20] [--marks N]
//       connects with @foxglove/ws-protocol's FoxgloveClient (the client Foxglove Studio uses),
//       subscribes to every channel, parses each channel's schema (a base64 protobuf
//       FileDescriptorSet) with protobufjs and decodes every message it receives. With --marks,
//       it advertises /marks (json, tankviz.Mark) as Studio's Publish panel does and publishes N
//       marks ("conformance 1", ... category "ws-protocol"), one every 1.5 s once the channels
//       settled, each after the one before came back on /log; findings.marks has, for each, the
//       log time of the latest scene before it was sent, of its /log line and of the first scene
//       after that line.
//   node tools/conformance.mjs mcap DRIVE.mcap
//       reads a drive with @mcap/core's indexed reader (summary, statistics, chunk indexes,
//       message indexes, CRCs) and its stream reader (every record in file order), checks that
//       the counts agree, and decodes every message with its schema.
//
// Prints one JSON object (the findings) on stdout; exits 1 when a check failed, 2 on bad usage.
// The npm packages come from tests/browser (npm ci there): @foxglove/ws-protocol, ws,
// @mcap/core, @mcap/support, protobufjs.

import { createRequire } from "node:module";
import fs from "node:fs/promises";
import path from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

const HERE = path.dirname(fileURLToPath(import.meta.url));
const PACKAGES = path.resolve(HERE, "..", "tests", "browser", "package.json");
const require = createRequire(PACKAGES);

async function load(name) {
  try {
    return await import(pathToFileURL(require.resolve(name)).href);
  } catch (error) {
    throw new Error(`cannot load ${name} (run npm ci in tests/browser): ${error.message}`);
  }
}

const { protobufFromBinaryDescriptor, loadDecompressHandlers } = await load("@mcap/support");

/** protobuf type of a schema, cached by schema name and bytes. */
function schemaDecoder() {
  const cache = new Map();
  return (name, bytes) => {
    const key = `${name}\0${Buffer.from(bytes).toString("base64")}`;
    if (!cache.has(key)) {
      try {
        const root = protobufFromBinaryDescriptor(bytes);
        cache.set(key, { type: root.lookupType(name) });
      } catch (error) {
        cache.set(key, { error: `${name}: ${error.message}` });
      }
    }
    return cache.get(key);
  };
}

// --- live ----------------------------------------------------------------------------------------

async function live(url, seconds, marks = 0) {
  const protocol = await load("@foxglove/ws-protocol");
  const FoxgloveClient = protocol.FoxgloveClient ?? protocol.default?.FoxgloveClient;
  const wsModule = await load("ws");
  const WebSocket = wsModule.WebSocket ?? wsModule.default;
  const decoderFor = schemaDecoder();
  const findings = {
    mode: "live",
    url,
    serverInfo: undefined,
    channels: {},
    schemaErrors: [],
    decodeErrors: [],
    protocolErrors: [],
    timeMessages: 0,
    marks: [],
    statuses: [],
  };
  const marking = {
    channel: undefined, waiting: false, sentAt: 0, latestScene: undefined, echoed: undefined };
  const byId = new Map();
  const bySubscription = new Map();
  const client = new FoxgloveClient({
    ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
  });
  let lastNew = Date.now();
  const done = new Promise((resolve) => {
    const started = Date.now();
    const timer = setInterval(() => {
      // Done when every channel (but /log, which speaks only when something happens) has
      // carried messages and nothing new came for a second.
      const channels = Object.values(findings.channels).filter((c) => c.topic !== "/log");
      const marked = findings.marks.length === marks && !marking.waiting && !marking.echoed;
      const settled = channels.length > 0 && channels.every((c) => c.messages > 0) &&
        Date.now() - lastNew > 1000 && marked;
      // Marks once no channel carried its first message for a second (what came first was
      // behind the drive)
      if (findings.marks.length < marks && !marking.waiting && Date.now() - lastNew > 1000 &&
          marking.latestScene !== undefined && Date.now() - marking.sentAt > 1500) {
        mark();
      }
      if (settled || Date.now() - started > seconds * 1000) {
        clearInterval(timer);
        resolve();
      }
    }, 100);
  });
  /** Publishes the next mark, as Studio's Publish panel does (JSON on a client channel). */
  function mark() {
    if (marking.channel === undefined) {
      if (!findings.serverInfo?.capabilities?.includes("clientPublish")) {
        findings.protocolErrors.push("--marks: the server does not advertise clientPublish");
        marks = findings.marks.length;
        return;
      }
      marking.channel = client.advertise({
        topic: "/marks", encoding: "json", schemaName: "tankviz.Mark" });
    }
    const text = `conformance ${findings.marks.length + 1}`;
    findings.marks.push({ text, sceneBeforeNs: String(marking.latestScene) });
    client.sendMessage(marking.channel,
      new TextEncoder().encode(JSON.stringify({ text, category: "ws-protocol" })));
    marking.waiting = true;
    marking.sentAt = Date.now();
  }
  client.on("status", (status) => findings.statuses.push(status));
  client.on("error", (error) => findings.protocolErrors.push(String(error?.message ?? error)));
  client.on("serverInfo", (info) => {
    findings.serverInfo = info;
  });
  client.on("time", () => {
    findings.timeMessages++;
  });
  client.on("advertise", (channels) => {
    for (const channel of channels) {
      byId.set(channel.id, channel);
      const entry = {
        topic: channel.topic,
        encoding: channel.encoding,
        schemaName: channel.schemaName,
        schemaEncoding: channel.schemaEncoding,
        messages: 0,
        firstLogTimeNs: undefined,
      };
      findings.channels[channel.topic] = entry;
      if (channel.encoding !== "protobuf" || channel.schemaEncoding !== "protobuf") {
        findings.schemaErrors.push(`${channel.topic}: encoding ${channel.encoding}, schema ` +
          `encoding ${channel.schemaEncoding} (expected protobuf)`);
        continue;
      }
      const decoded = decoderFor(channel.schemaName, Buffer.from(channel.schema, "base64"));
      if (decoded.error) {
        findings.schemaErrors.push(`${channel.topic}: ${decoded.error}`);
        continue;
      }
      bySubscription.set(client.subscribe(channel.id), channel);
      lastNew = Date.now();
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const channel = bySubscription.get(subscriptionId);
    if (!channel) {
      findings.protocolErrors.push(`message for unknown subscription ${subscriptionId}`);
      return;
    }
    const entry = findings.channels[channel.topic];
    const { type } = decoderFor(channel.schemaName, Buffer.from(channel.schema, "base64"));
    try {
      const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
      const message = type.decode(bytes);
      const object = type.toObject(message,
        { longs: String, enums: String, bytes: String, defaults: true });
      if (channel.topic === "/scene/ego") {
        marking.latestScene = timestamp;
        if (marking.echoed) {
          marking.echoed.sceneAfterNs = String(timestamp);
          marking.echoed = undefined;
        }
      }
      const said = channel.topic === "/log" &&
        /^MARK (\d+): (conformance \d+) \[ws-protocol\] \(viewer (.+)\)$/.exec(object.message);
      const sent = said && findings.marks.find((m) => m.text === said[2]);
      if (sent) {
        Object.assign(sent, { number: Number(said[1]), by: said[3], loggedNs: String(timestamp) });
        marking.waiting = false;
        marking.echoed = sent;
      }
    } catch (error) {
      if (findings.decodeErrors.length < 20) {
        findings.decodeErrors.push(`${channel.topic}: ${error.message}`);
      }
      entry.decodeErrors = (entry.decodeErrors ?? 0) + 1;
    }
    if (entry.messages === 0) {
      entry.firstLogTimeNs = String(timestamp);
      lastNew = Date.now();
    }
    entry.messages++;
  });
  await done;
  client.close();
  findings.ok = Boolean(findings.serverInfo) && findings.schemaErrors.length === 0 &&
    findings.decodeErrors.length === 0 && findings.protocolErrors.length === 0 &&
    Object.keys(findings.channels).length > 0 &&
    findings.marks.filter((m) => m.loggedNs !== undefined).length === marks;
  return findings;
}

// --- mcap ----------------------------------------------------------------------------------------

async function mcap(file) {
  const { McapIndexedReader, McapStreamReader } = await load("@mcap/core");
  const decompressHandlers = await loadDecompressHandlers();
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
  const problems = [];
  const decoderFor = schemaDecoder();
  const findings = { mode: "mcap", file, problems };
  try {
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const stats = reader.statistics;
    if (!stats) {
      problems.push("no Statistics record in the summary");
    }
    findings.profile = reader.header.profile;
    findings.library = reader.header.library;
    findings.channels = reader.channelsById.size;
    findings.schemas = reader.schemasById.size;
    findings.chunks = reader.chunkIndexes.length;
    findings.compression = [...new Set(reader.chunkIndexes.map((c) => c.compression))];
    findings.metadata = reader.metadataIndexes.map((m) => m.name);
    findings.attachments = reader.attachmentIndexes.map((a) => a.name);
    findings.messageCount = stats ? String(stats.messageCount) : undefined;
    findings.messageStartTime = stats ? String(stats.messageStartTime) : undefined;
    findings.messageEndTime = stats ? String(stats.messageEndTime) : undefined;
    if (reader.chunkIndexes.length === 0) {
      problems.push("no chunk indexes in the summary");
    }
    if (stats && stats.chunkCount !== reader.chunkIndexes.length) {
      problems.push(`statistics say ${stats.chunkCount} chunks, the summary indexes ${reader.chunkIndexes.length}`);
    }
    if (stats && stats.channelCount !== reader.channelsById.size) {
      problems.push(`statistics say ${stats.channelCount} channels, the summary has ${reader.channelsById.size}`);
    }
    // Every chunk index: sane bounds, a message index for each channel it holds.
    for (const [i, chunk] of reader.chunkIndexes.entries()) {
      if (chunk.messageStartTime > chunk.messageEndTime) {
        problems.push(`chunk ${i}: message start time after end time`);
      }
      if (chunk.messageIndexOffsets.size === 0) {
        problems.push(`chunk ${i}: no message indexes`);
      }
      for (const channelId of chunk.messageIndexOffsets.keys()) {
        if (!reader.channelsById.has(channelId)) {
          problems.push(`chunk ${i}: message index for unknown channel ${channelId}`);
        }
      }
    }
    // Every schema parses.
    for (const schema of reader.schemasById.values()) {
      if (schema.encoding !== "protobuf") {
        problems.push(`schema ${schema.name}: encoding ${schema.encoding}`);
        continue;
      }
      const decoded = decoderFor(schema.name, schema.data);
      if (decoded.error) {
        problems.push(`schema ${decoded.error}`);
      }
    }
    // Every message, through the indexes (CRCs checked), decoded with its schema.
    const counts = new Map();
    let previous = -1n;
    let outOfOrder = 0;
    let decodeErrors = 0;
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      counts.set(message.channelId, (counts.get(message.channelId) ?? 0) + 1);
      if (message.logTime < previous) {
        outOfOrder++;
      }
      previous = message.logTime;
      const channel = reader.channelsById.get(message.channelId);
      const schema = reader.schemasById.get(channel.schemaId);
      const { type } = decoderFor(schema.name, schema.data);
      try {
        type?.decode(message.data);
      } catch (error) {
        if (decodeErrors++ < 10) {
          problems.push(`${channel.topic}: message does not decode: ${error.message}`);
        }
      }
    }
    if (outOfOrder) {
      problems.push(`${outOfOrder} messages out of log-time order`);
    }
    const total = [...counts.values()].reduce((a, b) => a + b, 0);
    findings.messagesRead = total;
    findings.decodeErrors = decodeErrors;
    if (stats && BigInt(total) !== stats.messageCount) {
      problems.push(`statistics say ${stats.messageCount} messages, the indexes give ${total}`);
    }
    findings.topics = {};
    for (const [channelId, channel] of reader.channelsById) {
      const read = counts.get(channelId) ?? 0;
      const stated = stats?.channelMessageCounts.get(channelId);
      findings.topics[channel.topic] = read;
      if (stated !== undefined && BigInt(read) !== stated) {
        problems.push(`${channel.topic}: statistics say ${stated} messages, read ${read}`);
      }
    }
    // The whole file in order with the stream reader: chunks, message indexes and messages
    // agree with the summary.
    const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true, includeChunks: true });
    stream.append(new Uint8Array(await fs.readFile(file)));
    const streamCounts = new Map();
    let chunks = 0;
    let messageIndexRecords = 0;
    const indexed = new Map();
    let footer = false;
    for (let record; (record = stream.nextRecord()); ) {
      if (record.type === "Chunk") {
        chunks++;
      } else if (record.type === "Message") {
        streamCounts.set(record.channelId, (streamCounts.get(record.channelId) ?? 0) + 1);
      } else if (record.type === "MessageIndex") {
        messageIndexRecords++;
        indexed.set(record.channelId, (indexed.get(record.channelId) ?? 0) + record.records.length);
      } else if (record.type === "Footer") {
        footer = true;
      }
    }
    if (!stream.done()) {
      problems.push("the stream reader did not reach the end magic");
    }
    if (!footer) {
      problems.push("no footer");
    }
    findings.streamChunks = chunks;
    findings.messageIndexRecords = messageIndexRecords;
    if (chunks !== reader.chunkIndexes.length) {
      problems.push(`${chunks} chunks in the file, ${reader.chunkIndexes.length} chunk indexes`);
    }
    for (const [channelId, channel] of reader.channelsById) {
      const inStream = streamCounts.get(channelId) ?? 0;
      if (inStream !== (counts.get(channelId) ?? 0)) {
        problems.push(`${channel.topic}: ${inStream} messages in the file, ${counts.get(channelId) ?? 0} through the indexes`);
      }
      if ((indexed.get(channelId) ?? 0) !== inStream) {
        problems.push(`${channel.topic}: message indexes list ${indexed.get(channelId) ?? 0} of ${inStream} messages`);
      }
    }
  } catch (error) {
    problems.push(`cannot read: ${error.stack ?? error}`);
  } finally {
    await handle.close();
  }
  findings.ok = problems.length === 0;
  return findings;
}

// --- main ----------------------------------------------------------------------------------------

const [mode, target, ...rest] = process.argv.slice(2);
const secondsAt = rest.indexOf("--seconds");
const seconds = secondsAt >= 0 ? Number(rest[secondsAt + 1]) : 20;
const marksAt = rest.indexOf("--marks");
const marks = marksAt >= 0 ? Number(rest[marksAt + 1]) : 0;
if (!target || !["live", "mcap"].includes(mode)) {
  console.error("usage: node tools/conformance.mjs live ws://HOST:PORT [--seconds S] " +
    "[--marks N] | mcap FILE.mcap");
  process.exit(2);
}
const findings = mode === "live" ? await live(target, seconds, marks) : await mcap(target);
process.stdout.write(`${JSON.stringify(findings, (_, v) => (typeof v === "bigint" ? String(v) : v))}\n`);
process.exit(findings.ok ? 0 : 1);
