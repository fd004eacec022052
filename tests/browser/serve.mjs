// A small static HTTP server for the Foxglove test host, with HTTP Range requests (the MCAP
// remote-file data source reads a drive by ranges).
//
//   /                      host/index.html
//   /host/…                host/
//   /vendor/react.js       react 17 UMD build;  /vendor/react-dom.js  react-dom 17 UMD build
//   /studio/…              node_modules/@foxglove/studio-base/assets/ (the prebuilt web app)
//   /layouts/…             the repository's layouts/
//   /data/…                a folder given by the caller (drives to open with ds=remote-file)
//
// Run by hand: node tests/browser/serve.mjs [--port 8080] [--data DIR]
// then open http://127.0.0.1:8080/?ds=foxglove-websocket&ds.url=ws://127.0.0.1:8765&layout=/layouts/tank-viz.json

import fs from "node:fs";
import http from "node:http";
import path from "node:path";
import { fileURLToPath } from "node:url";

const HERE = path.dirname(fileURLToPath(import.meta.url));
const MODULES = path.join(HERE, "node_modules");
const REPO = path.resolve(HERE, "..", "..");

const TYPES = {
  ".html": "text/html; charset=utf-8",
  ".js": "text/javascript; charset=utf-8",
  ".mjs": "text/javascript; charset=utf-8",
  ".json": "application/json",
  ".wasm": "application/wasm",
  ".png": "image/png",
  ".svg": "image/svg+xml",
  ".ttf": "font/ttf",
  ".woff": "font/woff",
  ".woff2": "font/woff2",
  ".mcap": "application/octet-stream",
  ".map": "application/json",
};

function routes(dataDir) {
  return [
    ["/host/", path.join(HERE, "host")],
    ["/studio/", path.join(MODULES, "@foxglove", "studio-base", "assets")],
    ["/layouts/", path.join(REPO, "layouts")],
    ...(dataDir ? [["/data/", path.resolve(dataDir)]] : []),
  ];
}

const FILES = {
  "/": path.join(HERE, "host", "index.html"),
  "/index.html": path.join(HERE, "host", "index.html"),
  "/vendor/react.js": path.join(MODULES, "react", "umd", "react.production.min.js"),
  "/vendor/react-dom.js": path.join(MODULES, "react-dom", "umd", "react-dom.production.min.js"),
};

function resolvePath(urlPath, dataDir) {
  if (FILES[urlPath]) {
    return FILES[urlPath];
  }
  for (const [prefix, dir] of routes(dataDir)) {
    if (urlPath.startsWith(prefix)) {
      const file = path.resolve(dir, "." + urlPath.slice(prefix.length - 1));
      return file.startsWith(dir + path.sep) ? file : undefined; // no escaping the folder
    }
  }
  return undefined;
}

function handle(req, res, dataDir, log) {
  const url = new URL(req.url, "http://localhost");
  let urlPath;
  try {
    urlPath = decodeURIComponent(url.pathname);
  } catch {
    res.writeHead(400).end();
    return;
  }
  const common = {
    "Access-Control-Allow-Origin": "*",
    "Access-Control-Allow-Headers": "Range",
    "Access-Control-Expose-Headers": "Content-Length, Content-Range, Accept-Ranges",
    "Accept-Ranges": "bytes",
    "Cache-Control": "no-store",
  };
  if (req.method === "OPTIONS") {
    res.writeHead(204, common).end();
    return;
  }
  if (req.method !== "GET" && req.method !== "HEAD") {
    res.writeHead(405, common).end();
    return;
  }
  const file = resolvePath(urlPath, dataDir);
  let stat;
  try {
    stat = file ? fs.statSync(file) : undefined;
  } catch {
    stat = undefined;
  }
  if (!stat || !stat.isFile()) {
    log(`404 ${urlPath}`);
    res.writeHead(404, { ...common, "Content-Type": "text/plain" }).end(`not found: ${urlPath}\n`);
    return;
  }
  const headers = {
    ...common,
    "Content-Type": TYPES[path.extname(file).toLowerCase()] ?? "application/octet-stream",
    "Last-Modified": stat.mtime.toUTCString(),
  };
  const size = stat.size;
  let start = 0;
  let end = size - 1;
  let status = 200;
  const range = req.headers.range;
  if (range) {
    const match = /^bytes=(\d*)-(\d*)$/.exec(range.trim());
    if (!match || (match[1] === "" && match[2] === "")) {
      res.writeHead(416, { ...headers, "Content-Range": `bytes */${size}` }).end();
      return;
    }
    if (match[1] === "") {
      start = Math.max(0, size - Number(match[2])); // the last N bytes
    } else {
      start = Number(match[1]);
      end = match[2] === "" ? size - 1 : Math.min(Number(match[2]), size - 1);
    }
    if (start > end || start >= size) {
      res.writeHead(416, { ...headers, "Content-Range": `bytes */${size}` }).end();
      return;
    }
    status = 206;
    headers["Content-Range"] = `bytes ${start}-${end}/${size}`;
  }
  headers["Content-Length"] = String(end - start + 1);
  res.writeHead(status, headers);
  if (req.method === "HEAD" || size === 0) {
    res.end();
    return;
  }
  const stream = fs.createReadStream(file, { start, end });
  stream.on("error", () => res.destroy());
  stream.pipe(res);
}

/** Start the server on 127.0.0.1; resolves to { server, port, url }. */
export function startServer({ port = 0, dataDir, log = () => {} } = {}) {
  return new Promise((resolve, reject) => {
    const server = http.createServer((req, res) => handle(req, res, dataDir, log));
    server.on("error", reject);
    server.listen(port, "127.0.0.1", () => {
      const actual = server.address().port;
      resolve({ server, port: actual, url: `http://127.0.0.1:${actual}` });
    });
  });
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  const args = process.argv.slice(2);
  const option = (name, fallback) => {
    const i = args.indexOf(name);
    return i >= 0 ? args[i + 1] : fallback;
  };
  const { url } = await startServer({
    port: Number(option("--port", "8080")),
    dataDir: option("--data", undefined),
    log: (line) => console.error(line),
  });
  console.log(`serving the Foxglove test host on ${url}/`);
}
