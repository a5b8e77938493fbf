// Reading a .gspc file in parts from a byte source (spec 10.14, "Reading part of a file"): the preamble,
// header and tile index first (section 8's checks 1 to 8, the tiles' layout and every tile's bounds), then
// each tile's chunks (its attribute chunks and its side information, TSID, spec 10.15), checked and decoded
// as they arrive, so that a viewer draws the first tiles before the last have arrived. A decode of every
// tile reads the file in order and checks all of section 8 (every chunk, the trailer, the whole file's CRC)
// and the side information before it reports the scene complete; a region's decode reads only the tiles it
// needs. An untiled file is one section: it is decoded whole once all of it has arrived.

import { PREAMBLE_BYTES, checkChunk, checkFileSize, checkHeaderPadding, checkTrailer, readHeader, readPreamble, regionAt } from './container.mjs';
import { crc32 } from './crc32.mjs';
import { Truncated } from './errors.mjs';
import { readFileHeader } from './header.mjs';
import { decodeGspc } from './decode.mjs';
import { readSideViews } from './side.mjs';
import { SourceEnded } from './sources.mjs';
import { boxMeets, checkUntiledSide, decodeTile, readTileIndex, tileIndexEntry, tileLayout, tileSideViews } from './tiles.mjs';
import { toPlain } from './msgpack.mjs';

/** The box of positions `means` (n x 3): low x, y, z, high x, y, z. */
function boundsOf(means) {
  const box = [Infinity, Infinity, Infinity, -Infinity, -Infinity, -Infinity];
  for (let i = 0; i < means.length; i += 3) {
    for (let a = 0; a < 3; a++) {
      box[a] = Math.min(box[a], means[i + a]);
      box[a + 3] = Math.max(box[a + 3], means[i + a]);
    }
  }
  return box;
}

/**
 * A .gspc file opened from a byte source (sources.mjs): its head read and checked. Fields: size, version
 * ([major, minor]), meta (plain JavaScript), header (readFileHeader's records), tiled, tiles ([{number, box,
 * count, bytes, drawn, span}]: one per tile, `drawn` and `span` its index entry's, spec 10.14 and 10.17; an
 * untiled file's one tile has a null box until decoded), count (Gaussians in all), shDegree.
 * `decode({region})` yields the tiles.
 */
class GspcReader {
  constructor(source, preamble, layout) {
    this.source = source;
    this.size = source.size;
    this.preamble = preamble;
    this.layout = layout;
    this.version = [preamble.major, preamble.minor];
    this.meta = toPlain(layout.meta);
    this.head = null; // bytes 0 .. dataStart, and on through the tile index of a tiled file
    this.index = null;
    this.tileLayout = null;
  }

  /** `length` bytes at `offset`; a source that ends first is a truncated file, named by region. */
  async read(offset, length) {
    try {
      return await this.source.read(offset, length);
    } catch (err) {
      if (!(err instanceof SourceEnded)) throw err;
      const where = regionAt(err.end, this.preamble.headerLength, this.layout.entries, this.layout.trailerAt);
      const why = err.reason ? ` (${err.reason})` : '';
      throw new Truncated(`file ends at offset ${err.end}, inside the ${where}; the header declares ${this.layout.fileSize} bytes${why}`);
    }
  }

  get tiles() {
    if (!this.index) return [{ number: 0, box: null, count: this.header.attributes.n, bytes: this.size, drawn: [], span: 1 }];
    return this.index.tiles.map((t, k) => ({ number: k, box: t.box, count: t.section.n, bytes: this.tileLayout.tiles[k].bytes, drawn: t.drawn, span: t.span }));
  }

  get count() {
    return this.index ? this.index.count : this.header.attributes.n;
  }

  get shDegree() {
    return this.index ? this.index.shDegree : this.header.attributes.shDegree;
  }

  /**
   * The tiles that meet `region` (6 numbers: low x, y, z, high x, y, z; every tile when null), decoded one
   * at a time in file order: each {number, box, count, shDegree, views, means, quats, logScales, opacities,
   * shDc, shRest} (decodeAttributes' arrays; `views` the side views of the tile's Gaussians as decodeGspc
   * gives `views`: a tile's TSID views, spec 10.15, [] without one; an untiled file's, its scene's). Without
   * a region the whole file is checked before the last yield returns (an untiled file is one tile, its box
   * that of its positions).
   */
  async *decode({ region = null } = {}) {
    if (!this.index) {
      const scene = decodeGspc(await this.read(0, this.size));
      const { count, shDegree, views } = scene;
      yield { number: 0, box: boundsOf(scene.means), count, shDegree, views, ...arrays(scene) };
      return;
    }
    const chosen = this.index.tiles.filter((t) => region === null || boxMeets(t.box, region));
    if (region === null) {
      yield* this.decodeInOrder();
      return;
    }
    for (const tile of chosen) {
      const part = this.tileLayout.tiles[tile.number];
      const bytes = await this.read(part.start, part.end - part.start);
      yield this.decodeOne(tile, bytes, part.start);
    }
  }

  /**
   * Tile `tile` from `bytes` (the file's bytes from offset `base` on, its chunks among them): each of its
   * chunks' CRC and padding, its side information (TSID: the SIDE layout and its pixel share), then its
   * attributes.
   */
  decodeOne(tile, bytes, base) {
    const part = this.tileLayout.tiles[tile.number];
    const payloads = {};
    for (const [type, entry] of Object.entries(part.entries)) payloads[type] = checkChunk(bytes, entry, base);
    const side = part.side ? checkChunk(bytes, part.side, base) : null;
    const views = tileSideViews(tile.number, side, part, this.tileLayout);
    const scene = decodeTile(tile, payloads, part.bytes, this.tileLayout.bytes);
    return { number: tile.number, box: tile.box, count: scene.count, shDegree: scene.shDegree, views, ...arrays(scene) };
  }

  /** Every tile, reading the file from its start to its end and checking every part of it on the way. */
  async *decodeInOrder() {
    const { entries } = this.layout;
    let crc = crc32(this.head);
    let at = this.head.length; // the head's chunks (those before the tile index's end) are checked below
    const kept = []; // side information: checked once the whole file is read
    let next = 0; // the next entry to check, in file order
    const checkThrough = (bytes, base, end) => {
      for (; next < entries.length && entries[next].offset < end; next++) {
        const e = entries[next];
        const payload = checkChunk(bytes, e, base);
        if (e.type === 'SIDE' || e.type === 'RESI') kept.push({ type: e.type, index: e.index, payload });
      }
    };
    checkThrough(this.head, 0, at);
    for (const tile of this.index.tiles) {
      const part = this.tileLayout.tiles[tile.number];
      const bytes = await this.read(at, part.end - at);
      crc = crc32(bytes, crc);
      checkThrough(bytes, at, part.end);
      const decoded = this.decodeOne(tile, bytes, at);
      at = part.end;
      yield decoded;
    }
    const rest = await this.read(at, this.size - at);
    checkThrough(rest, at, this.layout.trailerAt);
    const trailerAt = this.layout.trailerAt;
    crc = crc32(rest.subarray(0, this.size - 4 - at), crc);
    checkTrailer(rest.subarray(trailerAt - at), trailerAt, crc, this.size);
    readSideViews(this.header.sideInfo, kept, this.size);
  }
}

function arrays(scene) {
  const { means, quats, logScales, opacities, shDc, shRest } = scene;
  return { means, quats, logScales, opacities, shDc, shRest };
}

/**
 * Open a .gspc file from `source` ({size, read(offset, length)}, sources.mjs): checks 1 to 8 of spec
 * section 8 and the header padding, the header's records, and for a tiled file its tile index and every
 * rule of 10.14, 10.15 and 10.17 that the chunk table decides (chunk order, TSID placement, spans, counts
 * and each tile's bounds), reading only the file's head and its TIDX chunk; an untiled file with a TSID chunk is refused. Throws FormatError or CodecError as decodeGspc does.
 */
export async function openGspc(source) {
  const size = source.size;
  const first = await readOrTruncated(source, 0, Math.min(size, PREAMBLE_BYTES), size);
  const preamble = readPreamble(first, size);
  const headerEnd = PREAMBLE_BYTES + preamble.headerLength;
  const headerBytes = await readOrTruncated(source, PREAMBLE_BYTES, preamble.headerLength, size);
  const layout = readHeader(preamble, headerBytes);
  checkFileSize(size, preamble, layout);
  const indexEntry = tileIndexEntry(layout.entries);
  // The head runs to the first payload, and in a tiled file on through the tile index (and any chunk
  // before it).
  const headEnd = indexEntry ? Math.ceil((indexEntry.offset + indexEntry.length) / 8) * 8 : layout.dataStart;
  const reader = new GspcReader(source, preamble, layout);
  // Read before allocating: a source allocates only for bytes that have arrived.
  const rest = await reader.read(headerEnd, headEnd - headerEnd);
  const head = new Uint8Array(headEnd);
  head.set(first);
  head.set(headerBytes, PREAMBLE_BYTES);
  head.set(rest, headerEnd);
  reader.head = head;
  checkHeaderPadding(head, preamble, layout);
  reader.header = readFileHeader(layout.meta, indexEntry !== null);
  if (indexEntry) {
    reader.index = readTileIndex(checkChunk(head, indexEntry));
    reader.tileLayout = tileLayout(layout.entries, reader.index);
  } else {
    checkUntiledSide(layout.entries);
  }
  return reader;
}

/** Bytes of the head, before the header's layout is known: a short source is a truncated preamble or header. */
async function readOrTruncated(source, offset, length, size) {
  try {
    return await source.read(offset, length);
  } catch (err) {
    if (!(err instanceof SourceEnded)) throw err;
    const why = err.reason ? ` (${err.reason})` : '';
    throw new Truncated(`file ends at offset ${err.end}, inside the ${offset === 0 ? 'preamble' : 'header'}; the source said ${size} bytes${why}`);
  }
}

