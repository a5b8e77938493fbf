#!/usr/bin/env node
// gspc-decode IN.gspc OUT.ply [--region XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX]: decode a .gspc file's attributes
// (no restoration, no refinement) into an INRIA PLY, byte for byte what `gspc decode IN.gspc -o OUT.ply
// --no-refine --no-restore` writes; with --region, only the tiles of a tiled file that meet the box (an
// untiled file is decoded whole), as `gspc decode --region` does.
// Errors: one line on stderr, exit status 1, and no output file (the PLY is written to a temporary file
// in the output's folder and renamed over OUT only when complete).

import { closeSync, openSync, readFileSync, renameSync, rmSync, statSync, writeSync } from 'node:fs';
import { basename, dirname, join, resolve } from 'node:path';
import { bytesSource, decodeGspc, GspcError, openGspc } from '../src/index.mjs';
import { plyHeader, plyParts, plyRows } from '../src/ply.mjs';

const USAGE = 'usage: gspc-decode IN.gspc OUT.ply [--region XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX]';

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

function parseRegion(text) {
  const box = text.split(',').map((v) => (v.trim() === '' ? NaN : Number(v)));
  if (box.length !== 6 || !box.every(Number.isFinite)) {
    throw new UsageError(`--region ${text}: give six finite numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX`);
  }
  if ([0, 1, 2].some((a) => box[a] > box[a + 3])) throw new UsageError(`--region ${text}: a minimum is above its maximum`);
  return box;
}

/** The PLY of the tiles of a tiled file that meet `region`, tile by tile. */
async function regionParts(bytes, region) {
  const reader = await openGspc(bytesSource(bytes));
  if (!reader.index) return [...plyParts(decodeGspc(bytes))];
  const tiles = [];
  for await (const tile of reader.decode({ region })) tiles.push(tile);
  if (!tiles.length) throw new UsageError(`--region meets none of the file's ${reader.tiles.length} tiles; nothing to write`);
  const count = tiles.reduce((n, t) => n + t.count, 0);
  return [plyHeader(count, (reader.shDegree + 1) ** 2 - 1), ...tiles.flatMap((t) => [...plyRows(t)])];
}

async function main(args) {
  const at = args.indexOf('--region');
  const region = at >= 0 ? parseRegion(args[at + 1] ?? '') : null;
  const files = at >= 0 ? [...args.slice(0, at), ...args.slice(at + 2)] : args;
  if (files.length !== 2 || files.some((f) => f.startsWith('--'))) throw new UsageError(USAGE);
  const [input, output] = files;
  if (resolve(input) === resolve(output)) throw new UsageError(`the output ${output} would overwrite the input`);
  const bytes = readInput(input);
  writeAtomically(output, region ? await regionParts(bytes, region) : plyParts(decodeGspc(bytes)));
}

main(process.argv.slice(2)).catch((err) => {
  const known = err instanceof GspcError || err instanceof UsageError;
  const text = known ? err.message : `internal error: ${err && err.stack ? err.stack.split('\n')[0] : err}`;
  const name = err instanceof GspcError ? `${err.name}: ` : '';
  process.stderr.write(`gspc-decode: ${name}${text.replace(/\s+/g, ' ')}\n`);
  process.exitCode = 1;
});
