// The worked examples of spec 10.0: the range decoder's table, the probability-table example and the kind-2
// ratios; and the refusals of the range decoder and of model specs.

import test from 'node:test';
import assert from 'node:assert/strict';
import { RangeDecoder } from '../src/rangeDecoder.mjs';
import { readModels, ratio, tableFromStarts, tableOf, TableBudget } from '../src/models.mjs';
import { CodecError } from '../src/errors.mjs';
import { msgpack } from './writer.mjs';
import { SpecDecoder } from './specDecoder.mjs';

const hex = (s) => BigInt(`0x${s}`);
/** The frequencies of a table of `size` symbols (its starts, then its slots). */
const frequencies = (table, size) => Array.from(table.subarray(1, size + 1), (c, i) => c - table[i]);

/** The single spec `spec` of a one-column model list (every bucket the same spec). */
function specTable(spec) {
  const models = readModels(msgpack([[0, Array(15).fill(spec)]]), 1, [new TableBudget(2 ** 30, 'test')]);
  return tableOf(models[0].specs[0]);
}

test('range decoder: the worked example of spec 10.0, state after every step', () => {
  const a = tableFromStarts([0, 4194304, 12582912, 16777216]);
  const b = tableFromStarts([0, 1, 16777215, 16777216]);
  const dec = new RangeDecoder(Uint8Array.of(0x7f, 0x00, 0x00, 0x40, 0x01, 0xe0, 0xbf, 0xfe));
  const start = dec.state();
  assert.equal(start.range, hex('ffffffffffffffff'));
  assert.equal(start.offset, hex('4000007ffebfe001'));
  const steps = [
    [a, 1, '3fffffffffc00000', '7fffffffff800000', '4000007ffebfe001'],
    [b, 0, '3fffffffffc00000', '0000007fffffffff', '4000007ffebfe001'],
    [b, 2, 'febf800100000000', '00007fff00000000', 'febfe00100000000'],
    [a, 2, 'febfe00040000000', '00001fffc0000000', 'febfe00100000000'],
    [a, 0, 'febfe00040000000', '000007fff0000000', 'febfe00100000000'],
  ];
  for (const [table, symbol, lower, range, point] of steps) {
    assert.equal(dec.decode(table, 3), symbol);
    const state = dec.state();
    assert.equal(state.range, hex(range));
    assert.equal(state.offset, (hex(point) - hex(lower)) & (2n ** 64n - 1n));
  }
});

test('range decoder: a quantile of 2^24 is refused; missing words read as 0', () => {
  const ff = new RangeDecoder(new Uint8Array(8).fill(0xff));
  const half = tableFromStarts([0, 8388608, 16777216]);
  assert.throws(() => ff.decode(half, 2), CodecError);
  const empty = new RangeDecoder(new Uint8Array(0));
  assert.equal(empty.decode(half, 2), 0);
  // The example's words read big-endian decode other symbols: the same first one (spec 10.0 says otherwise:
  // its quantile 0x7f0000 falls in A's symbol 1 as 0x400000 does), then 1 where the example has 0.
  const a = tableFromStarts([0, 4194304, 12582912, 16777216]);
  const b = tableFromStarts([0, 1, 16777215, 16777216]);
  const swapped = new RangeDecoder(Uint8Array.of(0x40, 0x00, 0x00, 0x7f, 0xfe, 0xbf, 0xe0, 0x01));
  assert.deepEqual([a, b].map((t) => swapped.decode(t, 3)), [1, 1]);
});

test('probability tables: the example [3, 0, 2, 1, 2, 1] of spec 10.0', () => {
  const cum = specTable([3, 0, 2, 1, 2, 1]);
  assert.deepEqual(frequencies(cum, 3), [4194304, 8388608, 4194304]);
  assert.deepEqual(Array.from(cum.subarray(0, 3)), [0, 4194304, 12582912]);
  assert.deepEqual(frequencies(specTable([3, 0, 2, 0, 1, 0]), 3), [1, 16777214, 1]);
});

/** Kind 2's frequencies by the spec's formulas, in BigInt: an independent check of models.mjs. */
function geometricFrequencies([, lo, hi, c, u, b]) {
  const boosts = [1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, 362, 512, 724, 1024, 1448, 2048];
  let m = 2n ** 20n;
  for (let i = 0; i < u; i++) m = (m * 60097n) >> 16n;
  const theta = 1 - Number(m) / 2 ** 20;
  const p = [1];
  for (let d = 1; d <= Math.max(c - lo, hi - c); d++) p.push(p[d - 1] * theta);
  const w = [];
  for (let x = lo; x <= hi; x++) w.push(x === c ? (2n ** 30n * BigInt(boosts[b])) >> 3n : BigInt(Math.max(Math.floor(p[Math.abs(x - c)] * 2 ** 30), 1)));
  const total = w.reduce((x, y) => x + y, 0n);
  const size = BigInt(w.length);
  const f = w.map((x) => 1n + (x * (2n ** 24n - size)) / total);
  const top = w.reduce((best, x, i) => (x > w[best] ? i : best), 0);
  f[top] += 2n ** 24n - f.reduce((x, y) => x + y, 0n);
  return f.map(Number);
}

test('probability tables: kind 2 ratios, and tables as the spec computes them', () => {
  assert.equal(ratio(0), 2 ** 20);
  assert.equal(ratio(1), 961552);
  assert.equal(ratio(2), 881750);
  assert.deepEqual([ratio(128), ratio(129), ratio(130)], [10, 9, 8]);
  const specs = [[2, -5, 5, 0, 3, 0], [2, -100, 40, -7, 130, 21], [2, 0, 1000, 1000, 60, 9], [2, -3, 3, 0, 0, 0], [2, -4000, 4000, 17, 1, 5]];
  for (const spec of specs) {
    const f = frequencies(specTable(spec), spec[2] - spec[1] + 1);
    assert.equal(f.reduce((x, y) => x + y, 0), 2 ** 24);
    assert.ok(f.every((x) => x >= 1));
    assert.deepEqual(f, geometricFrequencies(spec), JSON.stringify(spec));
  }
});

test('probability tables: weights near 2^39 over a wide window (sums past 2^53) stay exact', () => {
  const size = 2 ** 15;
  const weights = Array.from({ length: size }, (_, i) => 2 ** 39 - 1 - (i % 7));
  const f = frequencies(specTable([3, 0, size - 1, ...weights]), size);
  const total = weights.reduce((x, y) => x + BigInt(y), 0n);
  const want = weights.map((w) => 1n + (BigInt(w) * BigInt(2 ** 24 - size)) / total);
  const shortfall = 2n ** 24n - want.reduce((x, y) => x + y, 0n);
  want[0] += shortfall; // the first largest weight
  assert.deepEqual(f, want.map(Number));
});

test('model specs: every rule of spec 10.0 refused by name', () => {
  const cases = [
    [[2, 0, 9, 0, -1, 0], 'ratio'],
    [[2, 0, 9, 0, 131, 0], 'ratio'],
    [[2, 0, 9, 0, 3, 22], 'boost'],
    [[2, 0, 9, 2 ** 40, 3, 0], 'centre'],
    [[7], 'kind'],
    [[3, 0, 3, 1, 1], 'weights'],
    [[1, 2 ** 50], '2^48'],
    [[3, 5, 5, 1], 'window'],
    [[2, 0, 2 ** 22, 0, 3, 0], 'window'],
    [[3, 0, 1, 0, 0], 'positive'],
    [[3, 0, 1, 2 ** 39, 1], 'weight'],
    [[1], 'integers'],
    [[0, 1], 'integers'],
    [[2, 0, 9, 0, 3], 'integers'],
    [[1, 1.5], 'integer'],
  ];
  for (const [spec, words] of cases) {
    assert.throws(
      () => readModels(msgpack([[0, Array(15).fill(spec)]]), 1, [new TableBudget(2 ** 30, 'test')]),
      (err) => err instanceof CodecError && err.message.includes(words),
      `${JSON.stringify(spec)} should be refused naming '${words}'`,
    );
  }
  assert.throws(() => readModels(msgpack([[2, Array(15).fill([1, 0])]]), 1, []), /prediction mode/);
  assert.throws(() => readModels(msgpack([[0, Array(15).fill([1, 0])], [4, Array(15).fill([1, 0])]]), 2, []), /prediction mode/);
  assert.throws(() => readModels(msgpack([[0, Array(14).fill([1, 0])]]), 1, []), /15 model specs/);
  const trailing = Uint8Array.of(...msgpack([[0, Array(15).fill([1, 0])]]), 0xc0);
  assert.throws(() => readModels(trailing, 1, []), /after/);
});

test('model tables: the windows of one matrix are bounded before any table is built', () => {
  const wide = [2, 0, 2 ** 22 - 1, 0, 3, 0];
  const budget = new TableBudget(2 ** 22, 'matrix');
  assert.throws(() => readModels(msgpack([[0, [wide, [2, 0, 1, 0, 3, 0], ...Array(13).fill([1, 0])]]]), 1, [budget]), /table entries/);
  const ok = readModels(msgpack([[0, [wide, ...Array(14).fill([1, 0])]]]), 1, [new TableBudget(2 ** 22, 'matrix')]);
  assert.equal(ok[0].specs[0].cum, null, 'no table is built before a row needs it');
});

test('range decoder: the same symbols and states as the spec written in BigInt, over random words', () => {
  let seed = 12345;
  const random = () => {
    seed = (Math.imul(seed, 1103515245) + 12345) >>> 0;
    return seed / 2 ** 32;
  };
  // tables with tiny, huge and uneven frequencies
  const tables = [[0, 1, 2 ** 24 - 1, 2 ** 24], [0, 2 ** 23, 2 ** 24], [0, 3, 700, 70000, 9000000, 2 ** 24 - 2, 2 ** 24]];
  for (let s = 0; s < 4; s++) {
    const size = 2 + Math.floor(random() * 300);
    const cuts = new Set([0, 2 ** 24]);
    while (cuts.size < size + 1) cuts.add(1 + Math.floor(random() ** 3 * (2 ** 24 - 1)));
    tables.push([...cuts].sort((x, y) => x - y));
  }
  for (let trial = 0; trial < 20; trial++) {
    const words = Uint8Array.from({ length: 4 * (2 + Math.floor(random() * 64)) }, () => Math.floor(random() * 256));
    const ours = new RangeDecoder(words);
    const spec = new SpecDecoder(words);
    for (let k = 0; k < 400; k++) {
      const starts = tables[Math.floor(random() * tables.length)];
      let want;
      try {
        want = spec.decode(starts);
      } catch {
        assert.throws(() => ours.decode(tableFromStarts(starts), starts.length - 1), CodecError);
        break;
      }
      assert.equal(ours.decode(tableFromStarts(starts), starts.length - 1), want);
      const state = ours.state();
      assert.equal(state.range, spec.range);
      assert.equal(state.offset, (spec.point - spec.lower) & (2n ** 64n - 1n));
    }
  }
});
