// Mutate the conformance vectors and decode them: every outcome must be a scene or a GspcError (never
// another exception), and no decode may run long. Two kinds of mutation, alternating: bytes of one chunk's
// payload with the container rebuilt around it (valid checksums, so the codec sees the damage), and bytes of
// the header with its checksum and the file's repaired.
//
// usage: node web/tools/fuzz.mjs [SEED] [SECONDS]

import { readFileSync, readdirSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { GspcError, decodeGspc, readContainer } from '../src/index.mjs';
import { crc32 } from '../src/crc32.mjs';
import { gspcFile } from '../test/writer.mjs';

const DIR = fileURLToPath(new URL('../../spec/vectors/', import.meta.url));
const SLOW_MS = 2000;
const files = readdirSync(DIR).filter((f) => f.endsWith('.gspc'));
const decodable = files.filter((f) => f.startsWith('codec_') && !f.includes('invalid'));

let seed = Number(process.argv[2] ?? 1) >>> 0;
const random = () => {
  seed = (Math.imul(seed, 1103515245) + 12345) >>> 0;
  return seed / 2 ** 32;
};
const pick = (list) => list[Math.floor(random() * list.length)];

function mutate(bytes, from, to) {
  for (let i = 1 + Math.floor(random() * 4); i > 0 && to > from; i--) {
    const at = from + Math.floor(random() * (to - from));
    bytes[at] = random() < 0.5 ? bytes[at] ^ (1 << Math.floor(random() * 8)) : Math.floor(random() * 256);
  }
}

/** A decodable vector with one chunk's payload damaged (or cut short), in a valid container. */
function payloadCase() {
  const c = readContainer(new Uint8Array(readFileSync(DIR + pick(decodable))));
  const chunks = c.chunks.map((ch) => ({ type: ch.type, index: ch.index, flags: ch.flags, payload: ch.payload.slice() }));
  const chunk = pick(chunks);
  if (random() < 0.2) chunk.payload = chunk.payload.subarray(0, Math.floor(random() * chunk.payload.length));
  else mutate(chunk.payload, 0, chunk.payload.length);
  return gspcFile(c.metaTree, chunks, { major: c.version[0], minor: c.version[1] });
}

/** Any vector with header bytes damaged and the header's and the file's checksums repaired. */
function headerCase() {
  const bytes = new Uint8Array(readFileSync(DIR + pick(files)));
  if (bytes.length < 28) return bytes;
  const view = new DataView(bytes.buffer);
  const length = view.getUint32(12, true);
  if (20 + length > bytes.length - 8) return bytes;
  mutate(bytes, 20, 20 + length);
  view.setUint32(16, crc32(bytes.subarray(20, 20 + length)), true);
  view.setUint32(bytes.length - 4, crc32(bytes.subarray(0, bytes.length - 4)), true);
  return bytes;
}

const outcomes = {};
const seconds = Number(process.argv[3] ?? 30);
const start = Date.now();
let runs = 0;
while (Date.now() - start < seconds * 1000) {
  const bytes = runs % 2 ? headerCase() : payloadCase();
  const t0 = Date.now();
  let outcome = 'decoded';
  try {
    decodeGspc(bytes);
  } catch (err) {
    if (!(err instanceof GspcError)) {
      console.log(`not a GspcError after ${runs} runs: ${err.stack}`);
      process.exit(1);
    }
    outcome = err.name;
  }
  if (Date.now() - t0 > SLOW_MS) console.log(`a decode took ${Date.now() - t0} ms (run ${runs})`);
  outcomes[outcome] = (outcomes[outcome] ?? 0) + 1;
  runs++;
}
console.log(`${runs} mutated files in ${seconds} s:`, outcomes);
