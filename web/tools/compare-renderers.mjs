// Splat renderers side by side in headless Chromium (software WebGL), for tools/bench_web_viewer.py: each
// configuration loads the same decoded scene (an INRIA PLY), captures it from the given cameras and times
// its frames. The renderers come from NPM_DIR/node_modules (three and @sparkjsdev/spark, as web/ installs
// them; playcanvas for the comparison: `npm install --prefix NPM_DIR playcanvas@2.23.3`).
//
// usage: node web/tools/compare-renderers.mjs JOB.json, JOB = {chromium, ply, background, cameras: [{w2c,
// fx, fy, cx, cy, width, height}], configs: [{name, page ('spark' or 'playcanvas'), npm (NPM_DIR), options,
// out}]}.
// Prints one JSON line: per configuration {name, loadMs, frameMs, captured: [png paths]}; each config's
// captures are written as OUT_k.png.

import { createServer } from 'node:http';
import { readFileSync, writeFileSync } from 'node:fs';
import { extname, join, normalize } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const PAGES = fileURLToPath(new URL('./renderers/', import.meta.url));
const TYPES = { '.mjs': 'text/javascript', '.js': 'text/javascript', '.html': 'text/html' };
const ARGS = ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist', '--no-sandbox', '--disable-gpu-vsync', '--disable-frame-rate-limit'];
const FRAMES = 20;

function serve(job, npm) {
  const server = createServer((req, res) => {
    const path = normalize(decodeURIComponent(new URL(req.url, 'http://x').pathname));
    let file = null;
    if (path === '/scene.ply') file = job.ply;
    else if (path.startsWith('/npm/')) file = join(npm, 'node_modules', path.slice(5));
    else if (path.startsWith('/renderers/')) file = join(PAGES, path.slice(11));
    let data;
    try {
      data = readFileSync(file);
    } catch {
      res.writeHead(404);
      res.end();
      return;
    }
    res.writeHead(200, { 'content-type': TYPES[extname(file)] ?? 'application/octet-stream', 'content-length': data.length });
    res.end(data);
  });
  return new Promise((ok) => server.listen(0, '127.0.0.1', () => ok(server)));
}

const job = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const browser = await chromium.launch({ executablePath: job.chromium, args: ARGS });
const results = [];
try {
  const [first] = job.cameras;
  for (const config of job.configs) {
    const server = await serve(job, config.npm);
    const page = await browser.newPage({ viewport: { width: first.width, height: first.height }, deviceScaleFactor: 1 });
    const query = new URLSearchParams({ w: first.width, h: first.height, options: JSON.stringify(config.options ?? {}) });
    await page.goto(`http://127.0.0.1:${server.address().port}/renderers/${config.page}.html?${query}`);
    await page.waitForFunction(() => window.ready === true, null, { timeout: 120000 });
    await page.evaluate((rgb) => window.hook.setBackground(rgb), job.background);
    await page.evaluate((c) => window.hook.setCamera(c.w2c, c.fx, c.fy, c.cx, c.cy, c.width, c.height), first);
    const loadMs = await page.evaluate(() => window.hook.load('/scene.ply'));
    const captured = [];
    for (const [k, c] of job.cameras.entries()) {
      await page.evaluate((v) => window.hook.setCamera(v.w2c, v.fx, v.fy, v.cx, v.cy, v.width, v.height), c);
      const url = await page.evaluate(() => window.hook.capture());
      const png = `${config.out}_${k}.png`;
      writeFileSync(png, Buffer.from(url.slice(url.indexOf(',') + 1), 'base64'));
      captured.push(png);
    }
    const frameMs = await page.evaluate((n) => window.hook.frameTime(n), FRAMES);
    results.push({ name: config.name, loadMs, frameMs, captured });
    await page.close();
    server.close();
  }
  process.stdout.write(`${JSON.stringify(results)}\n`);
} finally {
  await browser.close();
}
