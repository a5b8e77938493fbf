// PREC (spec 10.13, attribute codec version 4): each Gaussian's precision class and SH degree, and the row
// sets they define: "the rows of class k" (in decoded order) and, per SH band b, those of class k whose
// degree is at least b.

import { CodecError } from './errors.mjs';
import { decodeEcm, readEcm } from './ecm.mjs';

/**
 * Decode the PREC `payload` for `n` Gaussians with `numClasses` classes and SH degree `shDegree` (`tile`:
 * null or a tile's TileBudget): {classOf, degreeOf} (Uint8Array n each).
 */
export function decodePrecision(payload, n, numClasses, shDegree, tile = null) {
  const ecm = readEcm(payload, n, shDegree === 0 ? 1 : 2, 'PREC', null, tile);
  const classOf = new Uint8Array(n);
  const degreeOf = new Uint8Array(n);
  decodeEcm(
    ecm,
    (j, q) => {
      const [out, most, name] = j === 0 ? [classOf, numClasses - 1, 'precision class'] : [degreeOf, shDegree, 'SH degree'];
      for (let i = 0; i < n; i++) {
        const v = q[i];
        if (!(v >= 0 && v <= most)) throw new CodecError(`PREC row ${i} names ${name} ${v} (allowed 0..${most})`);
        out[i] = v;
      }
    },
    'PREC',
  );
  return { classOf, degreeOf };
}

/**
 * The rows (Int32Array each, decoded order) of every class 0..numClasses-1 whose SH degree is at least
 * `minDegree`.
 */
export function rowsByClass(precision, numClasses, minDegree = 0) {
  const { classOf, degreeOf } = precision;
  const counts = new Int32Array(numClasses);
  for (let i = 0; i < classOf.length; i++) if (degreeOf[i] >= minDegree) counts[classOf[i]]++;
  const rows = Array.from(counts, (c) => new Int32Array(c));
  counts.fill(0);
  for (let i = 0; i < classOf.length; i++) {
    if (degreeOf[i] >= minDegree) rows[classOf[i]][counts[classOf[i]]++] = i;
  }
  return rows;
}
