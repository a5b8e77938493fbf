// Entropy-coded matrices (spec 10.0): an m x c integer matrix coded column by column, rows in levels of a
// binary hierarchy, each row's residual read with the model of its context bucket from one range-decoder
// stream. `readEcm` checks everything that needs no symbol (shape, models, table budget); `decodeEcm` then
// decodes the columns one at a time and hands each to the caller, so a matrix holds only its current and
// previous column (values, residuals, neighbour predictions), never the whole m x c.

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
 * bound, against `chunkBudget` when given (version 4: the chunk's bound) and against `tile` (a TileBudget:
 * a tile's share of its file's bounds, spec 10.14), which the `models` frame's content spends too. Returns
 * {rows, columns, models, words}; `what` names the matrix in messages.
 */
export function readEcm(payload, rows, columns, what, chunkBudget = null, tile = null) {
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
  const own = maxModelListBytes(packed.length);
  const limit = tile ? Math.min(own, tile.modelBytesLeft) : own;
  const shared = limit < own ? ` (what is left of ${tile.what}'s model bytes, spec 10.14)` : '';
  const content = decompressFrame(packed, limit, `${what}: entropy models${shared}`);
  if (tile) tile.spendModelBytes(content.length);
  const budgets = [new TableBudget(maxModelEntries(payload.length), `${what}'s models`)];
  if (chunkBudget) budgets.push(chunkBudget);
  if (tile) budgets.push(tile.tables);
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

/** min(bitlen(|x|), 3): 0 for 0, 1 for 1, 2 for 2..3, 3 from 4 on. */
function spatialClass(x) {
  const a = x < 0 ? -x : x;
  return a >= 4 ? 3 : a >= 2 ? 2 : a;
}

/** min(bitlen(|x|), 2). */
function intraClass(x) {
  const a = x < 0 ? -x : x;
  return a >= 2 ? 2 : a;
}

/**
 * One level's context (spec 10.0, "Coding order"): each row's neighbour prediction nb and bucket, and the
 * rows sorted by bucket (stable) into `order`; `ends[k]` is where bucket k's rows end. `prevRes` holds the
 * previous column's residuals (zeros for column 0: e' = 0 there).
 */
function levelContext(q, prevRes, nb, bucketOf, order, ends, m, h) {
  const top = h === LEVEL0_STRIDE;
  const start = top ? 0 : h;
  const step = top ? LEVEL0_STRIDE : 2 * h;
  ends.fill(0);
  if (top) {
    // Level 0: no neighbours, nb = 0 and spatial class 4.
    for (let r = 0; r < m; r += step) {
      nb[r] = 0;
      const bucket = 12 + intraClass(prevRes[r]);
      bucketOf[r] = bucket;
      ends[bucket + 1]++;
    }
  } else {
    const last = m - h; // rows r >= last have no r + h: b = r - h
    for (let r = start; r < m; r += step) {
      const qa = q[r - h];
      const qb = r < last ? q[r + h] : qa;
      nb[r] = Math.floor((qa + qb) * 0.5);
      const bucket = 3 * spatialClass(qa - qb) + intraClass(prevRes[r]);
      bucketOf[r] = bucket;
      ends[bucket + 1]++;
    }
  }
  for (let k = 0; k < NUM_BUCKETS; k++) ends[k + 1] += ends[k];
  for (let r = start; r < m; r += step) order[ends[bucketOf[r]]++] = r;
}

/** The residuals of rows order[from..to) from one table (a kind-2 or kind-3 model). */
function decodeRun(dec, cum, size, lo, order, from, to, res) {
  for (let i = from; i < to; i++) res[order[i]] = lo + dec.decode(cum, size);
}

/** q = residual + prediction by `mode` for one level's rows; false when a value leaves -2^48..2^48. */
function predictLevel(mode, q, res, nb, prevQ, prevNb, m, h) {
  const top = h === LEVEL0_STRIDE;
  const start = top ? 0 : h;
  const step = top ? LEVEL0_STRIDE : 2 * h;
  let low = 0;
  let high = 0;
  // One loop per mode: each stays monomorphic.
  if (mode === 0) {
    for (let r = start; r < m; r += step) q[r] = res[r];
  } else if (mode === 1) {
    for (let r = start; r < m; r += step) q[r] = res[r] + nb[r];
  } else if (mode === 2) {
    for (let r = start; r < m; r += step) q[r] = res[r] + prevQ[r];
  } else {
    for (let r = start; r < m; r += step) q[r] = res[r] + (nb[r] + prevQ[r] - prevNb[r]);
  }
  for (let r = start; r < m; r += step) {
    const v = q[r];
    if (v < low) low = v;
    if (v > high) high = v;
  }
  return low >= -MAX_CODEC_INT && high <= MAX_CODEC_INT;
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
  const ends = new Int32Array(NUM_BUCKETS + 1);
  for (let j = 0; j < columns; j++) {
    const { mode, specs } = models[j];
    // Level 0 (every 64th row, no neighbours), then h = 32, 16, ..., 1.
    for (let h = LEVEL0_STRIDE; h >= 1; h >>= 1) {
      levelContext(q, prevRes, nb, bucketOf, order, ends, m, h);
      // ends[k] is now where bucket k ends: its rows are order[ends[k - 1] .. ends[k]).
      for (let k = 0; k < NUM_BUCKETS; k++) {
        const from = k === 0 ? 0 : ends[k - 1];
        const to = ends[k];
        if (from === to) continue;
        const spec = specs[k];
        if (spec.kind === KIND_CONSTANT) {
          for (let i = from; i < to; i++) res[order[i]] = spec.value;
        } else if (spec.kind === KIND_EMPTY) {
          throw new CodecError(`${what}: row ${order[from]} of column ${j} needs a symbol from an empty model (spec [0])`);
        } else {
          decodeRun(dec, tableOf(spec), spec.size, spec.lo, order, from, to, res);
        }
      }
      if (!predictLevel(mode, q, res, nb, prevQ, prevNb, m, h)) {
        throw new CodecError(`${what}: column ${j} decodes to a value outside -2^48..2^48`);
      }
    }
    visit(j, q);
    [q, prevQ] = [prevQ, q];
    [res, prevRes] = [prevRes, res];
    [nb, prevNb] = [prevNb, nb];
  }
}
