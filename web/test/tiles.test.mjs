// Spatial tiles (format 1.5, spec 10.14): a tiled file made by gspc's encoder decodes to the PLY gspc's
// decoder writes (fixtures/reference_ply.json, checked in ply.test.mjs too), tile by tile from a byte
// source as from memory, over HTTP as one stream or by range requests; and hand-made files breaking each
// rule of 10.14 and 10.11 are refused, by the whole-file decoder and by the streaming reader alike.

import test from 'node:test';
import assert from 'node:assert/strict';
import { createServer } from 'node:http';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import {
  CodecError,
  FormatError,
  Truncated,
  bytesSource,
  decodeGspc,
  fetchRangeSource,
  fetchStreamSource,
  openGspc,
  writePly,
} from '../src/index.mjs';
import { readEcm } from '../src/ecm.mjs';
import { concatScenes } from '../src/tiles.mjs';
import { tileModelBytes, tileTableEntries } from '../src/limits.mjs';
import { TileBudget } from '../src/models.mjs';
import { sha256 } from './vectors.mjs';
import { F64, box, constantEcm, constantScene, ecm, gspcFile, msgpack, tiledScene, zstdRaw } from './writer.mjs';

const FIXTURES = fileURLToPath(new URL('./fixtures/', import.meta.url));
const TILED = new Uint8Array(readFileSync(`${FIXTURES}tiny_tiled_sh1.gspc`));
const REFERENCE = JSON.parse(readFileSync(`${FIXTURES}reference_ply.json`, 'utf8')).ply_sha256;
const TILED_VERSION = { major: 1, minor: 5 };

async function streamed(source, options) {
  const reader = await openGspc(source);
  const tiles = [];
  for await (const tile of reader.decode(options)) tiles.push(tile);
  return { reader, tiles };
}

/** The tiles' arrays one after another, as one scene. */
const joined = (tiles) => concatScenes(tiles, tiles[0].shDegree);

test('tiles: a tiled file from gspc decodes to the PLY gspc writes, its tiles in file order', () => {
  const scene = decodeGspc(TILED);
  assert.deepEqual(scene.header.version, [1, 5]);
  assert.equal(scene.header.attributes, null);
  assert.equal(scene.header.tiles.length, 4);
  assert.equal(scene.count, scene.header.tiles.reduce((n, t) => n + t.section.n, 0));
  assert.equal(sha256(writePly(scene)), REFERENCE['fixtures/tiny_tiled_sh1.gspc']);
});

test('tiles: the streaming reader yields each tile, in its box, the same bits as the whole decode', async () => {
  const { reader, tiles } = await streamed(bytesSource(TILED));
  assert.equal(reader.tiles.length, 4);
  assert.deepEqual(tiles.map((t) => t.number), [0, 1, 2, 3]);
  assert.deepEqual(tiles.map((t) => t.count), reader.tiles.map((t) => t.count));
  assert.equal(sha256(writePly(joined(tiles))), REFERENCE['fixtures/tiny_tiled_sh1.gspc']);
  for (const t of tiles) {
    for (let i = 0; i < t.means.length; i++) {
      const a = i % 3;
      assert.ok(t.means[i] >= Math.fround(t.box[a]) && t.means[i] <= Math.fround(t.box[a + 3]));
    }
  }
  // An untiled file is one tile, its box that of its positions.
  const untiled = await streamed(bytesSource(new Uint8Array(readFileSync(`${FIXTURES}tiny_v4_sh2.gspc`))));
  assert.equal(untiled.tiles.length, 1);
  assert.equal(sha256(writePly(untiled.tiles[0])), REFERENCE['fixtures/tiny_v4_sh2.gspc']);
});

test('tiles: a region decodes the tiles whose boxes meet it, and reads only theirs', async () => {
  const reader = await openGspc(bytesSource(TILED));
  const [t0, t1] = reader.tiles;
  const region = t1.box.slice(); // tile 1's own box meets tile 1 and maybe neighbours, never none
  const { tiles } = await streamed(bytesSource(TILED), { region });
  assert.ok(tiles.some((t) => t.number === 1));
  const meets = (b) => [0, 1, 2].every((a) => b[a] <= region[a + 3] && region[a] <= b[a + 3]);
  assert.deepEqual(tiles.map((t) => t.number), reader.tiles.filter((t) => meets(t.box)).map((t) => t.number));
  const far = [1e9, 1e9, 1e9, 2e9, 2e9, 2e9];
  assert.deepEqual((await streamed(bytesSource(TILED), { region: far })).tiles, []);
  assert.ok(t0.bytes > 0);
});

/** A local HTTP server of `bytes` (Range requests answered unless `ranges` is false); `sent` counts body bytes. */
async function serveBytes(bytes, { ranges = true, cut = null } = {}) {
  const stats = { sent: 0, requests: 0 };
  const server = createServer((req, res) => {
    stats.requests++;
    const m = ranges && /^bytes=(\d+)-(\d+)$/.exec(req.headers.range ?? '');
    if (m) {
      const start = Number(m[1]);
      const end = Math.min(Number(m[2]), bytes.length - 1);
      res.writeHead(206, { 'content-length': end - start + 1, 'content-range': `bytes ${start}-${end}/${bytes.length}` });
      stats.sent += end - start + 1;
      res.end(bytes.subarray(start, end + 1));
      return;
    }
    res.writeHead(200, { 'content-length': bytes.length });
    if (cut !== null) {
      // A download that stops: the first `cut` bytes, then the connection closes.
      res.write(bytes.subarray(0, cut), () => res.destroy());
      return;
    }
    stats.sent += bytes.length;
    res.end(bytes);
  });
  await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
  return { url: `http://127.0.0.1:${server.address().port}/scene.gspc`, stats, close: () => server.close() };
}

test('tiles: over HTTP, one stream or range requests give the same tiles; a region fetches less', async () => {
  const site = await serveBytes(TILED);
  try {
    const whole = sha256(writePly(joined((await streamed(await fetchStreamSource(site.url))).tiles)));
    assert.equal(whole, REFERENCE['fixtures/tiny_tiled_sh1.gspc']);
    const ranged = await streamed(await fetchRangeSource(site.url, { first: 1024 }));
    assert.equal(sha256(writePly(joined(ranged.tiles))), whole);
    site.stats.sent = 0;
    const last = ranged.reader.tiles[3];
    const region = await streamed(await fetchRangeSource(site.url, { first: 1024 }), { region: last.box });
    assert.ok(region.tiles.length >= 1 && region.tiles.length < 4);
    assert.ok(site.stats.sent < TILED.length, `${site.stats.sent} of ${TILED.length} bytes fetched`);
  } finally {
    site.close();
  }
  // A server that ignores ranges is read as one stream.
  const plain = await serveBytes(TILED, { ranges: false });
  try {
    const { tiles } = await streamed(await fetchRangeSource(plain.url));
    assert.equal(sha256(writePly(joined(tiles))), REFERENCE['fixtures/tiny_tiled_sh1.gspc']);
  } finally {
    plain.close();
  }
});

test('tiles: a download that stops, or a file cut short, is Truncated naming where; earlier tiles came', async () => {
  const cutAt = Math.floor(TILED.length * 0.7);
  const site = await serveBytes(TILED, { cut: cutAt });
  try {
    const reader = await openGspc(await fetchStreamSource(site.url));
    const got = [];
    await assert.rejects(
      async () => {
        for await (const tile of reader.decode()) got.push(tile.number);
      },
      (err) => err instanceof Truncated && /file ends at offset \d+, inside the /.test(err.message) && /download/.test(err.message),
    );
    assert.ok(got.length >= 1 && got.length < 4, `tiles before the cut: ${got}`);
  } finally {
    site.close();
  }
  const short = await serveBytes(TILED.subarray(0, cutAt));
  try {
    await assert.rejects(openGspc(await fetchStreamSource(short.url)), (err) => err instanceof Truncated && /chunk/.test(err.message));
  } finally {
    short.close();
  }
});

test('tiles: a damaged chunk of a later tile stops the decode there (ChecksumMismatch); the trailer is checked', async () => {
  const reader = await openGspc(bytesSource(TILED));
  const lastTile = reader.tileLayout.tiles[3];
  const damaged = TILED.slice();
  damaged[lastTile.start + 5] ^= 0xff;
  const got = [];
  await assert.rejects(async () => {
    for await (const tile of (await openGspc(bytesSource(damaged))).decode()) got.push(tile.number);
  }, /ChecksumMismatch|CRC-32/);
  assert.deepEqual(got, [0, 1, 2]);
  const badTrailer = TILED.slice();
  badTrailer[badTrailer.length - 1] ^= 1;
  await assert.rejects(streamed(bytesSource(badTrailer)), (err) => err instanceof FormatError && /whole file/.test(err.message));
  // A region's decode reads neither the trailer nor the other tiles.
  const { tiles } = await streamed(bytesSource(badTrailer), { region: reader.tiles[0].box });
  assert.ok(tiles.length >= 1);
});

test('tiles: a file of a newer major version, or with a chunk type this reader lacks, is refused by name', async () => {
  const newer = TILED.slice();
  newer[8] = 2;
  await assert.rejects(openGspc(bytesSource(newer)), /version 2\.5 is a newer major version/);
  const { meta, chunks } = tiledScene([40, 40]);
  const unknown = gspcFile(meta, [...chunks, { type: 'TNEW', payload: new Uint8Array(3) }], TILED_VERSION);
  await assert.rejects(openGspc(bytesSource(unknown)), /TNEW#0.*newer gspc/);
});

// --- refusals (spec 10.14, 10.11) ------------------------------------------------------------------------

/** Refused by decodeGspc and by the streaming reader, with a CodecError whose message holds `words`. */
async function refused(bytes, words) {
  const check = (err) => {
    assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
    assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
    return true;
  };
  assert.throws(() => decodeGspc(bytes), check);
  await assert.rejects(streamed(bytesSource(bytes)), check);
}

const file = ({ meta, chunks }) => gspcFile(meta, chunks, TILED_VERSION);
const withTile = (counts, k, change) => file(tiledScene(counts, (i, map) => (i === k ? change(map) : map)));

test('tiles: the tiled fixtures of the hand-made kind decode', async () => {
  const bytes = file(tiledScene([40, 70, 10]));
  const scene = decodeGspc(bytes);
  assert.equal(scene.count, 120);
  const { tiles } = await streamed(bytesSource(bytes));
  assert.deepEqual(tiles.map((t) => t.count), [40, 70, 10]);
});

test('tiles: a TIDX payload that is not an array of 2 to 8192 tile maps is refused', async () => {
  const index = (payload) => {
    const { meta, chunks } = tiledScene([40, 40]);
    return file({ meta, chunks: chunks.map((c) => (c.type === 'TIDX' ? { ...c, payload } : c)) });
  };
  await refused(index(msgpack({ tiles: [] })), 'not an array of 2..8192 tiles');
  await refused(index(msgpack([{ box: box(-1, -1, -1, 1, 1, 1), attributes: constantScene(40).meta.attributes }])), 'an array of 1');
  await refused(index(msgpack(Array(8193).fill(0))), 'an array of 8193');
  await refused(index(msgpack([0, 0])), 'tile 0 of chunk TIDX is not a map');
  const valid = tiledScene([40, 40]).chunks[0].payload;
  await refused(index(Uint8Array.from([...valid, 0xc0])), 'after its msgpack value');
  // The msgpack rules of spec section 4 hold: a map holding a key twice is refused.
  const pair = [...msgpack('box'), ...msgpack(box(0, 0, 0, 1, 1, 1))];
  await refused(index(Uint8Array.from([0x92, 0x82, ...pair, ...pair, 0x80])), 'not one msgpack value');
});

test('tiles: a tile without a box of 6 finite floats (low at most high) or without attributes is refused', async () => {
  await refused(withTile([40, 40], 1, ({ attributes }) => ({ attributes })), 'tile 1 of chunk TIDX is not a map with a box');
  await refused(withTile([40, 40], 0, ({ box: b }) => ({ box: b })), 'tile 0 of chunk TIDX is not a map with a box');
  await refused(withTile([40, 40], 1, (m) => ({ ...m, box: box(-1, -1, -1, 1, 1) })), "tile 1's box");
  await refused(withTile([40, 40], 1, (m) => ({ ...m, box: [-1, -1, -1, 1, 1, 1] })), "tile 1's box"); // integers
  await refused(withTile([40, 40], 1, (m) => ({ ...m, box: box(-1, NaN, -1, 1, 1, 1) })), "tile 1's box");
  await refused(withTile([40, 40], 1, (m) => ({ ...m, box: box(-1, -1, -1, 1, Infinity, 1) })), "tile 1's box");
  await refused(withTile([40, 40], 0, (m) => ({ ...m, box: box(-1, 2, -1, 1, 1, 1) })), 'low corner above its high one');
  await refused(withTile([40, 40], 1, (m) => ({ ...m, attributes: { ...m.attributes, n: new F64(40) } })), 'tile 1: attribute codec header');
});

test('tiles: tiles of different SH degrees, or a meta attributes section, are refused', async () => {
  const degrees = withTile([40, 40], 1, (m) => ({ ...m, attributes: { ...m.attributes, sh_degree: 1, sh_steps: [new F64(0.1), new F64(0.1), new F64(0.1)] } }));
  await refused(degrees, 'SH degrees 0, 1');
  const { meta, chunks } = tiledScene([40, 40]);
  await refused(file({ meta: { ...meta, attributes: constantScene(80).meta.attributes }, chunks }), 'has an attributes section');
});

test('tiles: an attribute chunk naming no tile, before the index or after a later tile\'s, is refused', async () => {
  const { meta, chunks } = tiledScene([40, 40]);
  const moved = (from, to) => {
    const out = chunks.slice();
    const [c] = out.splice(from, 1);
    out.splice(to, 0, c);
    return file({ meta, chunks: out });
  };
  await refused(file({ meta, chunks: [...chunks, { type: 'SHDC', index: 2, payload: constantEcm(40, 3, 1) }] }), 'SHDC#2 names no tile');
  await refused(moved(1, 0), 'POSN#0 comes before the tile index');
  await refused(moved(6, 3), "SCAL#0 comes after tile 1's chunks");
  await refused(file({ meta, chunks: chunks.map((c) => (c.type === 'TIDX' ? { ...c, index: 1 } : c)) }), 'one TIDX chunk, of index 0');
  await refused(file({ meta, chunks: chunks.filter((c) => !(c.type === 'OPAC' && c.index === 1)) }), 'tile 1: chunk OPAC is missing');
});

test('tiles: a position outside its tile\'s box, or a count its chunks do not hold, is refused', async () => {
  await refused(withTile([40, 40], 1, (m) => ({ ...m, box: box(0.5, -1, -1, 1, 1, 1) })), 'outside its box');
  // The box's bounds are compared as binary32: a bound that rounds to the position holds it.
  const edge = decodeGspc(withTile([40, 40], 1, (m) => ({ ...m, box: box(1e-46, -1, -1, 1, 1, 1) })));
  assert.equal(edge.count, 80);
  await refused(withTile([40, 40], 1, (m) => ({ ...m, attributes: { ...m.attributes, n: 41 } })), 'expected 41x');
});

test('tiles: the Gaussians of all tiles are bounded by all their bytes together', async () => {
  assert.equal(decodeGspc(file(tiledScene([2 ** 15, 2 ** 15]))).count, 2 ** 16);
  await refused(file(tiledScene([2 ** 16, 2 ** 16])), 'Gaussians in all');
});

test('tiles: the model tables of a tile share the file\'s bound in proportion to its bytes', async () => {
  // One table of the widest window per matrix is within each matrix's own bound (never built: no row uses
  // its bucket). Five of them in one tile ask for 5 x 2^22 entries: past a tile's share of 2^25 when it
  // holds half of the file's bytes, though an untiled file of the same matrices decodes.
  const wide = [2, 0, 2 ** 22 - 1, 0, 3, 0];
  const models = (c) => Array.from({ length: c }, (_, j) => [0, j === 0 ? [...Array(14).fill([1, 0]), wide] : Array(15).fill([1, 0])]);
  const widen = (chunks) =>
    chunks.map((c) => {
      const columns = { OPAC: 1, SCAL: 3, ROTN: 4, SHDC: 3 }[c.type];
      if (c.type === 'POSN') return { ...c, payload: msgpack([ecm(40, 1, models(1)), new Uint8Array(0)]) };
      return columns ? { ...c, payload: ecm(40, columns, models(columns)) } : c;
    });
  const untiled = constantScene(40);
  assert.equal(decodeGspc(gspcFile(untiled.meta, widen(untiled.chunks))).count, 40);
  const { meta, chunks } = tiledScene([40, 40]);
  await refused(file({ meta, chunks: widen(chunks) }), "tile 0's matrices together need more than");
  assert.equal(tileTableEntries(100, 200), 2 ** 24);
  assert.equal(tileTableEntries(2 ** 40, 2 ** 41), 16 * 2 ** 40);
});

test('tiles: the models frames of a tile decompress to at most its share of the file\'s bytes', () => {
  assert.equal(tileModelBytes(100, 400), 2 ** 21);
  assert.equal(tileModelBytes(1, 2 ** 40), 32);
  const content = msgpack([[0, Array(15).fill([1, 7])]]);
  const payload = msgpack([5, 1, zstdRaw(content), new Uint8Array(0)]);
  const budget = new TileBudget(2 ** 30, 2 * content.length, 'tile 3');
  readEcm(payload, 5, 1, 'OPAC', null, budget);
  readEcm(payload, 5, 1, 'OPAC', null, budget);
  assert.throws(() => readEcm(payload, 5, 1, 'OPAC', null, budget), (err) => err instanceof CodecError && /tile 3's model bytes/.test(err.message));
});
