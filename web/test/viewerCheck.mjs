// Drives the viewer (web/viewer) in headless Chromium for tests/test_browser.py: playwright-core from
// web/node_modules, with the Chromium at the given path (no browser is downloaded), on a software WebGL
// (SwiftShader: CI machines have no GPU).
//
// usage: node web/test/viewerCheck.mjs JOBS.json, JOBS = {chromium, jobs: [{url, cameras: [{w2c (16,
// row-major OpenCV world-to-camera), fx, fy, cx, cy, width, height, png}], expectError}]}. Prints one JSON
// line: per job {shown ({tiles, count, seconds}), status (the page's progress line), digests, seconds (from
// opening the page to the last tile), captured (PNG paths written)} or, with expectError, {error (the
// page's message), lines (its line count), responsive (the page still ran a script after it)}.

import { readFileSync, writeFileSync } from 'node:fs';
import { chromium } from 'playwright-core';

const SHOWN_TIMEOUT_MS = 600000;
const ARGS = ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist', '--no-sandbox'];

async function runJob(browser, job) {
  const page = await browser.newPage({ viewport: { width: 640, height: 480 }, deviceScaleFactor: 1 });
  const problems = [];
  page.on('pageerror', (err) => problems.push(err.message));
  const start = Date.now();
  try {
    await page.goto(job.url);
    await page.waitForFunction(() => window.gspcViewer !== undefined, null, { timeout: 60000 });
    const outcome = await page.evaluate(
      (ms) =>
        Promise.race([
          window.gspcViewer.shown.then((shown) => ({ shown }), (err) => ({ failed: String(err && err.message) })),
          new Promise((resolve) => setTimeout(() => resolve({ timedOut: true }), ms)),
        ]),
      SHOWN_TIMEOUT_MS,
    );
    const seconds = (Date.now() - start) / 1000;
    const error = await page.evaluate(() => {
      const box = document.getElementById('error');
      return box.hidden ? null : box.textContent;
    });
    if (job.expectError) {
      const responsive = await page.evaluate(() => new Promise((resolve) => requestAnimationFrame(() => resolve(true))));
      return { error, lines: error === null ? 0 : error.split('\n').length, failed: outcome.failed ?? null, responsive, problems };
    }
    if (!outcome.shown) return { error, outcome, problems };
    const status = await page.evaluate(() => document.getElementById('status').textContent);
    const digests = await page.evaluate(() => window.gspcViewer.digests().catch(() => null)); // null without digest=1
    const captured = [];
    for (const c of job.cameras) {
      await page.evaluate((v) => window.gspcViewer.setCamera(v.w2c, v.fx, v.fy, v.cx, v.cy, v.width, v.height), c);
      const url = await page.evaluate(() => window.gspcViewer.capture());
      writeFileSync(c.png, Buffer.from(url.slice(url.indexOf(',') + 1), 'base64'));
      captured.push(c.png);
    }
    return { shown: outcome.shown, status, digests, seconds, captured, error, problems };
  } finally {
    await page.close();
  }
}

const spec = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const browser = await chromium.launch({ executablePath: spec.chromium, args: ARGS });
try {
  const results = [];
  for (const job of spec.jobs) results.push(await runJob(browser, job));
  process.stdout.write(`${JSON.stringify(results)}\n`);
} finally {
  await browser.close();
}
