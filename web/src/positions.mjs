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

// 2^0 .. 2^40, exact.
const POW2 = Float64Array.from({ length: 41 }, (_, k) => 2 ** k);

/** `k` (0..32) bits of the MSB-first bit string `raw` (spec 10.0 "Raw bits") from bit `pos`, as a number;
 * `raw` is padded with at least 5 zero bytes past its end. */
function bitsAt(raw, pos, k) {
  const i = pos >>> 3;
  const window = raw[i] * TWO32 + (((raw[i + 1] << 24) | (raw[i + 2] << 16) | (raw[i + 3] << 8) | raw[i + 4]) >>> 0);
  const bits = Math.floor(window / POW2[40 - (pos & 7) - k]);
  return bits - Math.floor(bits / POW2[k]) * POW2[k];
}

/**
 * The voxels (Uint32Array count x 3, curve order) of one curve of `count` codes on `bits` bits per axis,
 * from its `classes` ECM and `raw` bits.
 */
function decodeCurve(classesBin, raw, count, bits, what, tile) {
  const ecm = readEcm(classesBin, count, 1, `POSN ${what} classes`, null, tile);
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
  const padded = new Uint8Array(bytes + 8);
  padded.set(raw);
  // Codes must stay below 2^(3 bits): with 3 bits >= 32, the high half below 2^(3 bits - 32).
  const hiLimit = maxLength >= 32 ? POW2[maxLength - 32] : 0;
  const loLimit = maxLength >= 32 ? 0 : POW2[maxLength];
  const voxels = new Uint32Array(3 * count);
  let pos = 0;
  let hi = 0;
  let lo = 0;
  for (let i = 0; i < count; i++) {
    const l = lengths[i];
    if (l > 0) {
      // d = 2^(l - 1) + the l - 1 bits below the leading one, as halves dHi 2^32 + dLo.
      const k = l - 1;
      let dHi = 0;
      let dLo;
      if (k <= 32) {
        dLo = bitsAt(padded, pos, k);
      } else {
        dHi = bitsAt(padded, pos, k - 32);
        dLo = bitsAt(padded, pos + k - 32, 32);
      }
      pos += k;
      if (k < 32) dLo += POW2[k];
      else dHi += POW2[k - 32];
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
    const t0 = DEINTERLEAVE9[lo & 511];
    const t1 = DEINTERLEAVE9[(lo >>> 9) & 511];
    const t2 = DEINTERLEAVE9[(lo >>> 18) & 511];
    const t3 = DEINTERLEAVE9[(lo >>> 27) | ((hi & 15) << 5)];
    const t4 = DEINTERLEAVE9[(hi >>> 4) & 511];
    const t5 = DEINTERLEAVE9[(hi >>> 13) & 511];
    const t6 = DEINTERLEAVE9[(hi >>> 22) & 511];
    voxels[3 * i] = gather(t0, t1, t2, t3, t4, t5, t6, 0);
    voxels[3 * i + 1] = gather(t0, t1, t2, t3, t4, t5, t6, 3);
    voxels[3 * i + 2] = gather(t0, t1, t2, t3, t4, t5, t6, 6);
  }
  return voxels;
}

/**
 * Positions of the `n` Gaussians (Float32Array n x 3) from the POSN `payload` on the grid `grid` (from
 * readAttributeSection; `tile`: null or a tile's TileBudget). The grid's bounds were checked with the header.
 */
export function decodePositions(payload, grid, n, tile = null) {
  const far = grid.far;
  const bins = readBinArray(payload, far ? 4 : 2, 'POSN');
  const means = new Float32Array(3 * n);
  const near = far ? n - far.count : n;
  const place = grid.contraction ? placeContracted : placePlain;
  place(grid, decodeCurve(bins[0], bins[1], near, grid.bits, 'curve', tile), 1, means, 0);
  if (far) {
    // A far voxel w stands for the grid voxel w 2^s (exact).
    place(grid, decodeCurve(bins[2], bins[3], far.count, grid.bits - far.shift, 'far set', tile), pow2(far.shift), means, near);
  }
  return means;
}

/** Plain grid (version 1): x_a = float32(lo_a + v_a step_a), voxels v = w scale from row `first` on. */
function placePlain(grid, voxels, scale, means, first) {
  const [l0, l1, l2] = grid.lo;
  const [s0, s1, s2] = grid.step;
  const out = means.subarray(3 * first);
  for (let i = 0; i < voxels.length; i += 3) {
    out[i] = l0 + voxels[i] * scale * s0;
    out[i + 1] = l1 + voxels[i + 1] * scale * s1;
    out[i + 2] = l2 + voxels[i + 2] * scale * s2;
  }
}

/** Contracted grid (versions 2, 3): the grid point y expanded to world space (spec 10.1, steps 1-3). */
function placeContracted(grid, voxels, scale, means, first) {
  const [l0, l1, l2] = grid.lo;
  const [s0, s1, s2] = grid.step;
  const [c0, c1, c2] = grid.contraction.centre;
  const radius = grid.contraction.radius;
  const out = means.subarray(3 * first);
  for (let i = 0; i < voxels.length; i += 3) {
    const y0 = l0 + voxels[i] * scale * s0;
    const y1 = l1 + voxels[i + 1] * scale * s1;
    const y2 = l2 + voxels[i + 2] * scale * s2;
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
    out[i] = c0 + radius * u0;
    out[i + 1] = c1 + radius * u1;
    out[i + 2] = c2 + radius * u2;
  }
}
