// Side information per tile (format 1.6, spec 10.15): hand-made tiled files whose tiles carry TSID chunks
// (the SIDE layout of 10.9) decode and expose each tile's views, by the whole-file decoder and by the
// streaming reader as it reads each tile; a TSID that names no tile, breaks the tiles' chunk order, sits in
// an untiled file, breaks a SIDE rule or asks for more pixels than its tile's share of the file's floor is
// refused by both.

import test from 'node:test';
import assert from 'node:assert/strict';
import { ChecksumMismatch, CodecError, DuplicateChunk, bytesSource, decodeGspc, openGspc } from '../src/index.mjs';
import { tileViewPixelBudget } from '../src/limits.mjs';
import { box, constantScene, gspcFile, sidePayload, tiledScene, webpHeader } from './writer.mjs';

const VERSION = { major: 1, minor: 6 };

/** A TSID chunk of tile `index`; writers mark it optional (spec 6). */
const tsid = (index, payload, flags = 0) => ({ type: 'TSID', index, flags, payload });

/**
 * meta and chunks of a tiled scene (tiledScene) of `counts` Gaussians per tile, tile k's TSID payload
 * `sides[k]` (where given) after its attribute chunks.
 */
function sided(counts, sides, tile = undefined) {
  const { meta, chunks } = tiledScene(counts, tile);
  const out = [];
  chunks.forEach((c, i) => {
    out.push(c);
    const next = chunks[i + 1];
    if (c.type !== 'TIDX' && (!next || next.index !== c.index) && sides[c.index]) out.push(tsid(c.index, sides[c.index]));
  });
  return { meta, chunks: out };
}

const file = ({ meta, chunks }) => gspcFile(meta, chunks, VERSION);

async function streamed(bytes, options) {
  const reader = await openGspc(bytesSource(bytes));
  const tiles = [];
  for await (const tile of reader.decode(options)) tiles.push(tile);
  return { reader, tiles };
}

/** Refused by decodeGspc and by the streaming reader, with a CodecError whose message holds `words`. */
async function refused(bytes, words) {
  const check = (err) => {
    assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
    assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
    return true;
  };
  assert.throws(() => decodeGspc(bytes), check);
  await assert.rejects(streamed(bytes), check);
}

// Tile 0: two views, the second with a half-resolution residual; tile 2: one view, 40 x 30.
const SIDE_0 = sidePayload([{}, { image: webpHeader(12, 10), gain: 25 }], { scale: 2 });
const SIDE_2 = sidePayload([{}], { width: 40, height: 30 });

test('tsid: a tiled file with TSID chunks decodes, each tile exposing its own views', async () => {
  const bytes = file(sided([40, 70, 10], { 0: SIDE_0, 2: SIDE_2 }));
  const scene = decodeGspc(bytes);
  assert.deepEqual(scene.header.version, [1, 6]);
  assert.equal(scene.count, 120);
  assert.deepEqual(scene.views, []); // the whole scene has no side information
  assert.deepEqual(scene.tileViews.map((v) => v.length), [2, 0, 1]);
  const [plain, withResidual] = scene.tileViews[0];
  assert.deepEqual([plain.camera.width, plain.camera.height, plain.camera.fx], [24, 20, 30]);
  assert.equal(plain.residual, null);
  assert.deepEqual(withResidual.residual.fullShape, [20, 24]);
  assert.deepEqual(withResidual.residual.shape, [10, 12]);
  assert.equal(withResidual.residual.gain, 25);
  assert.deepEqual([...withResidual.residual.image], [...webpHeader(12, 10)]);
  assert.deepEqual([scene.tileViews[2][0].camera.width, scene.tileViews[2][0].camera.height], [40, 30]);

  // The streaming reader gives each tile its views as it reads the tile; the same records.
  const { tiles } = await streamed(bytes);
  assert.deepEqual(tiles.map((t) => t.views.length), [2, 0, 1]);
  assert.deepEqual(tiles.map((t) => t.count), [40, 70, 10]);
  assert.deepEqual(tiles[0].views[1].residual.shape, [10, 12]);
  assert.deepEqual(tiles[2].views[0].camera, scene.tileViews[2][0].camera);
});

test('tsid: a TSID anywhere among its tile\'s chunks, marked required or not, is read', async () => {
  const { meta, chunks } = tiledScene([40, 40]);
  // TIDX, tile 0's five chunks, tile 1's five: tile 1's TSID first among its chunks, tile 0's amid its own.
  const order = [chunks[0], chunks[1], chunks[2], tsid(0, SIDE_2, 1), ...chunks.slice(3, 6), tsid(1, SIDE_0), ...chunks.slice(6)];
  const bytes = file({ meta, chunks: order });
  assert.deepEqual(decodeGspc(bytes).tileViews.map((v) => v.length), [1, 2]);
  assert.deepEqual((await streamed(bytes)).tiles.map((t) => t.views.length), [1, 2]);
});

test('tsid: a region\'s decode reads the TSID of each tile it decodes with the tile', async () => {
  const boxes = [box(-1, -1, -1, 0, 0, 0), box(0, 0, 0, 1, 1, 1)];
  const bytes = file(sided([40, 40], { 1: SIDE_0 }, (k, map) => ({ ...map, box: boxes[k] })));
  const { tiles } = await streamed(bytes, { region: [0.5, 0.5, 0.5, 1, 1, 1] });
  assert.deepEqual(tiles.map((t) => t.number), [1]);
  assert.equal(tiles[0].views.length, 2);
  // A damaged TSID is found when its tile is read, by a region's decode too; the tiles before it came.
  const reader = await openGspc(bytesSource(bytes));
  const damaged = bytes.slice();
  damaged[reader.tileLayout.tiles[1].side.offset + 3] ^= 1;
  await assert.rejects(streamed(damaged, { region: [0.5, 0.5, 0.5, 1, 1, 1] }), ChecksumMismatch);
  const got = [];
  await assert.rejects(async () => {
    for await (const tile of (await openGspc(bytesSource(damaged))).decode()) got.push(tile.number);
  }, (err) => err instanceof ChecksumMismatch && /TSID#1/.test(err.message));
  assert.deepEqual(got, [0]);
  assert.throws(() => decodeGspc(damaged), ChecksumMismatch);
});

test('tsid: untiled files have no tile views; their one streamed tile gives the scene\'s views', async () => {
  const { meta, chunks } = constantScene(10);
  const bytes = gspcFile(meta, [...chunks, { type: 'SIDE', payload: SIDE_2 }]);
  const scene = decodeGspc(bytes);
  assert.equal(scene.tileViews, null);
  const { tiles } = await streamed(bytes);
  assert.deepEqual(tiles[0].views, scene.views);
  assert.equal(tiles[0].views.length, 1);
});

// --- refusals (spec 10.15) -------------------------------------------------------------------------------

test('tsid: a TSID whose index names no tile is refused', async () => {
  const { meta, chunks } = tiledScene([40, 40]);
  await refused(file({ meta, chunks: [...chunks, tsid(2, SIDE_2)] }), 'chunk TSID#2 names no tile (the file has 2)');
  await refused(file({ meta, chunks: [...chunks, tsid(2 ** 32 - 1, SIDE_2)] }), 'names no tile');
});

test('tsid: a TSID out of its tile\'s place in the chunk order is refused', async () => {
  const { meta, chunks } = tiledScene([40, 40, 40]);
  // After a later tile's chunks.
  await refused(file({ meta, chunks: [...chunks, tsid(0, SIDE_2)] }), "chunk TSID#0 comes after tile 2's chunks");
  await refused(file({ meta, chunks: [...chunks.slice(0, 11), tsid(0, SIDE_2), ...chunks.slice(11)] }), "chunk TSID#0 comes after tile 1's chunks");
  // Before an earlier tile's chunks: those then come after it.
  await refused(file({ meta, chunks: [chunks[0], tsid(1, SIDE_2), ...chunks.slice(1)] }), "chunk POSN#0 comes after tile 1's chunks");
  // Before the tile index.
  await refused(file({ meta, chunks: [tsid(0, SIDE_2), ...chunks] }), 'chunk TSID#0 comes before the tile index (TIDX)');
});

test('tsid: a TSID in a file without a tile index is refused', async () => {
  const { meta, chunks } = constantScene(10);
  const untiled = gspcFile(meta, [...chunks, tsid(0, SIDE_2)], VERSION);
  await refused(untiled, 'chunk TSID#0 (a tile\'s side information, spec 10.15) in a file without a tile index');
  // Refused when the file is opened, from the chunk table, before any payload is decoded.
  await assert.rejects(openGspc(bytesSource(untiled)), /without a tile index/);
  // Also beside a SIDE chunk, which is the whole scene's.
  await refused(gspcFile(meta, [...chunks, { type: 'SIDE', payload: SIDE_2 }, tsid(0, SIDE_2)], VERSION), 'without a tile index');
});

test('tsid: two TSID chunks of one tile are refused by the container', () => {
  const { meta, chunks } = sided([40, 40], { 1: SIDE_2 });
  assert.throws(() => decodeGspc(file({ meta, chunks: [...chunks, tsid(1, SIDE_0)] })), DuplicateChunk);
});

test('tsid: a TSID payload breaking a SIDE rule (10.9) is refused, naming the tile', async () => {
  const bad = (payload) => file(sided([40, 40], { 0: SIDE_2, 1: payload }));
  const said = "tile 1's side information: ";
  await refused(bad(sidePayload([{ image: webpHeader(12, 10), gain: 0 }], { scale: 2 })), `${said}side-information view 0: residual gain`);
  await refused(bad(sidePayload([{ image: webpHeader(12, 10), gain: -1 }], { scale: 2 })), 'residual gain');
  await refused(bad(Uint8Array.of(...SIDE_2, 0)), `${said}TSID#1 chunk images need 0 bytes after the view table, found 1`);
  await refused(bad(SIDE_2.subarray(0, 40)), `${said}TSID#1 chunk is truncated`);
  await refused(bad(SIDE_2.subarray(0, 5)), `${said}TSID#1 chunk is truncated`);
  await refused(bad(new Uint8Array(0)), `${said}TSID#1 chunk is truncated`);
  await refused(bad(sidePayload([{}], { codec: 3 })), `${said}TSID#1 chunk names codec 3`);
  await refused(bad(sidePayload([{}], { scale: 17 })), 'scale 17');
  await refused(bad(sidePayload([{}], { width: 0 })), 'width');
  await refused(bad(sidePayload([{}], { fx: -1 })), 'focal');
  await refused(bad(sidePayload([])), `${said}TSID#1 chunk has 0 views`);
  const flags = sidePayload([{}]);
  flags[4] = 2;
  await refused(bad(flags), 'unknown flags 0x2');
  // The residual image's declared size is checked, though no image is decoded (10.7).
  await refused(bad(sidePayload([{ image: webpHeader(24, 20) }], { scale: 2 })), `${said}side-information view 0: residual webp image declares 24x20`);
  await refused(bad(sidePayload([{ image: new Uint8Array(40) }])), 'RIFF');
});

test('tsid: each tile\'s views are within its share of the file\'s pixel floor (10.15)', async () => {
  // Tile 0's TSID holds two views with their own cameras, 65536 x h and r x 1: the payload's length, and so
  // the tile's bytes Q_0 and the tiles' Q, do not depend on h and r.
  const twoViews = (h, r) => sidePayload([{ width: 65536, height: h }, { width: r, height: 1 }], { perView: true });
  const build = (h, r) => sided([40, 40], { 0: twoViews(h, r) });
  const { chunks } = build(1, 1);
  const bytesOf = (k) => chunks.filter((c) => c.type !== 'TIDX' && c.index === k).reduce((n, c) => n + c.payload.length, 0);
  const q0 = bytesOf(0);
  const q = q0 + bytesOf(1);
  const budget = Math.min(2 ** 28, Math.max(Math.floor((2 ** 22 * q0) / q), 1024 * q0));
  assert.ok(budget < 2 ** 22, `tile 0's share ${budget} is below an untiled file's floor`);
  const h = Math.floor((budget - 1) / 65536);
  const r = budget - 65536 * h; // 1 .. 65536
  assert.ok(h >= 1 && r >= 1 && r < 65536);
  // Exactly the share: read. One pixel more: refused.
  const exact = file(build(h, r));
  assert.deepEqual(decodeGspc(exact).tileViews.map((v) => v.length), [2, 0]);
  assert.deepEqual((await streamed(exact)).tiles[0].views.map((v) => v.camera.width), [65536, r]);
  await refused(file(build(h, r + 1)), `tile 0's side information: side-information views ask for ${budget + 1} pixels in tile 0 (${q0} of the tiles' ${q} bytes); the limit is ${budget}`);
  // The same views fit the floor of an untiled file's SIDE chunk (10.8), which a tile shares with the others.
  const { meta, chunks: own } = constantScene(40);
  assert.equal(decodeGspc(gspcFile(meta, [...own, { type: 'SIDE', payload: twoViews(h, r + 1) }])).views.length, 2);
  // One view is at most 2^24 pixels, whatever the share.
  await refused(file(sided([40, 40], { 1: sidePayload([{}], { width: 4097, height: 4096 }) })), "tile 1's side information: side-information view 0 is 4097x4096 = 16781312 pixels; the limit is 16777216");
});

test('tsid: a tile\'s pixel share, min(2^28, max(floor(2^22 Q_k / Q), 1024 Q_k)), in exact integers', () => {
  assert.equal(tileViewPixelBudget(1, 3), Math.floor(2 ** 22 / 3));
  assert.equal(tileViewPixelBudget(1000, 3000), 1398101);
  assert.equal(tileViewPixelBudget(2000, 3000), 2796202);
  assert.equal(tileViewPixelBudget(3000, 3000), 2 ** 22); // one tile: the untiled file's floor
  assert.equal(tileViewPixelBudget(5000, 5000), 1024 * 5000); // past 4096 bytes the per-byte rule wins
  assert.equal(tileViewPixelBudget(2 ** 18, 2 ** 40), 2 ** 28);
  assert.equal(tileViewPixelBudget(2 ** 45 + 1, 2 ** 46 + 3), 2 ** 28); // 2^22 Q_k passes 2^53
  assert.equal(tileViewPixelBudget(7, 2 ** 40), 7 * 1024);
});
