// Spatial tiles (format 1.5, spec 10.14): the TIDX chunk's tile index, the rules that tie each tile to its
// chunks in the chunk table (its attribute chunks and, from format 1.6, its optional TSID chunk of side
// information, 10.15, which from format 1.9 may serve a span of tiles, 10.17), and the decoding of one tile
// with its share of the file's decode bounds.
//
// Everything here works from the chunk table's entries (type, index, length) and the tile index alone, so a
// reader that has only the header and the TIDX chunk can check a file's layout and bound every tile's work
// before it reads any tile.

import { ATTRIBUTE_TYPES, checkAttributeChunks, decodeAttributes } from './attributes.mjs';
import { CodecError, show } from './errors.mjs';
import { MAX_DRAWN_TILES, MAX_SPAN_TILES, MAX_TILES, MIN_TILES, maxCodedGaussians, tileModelBytes, tileTableEntries } from './limits.mjs';
import { TileBudget } from './models.mjs';
import { MsgReader, MsgpackError, kindOf } from './msgpack.mjs';
import { readAttributeSection } from './section.mjs';
import { readTileSideViews } from './side.mjs';

export const TIDX = 'TIDX';
/** A tile's side information (format 1.6, spec 10.15): index the tile's number, payload in the SIDE layout. */
export const TSID = 'TSID';
const BOX_VALUES = 6;
const nameOf = (e) => `${e.type}#${e.index}`;

function readBox(value, k) {
  const ok = Array.isArray(value) && value.length === BOX_VALUES && value.every((x) => typeof x === 'number');
  if (!ok || !value.every(Number.isFinite)) {
    throw new CodecError(`tile ${k}'s box is ${show(value)}, not an array of ${BOX_VALUES} finite floats`);
  }
  for (let a = 0; a < 3; a++) {
    if (value[a] > value[a + 3]) throw new CodecError(`tile ${k}'s box has its low corner above its high one on axis ${a}`);
  }
  return value.slice();
}

function readDrawn(value, k, count) {
  if (value === undefined) return [];
  // msgpack integers read as BigInt (msgpack.mjs): a float is not a tile's number.
  const ok = Array.isArray(value) && value.length <= MAX_DRAWN_TILES && new Set(value).size === value.length
    && value.every((j) => typeof j === 'bigint' && j >= 0n && j < BigInt(count) && j !== BigInt(k));
  if (!ok) {
    throw new CodecError(`tile ${k}'s drawn tiles are ${show(value)}, not an array of at most ${MAX_DRAWN_TILES} distinct other tiles' numbers`);
  }
  return value.map(Number);
}

function readSpan(value, k, count) {
  if (value === undefined) return 1;
  const most = Math.min(MAX_SPAN_TILES, count - k);
  // msgpack integers read as BigInt (msgpack.mjs): a float or a boolean is not a span.
  if (typeof value !== 'bigint' || value < 1n || value > BigInt(most)) {
    throw new CodecError(`tile ${k}'s span is ${show(value)}, not an integer 1..${most} (spec 10.17)`);
  }
  return Number(value);
}

/**
 * The tile index of a TIDX payload (spec 10.14): {tiles: [{number, box (6 numbers: low x, y, z, high x, y,
 * z), section (readAttributeSection), drawn (the tiles its side-information views show beside it, format
 * 1.7), span (the tiles number .. number + span - 1 its side information serves, format 1.9; 1: itself
 * alone)}], count (all tiles' Gaussians), shDegree}. The msgpack rules of spec section 4 hold; CodecError
 * names the first bad field. The spans' rules that need the chunk table are tileLayout's.
 */
export function readTileIndex(payload) {
  const r = new MsgReader(payload);
  let value;
  try {
    value = r.readValue(1);
  } catch (err) {
    if (err instanceof MsgpackError) throw new CodecError(`chunk ${TIDX} is not one msgpack value (${err.message})`);
    throw err;
  }
  if (r.remaining) throw new CodecError(`chunk ${TIDX} holds ${r.remaining} bytes after its msgpack value`);
  if (!Array.isArray(value) || value.length < MIN_TILES || value.length > MAX_TILES) {
    const what = Array.isArray(value) ? `an array of ${value.length}` : `a msgpack ${kindOf(value)}`;
    throw new CodecError(`chunk ${TIDX} is ${what}, not an array of ${MIN_TILES}..${MAX_TILES} tiles`);
  }
  const tiles = value.map((entry, k) => {
    if (!(entry instanceof Map) || !entry.has('box') || !entry.has('attributes')) {
      throw new CodecError(`tile ${k} of chunk ${TIDX} is not a map with a box and attributes`);
    }
    const box = readBox(entry.get('box'), k);
    let section;
    try {
      section = readAttributeSection(entry.get('attributes'));
    } catch (err) {
      if (err instanceof CodecError) throw new CodecError(`tile ${k}: ${err.message}`);
      throw err;
    }
    const drawn = readDrawn(entry.get('drawn'), k, value.length);
    const span = readSpan(entry.get('span'), k, value.length);
    return { number: k, box, section, drawn, span };
  });
  const degrees = [...new Set(tiles.map((t) => t.section.shDegree))];
  if (degrees.length !== 1) {
    throw new CodecError(`the tiles of chunk ${TIDX} have SH degrees ${degrees.sort().join(', ')}; a scene has one`);
  }
  const count = tiles.reduce((sum, t) => sum + t.section.n, 0);
  return { tiles, count, shDegree: degrees[0] };
}

/**
 * The TIDX entry of a tiled file's chunk table (`entries`, in file order): exactly one, of index 0; null
 * when the file has none (it is not tiled).
 */
export function tileIndexEntry(entries) {
  const found = entries.filter((e) => e.type === TIDX);
  if (!found.length) return null;
  if (found.length !== 1 || found[0].index !== 0) {
    throw new CodecError(`a tiled file holds one ${TIDX} chunk, of index 0; this one has ${found.map(nameOf).join(', ')}`);
  }
  return found[0];
}

/**
 * A TSID chunk belongs to a tile (spec 10.15): `entries` (chunk table entries or chunks, with type and
 * index) of a file without a tile index may hold none.
 */
export function checkUntiledSide(entries) {
  const found = entries.find((e) => e.type === TSID);
  if (found) throw new CodecError(`chunk ${nameOf(found)} (a tile's side information, spec 10.15) in a file without a tile index`);
}

/**
 * The rules of spans (format 1.9, spec 10.17) that need the chunk table, `laid` tileLayout's tiles: a span
 * above 1 only on a tile with a TSID; its members (tiles k + 1 .. k + span - 1) with no TSID, no drawn
 * tiles and no span of their own; none of its tiles in its first tile's drawn list.
 */
function checkSpans(index, laid) {
  index.tiles.forEach((t, k) => {
    if (t.span === 1) return;
    if (!laid[k].side) throw new CodecError(`tile ${k} has a span of ${t.span} tiles but no ${TSID} chunk (spec 10.17)`);
    for (let j = k + 1; j < k + t.span; j++) {
      const m = index.tiles[j];
      const own = laid[j].side ? `a ${TSID} chunk` : m.drawn.length ? 'drawn tiles' : m.span > 1 ? `a span of ${m.span}` : null;
      if (own) throw new CodecError(`tile ${j}, in tile ${k}'s span, has ${own} of its own (spec 10.17)`);
      if (t.drawn.includes(j)) throw new CodecError(`tile ${k}'s drawn tiles name tile ${j}, of its own span (spec 10.17)`);
    }
  });
}

/**
 * Each tile's chunks from the chunk table (spec 10.14, 10.15), checked before any tile is read: the TIDX
 * entry before every attribute and TSID chunk, each of them naming a tile and coming after the previous
 * tiles' chunks (a TSID is one of its tile's chunks), the spans' rules (10.17), each tile's attribute chunks
 * those its section needs (10.10), and the Gaussians within what the bytes may declare, per tile and in
 * all. `entries` are the table's entries (type, index, length, offset) in file order. Returns {tiles:
 * [{entries: {type: entry}, side (the TSID entry or null), bytes, sideBytes, start, end}], bytes,
 * sideBytes}: `start .. end` the file bytes of a tile's chunks with their padding, `bytes` its attribute
 * payload bytes (P_k) and in all (P), `sideBytes` its attribute and TSID payload bytes (Q_k, 10.15; the
 * first tile of a span those of all the span's tiles, a member 0: 10.17) and in all (Q).
 */
export function tileLayout(entries, index) {
  const tiles = index.tiles.map(() => ({ entries: {}, side: null, bytes: 0, sideBytes: 0, start: Infinity, end: 0 }));
  let last = -1;
  let seenIndex = false;
  for (const e of entries) {
    if (e.type === TIDX) {
      seenIndex = true;
      continue;
    }
    const isSide = e.type === TSID;
    if (!isSide && !ATTRIBUTE_TYPES.includes(e.type)) continue;
    if (!seenIndex) throw new CodecError(`chunk ${nameOf(e)} comes before the tile index (${TIDX})`);
    if (e.index >= tiles.length) throw new CodecError(`chunk ${nameOf(e)} names no tile (the file has ${tiles.length})`);
    if (e.index < last) throw new CodecError(`chunk ${nameOf(e)} comes after tile ${last}'s chunks`);
    last = e.index;
    const tile = tiles[e.index];
    // At most one TSID per tile: the container refuses a repeated (type, index) pair (DuplicateChunk).
    if (isSide) tile.side = e;
    else {
      tile.entries[e.type] = e;
      tile.bytes += e.length;
    }
    tile.sideBytes += e.length;
    tile.start = Math.min(tile.start, e.offset);
    tile.end = Math.max(tile.end, Math.ceil((e.offset + e.length) / 8) * 8);
  }
  checkSpans(index, tiles);
  // A span's side information has one share of the floors, by the bytes of all its tiles (10.17).
  index.tiles.forEach((t, k) => {
    for (let j = k + 1; j < k + t.span; j++) {
      tiles[k].sideBytes += tiles[j].sideBytes;
      tiles[j].sideBytes = 0;
    }
  });
  index.tiles.forEach((t, k) => {
    try {
      checkAttributeChunks(t.section, tiles[k].entries);
    } catch (err) {
      if (err instanceof CodecError) throw new CodecError(`tile ${k}: ${err.message}`);
      throw err;
    }
  });
  const bytes = tiles.reduce((sum, t) => sum + t.bytes, 0);
  const sideBytes = tiles.reduce((sum, t) => sum + t.sideBytes, 0);
  const most = maxCodedGaussians(bytes);
  if (index.count > most) {
    throw new CodecError(`${index.count} Gaussians in all from ${bytes} attribute payload bytes (at most ${most}, spec 10.14)`);
  }
  return { tiles, bytes, sideBytes };
}

/**
 * Tile `number`'s side views (spec 10.15) from its TSID payload (null: the tile has none, []), with `part`
 * its entry of tileLayout's tiles and `layout` tileLayout's result: the SIDE layout's rules and the
 * tile's pixel share (its span's, 10.17), checked when the tile is read. Returns [{camera, residual}] as
 * readSideViews does.
 */
export function tileSideViews(number, payload, part, layout) {
  if (payload === null) return [];
  return readTileSideViews(number, payload, part.sideBytes, layout.sideBytes);
}

/** Whether `box` meets the closed box `region` (each: low x, y, z, high x, y, z). */
export function boxMeets(box, region) {
  for (let a = 0; a < 3; a++) if (box[a] > region[a + 3] || region[a] > box[a + 3]) return false;
  return true;
}

/**
 * Decode tile `tile` (from readTileIndex) from its attribute payloads by type, `tileBytes` (P_k) and
 * `fileBytes` (P) bounding its work (spec 10.14). Returns the scene arrays of decodeAttributes, every
 * position checked inside the tile's box as binary32.
 */
export function decodeTile(tile, payloads, tileBytes, fileBytes) {
  const what = `tile ${tile.number}`;
  const budget = new TileBudget(tileTableEntries(tileBytes, fileBytes), tileModelBytes(tileBytes, fileBytes), what);
  let scene;
  try {
    scene = decodeAttributes(tile.section, payloads, budget);
  } catch (err) {
    if (err instanceof CodecError) throw new CodecError(`${what}: ${err.message}`);
    throw err;
  }
  const lo = tile.box.slice(0, 3).map(Math.fround);
  const hi = tile.box.slice(3).map(Math.fround);
  const { means } = scene;
  for (let i = 0; i < means.length; i += 3) {
    for (let a = 0; a < 3; a++) {
      const v = means[i + a];
      if (!(v >= lo[a] && v <= hi[a])) {
        throw new CodecError(`${what}: Gaussian ${i / 3} decodes at ${v} on axis ${a}, outside its box ${show(tile.box)}`);
      }
    }
  }
  return scene;
}

/** The scenes of decoded tiles one after another (spec 10.14, "Decoded scene"), in the given order. */
export function concatScenes(scenes, shDegree) {
  const count = scenes.reduce((sum, s) => sum + s.count, 0);
  const numRest = (shDegree + 1) ** 2 - 1;
  const out = { count, shDegree };
  for (const [key, width] of [['means', 3], ['quats', 4], ['logScales', 3], ['opacities', 1], ['shDc', 3], ['shRest', 3 * numRest]]) {
    const array = new Float32Array(count * width);
    let at = 0;
    for (const s of scenes) {
      array.set(s[key], at);
      at += s[key].length;
    }
    out[key] = array;
  }
  return out;
}
