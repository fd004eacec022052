// End-to-end driver: the real Foxglove Studio web app (host/, served by serve.mjs) in headless
// Chromium, driven by playwright-core, reads tankviz output live (Foxglove WebSocket) or from a
// drive (MCAP, remote-file source), with a layout applied through the app's own "Import layout"
// button (its file picker is fed the layout file) or preloaded into its layout storage.
//
//   node tests/browser/e2e.mjs PLAN.json      (prints a JSON line per shot, then the result, on stdout)
//
// PLAN: {
//   "chromium": "/usr/bin/chromium", "viewport": {"width": 1600, "height": 1000},
//   "dataDir": "/tmp/…" (served as /data/ for remote-file sources),
//   "timeoutMs": 120000,  the budget of each wait for a condition (the app started, the layout
//                         imported, the panels shown, everything expected on screen); a wait
//                         ends as soon as its condition holds, so it only costs time when
//                         something is not ready
//   "reportMs": 15000,    while waiting, what is still missing is logged this often (stderr)
//   "shots": [{
//     "name": "live",
//     "source": {"ws": "ws://127.0.0.1:PORT"} | {"mcap": "drive.mcap", "time": "2026-01-01T12:00:09Z"}
//               | {"serve": "demo"}   a live source started for this shot only, when the shot
//                                     begins: the driver prints {"start": "demo", "shot": NAME}
//                                     on stdout and reads {"ws": URL} (or {"error": TEXT}) from
//                                     stdin (tests/test_e2e_browser.py answers, and stops that
//                                     source when the shot's result line comes),
//     "layout": "/abs/path/layouts/tank-viz.json", "via": "import" | "preload",
//     "scene": {"panel": "3D!tankviz", "expect": ["ego", "greenLanes", …], "absent": [...]},
//                                        (the 3D panel to read; keys of pixels.mjs verdict())
//              "inside": {"red": ["blue", "white"]}   optional: pixels.mjs colour classes that
//                                        must show inside a compact blob of another (a detection
//                                        inside its track), read as reading.inside (insideOf)
//     "plots": true, "plotExtent": 0.8,  every Plot panel shows a value for each of its paths
//                                        and data lines over that share of its width
//     "panelText": {"RawMessages!lead": ["tankviz.LeadVehicle @", …]},  text in a panel
//     "indicators": {"Indicator!radar.silent": {"label": "OK", "color": "#1e8e3e"}, …},
//                                        Indicator panels showing that label, and that colour
//                                        on most of their coloured box (read from the pixels)
//     "ocr": ["Lead\\s*Vehicle", "x[:;]\\s*\\d+"],  regular expressions to match in the text
//                                        of the 3D labels (OCR with tesseract: screenshots are
//                                        read until each was matched, at most ten)
//     "ocrPanels": {"Table!ids-can0": ["0x2C4"]},  regular expressions to match in what OCR
//                                        reads of a panel's pixels (the whole panel, made dark
//                                        on light and scaled 2x; read until each was matched,
//                                        at most "ocrAttempts" screenshots, default 4), as
//                                        ocrPanels[id]
//     "image": {"panel": "ImageViewPanel!bits", "minBright": 200},  an Image panel showing an
//                                        image with at least that many bright orange pixels (the
//                                        bit map's flipping bits; white ones are counted apart: a
//                                        panel without an image is white too), as image
//     "clicks": [{"panel": "Publish!mark", "button": "Mark"}],  buttons clicked once the panels
//                                        show, each when it is enabled
//     "viewport": {"width": 1280, "height": 800},  this shot's window (default: the plan's)
//     "screenshot": "/abs/out.png"
//   }]
// }
// Result: {"ok", "seconds", "shots": [{"name", "ok", "failures", "verdict", "reading", "plots",
// "indicators", "ocr", "steps", "errors", "seconds"}]}; each shot's result is also printed on its
// own line as it ends, {"shot": {...}}, so that a run cut short still tells what it did.
// Every wait is for a condition, with the plan's timeout; a shot that times out is reported with
// what was not ready (the step, and what was seen last; its screenshot too), not thrown.

import { spawnSync } from "node:child_process";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";
import readline from "node:readline";

import { chromium } from "playwright-core";

import { decodePng } from "./png.mjs";
import { encodePng } from "./pngout.mjs";
import { blobs, CLASSES, readTankViz, verdict } from "./pixels.mjs";
import { startServer } from "./serve.mjs";

export const CHROMIUM_ARGS = [
  "--headless",
  "--no-sandbox",
  "--disable-gpu",
  "--disable-quic",
  "--no-first-run",
  "--disable-background-networking",
  "--disable-component-update",
  "--disable-sync",
  "--use-gl=angle",
  "--use-angle=swiftshader",
  "--enable-unsafe-swiftshader",
];

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function log(...args) {
  console.error(`[e2e ${new Date().toISOString().slice(11, 23)}]`, ...args);
}

/** A wait for a condition that ran out of time: `message` says what was not ready (`summary`:
 * which wait, and how long it waited). */
class NotReady extends Error {
  constructor(summary, detail) {
    super(detail ? `${summary}: ${detail}` : summary);
    this.summary = summary;
  }
}

const seconds = (ms) => +(ms / 1000).toFixed(1);

/**
 * Poll `check` (async: returns a truthy value when done, else undefined) until it is done or
 * `timeoutMs` is up; `missing()` says what is not there yet: logged every `reportMs` while
 * waiting, and the message of the NotReady thrown when time is up.
 */
async function until(label, check, { timeoutMs, reportMs = 15000, stepMs = 250, missing = () => "" }) {
  const started = Date.now();
  let report = started + reportMs;
  for (;;) {
    const value = await check();
    if (value) {
      return value;
    }
    const now = Date.now();
    if (now - started > timeoutMs) {
      throw new NotReady(`${label}: not ready after ${seconds(now - started)} s`, missing());
    }
    if (now >= report) {
      log(label, `still waiting after ${seconds(now - started)} s: ${missing()}`);
      report = now + reportMs;
    }
    await sleep(stepMs);
  }
}

/** Run one step of a shot; a playwright timeout in it says which step was not ready. */
async function step(label, action) {
  try {
    return await action();
  } catch (error) {
    if (error instanceof NotReady || error?.name !== "TimeoutError") {
      throw error;
    }
    throw new NotReady(`${label}: not ready: ${String(error.message).split("\n")[0]}`);
  }
}

let replies;

/** A live source started for this shot by whoever runs the driver (see PLAN "serve"). */
async function serve(shot, timeoutMs) {
  replies ??= readline.createInterface({ input: process.stdin })[Symbol.asyncIterator]();
  process.stdout.write(`${JSON.stringify({ start: shot.source.serve, shot: shot.name })}\n`);
  let timer;
  const timeout = new Promise((resolve) => {
    timer = setTimeout(() => resolve({ timedOut: true }), timeoutMs);
  });
  const reply = await Promise.race([replies.next(), timeout]);
  clearTimeout(timer);
  if (reply.timedOut || reply.done) {
    throw new NotReady(`source ${shot.source.serve}: ${reply.done ? "stdin closed" : `no answer within ${seconds(timeoutMs)} s`}`);
  }
  const answer = JSON.parse(reply.value);
  if (!answer.ws) {
    throw new NotReady(`source ${shot.source.serve} did not start: ${answer.error}`);
  }
  return { ws: answer.ws };
}

function appUrl(base, shot, source) {
  const params = new URLSearchParams();
  if (source.ws) {
    params.set("ds", "foxglove-websocket");
    params.set("ds.url", source.ws);
  } else {
    params.set("ds", "remote-file");
    params.set("ds.url", `${base}/data/${encodeURIComponent(source.mcap)}`);
    if (source.time) {
      params.set("time", source.time);
    }
  }
  if (shot.via === "preload") {
    params.set("layout", `/layouts/${path.basename(shot.layout)}`);
  }
  return `${base}/?${params}`;
}

/** Before any page script: a user who has seen the 3D onboarding tooltip, and a file picker that
 * answers with the layout file (the app's Import layout calls window.showOpenFilePicker). */
function initScript({ name, content }) {
  const profile = JSON.parse(localStorage.getItem("studio.profile-data") ?? "{}");
  profile.onboarding = { settingsTooltipShownForPanelTypes: ["3D", "Plot", "RawMessages"] };
  localStorage.setItem("studio.profile-data", JSON.stringify(profile));
  window.__tankvizPicked = 0;
  window.showOpenFilePicker = async () => {
    window.__tankvizPicked++;
    const file = new File([content], name, { type: "application/json" });
    return [{ kind: "file", name, getFile: async () => file }];
  };
}

async function importLayout(page, timeoutMs) {
  const nav = page.locator('button[title="Layouts"]');
  await step("the Layouts button", () => nav.click({ timeout: timeoutMs }));
  await step("the Import layout button", () =>
    page.locator('button[aria-label="Import layout"]').click({ timeout: timeoutMs }));
  await step("the layout file picker (window.showOpenFilePicker)", () =>
    page.waitForFunction(() => window.__tankvizPicked > 0, null, { timeout: timeoutMs }));
}

/**
 * One panel of the layout, by its id (Foxglove marks each panel root with
 * data-testid="panel-mouseenter-container <id>"): its largest canvas, the small elements drawn
 * over that canvas (toolbar buttons, plot legends; masked before reading pixels) and its text.
 */
async function panelInfo(page, panelId) {
  return page.evaluate((id) => {
    const root = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
    if (!root) {
      return undefined;
    }
    const text = root.innerText;
    let canvas;
    let best = 0;
    for (const c of root.querySelectorAll("canvas")) {
      const r = c.getBoundingClientRect();
      if (r.width * r.height > best) {
        best = r.width * r.height;
        canvas = c;
      }
    }
    if (!canvas || best < 100 * 100) {
      return { text, region: undefined, overlays: [] };
    }
    const r = canvas.getBoundingClientRect();
    const region = {
      x: Math.max(0, Math.round(r.x)),
      y: Math.max(0, Math.round(r.y)),
      width: Math.round(Math.min(r.width, window.innerWidth - r.x)),
      height: Math.round(Math.min(r.height, window.innerHeight - r.y)),
    };
    const overlays = [];
    for (const el of root.querySelectorAll("*")) {
      if (el === canvas || el.contains(canvas) || el.tagName === "CANVAS") {
        continue;
      }
      const b = el.getBoundingClientRect();
      const overlaps = b.right > r.left && b.left < r.right && b.bottom > r.top && b.top < r.bottom;
      const small = b.width * b.height < 0.25 * r.width * r.height;
      const shown = getComputedStyle(el).visibility !== "hidden" && b.width > 0 && b.height > 0;
      if (overlaps && small && shown) {
        overlays.push({ x: Math.floor(b.x) - 2, y: Math.floor(b.y) - 2, width: Math.ceil(b.width) + 4, height: Math.ceil(b.height) + 4 });
      }
    }
    return { text, region, overlays };
  }, panelId);
}

/**
 * An Indicator panel: its label (the MUI h1 text) and the box its colour is painted on (the
 * element with the inline background colour: the whole panel body in "background" style, the
 * bulb in "bulb" style).
 */
async function indicatorInfo(page, panelId) {
  return page.evaluate((id) => {
    const root = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
    const label = root?.querySelector(".MuiTypography-h1");
    if (!label) {
      return undefined;
    }
    const painted = [...root.querySelectorAll("[style]")].filter((el) => el.style.backgroundColor);
    const box = painted[painted.length - 1];
    const r = (box ?? label).getBoundingClientRect();
    return {
      label: label.innerText,
      css: box ? getComputedStyle(box).backgroundColor : undefined,
      box: { x: Math.round(r.x), y: Math.round(r.y), width: Math.round(r.width), height: Math.round(r.height) },
    };
  }, panelId);
}

const hex = (r, g, b) => `#${[r, g, b].map((v) => v.toString(16).padStart(2, "0")).join("")}`;

/** The most frequent colour in a box of the screenshot, and its share of the box's pixels. */
function dominantColor(image, box) {
  const counts = new Map();
  let total = 0;
  for (let y = Math.max(0, box.y); y < Math.min(image.height, box.y + box.height); y++) {
    for (let x = Math.max(0, box.x); x < Math.min(image.width, box.x + box.width); x++) {
      const i = (y * image.width + x) * 4;
      const key = hex(image.data[i], image.data[i + 1], image.data[i + 2]);
      counts.set(key, (counts.get(key) ?? 0) + 1);
      total++;
    }
  }
  let best;
  let most = 0;
  for (const [key, n] of counts) {
    if (n > most) {
      best = key;
      most = n;
    }
  }
  return { color: best, share: total ? +(most / total).toFixed(3) : 0 };
}

function colorDistance(a, b) {
  const parse = (h) => [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16));
  const [p, q] = [parse(a), parse(b)];
  return Math.max(...p.map((v, i) => Math.abs(v - q[i])));
}

/** How much of a plot's width carries coloured data lines (0..1) and how many such pixels. */
function plotCoverage(image, region) {
  let min = Infinity;
  let max = -Infinity;
  let pixels = 0;
  for (let y = region.y; y < region.y + region.height; y++) {
    for (let x = region.x; x < region.x + region.width; x++) {
      const i = (y * image.width + x) * 4;
      const r = image.data[i];
      const g = image.data[i + 1];
      const b = image.data[i + 2];
      if (Math.max(r, g, b) - Math.min(r, g, b) >= 80) {
        pixels++;
        min = Math.min(min, x);
        max = Math.max(max, x);
      }
    }
  }
  return { pixels, extent: pixels ? +((max - min + 1) / region.width).toFixed(3) : 0 };
}

const escapeRegExp = (text) => text.replace(/[.*+?^${}()|[\]\\]/g, "\\$&");

/** Plot legend labels (or paths) each followed by a number: the path resolved to data. */
function legendValues(text, config) {
  const missing = [];
  for (const p of config.paths ?? []) {
    const label = p.label || p.value;
    const pattern = new RegExp(`${escapeRegExp(label)}\\s*\\n\\s*-?[0-9]`);
    if (!pattern.test(text)) {
      missing.push(label);
    }
  }
  return missing;
}

/**
 * Blobs of one colour class shown inside blobs of another (`spec`: container class -> classes
 * that must show inside it), e.g. {"red": ["blue", "white"]}: detections inside their track.
 * A container is a compact blob (a track's disc); a blob is inside when its centre lies in the
 * container's box and the container's colour is on at least a fifth of the ring of pixels around
 * it (a text label beside a track is not inside it). Returns {class: [[container, blob], …]}.
 */
export function insideOf(image, region, spec) {
  const found = {};
  const summary = ({ area, cx, cy, x0, y0, x1, y1 }) => ({ area, cx, cy, x0, y0, x1, y1 });
  for (const [outer, inner] of Object.entries(spec)) {
    const isOuter = CLASSES[outer];
    const containers = blobs(image, isOuter, region).filter(
      (b) => b.area >= 20 && b.fill >= 0.45 && b.w <= 4 * b.h && b.h <= 4 * b.w,
    );
    for (const name of inner) {
      found[name] = [];
      for (const blob of blobs(image, CLASSES[name], region).filter((b) => b.area >= 4)) {
        const box = containers.find((c) => c.area > blob.area && blob.cx >= c.x0 && blob.cx <= c.x1
          && blob.cy >= c.y0 && blob.cy <= c.y1);
        if (!box) continue;
        let ring = 0;
        let outerColour = 0;
        for (let y = blob.y0 - 2; y <= blob.y1 + 2; y++) {
          for (let x = blob.x0 - 2; x <= blob.x1 + 2; x++) {
            if (x >= blob.x0 && x <= blob.x1 && y >= blob.y0 && y <= blob.y1) continue;
            if (x < 0 || y < 0 || x >= image.width || y >= image.height) continue;
            const i = (y * image.width + x) * 4;
            ring++;
            if (isOuter(image.data[i], image.data[i + 1], image.data[i + 2])) outerColour++;
          }
        }
        if (outerColour >= ring / 5) found[name].push([summary(box), summary(blob)]);
      }
    }
  }
  return found;
}

/** Paint the overlays background grey so that no class matches there. */
function maskOverlays(image, overlays) {
  for (const o of overlays) {
    for (let y = Math.max(0, o.y); y < Math.min(image.height, o.y + o.height); y++) {
      for (let x = Math.max(0, o.x); x < Math.min(image.width, o.x + o.width); x++) {
        const i = (y * image.width + x) * 4;
        image.data[i] = image.data[i + 1] = image.data[i + 2] = 48;
      }
    }
  }
}

/**
 * OCR of the scene's text labels. Foxglove draws them as white text on black boxes: find the
 * boxes, cut each out (white on black made black on white, scaled 3x), stack them in one image
 * and let tesseract read it as a block of lines.
 */
function ocrLabels(image, region, timeoutMs) {
  const probe = spawnSync("tesseract", ["--version"], { encoding: "utf8" });
  if (probe.error || probe.status !== 0) {
    return { available: false, text: "" };
  }
  const black = (r, g, b) => r < 12 && g < 12 && b < 12;
  const margin = 4;
  const inside = (b) => b.x0 - margin >= 0 && b.y0 - margin >= 0 &&
    b.x1 + margin < image.width && b.y1 + margin < image.height;
  const boxes = blobs(image, black, region)
    .filter((b) => b.w >= 25 && b.h >= 12 && b.fill > 0.3 && inside(b))
    .slice(0, 40);
  if (!boxes.length) {
    return { available: true, text: "", boxes: 0 };
  }
  const scale = 3;
  const gap = 10;
  const width = Math.max(...boxes.map((b) => b.w + 2 * margin)) * scale;
  const height = boxes.reduce((n, b) => n + (b.h + 2 * margin) * scale + gap, 0);
  const out = Buffer.alloc(width * height * 4, 255);
  let top = 0;
  for (const b of boxes) {
    for (let y = b.y0 - margin; y <= b.y1 + margin; y++) {
      for (let x = b.x0 - margin; x <= b.x1 + margin; x++) {
        const i = (y * image.width + x) * 4;
        const lightness = Math.min(image.data[i], image.data[i + 1], image.data[i + 2]);
        const inBox = x >= b.x0 && x <= b.x1 && y >= b.y0 && y <= b.y1;
        const ink = inBox ? 255 - lightness : 255;
        for (let sy = 0; sy < scale; sy++) {
          for (let sx = 0; sx < scale; sx++) {
            const o = ((top + (y - b.y0 + margin) * scale + sy) * width + (x - b.x0 + margin) * scale + sx) * 4;
            out[o] = out[o + 1] = out[o + 2] = ink;
          }
        }
      }
    }
    top += (b.h + 2 * margin) * scale + gap;
  }
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), "tankviz-ocr-"));
  const file = path.join(dir, "labels.png");
  fs.writeFileSync(file, encodePng({ width, height, data: out }));
  const run = spawnSync("tesseract", [file, "stdout", "--psm", "6"], { encoding: "utf8", timeout: timeoutMs });
  fs.rmSync(dir, { recursive: true, force: true });
  return { available: true, text: run.stdout ?? "", boxes: boxes.length,
    error: run.status === 0 ? undefined : run.stderr };
}

/** Pixels of an image region that are bright orange (a bit map's often flipping bits), and how
 * many are white (its bits that flip in every frame, or an empty light panel). */
function brightPixels(image, region) {
  let bright = 0;
  let white = 0;
  for (let y = region.y; y < region.y + region.height; y++) {
    for (let x = region.x; x < region.x + region.width; x++) {
      const i = (y * image.width + x) * 4;
      const [r, g, b] = [image.data[i], image.data[i + 1], image.data[i + 2]];
      if (r >= 200 && g >= 120 && r - b >= 80) bright++;
      else if (r >= 230 && g >= 230 && b >= 230) white++;
    }
  }
  return { bright, white };
}

/** The box of a panel's root element on screen. */
async function panelBox(page, panelId) {
  return page.evaluate((id) => {
    const root = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
    if (!root) return undefined;
    const r = root.getBoundingClientRect();
    return { x: Math.max(0, Math.round(r.x)), y: Math.max(0, Math.round(r.y)),
      width: Math.round(Math.min(r.width, window.innerWidth - r.x)),
      height: Math.round(Math.min(r.height, window.innerHeight - r.y)) };
  }, panelId);
}

/**
 * OCR of a region of the screenshot (a panel): grey, made dark on light (a dark panel is
 * inverted), scaled 2x, read by tesseract as a block of text (psm 6), then as sparse text
 * (psm 11) unless ``enough`` says the first reading is.
 */
function ocrRegion(image, region, timeoutMs, enough = () => false) {
  const probe = spawnSync("tesseract", ["--version"], { encoding: "utf8" });
  if (probe.error || probe.status !== 0) {
    return { available: false, text: "" };
  }
  const scale = 2;
  const width = region.width * scale;
  const height = region.height * scale;
  let sum = 0;
  for (let y = region.y; y < region.y + region.height; y++) {
    for (let x = region.x; x < region.x + region.width; x++) {
      const i = (y * image.width + x) * 4;
      sum += (image.data[i] + image.data[i + 1] + image.data[i + 2]) / 3;
    }
  }
  const dark = sum / (region.width * region.height) < 128;
  const out = Buffer.alloc(width * height * 4, 255);
  for (let y = 0; y < height; y++) {
    for (let x = 0; x < width; x++) {
      const i = ((region.y + Math.floor(y / scale)) * image.width + region.x + Math.floor(x / scale)) * 4;
      const grey = Math.max(image.data[i], image.data[i + 1], image.data[i + 2]);
      const o = (y * width + x) * 4;
      out[o] = out[o + 1] = out[o + 2] = dark ? 255 - grey : grey;
    }
  }
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), "tankviz-ocr-"));
  const file = path.join(dir, "panel.png");
  fs.writeFileSync(file, encodePng({ width, height, data: out }));
  const texts = [];
  for (const psm of ["6", "11"]) {
    const run = spawnSync("tesseract", [file, "stdout", "--psm", psm], { encoding: "utf8", timeout: timeoutMs });
    texts.push(run.stdout ?? "");
    if (enough(texts.join("\n"))) break;
  }
  fs.rmSync(dir, { recursive: true, force: true });
  return { available: true, text: texts.join("\n") };
}

async function closeSidebar(page, nav, timeoutMs) {
  // The left nav buttons toggle the sidebar: open the Layouts tab (if it is not) and close it.
  const importButton = page.locator('button[aria-label="Import layout"]');
  await step("closing the sidebar", async () => {
    if (!(await importButton.isVisible())) {
      await nav.click({ timeout: timeoutMs });
      await importButton.waitFor({ state: "visible", timeout: timeoutMs });
    }
    await nav.click({ timeout: timeoutMs });
    await importButton.waitFor({ state: "hidden", timeout: timeoutMs });
  });
}

async function runShot(ctx, base, shot, plan) {
  const timeoutMs = plan.timeoutMs ?? 120000;
  const reportMs = plan.reportMs ?? 15000;
  const started = Date.now();
  const layout = JSON.parse(fs.readFileSync(shot.layout, "utf8"));
  const layoutName = path.basename(shot.layout, ".json");
  const result = { name: shot.name, layout: layoutName, ok: false, steps: {}, errors: [], failures: [] };
  const mark = (step) => {
    result.steps[step] = Date.now() - started;
    log(shot.name, step, `${result.steps[step]} ms`);
  };
  const wait = (what, check, options) =>
    until(`${shot.name}: ${what}`, check, { timeoutMs, reportMs, ...options });
  let page;
  let last;
  try {
    const source = shot.source.serve ? await serve(shot, timeoutMs) : shot.source;
    if (shot.source.serve) {
      mark("served");
    }
    page = await ctx.newPage();
    if (shot.viewport) {
      await page.setViewportSize(shot.viewport);
    }
    page.on("pageerror", (error) => result.errors.push(`pageerror: ${error.message}`));
    page.on("console", (message) => {
      if (message.type() === "error" && !/favicon|Failed to load resource/.test(message.text())) {
        result.errors.push(`console: ${message.text().slice(0, 300)}`);
      }
    });
    await page.addInitScript(initScript, {
      name: path.basename(shot.layout),
      content: fs.readFileSync(shot.layout, "utf8"),
    });
    await step("loading the page", () => page.goto(appUrl(base, shot, source), { timeout: timeoutMs }));
    // The host page says when the app rendered (or why it could not start).
    let host;
    await wait("the Foxglove app started", async () => {
      try {
        host = await page.evaluate(() => window.__tankviz && { ...window.__tankviz });
      } catch (error) {
        host = { evaluate: String(error?.message ?? error).split("\n")[0] };
      }
      return host?.rendered || host?.errors?.length;
    }, { missing: () => `window.__tankviz = ${JSON.stringify(host ?? null)}` });
    if (host.errors.length) {
      throw new Error(`the Foxglove app did not start: ${host.errors.join("; ")}`);
    }
    mark("app");
    const nav = page.locator('button[title="Layouts"]');
    if (shot.via !== "preload") {
      await importLayout(page, timeoutMs);
      // The imported layout is listed (by its file name) and becomes the current one.
      await step(`the imported layout ${layoutName} listed`, () =>
        page.locator(`text=${layoutName}`).first().waitFor({ timeout: timeoutMs }));
      mark("imported");
    }
    // Every panel of the layout is on screen.
    const panelIds = Object.keys(layout.configById);
    let absent = panelIds;
    await wait("the layout's panels shown", async () => {
      absent = [];
      for (const id of panelIds) {
        if (!(await panelInfo(page, id))) {
          absent.push(id);
        }
      }
      return absent.length === 0;
    }, { missing: () => `not on screen: ${absent.join(", ")}` });
    await closeSidebar(page, nav, timeoutMs);
    mark("panels");
    // Buttons to click, once each is enabled (a Publish panel's, once the source takes
    // publishing).
    for (const click of shot.clicks ?? []) {
      const button = page.locator(
        `[data-testid="panel-mouseenter-container ${click.panel}"] button:has-text("${click.button}")`);
      await wait(`${click.panel}: "${click.button}" enabled`, async () =>
        (await button.count()) > 0 && (await button.first().isEnabled()));
      await button.first().click();
      mark(`clicked ${click.panel}`);
    }

    // Wait (polling screenshots and the DOM) until everything the shot expects is on screen.
    const scene = shot.scene;
    const plots = panelIds.filter((id) => id.startsWith("Plot!"));
    const minExtent = shot.plotExtent ?? 0;
    const panelText = shot.panelText ?? {};
    const check = async () => {
      const png = await page.screenshot({ type: "png", timeout: timeoutMs });
      const image = decodePng(png);
      const state = { png, image, failures: [] };
      if (scene) {
        const info = await panelInfo(page, scene.panel);
        if (!info?.region) {
          state.failures.push(`no canvas in ${scene.panel}`);
        } else {
          const masked = { ...image, data: Buffer.from(image.data) };
          maskOverlays(masked, info.overlays);
          state.reading = readTankViz(masked, info.region);
          state.verdict = verdict(state.reading);
          state.region = info.region;
          for (const k of scene.expect ?? []) {
            if (!state.verdict[k]) state.failures.push(`${scene.panel}: ${k} not on screen`);
          }
          for (const k of scene.absent ?? []) {
            if (state.verdict[k]) state.failures.push(`${scene.panel}: ${k} on screen, should not be`);
          }
          if (scene.inside) {
            state.reading.inside = insideOf(masked, info.region, scene.inside);
            for (const [outer, inner] of Object.entries(scene.inside)) {
              for (const k of inner) {
                if (!state.reading.inside[k].length) state.failures.push(`${scene.panel}: no ${k} inside ${outer}`);
              }
            }
          }
        }
      }
      state.plots = {};
      if (shot.plots) {
        for (const id of plots) {
          const info = await panelInfo(page, id);
          const missing = legendValues(info?.text ?? "", layout.configById[id]);
          const coverage = info?.region ? plotCoverage(image, info.region) : { pixels: 0, extent: 0 };
          state.plots[id] = { missingValues: missing, ...coverage };
          if (missing.length) state.failures.push(`${id}: no value for ${missing.join(", ")}`);
          if (coverage.pixels < 100 || coverage.extent < minExtent) {
            state.failures.push(`${id}: data lines cover ${coverage.extent} of the width (${coverage.pixels} px)`);
          }
        }
      }
      state.indicators = {};
      for (const [id, want] of Object.entries(shot.indicators ?? {})) {
        const info = await indicatorInfo(page, id);
        if (!info) {
          state.failures.push(`${id}: no Indicator label on screen`);
          continue;
        }
        const seen = dominantColor(image, info.box);
        state.indicators[id] = { label: info.label, css: info.css, ...seen };
        if (info.label !== want.label) {
          state.failures.push(`${id}: label ${JSON.stringify(info.label)}, expected ${JSON.stringify(want.label)}`);
        }
        if (!seen.color || colorDistance(seen.color, want.color) > 24 || seen.share < 0.5) {
          state.failures.push(`${id}: colour ${seen.color} on ${seen.share} of it, expected ${want.color}`);
        }
      }
      for (const [id, words] of Object.entries(panelText)) {
        const info = await panelInfo(page, id);
        for (const word of words) {
          if (!info?.text.includes(word)) state.failures.push(`${id}: no text ${JSON.stringify(word)}`);
        }
      }
      if (shot.image) {
        const info = await panelInfo(page, shot.image.panel);
        if (!info?.region) {
          state.failures.push(`no canvas in ${shot.image.panel}`);
        } else {
          const seen = { ...brightPixels(image, info.region), region: info.region };
          state.imageReading = seen;
          if (seen.bright < (shot.image.minBright ?? 1)) {
            state.failures.push(`${shot.image.panel}: ${seen.bright} bright and ${seen.white} white pixels`);
          }
        }
      }
      last = state;
      return state.failures.length === 0 ? state : undefined;
    };
    let seen;
    try {
      seen = await wait("everything expected on screen", check, {
        stepMs: 400,
        missing: () => (last?.failures ?? ["nothing checked"]).join("; "),
      });
      mark("seen");
      result.failures = [];
    } catch (error) {
      if (!(error instanceof NotReady)) {
        throw error;
      }
      mark("timeout");
      result.failures = [error.summary, ...(last?.failures ?? ["nothing checked"])];
    }

    // Labels: OCR of screenshots until every wanted pattern was matched in what was read.
    let ocr;
    if (shot.ocr?.length && scene && last) {
      const wanted = shot.ocr;
      const readText = [];
      for (let attempt = 0; attempt < 10; attempt++) {
        const info = await panelInfo(page, scene.panel);
        const image = attempt === 0 ? last.image : decodePng(await page.screenshot({ type: "png", timeout: timeoutMs }));
        const read = ocrLabels(image, info.region, timeoutMs);
        if (!read.available) {
          ocr = { available: false };
          break;
        }
        readText.push(read.text);
        const all = readText.join("\n");
        const found = wanted.filter((pattern) => new RegExp(pattern).test(all));
        ocr = { available: true, wanted, found, text: all.slice(0, 6000), attempts: attempt + 1 };
        if (found.length === wanted.length) {
          break;
        }
      }
      mark("ocr");
    }
    // Panels: OCR of screenshots until every wanted pattern was matched in what was read.
    const ocrPanels = {};
    for (const [id, wanted] of Object.entries(shot.ocrPanels ?? {})) {
      const readText = [];
      const matched = (text) => wanted.every((pattern) => new RegExp(pattern).test(text));
      for (let attempt = 0; attempt < (shot.ocrAttempts ?? 4) && last; attempt++) {
        const box = await panelBox(page, id);
        if (!box) break;
        const image = attempt === 0 ? last.image : decodePng(await page.screenshot({ type: "png", timeout: timeoutMs }));
        const read = ocrRegion(image, box, timeoutMs, matched);
        if (!read.available) {
          ocrPanels[id] = { available: false };
          break;
        }
        readText.push(read.text);
        const all = readText.join("\n");
        const found = wanted.filter((pattern) => new RegExp(pattern).test(all));
        ocrPanels[id] = { available: true, wanted, found, text: all.slice(0, 6000), attempts: attempt + 1 };
        if (found.length === wanted.length) break;
      }
    }
    if (shot.ocrPanels) {
      mark("ocrPanels");
    }
    Object.assign(result, {
      ok: Boolean(seen),
      verdict: last?.verdict,
      reading: last?.reading,
      plots: last?.plots,
      indicators: last?.indicators,
      ocr,
      ocrPanels,
      image: last?.imageReading,
    });
  } catch (error) {
    result.errors.push(String(error?.stack ?? error));
    result.failures.unshift(String(error?.message ?? error));
    log(shot.name, "failed:", String(error?.message ?? error));
  } finally {
    // The picture to keep: the one the checks passed on (or the last one seen).
    if (shot.screenshot && page) {
      try {
        fs.mkdirSync(path.dirname(shot.screenshot), { recursive: true });
        fs.writeFileSync(shot.screenshot, last?.png ?? (await page.screenshot({ type: "png", timeout: timeoutMs })));
      } catch {
        // the page may be gone
      }
    }
    result.seconds = seconds(Date.now() - started);
    await page?.close().catch(() => {});
  }
  return result;
}

export async function run(plan) {
  const timeoutMs = plan.timeoutMs ?? 120000;
  const { server, url: base } = await startServer({ dataDir: plan.dataDir });
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), "tankviz-chromium-"));
  const started = Date.now();
  let ctx;
  try {
    ctx = await step("starting chromium", () => chromium.launchPersistentContext(userDataDir, {
      executablePath: plan.chromium ?? "/usr/bin/chromium",
      headless: true,
      args: CHROMIUM_ARGS,
      viewport: plan.viewport ?? { width: 1600, height: 1000 },
      deviceScaleFactor: 1,
      timeout: timeoutMs,
    }));
    // Every playwright call without its own timeout (screenshots, waits) gets the plan's.
    ctx.setDefaultTimeout(timeoutMs);
    ctx.setDefaultNavigationTimeout(timeoutMs);
    log("chromium", ctx.browser()?.version() ?? "", `${Date.now() - started} ms`);
    const shots = [];
    for (const shot of plan.shots) {
      const result = await runShot(ctx, base, shot, plan);
      shots.push(result);
      process.stdout.write(`${JSON.stringify({ shot: result })}\n`);
    }
    return { ok: shots.every((s) => s.ok), seconds: seconds(Date.now() - started), shots };
  } finally {
    await ctx?.close().catch(() => {});
    server.close();
    fs.rmSync(userDataDir, { recursive: true, force: true });
  }
}

if (process.argv[1] && path.resolve(process.argv[1]) === new URL(import.meta.url).pathname) {
  const plan = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));
  const result = await run(plan);
  process.stdout.write(`${JSON.stringify(result)}\n`);
  process.exit(0);
}
