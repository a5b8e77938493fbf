// Entropy-coded matrices (spec 10.0): an m x c integer matrix coded column by column, rows in levels of a
// binary hierarchy, each row's residual read with the model of its context bucket from one range-decoder
// stream. `readEcm` checks everything that needs no symbol (shape, models, table budget); `decodeEcm` then
// decodes the columns one at a time and hands each to the caller, so a matrix never needs more than three
// columns of scratch memory of its own.

import { CodecError } from './errors.mjs';
import { MAX_CODEC_INT, maxModelEntries, maxModelListBytes } from './limits.mjs';
import { KIND_CONSTANT, KIND_EMPTY, NUM_BUCKETS, TableBudget, readModels, tableOf } from './models.mjs';
import { MsgReader, MsgpackError } from './msgpack.mjs';
import { RangeDecoder } from './rangeDecoder.mjs';
import { decompressFrame } from './zstdFrame.mjs';

const LEVEL0_STRIDE = 64;

/**
 * The matrix whose payload is `payload` (a msgpack array [m, c, models, words]), which must have `rows` x
 * `columns` entries (refused before decoding otherwise). Model tables are counted against the matrix's own
 * bound and against `chunkBudget` when given (version 4: the chunk's bound). Returns {rows, columns, models,
 * words}; `what` names the matrix in messages.
 */
export function readEcm(payload, rows, columns, what, chunkBudget = null) {
  const r = new MsgReader(payload);
  let m, c, packed, words;
  try {
    if (r.readArrayHeader() !== 4) throw new CodecError(`${what} is not an entropy-coded matrix (an array of 4 elements)`);
    m = r.readIntNumber();
    c = r.readIntNumber();
    packed = r.readBin();
    words = r.readBin();
  } catch (err) {
    if (err instanceof MsgpackError) throw new CodecError(`${what} is not an entropy-coded matrix (${err.message})`);
    throw err;
  }
  if (r.remaining) throw new CodecError(`${what} holds ${r.remaining} bytes after its msgpack value`);
  if (m !== rows || c !== columns) {
    throw new CodecError(`${what} is an entropy-coded matrix of ${m}x${c}, expected ${rows}x${columns}`);
  }
  if (m === 0) {
    if (packed.length || words.length) throw new CodecError(`${what}: an entropy-coded matrix of 0 rows has models or words`);
    return { rows, columns, models: [], words };
  }
  if (words.length % 4) throw new CodecError(`${what}: range coder words take ${words.length} bytes, not a multiple of 4`);
  const content = decompressFrame(packed, maxModelListBytes(packed.length), `${what}: entropy models`);
  const own = new TableBudget(maxModelEntries(payload.length), `${what}'s models`);
  const budgets = chunkBudget ? [own, chunkBudget] : [own];
  const models = readModels(content, columns, budgets, `${what}: entropy models`);
  return { rows, columns, models, words };
}

/** The `count` bins of a payload that is a msgpack array of exactly `count` bins (`what`: its chunk). */
export function readBinArray(payload, count, what) {
  const r = new MsgReader(payload);
  const bins = [];
  try {
    const n = r.readArrayHeader();
    if (n !== count) throw new MsgpackError(`it holds ${n} elements`);
    for (let i = 0; i < count; i++) bins.push(r.readBin());
  } catch (err) {
    if (err instanceof MsgpackError) throw new CodecError(`${what} payload is not an array of ${count} msgpack bins (${err.message})`);
    throw err;
  }
  if (r.remaining) throw new CodecError(`${what} payload holds ${r.remaining} bytes after its msgpack value`);
  return bins;
}

function bitlenCapped(x, cap) {
  // min(bitlen(|x|), cap) for cap <= 3: 0 for 0, 1 for 1, 2 for 2..3, 3 for 4 and up.
  const a = x < 0 ? -x : x;
  const bits = a === 0 ? 0 : a === 1 ? 1 : a < 4 ? 2 : 3;
  return bits < cap ? bits : cap;
}

/**
 * Decode the matrix `ecm` (from readEcm) column by column: `visit(j, q)` receives column j's values as a
 * Float64Array of `rows` exact integers, valid only until `visit` returns. `what` names it in messages.
 */
export function decodeEcm(ecm, visit, what) {
  const { rows: m, columns, models, words } = ecm;
  if (m === 0) {
    for (let j = 0; j < columns; j++) visit(j, new Float64Array(0));
    return;
  }
  const dec = new RangeDecoder(words);
  let q = new Float64Array(m);
  let res = new Float64Array(m);
  let nb = new Float64Array(m);
  let prevQ = new Float64Array(m);
  let prevRes = new Float64Array(m);
  let prevNb = new Float64Array(m);
  const bucketOf = new Uint8Array(m);
  const order = new Int32Array(m);
  const counts = new Int32Array(NUM_BUCKETS + 1);
  const kinds = new Int32Array(NUM_BUCKETS);
  const values = new Float64Array(NUM_BUCKETS);
  const tables = new Array(NUM_BUCKETS);
  const sizes = new Int32Array(NUM_BUCKETS);
  const los = new Float64Array(NUM_BUCKETS);

  for (let j = 0; j < columns; j++) {
    const { mode, specs } = models[j];
    for (let k = 0; k < NUM_BUCKETS; k++) {
      const s = specs[k];
      kinds[k] = s.kind;
      values[k] = s.kind === KIND_CONSTANT ? s.value : 0;
      tables[k] = null;
      sizes[k] = s.size || 0;
      los[k] = s.lo || 0;
    }
    const first = j === 0;
    // Level 0 (stride 64, no neighbours), then h = 32, 16, ..., 1.
    for (let h = LEVEL0_STRIDE; h >= 1; h >>= 1) {
      const start = h === LEVEL0_STRIDE ? 0 : h;
      const step = h === LEVEL0_STRIDE ? LEVEL0_STRIDE : 2 * h;
      const top = h === LEVEL0_STRIDE;
      counts.fill(0);
      for (let r = start; r < m; r += step) {
        let s = 4;
        let n = 0;
        if (!top) {
          const qa = q[r - h];
          const qb = r + h < m ? q[r + h] : qa;
          n = Math.floor((qa + qb) / 2);
          s = bitlenCapped(qa - qb, 3);
        }
        nb[r] = n;
        const t = first ? 0 : bitlenCapped(prevRes[r], 2);
        const bucket = 3 * s + t;
        bucketOf[r] = bucket;
        counts[bucket + 1]++;
      }
      for (let k = 0; k < NUM_BUCKETS; k++) counts[k + 1] += counts[k];
      for (let r = start; r < m; r += step) order[counts[bucketOf[r]]++] = r;
      // counts[k] now ends bucket k; decode in bucket order, rows ascending within a bucket.
      const total = counts[NUM_BUCKETS - 1];
      for (let i = 0; i < total; i++) {
        const r = order[i];
        const k = bucketOf[r];
        let e;
        const kind = kinds[k];
        if (kind === KIND_CONSTANT) e = values[k];
        else if (kind === KIND_EMPTY) {
          throw new CodecError(`${what}: row ${r} of column ${j} needs a symbol from an empty model (spec [0])`);
        } else {
          let cum = tables[k];
          if (cum === null) cum = tables[k] = tableOf(specs[k]);
          e = los[k] + dec.decode(cum, sizes[k]);
        }
        let p;
        if (mode === 0) p = 0;
        else if (mode === 1) p = nb[r];
        else if (mode === 2) p = prevQ[r];
        else p = nb[r] + prevQ[r] - prevNb[r];
        const v = e + p;
        if (!(v >= -MAX_CODEC_INT && v <= MAX_CODEC_INT)) {
          throw new CodecError(`${what}: column ${j} decodes to a value outside -2^48..2^48`);
        }
        q[r] = v;
        res[r] = e;
      }
    }
    visit(j, q);
    [q, prevQ] = [prevQ, q];
    [res, prevRes] = [prevRes, res];
    [nb, prevNb] = [prevNb, nb];
  }
}
