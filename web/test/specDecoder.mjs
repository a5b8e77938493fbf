// The range decoder of spec 10.0 transcribed as the spec writes it: lower, range and point as BigInt
// (unsigned 64-bit, wrap-around written out), the symbol found by bisection of the table's starts. The
// reference the tests compare src/rangeDecoder.mjs with, and the baseline of tools/bench-range-decoder.mjs.

import { CodecError } from '../src/errors.mjs';

const MASK = 2n ** 64n - 1n;

export class SpecDecoder {
  constructor(words) {
    this.words = new DataView(words.buffer, words.byteOffset, words.byteLength);
    this.pos = 0;
    this.lower = 0n;
    this.range = 2n ** 64n - 1n;
    this.point = (BigInt(this.next()) << 32n) + BigInt(this.next());
  }

  next() {
    if (this.pos + 4 > this.words.byteLength) return 0;
    this.pos += 4;
    return this.words.getUint32(this.pos - 4, true);
  }

  /** The next symbol's index in the table of starts `starts` (S + 1 numbers, 0 first, 2^24 last). */
  decode(starts) {
    const scale = this.range >> 24n;
    const quantile = ((this.point - this.lower) & MASK) / scale;
    if (quantile >= 2n ** 24n) throw new CodecError('quantile');
    const q = Number(quantile);
    let i = 0;
    let end = starts.length - 1;
    while (end - i > 1) {
      const mid = (i + end) >>> 1;
      if (starts[mid] <= q) i = mid;
      else end = mid;
    }
    this.lower = (this.lower + scale * BigInt(starts[i])) & MASK;
    this.range = scale * BigInt(starts[i + 1] - starts[i]);
    if (this.range < 2n ** 32n) {
      this.lower = (this.lower << 32n) & MASK;
      this.range <<= 32n;
      this.point = ((this.point << 32n) & MASK) + BigInt(this.next());
    }
    return i;
  }
}
