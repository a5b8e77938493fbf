#!/usr/bin/env node
// gspc-decode IN.gspc OUT.ply: decode a .gspc file's attributes (no restoration, no refinement) into an
// INRIA PLY, byte for byte what `gspc decode IN.gspc -o OUT.ply --no-refine --no-restore` writes.
// Errors: one line on stderr, exit status 1, and no output file (the PLY is written to a temporary file
// in the output's folder and renamed over OUT only when complete).

import { closeSync, openSync, readFileSync, renameSync, rmSync, statSync, writeSync } from 'node:fs';
import { basename, dirname, join, resolve } from 'node:path';
import { decodeGspc, GspcError } from '../src/index.mjs';
import { plyParts } from '../src/ply.mjs';

const USAGE = 'usage: gspc-decode IN.gspc OUT.ply';

class UsageError extends Error {}

function readInput(path) {
  let stat;
  try {
    stat = statSync(path);
  } catch (err) {
    throw new UsageError(`cannot read ${path}: ${err.code === 'ENOENT' ? 'no such file' : err.message}`);
  }
  if (!stat.isFile()) throw new UsageError(`cannot read ${path}: not a file`);
  const buffer = readFileSync(path);
  return new Uint8Array(buffer.buffer, buffer.byteOffset, buffer.byteLength);
}

function writeAtomically(path, parts) {
  const temp = join(dirname(path), `.${basename(path)}.${process.pid}.tmp`);
  let fd = null;
  try {
    fd = openSync(temp, 'wx');
    for (const part of parts) {
      let at = 0;
      while (at < part.length) at += writeSync(fd, part, at);
    }
    closeSync(fd);
    fd = null;
    renameSync(temp, path);
  } catch (err) {
    if (fd !== null) closeSync(fd);
    rmSync(temp, { force: true });
    throw new UsageError(`cannot write ${path}: ${err.message}`);
  }
}

function main(args) {
  if (args.length !== 2) throw new UsageError(USAGE);
  const [input, output] = args;
  if (resolve(input) === resolve(output)) throw new UsageError(`the output ${output} would overwrite the input`);
  const scene = decodeGspc(readInput(input));
  writeAtomically(output, plyParts(scene));
}

try {
  main(process.argv.slice(2));
} catch (err) {
  const known = err instanceof GspcError || err instanceof UsageError;
  const text = known ? err.message : `internal error: ${err && err.stack ? err.stack.split('\n')[0] : err}`;
  const name = err instanceof GspcError ? `${err.name}: ` : '';
  process.stderr.write(`gspc-decode: ${name}${text.replace(/\s+/g, ' ')}\n`);
  process.exitCode = 1;
}
