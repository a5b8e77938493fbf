// POSN (spec 10.1): Gaussian positions as a curve of Morton codes on a voxel grid, each code the running sum
// of gaps whose bit lengths are an entropy-coded matrix and whose lower bits are raw bits; the grid is a
// plain box (version 1) or lies in contracted space (versions 2 and 3), where a far set may follow on a
// coarser grid (version 3).
//
// Codes reach 2^63 (21 bits per axis), past binary64's exact integers, so they are kept as two 32-bit
// halves; the sum of a code below 2^63 and a gap below 2^63 never wraps 64 bits.

import { CodecError } from './errors.mjs';
import { decodeEcm, readBinArray, readEcm } from './ecm.mjs';
import { pow2 } from './dequantise.mjs';

const TWO32 = 2 ** 32;

// Morton deinterleave of 9 code bits (3 voxel bits per axis): entry = x | y << 3 | z << 6.
const DEINTERLEAVE9 = (() => {
  const t = new Uint16Array(512);
  for (let c = 0; c < 512; c++) {
    let out = 0;
    for (let i = 0; i < 3; i++) {
      for (let a = 0; a < 3; a++) out |= ((c >> (3 * i + a)) & 1) << (3 * a + i);
    }
    t[c] = out;
  }
  return t;
})();

/** One axis's 21 voxel bits from seven deinterleaved 9-bit groups (`s`: 0 x, 3 y, 6 z). */
function gather(t0, t1, t2, t3, t4, t5, t6, s) {
  return (
    ((t0 >> s) & 7) |
    (((t1 >> s) & 7) << 3) |
    (((t2 >> s) & 7) << 6) |
    (((t3 >> s) & 7) << 9) |
    (((t4 >> s) & 7) << 12) |
    (((t5 >> s) & 7) << 15) |
    (((t6 >> s) & 7) << 18)
  );
}

/** MSB-first reader of the raw bits (spec 10.0 "Raw bits"). */
class BitReader {
  constructor(bytes) {
    this.bytes = bytes;
    this.bit = 0;
  }

  /** The next k bits (k <= 32) as an unsigned number. */
  read(k) {
    let v = 0;
    const bytes = this.bytes;
    while (k > 0) {
      const byte = bytes[this.bit >>> 3];
      const used = this.bit & 7;
      const take = Math.min(k, 8 - used);
      const bits = (byte >>> (8 - used - take)) & ((1 << take) - 1);
      v = v * (1 << take) + bits;
      this.bit += take;
      k -= take;
    }
    return v;
  }
}

/**
 * Decode one curve of `count` codes on `bits` bits per axis from its `classes` ECM and `raw` bits, calling
 * `emit(i, vx, vy, vz)` with each voxel in curve order.
 */
function decodeCurve(classesBin, raw, count, bits, what, emit) {
  const ecm = readEcm(classesBin, count, 1, `POSN ${what} classes`);
  const maxLength = 3 * bits;
  const lengths = new Uint8Array(count);
  let total = 0;
  decodeEcm(
    ecm,
    (_, q) => {
      for (let i = 0; i < count; i++) {
        const l = q[i];
        if (!(l >= 0 && l <= maxLength)) throw new CodecError(`POSN ${what} gap length ${l} is outside 0..${maxLength}`);
        lengths[i] = l;
        if (l >= 2) total += l - 1;
      }
    },
    `POSN ${what} classes`,
  );
  const bytes = Math.ceil(total / 8);
  if (raw.length !== bytes) {
    throw new CodecError(`POSN ${what} raw-bit string is ${raw.length} bytes; its ${total} bits need ${bytes}`);
  }
  if (total % 8 && (raw[bytes - 1] & ((1 << (8 - (total % 8))) - 1)) !== 0) {
    throw new CodecError(`POSN ${what} raw-bit string has non-zero padding bits`);
  }
  // Codes must stay below 2^(3 bits): with 3 bits >= 32, the high half below 2^(3 bits - 32).
  const hiLimit = maxLength >= 32 ? 2 ** (maxLength - 32) : 0;
  const loLimit = maxLength >= 32 ? 0 : 2 ** maxLength;
  const reader = new BitReader(raw);
  let hi = 0;
  let lo = 0;
  for (let i = 0; i < count; i++) {
    const l = lengths[i];
    if (l > 0) {
      // d = 2^(l - 1) + the l - 1 bits below the leading one.
      const k = l - 1;
      let dHi = 0;
      let dLo;
      if (k <= 32) {
        dLo = reader.read(k);
      } else {
        dHi = reader.read(k - 32);
        dLo = reader.read(32);
      }
      if (k < 32) dLo += 2 ** k;
      else dHi += 2 ** (k - 32);
      lo += dLo;
      hi += dHi;
      if (lo >= TWO32) {
        lo -= TWO32;
        hi += 1;
      }
      if (maxLength >= 32 ? hi >= hiLimit : hi > 0 || lo >= loLimit) {
        throw new CodecError(`POSN ${what} code ${i} runs past 2^${maxLength} (${bits} bits per axis)`);
      }
    }
    const c3 = (lo >>> 27) | ((hi & 15) << 5);
    const t0 = DEINTERLEAVE9[lo & 511];
    const t1 = DEINTERLEAVE9[(lo >>> 9) & 511];
    const t2 = DEINTERLEAVE9[(lo >>> 18) & 511];
    const t3 = DEINTERLEAVE9[c3];
    const t4 = DEINTERLEAVE9[(hi >>> 4) & 511];
    const t5 = DEINTERLEAVE9[(hi >>> 13) & 511];
    const t6 = DEINTERLEAVE9[(hi >>> 22) & 511];
    emit(i, gather(t0, t1, t2, t3, t4, t5, t6, 0), gather(t0, t1, t2, t3, t4, t5, t6, 3), gather(t0, t1, t2, t3, t4, t5, t6, 6));
  }
}

/**
 * Positions of the `n` Gaussians (Float32Array n x 3) from the POSN `payload` on the grid `grid` (from
 * readAttributeSection). The grid's bounds were checked with the header.
 */
export function decodePositions(payload, grid, n) {
  const far = grid.far;
  const bins = readBinArray(payload, far ? 4 : 2, 'POSN');
  const means = new Float32Array(3 * n);
  const place = grid.contraction ? contractedPlacer(grid, means) : plainPlacer(grid, means);
  const near = far ? n - far.count : n;
  decodeCurve(bins[0], bins[1], near, grid.bits, 'curve', (i, x, y, z) => place(i, x, y, z));
  if (far) {
    const scale = pow2(far.shift);
    decodeCurve(bins[2], bins[3], far.count, grid.bits - far.shift, 'far set', (i, x, y, z) =>
      place(near + i, x * scale, y * scale, z * scale),
    );
  }
  return means;
}

function plainPlacer(grid, means) {
  const [l0, l1, l2] = grid.lo;
  const [s0, s1, s2] = grid.step;
  return (i, x, y, z) => {
    means[3 * i] = l0 + x * s0;
    means[3 * i + 1] = l1 + y * s1;
    means[3 * i + 2] = l2 + z * s2;
  };
}

function contractedPlacer(grid, means) {
  const [l0, l1, l2] = grid.lo;
  const [s0, s1, s2] = grid.step;
  const [c0, c1, c2] = grid.contraction.centre;
  const radius = grid.contraction.radius;
  return (i, x, y, z) => {
    const y0 = l0 + x * s0;
    const y1 = l1 + y * s1;
    const y2 = l2 + z * s2;
    const rho = Math.sqrt(y0 * y0 + y1 * y1 + y2 * y2);
    let u0 = y0;
    let u1 = y1;
    let u2 = y2;
    if (rho > 1) {
      const e = Math.floor(rho - 1);
      const f = rho - 1 - e;
      const r = (1 + f) * pow2(e);
      const s = r / rho;
      u0 = y0 * s;
      u1 = y1 * s;
      u2 = y2 * s;
    }
    means[3 * i] = c0 + radius * u0;
    means[3 * i + 1] = c1 + radius * u1;
    means[3 * i + 2] = c2 + radius * u2;
  };
}
