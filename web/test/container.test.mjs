// Every container vector of spec/vectors (spec section 13): valid files return their version, meta and
// chunks; invalid ones are refused with the reference reader's error class and the words it names.

import test from 'node:test';
import assert from 'node:assert/strict';
import { readContainer } from '../src/container.mjs';
import { crc32 } from '../src/crc32.mjs';
import { MANIFEST, asManifestJson, readVector, sha256 } from './vectors.mjs';

const chunkRecord = (c) => ({ type: c.type, index: c.index, required: c.required, length: c.length, sha256: sha256(c.payload) });

for (const v of MANIFEST.vectors) {
  test(`container: ${v.file} (${v.expect === 'ok' ? 'valid' : v.error})`, () => {
    const bytes = readVector(v.file);
    assert.equal(bytes.length, v.size);
    assert.equal(sha256(bytes), v.sha256);
    if (v.expect === 'error') {
      assert.throws(() => readContainer(bytes), (err) => {
        assert.equal(err.name, v.error);
        for (const words of v.message_contains) assert.ok(err.message.includes(words), `'${words}' not in: ${err.message}`);
        return true;
      });
      return;
    }
    const c = readContainer(bytes);
    assert.deepEqual(c.version, v.version);
    assert.deepEqual(asManifestJson(c.meta), v.meta);
    assert.deepEqual(c.chunks.map(chunkRecord), v.chunks);
    assert.deepEqual(c.skipped.map(chunkRecord), v.skipped);
  });
}

test('container: the smallest valid file, byte by byte as spec section 12 reads it', () => {
  const dump = `
    89 47 53 50 43 0d 0a 1a  01 00 00 00 0f 00 00 00
    1c f9 6b 64 82 a6 63 68  75 6e 6b 73 90 a4 6d 65
    74 61 80 00 00 00 00 00  47 45 4e 44 e1 c6 a4 6b`;
  const bytes = Uint8Array.from(dump.trim().split(/\s+/), (h) => parseInt(h, 16));
  assert.deepEqual(bytes, readVector('valid_minimal.gspc'));
  const c = readContainer(bytes);
  assert.deepEqual(c.version, [1, 0]);
  assert.deepEqual(c.meta, {});
  assert.deepEqual(c.chunks, []);
});

test('crc32: the check values of spec section 1, and continuation', () => {
  const ascii = (text) => new TextEncoder().encode(text);
  assert.equal(crc32(ascii('123456789')), 0xcbf43926);
  assert.equal(crc32(new Uint8Array(0)), 0);
  assert.equal(crc32(ascii('56789'), crc32(ascii('1234'))), 0xcbf43926);
  assert.equal(crc32(ascii('The quick brown fox jumps over the lazy dog')), 0x414fa339);
});
