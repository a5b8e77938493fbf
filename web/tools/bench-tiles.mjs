// Tiled decoding in node (spec 10.14): per file, in a fresh node process each, the whole-file decode
// (decodeGspc) against the streaming reader (openGspc on the bytes in memory): the time to the head and tile
// index, to the first tile and to the last (every check of the file done), and each tile's decode; then the
// same reader fed by a local HTTP server (another process) that sends the file at a fixed rate, as a
// download would arrive: when the first tile is ready against when the last byte arrives.
//
// usage: node web/tools/bench-tiles.mjs [--rate BYTES_PER_S] [--runs N] SCENE.gspc ...   (bench/web.md)

import { spawn, spawnSync } from 'node:child_process';
import { createServer } from 'node:http';
import { readFileSync } from 'node:fs';
import { basename } from 'node:path';
import { fileURLToPath } from 'node:url';
import { bytesSource, decodeGspc, fetchStreamSource, openGspc } from '../src/index.mjs';

const SELF = fileURLToPath(import.meta.url);
const median = (xs) => xs.slice().sort((a, b) => a - b)[(xs.length - 1) >> 1];

async function streamTimes(source, t0) {
  const reader = await openGspc(await source());
  const head = performance.now() - t0;
  const tiles = [];
  let last = performance.now();
  for await (const tile of reader.decode()) {
    const now = performance.now();
    tiles.push({ number: tile.number, count: tile.count, ms: now - last, at: now - t0 });
    last = now;
  }
  return { head, first: tiles[0].at, last: performance.now() - t0, tiles, count: reader.count };
}

/** Serve `path` at `rate` bytes per second, in 16 KiB writes, printing the port (its own process: a decode in
 * the measuring process would hold the sending back). */
async function serveThrottled(path, rate) {
  const bytes = new Uint8Array(readFileSync(path));
  const server = createServer(async (req, res) => {
    res.writeHead(200, { 'content-length': bytes.length });
    if (req.method === 'HEAD') {
      res.end();
      return;
    }
    const step = 16384;
    const start = performance.now();
    for (let at = 0; at < bytes.length; at += step) {
      const wait = start + (1000 * at) / rate - performance.now();
      if (wait > 0) await new Promise((r) => setTimeout(r, wait));
      res.write(bytes.subarray(at, Math.min(at + step, bytes.length)));
    }
    res.end();
  });
  await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
  console.log(server.address().port);
}

/** The throttled server of `path` in a child process: {url, stop}. */
async function throttled(path, rate) {
  const child = spawn(process.execPath, [SELF, '--serve', path, String(rate)], { stdio: ['ignore', 'pipe', 'inherit'] });
  const port = await new Promise((ok) => child.stdout.once('data', (d) => ok(Number(String(d).trim()))));
  return { url: `http://127.0.0.1:${port}/f.gspc`, stop: () => child.kill() };
}

async function measure(path, runs, rate) {
  const bytes = new Uint8Array(readFileSync(path));
  const whole = [];
  const streamed = [];
  for (let i = 0; i < runs; i++) {
    const t0 = performance.now();
    decodeGspc(bytes);
    whole.push(performance.now() - t0);
    const t1 = performance.now();
    streamed.push(await streamTimes(async () => bytesSource(bytes), t1));
  }
  const server = await throttled(path, rate);
  await fetch(server.url, { method: 'HEAD' }); // node loads its fetch on first use: not part of a download
  const t2 = performance.now();
  const download = await streamTimes(() => fetchStreamSource(server.url), t2);
  server.stop();
  console.log(JSON.stringify({ whole, streamed, download, size: bytes.length }));
}

function report(path, runs, rate) {
  const res = spawnSync(process.execPath, [SELF, '--measure', path, String(runs), String(rate)], { encoding: 'utf8' });
  if (res.status !== 0) throw new Error(`${path}: ${res.stderr}`);
  const { whole, streamed, download, size } = JSON.parse(res.stdout);
  const warm = streamed.slice(1);
  const tiles = streamed[0].tiles.length;
  const tileMs = warm.flatMap((s) => s.tiles.map((t) => t.ms));
  const row = [
    basename(path), size, streamed[0].count, tiles,
    whole[0].toFixed(0), median(whole.slice(1)).toFixed(0),
    median(warm.map((s) => s.head)).toFixed(1), median(warm.map((s) => s.first)).toFixed(0), median(warm.map((s) => s.last)).toFixed(0),
    `${median(tileMs).toFixed(0)} (${Math.min(...tileMs).toFixed(0)}-${Math.max(...tileMs).toFixed(0)})`,
    download.first.toFixed(0), download.last.toFixed(0), ((1000 * size) / rate).toFixed(0),
  ]; // fmt
  console.log(`| ${row.join(' | ')} |`);
}

const args = process.argv.slice(2);
if (args[0] === '--measure') {
  await measure(args[1], Number(args[2]), Number(args[3]));
} else if (args[0] === '--serve') {
  await serveThrottled(args[1], Number(args[2]));
} else {
  const take = (flag, fallback) => {
    const at = args.indexOf(flag);
    if (at < 0) return fallback;
    const [value] = args.splice(at, 2).slice(1);
    return Number(value);
  };
  const rate = take('--rate', 250000);
  const runs = take('--runs', 6);
  console.log(`node ${process.version}; ${runs} decodes per file (the first cold), a download at ${rate} B/s`);
  console.log(
    '| file | bytes | Gaussians | tiles | whole decode, cold ms | whole, warm ms | stream: head + index ms | first tile ms | ' +
      'last tile (all checked) ms | one tile ms, median (range) | download: first tile at ms | last tile at ms | last byte due at ms |',
  );
  console.log('|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|');
  for (const path of args) report(path, runs, rate);
}
