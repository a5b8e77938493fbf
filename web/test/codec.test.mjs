// Every codec vector of spec/vectors (spec sections 10 and 13): decoded attributes bit for bit (SHA-256 of
// each binary32 array, row 0's values), side-information views as listed, and every refused file refused
// with a CodecError naming what the reference's message names.

import test from 'node:test';
import assert from 'node:assert/strict';
import { CodecError, decodeGspc } from '../src/index.mjs';
import { MANIFEST, bytesOf, readVector, sha256 } from './vectors.mjs';

const ARRAYS = { means: 'means', quats: 'quats', log_scales: 'logScales', opacities: 'opacities', sh_dc: 'shDc', sh_rest: 'shRest' };

for (const v of MANIFEST.vectors.filter((x) => x.codec)) {
  test(`codec: ${v.file} (${v.codec.expect === 'ok' ? 'decodes' : 'refused'})`, () => {
    const bytes = readVector(v.file);
    if (v.codec.expect === 'error') {
      assert.throws(() => decodeGspc(bytes), (err) => {
        assert.ok(err instanceof CodecError, `${err.name}: ${err.message}`);
        for (const words of v.codec.message_contains) assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
        return true;
      });
      return;
    }
    const scene = decodeGspc(bytes);
    for (const [key, want] of Object.entries(v.codec.attributes)) {
      const array = scene[ARRAYS[key]];
      assert.ok(array instanceof Float32Array, key);
      const size = want.shape.reduce((a, b) => a * b, 1);
      assert.equal(array.length, size, `${key} length`);
      const row = size / want.shape[0];
      assert.deepEqual(Array.from(array.subarray(0, row)), want.first, `${key} row 0`);
      assert.equal(sha256(bytesOf(array)), want.sha256, `${key} SHA-256`);
    }
    assert.equal(scene.count, v.codec.attributes.means.shape[0]);
    // The manifest lists the whole scene's views, then each tile's own (spec 10.15) in tile order.
    const views = [...scene.views, ...(scene.tileViews ?? []).flat()];
    assert.equal(views.length, v.codec.views.length);
    views.forEach((view, k) => {
      const want = v.codec.views[k];
      assert.equal(view.camera.width, want.width);
      assert.equal(view.camera.height, want.height);
      // 'refused': the residual images are refused by a decoder that decodes them (spec 10.7); this one
      // does not, and keeps their records.
      if (v.codec.residuals === 'refused') return;
      assert.equal(view.residual !== null, 'residual' in want, `view ${k} residual`);
      if (view.residual) {
        assert.deepEqual(view.residual.fullShape, want.residual.shape.slice(0, 2));
        assert.ok(view.residual.image.length > 0);
      }
    });
  });
}
