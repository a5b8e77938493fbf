// Side information (spec 10.7-10.9) and meta's other sections (10.8): every record is checked when the file
// is read, also by a decoder that decodes no image (as this one), with hand-made files that break one rule.

import test from 'node:test';
import assert from 'node:assert/strict';
import { CodecError, decodeGspc } from '../src/index.mjs';
import { declaredSize } from '../src/imageHeaders.mjs';
import { F64, POSE, constantScene, f32, gspcFile, sidePayload, webpHeader } from './writer.mjs';

const camera = (overrides = {}) => ({ width: 24, height: 20, intrinsics: f32(30, 30, 12, 10), pose: POSE, ...overrides });
const residual = (overrides = {}) => ({ codec: 'webp', shape: [20, 24], bits: 8, gain: new F64(50), offset: 128, ...overrides });

/** A constant scene whose side_info is `side` (merged over {background}), with `extra` chunks. */
function file(side = {}, extra = [], meta = {}) {
  const scene = constantScene(10);
  Object.assign(scene.meta.side_info, side);
  Object.assign(scene.meta, meta);
  return gspcFile(scene.meta, [...scene.chunks, ...extra]);
}

function refused(bytes, words) {
  assert.throws(() => decodeGspc(bytes), (err) => {
    assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
    assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
    return true;
  });
}

const resi = (index, payload) => ({ type: 'RESI', index, payload });

test('side: a 1.0-layout view with a residual and its RESI chunk', () => {
  const scene = decodeGspc(file({ views: [{ camera: camera(), residual: residual() }, { camera: camera() }] }, [resi(0, webpHeader(24, 20))]));
  assert.equal(scene.views.length, 2);
  assert.deepEqual(scene.views[0].residual.shape, [20, 24]);
  assert.equal(scene.views[0].residual.gain, 50);
  assert.equal(scene.views[1].residual, null);
  const half = { scale: 2n, full_shape: [20, 24], shape: [10, 12] };
  assert.equal(decodeGspc(file({ views: [{ camera: camera(), residual: residual(half) }] }, [resi(0, webpHeader(12, 10))])).views[0].residual.scale, 2);
});

test('side: 1.0-layout records are refused by the rules of 10.7 and 10.8', () => {
  const one = (res, image = webpHeader(24, 20), cam = camera()) => file({ views: [{ camera: cam, residual: res }] }, [resi(0, image)]);
  refused(one(residual({ gain: 50 })), 'gain'); // an integer, not a msgpack float
  refused(one(residual({ gain: new F64(1e-50) })), 'gain');
  refused(one(residual({ gain: new F64(1e39) })), 'gain');
  refused(one(residual({ offset: 127 })), 'offset');
  refused(one(residual({ bits: 12 })), 'bits');
  refused(one(residual({ bits: new F64(8) })), 'bits');
  refused(one(residual({ codec: 'png' })), 'codec');
  refused(one(residual({ shape: [20, 23] })), 'cover');
  refused(one(residual({ scale: 17n })), 'scale');
  // Without full_shape, shape must be the camera's size (10.7): a half-resolution record needs full_shape.
  refused(one(residual({ scale: 2n, shape: [10, 12] }), webpHeader(12, 10)), 'cover');
  refused(one(residual(), webpHeader(24, 21)), 'declares 24x21');
  refused(one(residual(), new Uint8Array(40)), 'RIFF');
  refused(one(residual(), webpHeader(24, 20), camera({ intrinsics: f32(0, 30, 12, 10) })), 'focal');
  refused(one(residual(), webpHeader(24, 20), camera({ pose: f32(NaN, ...Array(11).fill(0)) })), 'NaN');
  refused(one(residual(), webpHeader(24, 20), camera({ width: new F64(24) })), 'width');
  refused(one(residual(), webpHeader(24, 20), camera({ intrinsics: f32(30, 30, 12) })), 'intrinsics');
  refused(file({ views: [{ camera: camera(), residual: residual() }] }), 'RESI chunk or a residual record');
  refused(file({ views: [{ camera: camera() }] }, [resi(0, webpHeader(24, 20))]), 'RESI chunk or a residual record');
  refused(file({ views: [{ camera: camera() }] }, [resi(3, webpHeader(24, 20))]), 'view 3');
});

const side = (payload, index = 0) => ({ type: 'SIDE', index, payload });

test('side: the SIDE chunk (10.9)', () => {
  const scene = decodeGspc(file({}, [side(sidePayload([{}, { image: webpHeader(12, 10) }], { scale: 2 }))]));
  assert.equal(scene.views.length, 2);
  assert.deepEqual(scene.views[1].residual.fullShape, [20, 24]);
  assert.deepEqual(scene.views[1].residual.shape, [10, 12]);
  refused(file({}, [side(sidePayload([{ image: webpHeader(12, 10), gain: 0 }], { scale: 2 }))]), 'gain');
  refused(file({}, [side(sidePayload([{ image: webpHeader(12, 10), gain: -1 }], { scale: 2 }))]), 'gain');
  refused(file({}, [side(sidePayload([{ image: webpHeader(24, 20) }], { scale: 2 }))]), 'declares 24x20');
  refused(file({}, [side(sidePayload([{}], { codec: 3 }))]), 'codec 3');
  refused(file({}, [side(sidePayload([{}], { scale: 17 }))]), 'scale 17');
  refused(file({}, [side(sidePayload([{}], { width: 0 }))]), 'width');
  refused(file({}, [side(sidePayload([{}], { fx: -1 }))]), 'focal');
  refused(file({}, [side(Uint8Array.of(...sidePayload([{}]), 0))]), 'images need 0 bytes');
  refused(file({}, [side(sidePayload([{}]), 1)]), 'index 1');
  refused(file({ views: [{ camera: camera() }] }, [side(sidePayload([{}]))]), 'both');
  refused(file({}, [side(sidePayload([{}])), resi(0, webpHeader(24, 20))]), 'both');
  // 8 views of 1024 x 1024 in a file of about 2 KB: past the 2^22-pixel floor
  refused(file({}, [side(sidePayload(Array(5).fill({}), { width: 1024, height: 1024 }))]), 'pixels');
});

test('side: side_info and scene fields (10.8)', () => {
  assert.equal(decodeGspc(file({ background: [0, new F64(0.5), 1], restorer: 'none', refine_iterations: 100000 })).header.sideInfo.refineIterations, 100000);
  refused(file({ background: [0, 0.5] }), 'background');
  refused(file({ background: [0, 0.5, 2] }), 'background');
  refused(file({ background: [0, 0.5, 'x'] }), 'background');
  refused(file({ restorer: '' }), 'restorer');
  refused(file({ restorer: 'x'.repeat(201) }), 'restorer');
  assert.equal(decodeGspc(file({ restorer: '\u{1F600}'.repeat(200) })).header.sideInfo.restorer.length, 400);
  refused(file({ refine_iterations: 100001 }), 'refine_iterations');
  refused(file({ refine_iterations: new F64(300) }), 'refine_iterations');
  refused(file({}, [], { scene: [] }), 'scene');
  refused(file({}, [], { scene: { sh_degree: 4 } }), 'scene.sh_degree');
  refused(file({}, [], { scene: { num_gaussians: -1 } }), 'scene.num_gaussians');
  assert.equal(decodeGspc(file({}, [], { scene: { source_gaussians: 'any' }, encoder: 7 })).count, 10);
  const noSide = constantScene(10);
  delete noSide.meta.side_info;
  refused(gspcFile(noSide.meta, noSide.chunks), 'side_info');
});

test('image headers: declared sizes of JPEG XL (bare and boxed), WebP and AVIF', () => {
  // JPEG XL SizeHeader, bits least significant first: small = 1, height / 8 - 1 (5 bits) = 1, ratio (3 bits)
  // 1 (1:1) or 4 (3:2)
  assert.deepEqual(declaredSize('jxl', Uint8Array.of(0xff, 0x0a, 0x43, 0x00, 0, 0)), [16, 16]);
  assert.deepEqual(declaredSize('jxl', Uint8Array.of(0xff, 0x0a, 0x03, 0x01, 0, 0)), [24, 16]);
  const boxed = Uint8Array.of(0, 0, 0, 0x0c, 0x4a, 0x58, 0x4c, 0x20, 0x0d, 0x0a, 0x87, 0x0a, 0, 0, 0, 14, 0x6a, 0x78, 0x6c, 0x63, 0xff, 0x0a, 0x03, 0x01, 0, 0);
  assert.deepEqual(declaredSize('jxl', boxed), [24, 16]);
  assert.deepEqual(declaredSize('webp', webpHeader(300, 7)), [300, 7]);
  const box = (type, body) => {
    const out = new Uint8Array(8 + body.length);
    new DataView(out.buffer).setUint32(0, out.length);
    out.set(new TextEncoder().encode(type), 4);
    out.set(body, 8);
    return out;
  };
  const ispe = box('ispe', Uint8Array.of(0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 99));
  const avif = Uint8Array.from([...box('ftyp', new TextEncoder().encode('avif')), ...box('meta', Uint8Array.from([0, 0, 0, 0, ...box('iprp', box('ipco', ispe))]))]);
  assert.deepEqual(declaredSize('avif', avif), [256, 99]);
  assert.throws(() => declaredSize('avif', box('meta', new Uint8Array(4))), CodecError);
  assert.throws(() => declaredSize('jxl', Uint8Array.of(0xff)), CodecError);
});
