// Decode every decodable conformance vector in a headless Chromium and compare the attributes' SHA-256 with
// spec/vectors/MANIFEST.json: the decoder's modules run in a browser as they are (fzstd mapped by an
// import map, no bundler).
//
// With --time FILE.gspc ... it first decodes each file six times in the page and prints the first decode's
// time (the first file's is the page's first decode: cold) and the median of the others (wall clock, the
// page's main thread): bench/web.md.
//
// usage: node web/tools/browser-check.mjs [--chromium PATH] [--time FILE.gspc ...]

import { execFile } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { createServer } from 'node:http';
import { basename, extname, join, normalize } from 'node:path';
import { fileURLToPath } from 'node:url';

const ROOT = fileURLToPath(new URL('../../', import.meta.url));
const TYPES = { '.mjs': 'text/javascript', '.js': 'text/javascript', '.json': 'application/json', '.gspc': 'application/octet-stream' };

const args = process.argv.slice(2);
const chromium = args.includes('--chromium') ? args[args.indexOf('--chromium') + 1] : 'chromium';
const timed = args.includes('--time') ? args.slice(args.indexOf('--time') + 1) : [];

const PAGE = `<!doctype html>
<script type="importmap">{"imports": {"fzstd": "/web/node_modules/fzstd/esm/index.mjs"}}</script>
<script type="module">
const TIMED = ${JSON.stringify(timed.map((f) => basename(f)))};
import { decodeGspc } from '/web/src/index.mjs';
const hex = (buf) => Array.from(new Uint8Array(buf), (b) => b.toString(16).padStart(2, '0')).join('');
const names = { means: 'means', quats: 'quats', log_scales: 'logScales', opacities: 'opacities', sh_dc: 'shDc', sh_rest: 'shRest' };
const lines = [];
for (const [i, name] of TIMED.entries()) {
  const bytes = new Uint8Array(await (await fetch('/timed/' + i)).arrayBuffer());
  const times = [];
  let count = 0;
  for (let run = 0; run < 6; run++) {
    const t0 = performance.now();
    count = decodeGspc(bytes).count;
    times.push(performance.now() - t0);
  }
  const warm = times.slice(1).sort((a, b) => a - b)[2];
  lines.push('time ' + name + ': ' + count + ' Gaussians, cold ' + times[0].toFixed(0) + ' ms, warm ' + warm.toFixed(0) + ' ms');
}
const manifest = await (await fetch('/spec/vectors/MANIFEST.json')).json();
for (const v of manifest.vectors.filter((x) => x.codec && x.codec.expect === 'ok')) {
  const bytes = new Uint8Array(await (await fetch('/spec/vectors/' + v.file)).arrayBuffer());
  let verdict = 'ok';
  try {
    const scene = decodeGspc(bytes);
    for (const [key, want] of Object.entries(v.codec.attributes)) {
      const a = scene[names[key]];
      const got = hex(await crypto.subtle.digest('SHA-256', new Uint8Array(a.buffer, a.byteOffset, a.byteLength)));
      if (got !== want.sha256) verdict = 'mismatch ' + key;
    }
  } catch (err) {
    verdict = err.name + ': ' + err.message;
  }
  lines.push(v.file + ' ' + verdict);
}
await fetch('/result', { method: 'POST', body: 'DONE ' + navigator.userAgent + '\\n' + lines.join('\\n') });
</script>`;

let browser = null;

function finish(text) {
  console.log(text);
  const results = text.split('\n').slice(1).filter((line) => !line.startsWith('time '));
  const ok = text.startsWith('DONE') && results.length > 0 && results.every((line) => line.endsWith(' ok'));
  process.exitCode = ok ? 0 : 1;
  browser?.kill();
  server.close();
}

const server = createServer((req, res) => {
  const path = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  if (path === '/result') {
    let body = '';
    req.on('data', (part) => {
      body += part;
    });
    req.on('end', () => {
      res.end();
      finish(body);
    });
    return undefined;
  }
  if (path.startsWith('/timed/')) {
    res.writeHead(200, { 'content-type': 'application/octet-stream' });
    return res.end(readFileSync(timed[Number(path.slice(7))]));
  }
  if (path === '/') {
    res.writeHead(200, { 'content-type': 'text/html' });
    return res.end(PAGE);
  }
  const file = normalize(join(ROOT, path));
  if (!file.startsWith(ROOT)) {
    res.writeHead(403);
    return res.end();
  }
  try {
    const body = readFileSync(file);
    res.writeHead(200, { 'content-type': TYPES[extname(file)] ?? 'application/octet-stream' });
    return res.end(body);
  } catch {
    res.writeHead(404);
    return res.end();
  }
});

server.listen(0, '127.0.0.1', () => {
  const { port } = server.address();
  // The page posts its results to /result; Chromium runs until then (or five minutes).
  const args = ['--headless', '--no-sandbox', '--disable-gpu', `http://127.0.0.1:${port}/`];
  browser = execFile(chromium, args, { timeout: 300000 }, () => {
    if (server.listening) finish('Chromium stopped before the page posted its results');
  });
});
