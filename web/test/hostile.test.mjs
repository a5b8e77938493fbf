// Small hand-made files that ask for large work or memory: each is refused by a limit of spec 7 or 10.10
// before anything of the asked size is allocated or decoded. A decoder without these checks would allocate
// gigabytes or run for minutes on some of them.

import test from 'node:test';
import assert from 'node:assert/strict';
import { CodecError, decodeGspc } from '../src/index.mjs';
import { F64, constantEcm, constantScene, ecm, gspcFile, msgpack, zstdRaw, zstdRleBomb } from './writer.mjs';

/** A constant scene of n Gaussians with `replace` (type -> payload) swapped in and `attributes` overridden. */
function file(n, replace = {}, attributes = {}, extra = []) {
  const { meta, chunks } = constantScene(n, attributes);
  const swapped = chunks.map((c) => (c.type in replace ? { ...c, payload: replace[c.type] } : c));
  return gspcFile(meta, [...swapped, ...extra]);
}

function refused(bytes, words) {
  assert.throws(() => decodeGspc(bytes), (err) => {
    assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
    assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
    return true;
  });
}

test('hostile: the smallest file of 65,536 Gaussians decodes (the count floor), one more is refused', () => {
  assert.equal(decodeGspc(file(2 ** 16)).count, 2 ** 16);
  refused(file(2 ** 16 + 1), 'payload bytes');
  refused(file(2 ** 26), 'payload bytes');
});

test('hostile: a matrix shape other than the chunk needs is refused before decoding', () => {
  const junk = new Uint8Array(3);
  refused(file(100, { OPAC: msgpack([2 ** 40, 1, junk, junk]) }), 'expected 100x1');
  refused(file(100, { SCAL: msgpack([100, 2 ** 20, junk, junk]) }), 'expected 100x3');
});

test('hostile: a models frame declaring 2^26 bytes from a few bytes is refused before decompressing', () => {
  const frame = Uint8Array.from([0x28, 0xb5, 0x2f, 0xfd, 0xa0, 0, 0, 0, 4, 0x01, 0, 0]); // declares 2^26
  refused(file(100, { OPAC: msgpack([100, 1, frame, new Uint8Array(0)]) }), 'declare');
});

test('hostile: a models frame with no declared size stops once its output passes the limit', () => {
  // 512 RLE blocks of 128 KiB: 2 KB of frame for 64 MiB of content
  refused(file(100, { OPAC: msgpack([100, 1, zstdRleBomb(512), new Uint8Array(0)]) }), 'decompress to more than');
});

test('hostile: model windows past the table bound are refused before any table is built', () => {
  const wide = [2, 0, 2 ** 22 - 1, 0, 3, 0];
  const models = [[0, Array(15).fill(wide)]];
  refused(file(100, { OPAC: ecm(100, 1, models) }), 'table entries');
  // one widest table is within the floor, and is never built: no row uses it
  const one = [[0, [[1, 10], ...Array(13).fill([1, 10]), wide]]];
  assert.equal(decodeGspc(file(100, { OPAC: ecm(100, 1, one) })).count, 100);
});

test('hostile: at version 4 the matrices of one chunk share the table bound', () => {
  const steps = { opacity_levels: 20, scale_step: new F64(0.5), rotation_levels: 36, dc_step: new F64(0.25), sh_steps: [] };
  const n = 160;
  // PREC: level-0 rows (0, 64, 128; bucket 12) in class 1, the others in class 0
  const prec = ecm(n, 1, [[0, [...Array(12).fill([1, 0]), [1, 1], [1, 0], [1, 0]]]]);
  const wide = [2, 0, 2 ** 22 - 100, 0, 3, 0];
  const withTable = (m) => ecm(m, 1, [[0, [...Array(14).fill([1, 10]), wide]]]);
  const build = (opac) => {
    const { meta, chunks } = constantScene(n, { version: 4, classes: [steps] });
    const swapped = chunks.map((c) => {
      if (c.type === 'OPAC') return { ...c, payload: msgpack(opac) };
      if (c.type === 'POSN') return c;
      return { ...c, payload: msgpack([constantEcm(157, c.type === 'ROTN' ? 4 : 3, 0), constantEcm(3, c.type === 'ROTN' ? 4 : 3, 0)]) };
    });
    return gspcFile(meta, [...swapped, { type: 'PREC', payload: prec }]);
  };
  // each matrix alone is within its own floor; together they pass the chunk's
  assert.equal(decodeGspc(build([withTable(157), constantEcm(3, 1, 10)])).count, n);
  refused(build([withTable(157), withTable(3)]), 'table entries');
});

test('hostile: a SIDE chunk cannot ask for more views, pixels or bytes than it holds', () => {
  const head = (views, flags = 0) => {
    const b = new Uint8Array(8 + 24);
    const v = new DataView(b.buffer);
    v.setUint32(0, views, true);
    b.set([flags, 0, 8, 1], 4);
    v.setUint32(8, 100, true);
    v.setUint32(12, 100, true);
    v.setFloat32(16, 100, true);
    v.setFloat32(20, 100, true);
    return b;
  };
  refused(file(100, {}, {}, [{ type: 'SIDE', payload: head(2 ** 20) }]), 'truncated');
  refused(file(100, {}, {}, [{ type: 'SIDE', payload: head(2 ** 20 + 1) }]), 'views');
  refused(file(100, {}, {}, [{ type: 'SIDE', payload: head(1, 2) }]), 'flags');
  const wide = head(1);
  new DataView(wide.buffer).setUint32(8, 65536, true);
  new DataView(wide.buffer).setUint32(12, 65536, true);
  const view = new Uint8Array(52);
  refused(file(100, {}, {}, [{ type: 'SIDE', payload: Uint8Array.from([...wide, ...view]) }]), 'pixels');
});

test('hostile: raw position bits are counted before any code is decoded', () => {
  // every gap of 63 bits on a 21-bit grid needs 62 raw bits per Gaussian; none are there
  const attributes = { version: 2, position: { bits: 21, lo: [new F64(-1), new F64(-1), new F64(-1)], step: [new F64(1e-6), new F64(1e-6), new F64(1e-6)], centre: [new F64(0), new F64(0), new F64(0)], radius: new F64(1) } };
  refused(file(1000, { POSN: msgpack([constantEcm(1000, 1, 63), new Uint8Array(0)]) }, attributes), 'raw-bit');
});

test('hostile: models are one frame of raw zstd content', () => {
  const models = msgpack([[0, Array(15).fill([1, 10])]]);
  assert.equal(decodeGspc(file(100, { OPAC: msgpack([100, 1, zstdRaw(models, { declare: false }), new Uint8Array(0)]) })).count, 100);
  refused(file(100, { OPAC: msgpack([100, 1, models, new Uint8Array(0)]) }), 'zstd');
});
