// Decoding a whole .gspc file held in memory: the container, the header's records, the side information's
// records and the attributes of its one section or of each of its tiles, one after another (spec 10.14),
// each tile's own side information (TSID, 10.15) checked as the tile is read.

import { ATTRIBUTE_TYPES, attributePayloads, decodeAttributes } from './attributes.mjs';
import { readContainer } from './container.mjs';
import { readFileHeader } from './header.mjs';
import { readSideViews } from './side.mjs';
import {
  TSID,
  checkUntiledSide,
  concatScenes,
  decodeTile,
  readTileIndex,
  tileIndexEntry,
  tileLayout,
  tileSideViews,
} from './tiles.mjs';

/**
 * Each tile's attribute payloads by type and its TSID payload (null without one), from a container's
 * chunks whose layout tileLayout checked: {payloads: [{type: bytes}], sides: [bytes or null]}.
 */
function tilePayloads(chunks, numTiles) {
  const payloads = Array.from({ length: numTiles }, () => ({}));
  const sides = Array(numTiles).fill(null);
  for (const c of chunks) {
    if (ATTRIBUTE_TYPES.includes(c.type)) payloads[c.index][c.type] = c.payload;
    else if (c.type === TSID) sides[c.index] = c.payload;
  }
  return { payloads, sides };
}

/**
 * Decode a .gspc file (`bytes`: Uint8Array or ArrayBuffer) to its Gaussians, without restoration or
 * refinement; a tiled file's tiles one after another (spec 10.14).
 *
 * Returns {header, views, tileViews, count, shDegree, means, quats, logScales, opacities, shDc, shRest}:
 * `header` holds the container's version, its meta as plain JavaScript (integers beyond 2^53 as BigInt, bins
 * as Uint8Array), the checked codec records and, for a tiled file, `tiles` (each tile's number, box, section,
 * drawn and span: readTileIndex); `views` the side-information views of the whole scene (camera, residual
 * record with its still-coded image bytes, or null); `tileViews` a tiled file's side views per tile (spec
 * 10.15: tile k's TSID views, in the form of `views`; [] for a tile without one), null for an untiled file;
 * the arrays are Float32Array in curve order: means N x 3, quats N x 4 (w, x, y, z), logScales N x 3,
 * opacities N (logits), shDc N x 3, shRest N x K x 3 (K = (shDegree + 1)^2 - 1). Throws FormatError (a
 * subclass naming the container's problem) or CodecError.
 */
export function decodeGspc(bytes) {
  if (bytes instanceof ArrayBuffer) bytes = new Uint8Array(bytes);
  const container = readContainer(bytes);
  const indexChunk = tileIndexEntry(container.chunks);
  const records = readFileHeader(container.metaTree, indexChunk !== null);
  const views = readSideViews(records.sideInfo, container.chunks, bytes.length);
  const header = { version: container.version, meta: container.meta, ...records };
  if (indexChunk === null) {
    checkUntiledSide(container.chunks);
    return { header, views, tileViews: null, ...decodeAttributes(records.attributes, attributePayloads(container.chunks)) };
  }
  const index = readTileIndex(indexChunk.payload);
  const layout = tileLayout(container.chunks, index);
  const { payloads, sides } = tilePayloads(container.chunks, index.tiles.length);
  const tileViews = [];
  const scenes = index.tiles.map((t, k) => {
    tileViews.push(tileSideViews(k, sides[k], layout.tiles[k], layout));
    return decodeTile(t, payloads[k], layout.tiles[k].bytes, layout.bytes);
  });
  header.tiles = index.tiles;
  return { header, views, tileViews, ...concatScenes(scenes, index.shDegree) };
}
