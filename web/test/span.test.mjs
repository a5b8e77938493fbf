// Spans (format 1.9, spec 10.17): a tile index entry's `span` makes tile k's TSID serve tiles k .. k + span
// - 1. Hand-made tiled files with spans decode as their tiles do without one, by the whole-file decoder and
// the streaming reader, which lists each tile's span; a span's views have one pixel share, by the bytes of
// all its tiles; and a file breaking a rule of 10.17 is refused by both, when it is opened.

import test from 'node:test';
import assert from 'node:assert/strict';
import { CodecError, bytesSource, decodeGspc, openGspc } from '../src/index.mjs';
import { F64, box, constantScene, gspcFile, sidePayload, tiledScene } from './writer.mjs';

const VERSION = { major: 1, minor: 9 };

/** A TSID chunk of tile `index`; writers mark it optional (spec 6). */
const tsid = (index, payload) => ({ type: 'TSID', index, flags: 0, payload });

/**
 * A file of a tiled scene (tiledScene) of `counts` Gaussians per tile, tile k's index map given the keys
 * `keys[k]` (a span, a drawn list) and its TSID payload `sides[k]` (where given) after its attribute chunks.
 */
function spanned(counts, keys, sides) {
  const { meta, chunks } = tiledScene(counts, (k, map) => ({ ...map, ...(keys[k] ?? {}) }));
  const out = [];
  chunks.forEach((c, i) => {
    out.push(c);
    const next = chunks[i + 1];
    if (c.type !== 'TIDX' && (!next || next.index !== c.index) && sides[c.index]) out.push(tsid(c.index, sides[c.index]));
  });
  return gspcFile(meta, out, VERSION);
}

async function streamed(bytes, options) {
  const reader = await openGspc(bytesSource(bytes));
  const tiles = [];
  for await (const tile of reader.decode(options)) tiles.push(tile);
  return { reader, tiles };
}

/** Refused by decodeGspc and, when the file is opened, by the streaming reader, with `words` in the message. */
async function refused(bytes, ...words) {
  const check = (err) => {
    assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
    for (const w of words) assert.ok(err.message.includes(w), `'${w}' not in: ${err.message}`);
    return true;
  };
  assert.throws(() => decodeGspc(bytes), check);
  await assert.rejects(openGspc(bytesSource(bytes)), check);
}

const SIDE = sidePayload([{}, {}]);
const SIDE_1 = sidePayload([{}], { width: 40, height: 30 });

test('span: a span decodes as its tiles do without one; the tiles list each tile\'s span', async () => {
  const plain = decodeGspc(spanned([40, 70, 10, 20], {}, { 0: SIDE, 3: SIDE_1 }));
  const bytes = spanned([40, 70, 10, 20], { 0: { span: 3 } }, { 0: SIDE, 3: SIDE_1 });
  const scene = decodeGspc(bytes);
  assert.deepEqual(scene.header.version, [1, 9]);
  assert.deepEqual(scene.header.tiles.map((t) => t.span), [3, 1, 1, 1]);
  assert.deepEqual(scene.tileViews.map((v) => v.length), [2, 0, 0, 1]);
  for (const key of ['means', 'quats', 'logScales', 'opacities', 'shDc', 'shRest']) assert.deepEqual(scene[key], plain[key], key);
  const { reader, tiles } = await streamed(bytes);
  assert.deepEqual(reader.tiles.map((t) => [t.span, t.drawn]), [[3, []], [1, []], [1, []], [1, []]]);
  assert.deepEqual(tiles.map((t) => [t.count, t.views.length]), [[40, 2], [70, 0], [10, 0], [20, 1]]);
  // A span of 1 written out is a tile alone; so is a tile without the key; an untiled file's one tile too.
  const ones = spanned([40, 70], { 0: { span: 1 }, 1: { span: 1 } }, { 1: SIDE_1 });
  assert.deepEqual(decodeGspc(ones).header.tiles.map((t) => t.span), [1, 1]);
  const { meta, chunks } = constantScene(10);
  assert.deepEqual((await openGspc(bytesSource(gspcFile(meta, chunks)))).tiles.map((t) => t.span), [1]);
});

test('span: at most 64 tiles, and the last tile\'s span is 1', async () => {
  const counts = Array(66).fill(10);
  const most = spanned(counts, { 1: { span: 64 } }, { 1: SIDE });
  assert.deepEqual(decodeGspc(most).tileViews.map((v) => v.length).slice(0, 3), [0, 2, 0]);
  assert.deepEqual((await openGspc(bytesSource(most))).tiles.map((t) => t.span).slice(0, 3), [1, 64, 1]);
  await refused(spanned(counts, { 1: { span: 65 } }, { 1: SIDE }), "tile 1's span is 65, not an integer 1..64");
  await refused(spanned([10, 10, 10], { 1: { span: 3 } }, { 1: SIDE }), "tile 1's span is 3, not an integer 1..2");
  await refused(spanned([10, 10, 10], { 2: { span: 2 } }, { 2: SIDE }), "tile 2's span is 2, not an integer 1..1");
  assert.equal(decodeGspc(spanned([10, 10, 10], { 1: { span: 2 } }, { 1: SIDE })).count, 30);
});

test('span: a span that is not an integer from 1 is refused', async () => {
  for (const [span, shown] of [[0, '0'], [-1, '-1'], [new F64(2), '2'], [1.5, '1.5'], [true, 'true'], ['2', "'2'"], [[2], '[2]']]) {
    await refused(spanned([10, 10, 10], { 0: { span } }, { 0: SIDE }), `tile 0's span is ${shown}, not an integer 1..3`);
  }
});

test('span: a span above 1 on a tile without a TSID is refused', async () => {
  await refused(spanned([10, 10, 10], { 1: { span: 2 } }, { 0: SIDE }), 'tile 1 has a span of 2 tiles but no TSID chunk');
  await refused(spanned([10, 10, 10], { 0: { span: 2 } }, {}), 'tile 0 has a span of 2 tiles but no TSID chunk');
});

test('span: a member with a TSID, drawn tiles or a span of its own is refused', async () => {
  await refused(spanned([10, 10, 10], { 0: { span: 3 } }, { 0: SIDE, 2: SIDE_1 }), "tile 2, in tile 0's span, has a TSID chunk of its own");
  await refused(spanned([10, 10, 10], { 0: { span: 2 } }, { 0: SIDE, 1: SIDE_1 }), "tile 1, in tile 0's span, has a TSID chunk of its own");
  await refused(spanned([10, 10, 10], { 0: { span: 2 }, 1: { drawn: [2] } }, { 0: SIDE }), "tile 1, in tile 0's span, has drawn tiles of its own");
  await refused(spanned([10, 10, 10, 10], { 0: { span: 3 }, 1: { span: 2 } }, { 0: SIDE }), "tile 1, in tile 0's span, has a span of 2 of its own");
  // An empty drawn list is no drawn tiles (spec 10.14: absent, empty); a member's span of 1 is none.
  const empty = spanned([10, 10, 10], { 0: { span: 2 }, 1: { drawn: [], span: 1 } }, { 0: SIDE });
  assert.deepEqual(decodeGspc(empty).tileViews.map((v) => v.length), [2, 0, 0]);
  // Spans side by side, and a span drawing the tiles outside it, are read.
  const two = spanned([10, 10, 10, 10], { 0: { span: 2, drawn: [2, 3] }, 2: { span: 2, drawn: [0] } }, { 0: SIDE, 2: SIDE_1 });
  assert.deepEqual(decodeGspc(two).tileViews.map((v) => v.length), [2, 0, 1, 0]);
});

test('span: a span\'s first tile drawing a tile of its own span is refused', async () => {
  await refused(spanned([10, 10, 10], { 0: { span: 2, drawn: [1] } }, { 0: SIDE }), "tile 0's drawn tiles name tile 1, of its own span");
  await refused(spanned([10, 10, 10], { 0: { span: 3, drawn: [2, 1] } }, { 0: SIDE }), "tile 0's drawn tiles name tile 1, of its own span");
});

test('span: a span\'s views have one pixel share, Q_k the bytes of all its tiles and its TSID (10.17)', async () => {
  // Tile 0's TSID: one view of 65536 x h and one of r x 1, their own cameras: its length, and so every Q_k
  // and Q, does not depend on h and r.
  const twoViews = (h, r) => sidePayload([{ width: 65536, height: h }, { width: r, height: 1 }], { perView: true });
  const counts = [40, 60, 50];
  const build = (span, h, r) => spanned(counts, { 0: { span } }, { 0: twoViews(h, r), 2: SIDE_1 });
  const reader = await openGspc(bytesSource(build(2, 1, 1)));
  const layout = reader.tileLayout;
  const own = (k) => layout.tiles[k].bytes + (layout.tiles[k].side?.length ?? 0);
  const q = own(0) + own(1) + own(2);
  assert.deepEqual(layout.tiles.map((t) => t.sideBytes), [own(0) + own(1), 0, own(2)]);
  assert.equal(layout.sideBytes, q);
  const share = (bytes) => Math.min(2 ** 28, Math.max(Math.floor((2 ** 22 * bytes) / q), 1024 * bytes));
  const budget = share(own(0) + own(1));
  assert.ok(share(own(0)) < budget && budget < 2 ** 22);
  const h = Math.floor((budget - 1) / 65536);
  const r = budget - 65536 * h;
  assert.ok(h >= 1 && r >= 1 && r < 65536);
  // Exactly the span's share: read. One pixel more: refused. The same views on tile 0 alone: refused.
  const exact = build(2, h, r);
  assert.deepEqual(decodeGspc(exact).tileViews.map((v) => v.length), [2, 0, 1]);
  assert.deepEqual((await streamed(exact)).tiles[0].views.map((v) => v.camera.width), [65536, r]);
  const over = `side-information views ask for ${budget + 1} pixels in tile 0 (${own(0) + own(1)} of the tiles' ${q} bytes); the limit is ${budget}`;
  assert.throws(() => decodeGspc(build(2, h, r + 1)), (err) => err instanceof CodecError && err.message.includes(over));
  await assert.rejects(streamed(build(2, h, r + 1)), (err) => err instanceof CodecError && err.message.includes(over));
  assert.throws(() => decodeGspc(build(1, h, r)), (err) => err instanceof CodecError && err.message.includes(`in tile 0 (${own(0)} of the tiles' ${q} bytes); the limit is ${share(own(0))}`));
});

test('span: a region\'s decode of a span\'s member reads the member alone, unrefined (10.17)', async () => {
  const boxes = [box(-1, -1, -1, 0, 0, 0), box(0, 0, 0, 1, 1, 1), box(2, 2, 2, 3, 3, 3)];
  const { meta, chunks } = tiledScene([40, 40, 40], (k, map) => ({ ...map, box: boxes[k], ...(k === 0 ? { span: 2 } : {}) }));
  const bytes = gspcFile(meta, [...chunks.slice(0, 6), tsid(0, SIDE), ...chunks.slice(6)], VERSION);
  const { tiles } = await streamed(bytes, { region: [0.5, 0.5, 0.5, 1, 1, 1] });
  assert.deepEqual(tiles.map((t) => [t.number, t.count, t.views.length]), [[1, 40, 0]]);
});
