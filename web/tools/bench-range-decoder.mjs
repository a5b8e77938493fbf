// The range decoder alone: ns per symbol of src/rangeDecoder.mjs (64-bit state as two binary64 parts, the
// symbol searched within its table's 256-slot index) against the spec's arithmetic in BigInt with a plain
// bisection (test/specDecoder.mjs), on pseudo-random words with a uniform table of S symbols (the worst case
// for the symbol search). Both must give the same symbols.
//
// usage: node web/tools/bench-range-decoder.mjs [S ...]   (default: 16 1024)

import { RangeDecoder } from '../src/rangeDecoder.mjs';
import { tableFromStarts } from '../src/models.mjs';
import { SpecDecoder } from '../test/specDecoder.mjs';

const SYMBOLS = 2 ** 20;
const words = Uint8Array.from({ length: 4 * SYMBOLS }, (_, i) => Math.imul(i, 2654435761) >>> 24);

for (const size of (process.argv.length > 2 ? process.argv.slice(2) : ['16', '1024']).map(Number)) {
  const starts = Array.from({ length: size + 1 }, (_, i) => Math.round((i * 2 ** 24) / size));
  const table = tableFromStarts(starts);
  const results = [];
  for (const [name, make, decode] of [
    ['binary64 parts', () => new RangeDecoder(words), (d) => d.decode(table, size)],
    ['BigInt (spec)', () => new SpecDecoder(words), (d) => d.decode(starts)],
  ]) {
    let best = Infinity;
    let sum = 0;
    for (let rep = 0; rep < 3; rep++) {
      const dec = make();
      sum = 0;
      const cpu0 = process.cpuUsage();
      for (let i = 0; i < SYMBOLS; i++) sum += decode(dec);
      const cpu = process.cpuUsage(cpu0);
      best = Math.min(best, ((cpu.user + cpu.system) * 1000) / SYMBOLS);
    }
    results.push(sum);
    console.log(`S = ${size}: ${name}: ${best.toFixed(0)} ns per symbol (best of 3, CPU)`);
  }
  if (results[0] !== results[1]) throw new Error('the two decoders disagree');
}
