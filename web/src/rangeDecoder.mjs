// The range decoder of spec 10.0 (constriction's: 32-bit words, 64-bit state, 24-bit probabilities), in
// binary64 arithmetic with no BigInt.
//
// The spec's state is three unsigned 64-bit integers: lower, range and point. Only d = (point - lower) mod
// 2^64 and range decide a symbol, and once the first quantile check has passed, d < range holds after every
// step, so neither ever wraps: after a symbol d' = d - scale F_i lies in [0, scale f_i) = [0, range'), and
// a renormalisation shifts a d' below 2^32 by 32 bits. Each is kept as a high part (bits 24 and up, below
// 2^40) and a low part (the low 24 bits). Then scale = range >> 24 is the high part of range, the quantile
// check is hi(d) < scale, and every product below stays under 2^53, exact in binary64.

import { CodecError } from './errors.mjs';
import { PROBABILITY_BITS } from './limits.mjs';
import { SLOT_BITS } from './models.mjs';

const SLOT_SHIFT = PROBABILITY_BITS - SLOT_BITS;

const TWO24 = 2 ** 24;
const INV24 = 2 ** -24;

export class RangeDecoder {
  /** `words`: the bytes of the ECM's `words` (a multiple of 4 long, u32 little-endian). */
  constructor(words) {
    this.words = words;
    this.pos = 0;
    // Every state field holds a binary64 from the start (never a small integer first), so the object keeps
    // one shape and optimised code is not thrown away when a field's first double arrives.
    this.dHi = 0.5;
    this.dLo = 0.5;
    this.rHi = 0.5;
    this.rLo = 0.5;
    const w1 = this.nextWord();
    const w2 = this.nextWord();
    // d = point - lower = w1 2^32 + w2; range = 2^64 - 1.
    this.dHi = w1 * 256 + (w2 >>> 24);
    this.dLo = w2 & 0xffffff;
    this.rHi = 2 ** 40 - 1; // (2^64 - 1) >> 24
    this.rLo = 0xffffff;
  }

  /** The next unread word, or 0 once every word has been read (spec 10.0: not an error). */
  nextWord() {
    const w = this.words;
    const p = this.pos;
    if (p + 4 > w.length) return 0;
    this.pos = p + 4;
    return (w[p] | (w[p + 1] << 8) | (w[p + 2] << 16) | (w[p + 3] << 24)) >>> 0;
  }

  /**
   * Decode one symbol of the table `cum` of `size` (S) symbols and return its index i (cum[i] <= quantile <
   * cum[i + 1]). CodecError when the quantile is 2^24 or more. `cum` holds S + 1 starts (cum[0] = 0, cum[S]
   * = 2^24), then 2^SLOT_BITS + 1 slots: slot j is the symbol containing the quantile j 2^(24 - SLOT_BITS),
   * the last S - 1 (models.mjs).
   */
  decode(cum, size) {
    const scale = this.rHi;
    const dHi = this.dHi;
    const dLo = this.dLo;
    // quantile >= 2^24 exactly when d >= scale 2^24, that is hi(d) >= scale.
    if (dHi >= scale) throw new CodecError('range decoder: quantile of 2^24 or more (corrupt words)');
    // scale = sA 2^24 + sB.
    const sA = Math.floor(scale * INV24);
    const sB = scale - sA * TWO24;
    // quantile = floor(d / scale): the binary64 quotient is within 2^-28 of d / scale (d rounds to 53 bits,
    // the quotient is below 2^24), so its floor is off by at most one; the remainder d - quantile scale,
    // an integer below 2^41 in magnitude, is exact and corrects it.
    let quantile = Math.floor((dHi * TWO24 + dLo) / scale);
    let rem = (dHi - quantile * sA) * TWO24 + (dLo - quantile * sB);
    if (rem < 0) {
      quantile -= 1;
      rem += scale;
    } else if (rem >= scale) {
      quantile += 1;
      rem -= scale;
    }
    // The symbol: the largest i with cum[i] <= quantile, among the symbols of the quantile's slot.
    const slot = size + 1 + (quantile >>> SLOT_SHIFT);
    let lo = cum[slot];
    let hi = cum[slot + 1] + 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >>> 1;
      if (cum[mid] <= quantile) lo = mid;
      else hi = mid;
    }
    const start = cum[lo];
    const freq = cum[lo + 1] - start;
    // d' = (quantile - start) scale + rem and range' = freq scale, as high and low parts.
    const t = quantile - start;
    const x = t * sB + rem;
    const xHi = Math.floor(x * INV24);
    let nHi = t * sA + xHi;
    let nLo = x - xHi * TWO24;
    const y = freq * sB;
    const yHi = Math.floor(y * INV24);
    let rHi = freq * sA + yHi;
    let rLo = y - yHi * TWO24;
    if (rHi < 256) {
      // range < 2^32: shift range and d left by 32 bits, a new word entering d's low bits.
      const range = rHi * TWO24 + rLo;
      const d = nHi * TWO24 + nLo;
      const w = this.nextWord();
      rHi = range * 256;
      rLo = 0;
      nHi = d * 256 + (w >>> 24);
      nLo = w & 0xffffff;
    }
    this.dHi = nHi;
    this.dLo = nLo;
    this.rHi = rHi;
    this.rLo = rLo;
    return lo;
  }

  /** {range, offset}: range and (point - lower) mod 2^64 as BigInt, for tests against the spec's table. */
  state() {
    const big = (hi, lo) => (BigInt(hi) << 24n) + BigInt(lo);
    return { range: big(this.rHi, this.rLo), offset: big(this.dHi, this.dLo) };
  }
}
