// The model list of an entropy-coded matrix (spec 10.0): per column a prediction mode and 15 model specs,
// read from the msgpack that the `models` zstd frame holds and checked in full before any symbol is
// decoded; and the probability table of a kind-2 or kind-3 spec, built when a row first needs it.
//
// A kind-3 spec's weights are not copied out of the model list: the spec keeps their offset, and its table
// reads them again when it is built, so a model list costs no memory beyond its own bytes until a table is
// built, and tables only for the models that rows use.

import { CodecError } from './errors.mjs';
import {
  MAX_BOOST_INDEX,
  MAX_CODEC_INT,
  MAX_RATIO_INDEX,
  MAX_WEIGHT_EXCLUSIVE,
  MAX_WINDOW,
  MIN_WINDOW,
  PROBABILITY_BITS,
} from './limits.mjs';
import { MsgReader, MsgpackError } from './msgpack.mjs';

export const NUM_BUCKETS = 15;
export const KIND_EMPTY = 0;
export const KIND_CONSTANT = 1;
export const KIND_GEOMETRIC = 2;
export const KIND_EXPLICIT = 3;

const TOTAL = 2 ** PROBABILITY_BITS;

// Kind 2's ratios: m_0 = 2^20, m_{i+1} = (m_i * 60097) >> 16 (131 values); theta = 1 - m_u / 2^20.
const RATIOS = (() => {
  const m = new Float64Array(MAX_RATIO_INDEX + 1);
  m[0] = 2 ** 20;
  for (let i = 0; i < MAX_RATIO_INDEX; i++) m[i + 1] = Math.floor((m[i] * 60097) / 65536);
  return m;
})();
// Kind 2's centre boosts B_b (b = 0..21): the centre's weight is (2^30 B_b) >> 3.
const BOOSTS = [1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, 362, 512, 724, 1024, 1448, 2048];

/** Kind 2's ratio m_u, for tests against the spec's listed values. */
export const ratio = (u) => RATIOS[u];

/**
 * A running bound on probability-table entries: `limit` entries in all, `what` naming the matrix or chunk
 * in messages. One per matrix, and at version 4 one more per chunk (spec 10.0, 10.10).
 */
export class TableBudget {
  constructor(limit, what) {
    this.limit = limit;
    this.used = 0;
    this.what = what;
  }

  spend(entries) {
    this.used += entries;
    if (this.used > this.limit) {
      throw new CodecError(`${this.what} need more than ${this.limit} probability table entries (spec 10.0)`);
    }
  }
}

/**
 * What decoding one tile of a tiled file may spend (spec 10.14): its share of the file's table entries and
 * decompressed model-list bytes, counted over all of the tile's matrices, each matrix once.
 */
export class TileBudget {
  constructor(tableEntries, modelBytes, what) {
    this.tables = new TableBudget(tableEntries, `${what}'s matrices together`);
    this.modelBytesLeft = modelBytes;
    this.modelBytes = modelBytes;
    this.what = what;
  }

  spendModelBytes(bytes) {
    if (bytes > this.modelBytesLeft) {
      throw new CodecError(`${this.what}'s entropy models decompress to more than ${this.modelBytes} bytes together (spec 10.14)`);
    }
    this.modelBytesLeft -= bytes;
  }
}

function integer(r, where) {
  let v;
  try {
    v = r.readIntNumber();
  } catch (err) {
    if (err instanceof MsgpackError) throw new CodecError(`${where}: ${err.message}`);
    throw err;
  }
  if (!(v >= -MAX_CODEC_INT && v <= MAX_CODEC_INT)) {
    throw new CodecError(`${where} holds the integer ${v}, outside -2^48..2^48`);
  }
  return v;
}

function arrayOf(r, where) {
  try {
    return r.readArrayHeader();
  } catch (err) {
    if (err instanceof MsgpackError) throw new CodecError(`${where}: ${err.message}`);
    throw err;
  }
}

/** One spec at the reader's cursor, checked (spec 10.0, 10.11); its table entries are spent from `budgets`. */
function readSpec(r, where, budgets) {
  const length = arrayOf(r, where);
  if (length < 1) throw new CodecError(`${where} is an empty array`);
  const kind = integer(r, where);
  const wrongLength = (want) => new CodecError(`${where} of kind ${kind} has ${length} integers, not ${want}`);
  if (kind === KIND_EMPTY) {
    if (length !== 1) throw wrongLength(1);
    return { kind };
  }
  if (kind === KIND_CONSTANT) {
    if (length !== 2) throw wrongLength(2);
    return { kind, value: integer(r, where) };
  }
  if (kind !== KIND_GEOMETRIC && kind !== KIND_EXPLICIT) throw new CodecError(`${where} has kind ${kind} (not 0..3)`);
  if (length < 3) throw wrongLength(kind === KIND_GEOMETRIC ? 6 : 'hi - lo + 4');
  const lo = integer(r, where);
  const hi = integer(r, where);
  const size = hi - lo + 1;
  if (!(size >= MIN_WINDOW && size <= MAX_WINDOW)) {
    throw new CodecError(`${where} has a window ${lo}..${hi} of ${size} symbols (allowed ${MIN_WINDOW}..${MAX_WINDOW})`);
  }
  if (kind === KIND_GEOMETRIC) {
    if (length !== 6) throw wrongLength(6);
    const centre = integer(r, where);
    const u = integer(r, where);
    const b = integer(r, where);
    if (!(centre >= lo && centre <= hi)) throw new CodecError(`${where} has its centre ${centre} outside ${lo}..${hi}`);
    if (!(u >= 0 && u <= MAX_RATIO_INDEX)) throw new CodecError(`${where} has ratio index u = ${u} (allowed 0..${MAX_RATIO_INDEX})`);
    if (!(b >= 0 && b <= MAX_BOOST_INDEX)) throw new CodecError(`${where} has boost index b = ${b} (allowed 0..${MAX_BOOST_INDEX})`);
    for (const budget of budgets) budget.spend(size);
    return { kind, lo, hi, size, centre, u, b, cum: null };
  }
  if (length !== 3 + size) {
    throw new CodecError(`${where} over ${lo}..${hi} lists ${length - 3} weights, not ${size}`);
  }
  for (const budget of budgets) budget.spend(size);
  const at = r.pos;
  let positive = false;
  for (let i = 0; i < size; i++) {
    const w = integer(r, where);
    if (!(w >= 0 && w < MAX_WEIGHT_EXCLUSIVE)) throw new CodecError(`${where} has a weight ${w} outside 0..2^39 - 1`);
    if (w > 0) positive = true;
  }
  if (!positive) throw new CodecError(`${where} has no positive weight`);
  return { kind, lo, hi, size, at, bytes: r.bytes, cum: null };
}

/**
 * The model list `content` of a matrix of `columns` columns: an array of {mode, specs (15)}, every spec
 * checked (spec 10.0) and its table entries spent from each of `budgets` (TableBudget) before it is kept;
 * `what` names the list in messages.
 */
export function readModels(content, columns, budgets, what = 'entropy models') {
  const r = new MsgReader(content);
  const count = arrayOf(r, what);
  if (count !== columns) throw new CodecError(`${what} list ${count} columns, the matrix has ${columns}`);
  const out = new Array(columns);
  for (let j = 0; j < columns; j++) {
    const where = `${what} of column ${j}`;
    if (arrayOf(r, where) !== 2) throw new CodecError(`${where} are not an array [mode, specs]`);
    const mode = integer(r, `${where}'s prediction mode`);
    if (!(mode >= 0 && mode <= 3) || (j === 0 && mode > 1)) {
      throw new CodecError(`${where} use prediction mode ${mode} (column 0: 0 or 1; others 0..3)`);
    }
    if (arrayOf(r, where) !== NUM_BUCKETS) throw new CodecError(`${where} do not hold ${NUM_BUCKETS} model specs`);
    const specs = new Array(NUM_BUCKETS);
    for (let k = 0; k < NUM_BUCKETS; k++) specs[k] = readSpec(r, `${what}: model spec ${k} of column ${j}`, budgets);
    out[j] = { mode, specs };
  }
  if (r.remaining) throw new CodecError(`${what} hold ${r.remaining} bytes after their msgpack value`);
  return out;
}

// --- probability tables -----------------------------------------------------------------------------------

/** floor(w k / total) for integers w < 2^39, k < 2^24, total < 2^61, exactly. */
function scaledFloor(w, k, total) {
  const a = w * k;
  if (a <= Number.MAX_SAFE_INTEGER && total <= Number.MAX_SAFE_INTEGER) {
    const q = Math.floor(a / total);
    return q * total > a ? q - 1 : q;
  }
  // The quotient is below 2^24 and the binary64 estimate is within 2^-27 of it: away from an integer
  // boundary the estimate's floor is exact; near one, BigInt decides.
  const x = a / total;
  const f = Math.floor(x);
  if (x - f > 2 ** -26 && f + 1 - x > 2 ** -26) return f;
  return Number((BigInt(w) * BigInt(k)) / BigInt(total));
}

// A table also holds, per 1/256 of the probability range, the symbol at the slot's start, so that the range
// decoder searches only the symbols of one slot (a probable symbol is found at once).
export const SLOT_BITS = 8;
const SLOTS = 2 ** SLOT_BITS;
const SLOT_SHIFT = PROBABILITY_BITS - SLOT_BITS;

/** A table of S symbols: S + 1 starts, then SLOTS + 1 slot symbols (the last is S - 1). */
function newTable(size) {
  return new Uint32Array(size + 1 + SLOTS + 1);
}

/** Fill the slots of `table` (whose starts are final): slot j holds the symbol containing j 2^16. */
function fillSlots(table, size) {
  let symbol = 0;
  for (let j = 0; j < SLOTS; j++) {
    const q = j << SLOT_SHIFT;
    while (table[symbol + 1] <= q) symbol++;
    table[size + 1 + j] = symbol;
  }
  table[size + 1 + SLOTS] = size - 1;
  return table;
}

/** The table of the starts `starts` (S + 1 numbers, 0 first, 2^24 last), for tests and tools. */
export function tableFromStarts(starts) {
  const size = starts.length - 1;
  const table = newTable(size);
  table.set(starts);
  return fillSlots(table, size);
}

/**
 * The table (see newTable) of weights `weight(i)` (i = 0..S-1) summing to `total`: f_i = 1 + floor(w_i
 * (2^24 - S) / W), the shortfall to 2^24 added to the first largest weight (spec 10.0), as starts F.
 */
function buildStarts(size, weight, total) {
  const cum = newTable(size);
  const k = TOTAL - size;
  let sum = 0;
  let best = 0;
  let bestWeight = -1;
  let lastW = -1;
  let lastF = 0;
  for (let i = 0; i < size; i++) {
    const w = weight(i);
    if (w !== lastW) {
      lastW = w;
      lastF = 1 + scaledFloor(w, k, total);
    }
    if (w > bestWeight) {
      bestWeight = w;
      best = i;
    }
    cum[i + 1] = lastF; // frequencies first, turned into starts below
    sum += lastF;
  }
  cum[best + 1] += TOTAL - sum;
  for (let i = 1; i <= size; i++) cum[i] += cum[i - 1];
  return fillSlots(cum, size);
}

function geometricStarts(spec) {
  const { lo, hi, centre, u, b, size } = spec;
  const reach = Math.max(centre - lo, hi - centre);
  // w(d) = max(floor(p_d 2^30), 1), p_0 = 1, p_d = p_{d-1} theta: non-increasing, 1 from some d on.
  const theta = 1 - RATIOS[u] / 2 ** 20;
  const byDistance = new Float64Array(reach + 1);
  let p = 1;
  let d = 0;
  for (; d <= reach; d++) {
    const w = Math.floor(p * 2 ** 30);
    if (w <= 1) break;
    byDistance[d] = w;
    p *= theta;
  }
  byDistance.fill(1, d);
  byDistance[0] = (2 ** 30 * BOOSTS[b]) / 8; // exact: (2^30 B_b) >> 3
  // Every weight is below 2^39 and S at most 2^22, so the sum is below 2^53: exact.
  let total = byDistance[0];
  for (let i = 1; i <= centre - lo; i++) total += byDistance[i];
  for (let i = 1; i <= hi - centre; i++) total += byDistance[i];
  const offset = centre - lo;
  return buildStarts(size, (i) => byDistance[Math.abs(i - offset)], total);
}

function explicitStarts(spec) {
  const weights = new Float64Array(spec.size);
  const r = new MsgReader(spec.bytes, spec.at);
  let total = 0;
  let big = 0n;
  for (let i = 0; i < spec.size; i++) weights[i] = r.readIntNumber();
  for (let i = 0; i < spec.size; i++) total += weights[i];
  if (total > Number.MAX_SAFE_INTEGER) {
    // Past 2^53 a binary64 sum may have rounded: add exactly.
    for (let i = 0; i < spec.size; i++) big += BigInt(weights[i]);
    total = Number(big);
    if (BigInt(total) !== big) return explicitStartsBig(weights, big);
  }
  return buildStarts(spec.size, (i) => weights[i], total);
}

/** The rare table whose weight sum is not a binary64 integer: every frequency in BigInt. */
function explicitStartsBig(weights, total) {
  const size = weights.length;
  const k = BigInt(TOTAL - size);
  const cum = newTable(size);
  let sum = 0;
  let best = 0;
  for (let i = 0; i < size; i++) {
    const f = 1 + Number((BigInt(weights[i]) * k) / total);
    if (weights[i] > weights[best]) best = i;
    cum[i + 1] = f;
    sum += f;
  }
  cum[best + 1] += TOTAL - sum;
  for (let i = 1; i <= size; i++) cum[i] += cum[i - 1];
  return fillSlots(cum, size);
}

/** The table of a kind-2 or kind-3 spec (starts, then slots), built on first use and kept on the spec. */
export function tableOf(spec) {
  if (spec.cum === null) spec.cum = spec.kind === KIND_GEOMETRIC ? geometricStarts(spec) : explicitStarts(spec);
  return spec.cum;
}
