// The PLY writer and the CLI: byte for byte the file gspc's Python decoder writes with --no-refine
// --no-restore (SHA-256s in fixtures/reference_ply.json, made with it), one line and exit status 1 on a bad
// file, and no output file then.

import test from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync, spawnSync } from 'node:child_process';
import { existsSync, mkdtempSync, readFileSync, readdirSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { decodeGspc, writePly } from '../src/index.mjs';
import { plyHeader } from '../src/ply.mjs';
import { VECTORS, sha256 } from './vectors.mjs';

const FIXTURES = fileURLToPath(new URL('./fixtures/', import.meta.url));
const CLI = fileURLToPath(new URL('../bin/gspc-decode.mjs', import.meta.url));
const REFERENCE = JSON.parse(readFileSync(join(FIXTURES, 'reference_ply.json'), 'utf8')).ply_sha256;
const pathOf = (name) => (name.startsWith('fixtures/') ? join(FIXTURES, name.slice(9)) : join(VECTORS, name));

test('ply: the header text is plyfile\'s (INRIA layout)', () => {
  const text = new TextDecoder().decode(plyHeader(2, 3));
  const props = ['x', 'y', 'z', 'nx', 'ny', 'nz', 'f_dc_0', 'f_dc_1', 'f_dc_2', ...Array.from({ length: 9 }, (_, i) => `f_rest_${i}`),
    'opacity', 'scale_0', 'scale_1', 'scale_2', 'rot_0', 'rot_1', 'rot_2', 'rot_3'];
  assert.equal(text, `ply\nformat binary_little_endian 1.0\nelement vertex 2\n${props.map((p) => `property float ${p}\n`).join('')}end_header\n`);
});

for (const [name, want] of Object.entries(REFERENCE)) {
  test(`ply: ${name} is byte for byte Python's`, () => {
    const scene = decodeGspc(new Uint8Array(readFileSync(pathOf(name))));
    assert.equal(sha256(writePly(scene)), want);
  });
}

test('cli: writes the PLY; a bad file gives one line, exit status 1 and no output', () => {
  const dir = mkdtempSync(join(tmpdir(), 'gspc-web-'));
  try {
    const out = join(dir, 'out.ply');
    execFileSync(process.execPath, [CLI, pathOf('fixtures/tiny_v4_sh2.gspc'), out]);
    assert.equal(sha256(readFileSync(out)), REFERENCE['fixtures/tiny_v4_sh2.gspc']);
    for (const [input, words] of [
      [join(VECTORS, 'codec_invalid_mode_4.gspc'), 'prediction mode'],
      [join(VECTORS, 'invalid_chunk_crc.gspc'), 'ChecksumMismatch'],
      [join(dir, 'missing.gspc'), 'no such file'],
    ]) {
      const target = join(dir, 'bad.ply');
      const res = spawnSync(process.execPath, [CLI, input, target], { encoding: 'utf8' });
      assert.equal(res.status, 1);
      assert.equal(res.stdout, '');
      assert.equal(res.stderr.trim().split('\n').length, 1, res.stderr);
      assert.ok(res.stderr.includes(words), res.stderr);
      assert.ok(!existsSync(target));
    }
    // An existing output is left as it was when decoding fails.
    writeFileSync(join(dir, 'keep.ply'), 'old');
    spawnSync(process.execPath, [CLI, join(VECTORS, 'codec_invalid_mode_4.gspc'), join(dir, 'keep.ply')]);
    assert.equal(readFileSync(join(dir, 'keep.ply'), 'utf8'), 'old');
    assert.deepEqual(readdirSync(dir).sort(), ['keep.ply', 'out.ply']);
    const usage = spawnSync(process.execPath, [CLI], { encoding: 'utf8' });
    assert.equal(usage.status, 1);
    assert.ok(usage.stderr.includes('usage'));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});
