// Decoding speed in node: gspc-web's decodeGspc on .gspc files and, side by side, splat-transform's SPZ
// reader on the same scenes. Each measurement runs in a fresh node process: "cold" is the first decode
// (the JIT compiling as it goes, what a one-shot CLI or a new Web Worker pays), "warm" the median of the
// next ones. Times are wall clock and CPU (user + system, all of the process's threads); peak RSS is the
// process's, runtime and imports included.
//
// usage: node web/tools/bench-decode.mjs [--spz NPM_DIR] [--python PYTHON] [--runs N] SCENE.gspc[:SCENE.spz] ...
//   NPM_DIR: a folder where `npm install @playcanvas/splat-transform@3.7.0` ran (its reader is imported
//   from there; it is no dependency of gspc-web). PYTHON: an interpreter with gspc installed, whose
//   decoder (gspc.pipeline.decode_bytes, no restoration or refinement) is timed the same way, imports
//   excluded.

import { spawnSync } from 'node:child_process';
import { readFileSync, statSync } from 'node:fs';
import { basename, join } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

const SELF = fileURLToPath(import.meta.url);

async function decoderFor(kind, npmDir) {
  if (kind === 'gspc') {
    const { decodeGspc } = await import('../src/index.mjs');
    return async (bytes) => decodeGspc(bytes).count;
  }
  const entry = join(npmDir, 'node_modules', '@playcanvas', 'splat-transform', 'dist', 'index.mjs');
  const st = await import(pathToFileURL(entry).href);
  // The whole scene into columns, as a viewer or converter needs it.
  return async (bytes) => {
    const fs = new st.MemoryReadFileSystem();
    fs.set('scene.spz', bytes);
    const [source] = await st.readFile({ filename: 'scene.spz', inputFormat: 'spz', fileSystem: fs });
    const table = await st.materializeToDataTable(source, st.createChunkDataPool());
    source.close();
    return table.numRows;
  };
}

// The same measurement of gspc's Python decoder, run by PYTHON with the file and the run count.
const PYTHON_MEASURE = `
import json, resource, sys, time
from gspc.options import DecodeOptions
from gspc.pipeline import decode_bytes
data = open(sys.argv[1], "rb").read()
out = []
for _ in range(int(sys.argv[2])):
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    scene, _ = decode_bytes(data, DecodeOptions(restore=False, refine=False))
    out.append({"count": scene.num_gaussians, "wall": 1e3 * (time.perf_counter() - t0),
                "cpu": 1e3 * (time.process_time() - cpu0)})
out[-1]["rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
`;

/** In a child process: decode `path` `runs` times, print {count, wall, cpu} per run as JSON. */
async function measure(kind, path, runs, npmDir) {
  const bytes = new Uint8Array(readFileSync(path));
  const decode = await decoderFor(kind, npmDir);
  const out = [];
  for (let i = 0; i < runs; i++) {
    const cpu0 = process.cpuUsage();
    const t0 = performance.now();
    const count = await decode(bytes);
    const wall = performance.now() - t0;
    const cpu = process.cpuUsage(cpu0);
    out.push({ count, wall, cpu: (cpu.user + cpu.system) / 1000 });
  }
  out[out.length - 1].rss = process.resourceUsage().maxRSS / 1024;
  console.log(JSON.stringify(out));
}

function run(kind, path, runs, npmDir, python) {
  const res =
    kind === 'python'
      ? spawnSync(python, ['-c', PYTHON_MEASURE, path, String(runs)], { encoding: 'utf8', env: { ...process.env, GSPC_THREADS: '1' } })
      : spawnSync(process.execPath, [SELF, '--measure', kind, path, String(runs), npmDir ?? ''], { encoding: 'utf8' });
  if (res.status !== 0) throw new Error(`${kind} ${path}: ${res.stderr}`);
  const rows = JSON.parse(res.stdout);
  const median = (key) => rows.slice(1).map((r) => r[key]).sort((a, b) => a - b)[(rows.length - 2) >> 1];
  return {
    count: rows[0].count,
    bytes: statSync(path).size,
    cold: rows[0],
    warm: { wall: median('wall'), cpu: median('cpu') },
    rss: rows[rows.length - 1].rss,
  };
}

const FORMATS = { gspc: 'gspc (gspc-web, node)', python: 'gspc (gspc, Python)', spz: 'SPZ (splat-transform 3.7.0, node)' };

const rate = (count, ms) => `${((count / ms) * 1e3 / 1e6).toFixed(2)}`;

async function main(argv) {
  if (argv[0] === '--measure') return measure(argv[1], argv[2], Number(argv[3]), argv[4] || null);
  let npmDir = null;
  let python = null;
  let runs = 6;
  const scenes = [];
  for (let i = 0; i < argv.length; i++) {
    if (argv[i] === '--spz') npmDir = argv[++i];
    else if (argv[i] === '--python') python = argv[++i];
    else if (argv[i] === '--runs') runs = Number(argv[++i]);
    else scenes.push(argv[i]);
  }
  console.log('| scene | format | Gaussians | bytes | cold ms (CPU ms) | warm ms (CPU ms) | cold M G/s (CPU) | warm M G/s (CPU) | peak RSS MB |');
  console.log('|---|---|---:|---:|---:|---:|---:|---:|---:|');
  for (const scene of scenes) {
    const [gspc, spz] = scene.split(':');
    const cases = [['gspc', gspc], ...(python ? [['python', gspc]] : []), ...(spz && npmDir ? [['spz', spz]] : [])];
    for (const [kind, path] of cases) {
      const r = run(kind, path, runs, npmDir, python);
      console.log(
        `| ${basename(gspc, '.gspc')} | ${FORMATS[kind]} | ${r.count} | ${r.bytes} | ` +
          `${r.cold.wall.toFixed(0)} (${r.cold.cpu.toFixed(0)}) | ${r.warm.wall.toFixed(0)} (${r.warm.cpu.toFixed(0)}) | ` +
          `${rate(r.count, r.cold.wall)} (${rate(r.count, r.cold.cpu)}) | ${rate(r.count, r.warm.wall)} (${rate(r.count, r.warm.cpu)}) | ` +
          `${r.rss.toFixed(0)} |`,
      );
    }
  }
  return undefined;
}

await main(process.argv.slice(2));
