// A matrix's `models` zstd frame (spec 10.0): one data frame, nothing after it, content within the limit
// whether or not the frame declares its size. The frames were made with Python's zstandard (libzstd), and
// each case's outcome is the reference decoder's.

import test from 'node:test';
import assert from 'node:assert/strict';
import { CodecError } from '../src/errors.mjs';
import { decompressFrame, readFrameLayout } from '../src/zstdFrame.mjs';

const hex = (s) => Uint8Array.from(s.match(/../g), (h) => parseInt(h, 16));
// msgpack [[0, [[1, 5] x 15]]] in frames of several kinds
const CONTENT = '9192009f' + '920105'.repeat(15);
const FRAMES = {
  contentSize: '28b52ffd2031750000409192009f920105920100841c17',
  checksum: '28b52ffd2431750000409192009f920105920100841c1758742802',
  noContentSize: '28b52ffd00006d0000389192009f9201050100859c11',
  window2p27: '28b52ffd00886d0000389192009f9201050100859c11',
};
const LIMIT = 2 ** 16;

test('zstd: frames with and without a declared size, a checksum, a declared window up to 2^27', () => {
  for (const [name, frame] of Object.entries(FRAMES)) {
    assert.equal(Buffer.from(decompressFrame(hex(frame), LIMIT)).toString('hex'), CONTENT, name);
  }
  assert.equal(readFrameLayout(hex(FRAMES.contentSize)).contentSize, CONTENT.length / 2);
  assert.equal(readFrameLayout(hex(FRAMES.noContentSize)).contentSize, -1);
});

test('zstd: refused frames, as the reference refuses them', () => {
  const bad = {
    'content checksum': '28b52ffd2431750000409192009f920105920100841c1758742803',
    'unused data': '28b52ffd2031750000409192009f920105920100841c1700',
    skippable: '502a4d180000000028b52ffd2031750000409192009f920105920100841c17',
    'unused data ': '28b52ffd2031750000409192009f920105920100841c17502a4d1800000000',
    window: '28b52ffd00906d0000389192009f9201050100859c11', // 2^28: libzstd's default limit is 2^27
    'reserved bit': '28b52ffd2831750000409192009f920105920100841c17',
    'ends inside': '28b52ffd2031750000409192009f92',
  };
  for (const [words, frame] of Object.entries(bad)) {
    assert.throws(() => decompressFrame(hex(frame), LIMIT), (e) => e instanceof CodecError && e.message.includes(words.trim()), words);
  }
});

test('zstd: content past the limit, declared (refused before decompressing) or not (refused on the way)', () => {
  // 70000 zero bytes, and 65536 of them with no declared size
  const declared = hex('28b52ffda07011010055000010000001006b1139c002');
  const undeclared = hex('28b52ffd003855000010000001006b1139c002');
  const atLimit = hex('28b52ffd00305500001000000100fb7f1d6001');
  assert.throws(() => decompressFrame(declared, LIMIT), /declare 70000 bytes/);
  assert.throws(() => decompressFrame(undeclared, LIMIT), /more than 65536 bytes/);
  assert.equal(decompressFrame(atLimit, LIMIT).length, 65536);
  assert.equal(decompressFrame(undeclared, 70000).length, 70000);
});
