// A matrix's `models` bytes (spec 10.0): exactly one zstd data frame (RFC 8878) whose content is at most
// `limit` bytes. The frame header and the block headers are read here, before anything is decompressed:
// a frame that declares more content than the limit is refused at once, one without a declared size is
// decompressed block by block (a block yields at most 128 KiB) and refused as soon as its output passes the
// limit, and the frame's exact extent is known, so a byte after it (a skippable frame included) is refused.
// The blocks themselves are decoded by fzstd.

// A relative path, not the bare name: module workers get no import map, and the same path resolves in
// node (web/node_modules) and in a browser served the web/ folder.
import { Decompress } from '../node_modules/fzstd/esm/index.mjs';
import { CodecError } from './errors.mjs';
import { MAX_ZSTD_WINDOW, ZSTD_BLOCK_MAX } from './limits.mjs';

const FRAME_MAGIC = 0xfd2fb528;
const SKIPPABLE_MASK = 0xfffffff0;
const SKIPPABLE_MAGIC = 0x184d2a50;

function u32le(b, p) {
  return (b[p] | (b[p + 1] << 8) | (b[p + 2] << 16) | (b[p + 3] << 24)) >>> 0;
}

/**
 * The header and layout of the zstd frame that must fill `bytes` exactly: {contentSize (or -1),
 * windowSize, windowByte (offset of the Window_Descriptor, or -1), checksum, blocks: [start, end) byte
 * ranges including their 3-byte headers, end}. CodecError when it is not one well-formed data frame.
 */
export function readFrameLayout(bytes) {
  const n = bytes.length;
  if (n < 4) throw new CodecError(`entropy models: ${n} bytes are not a zstd frame`);
  const magic = u32le(bytes, 0);
  if ((magic & SKIPPABLE_MASK) >>> 0 === SKIPPABLE_MAGIC) {
    throw new CodecError('entropy models start with a zstd skippable frame, not a data frame');
  }
  if (magic !== FRAME_MAGIC) throw new CodecError('entropy models are not a zstd frame (bad magic)');
  if (n < 5) throw new CodecError('entropy models: the zstd frame header is truncated');
  const fhd = bytes[4];
  const fcsFlag = fhd >> 6;
  const singleSegment = (fhd >> 5) & 1;
  const checksum = (fhd >> 2) & 1;
  const dictFlag = fhd & 3;
  if (fhd & 8) throw new CodecError('entropy models: the zstd frame header sets its reserved bit');
  let p = 5;
  let windowByte = -1;
  let windowSize = 0;
  if (!singleSegment) {
    windowByte = p;
    if (p >= n) throw new CodecError('entropy models: the zstd frame header is truncated');
    const wd = bytes[p++];
    const base = 2 ** (10 + (wd >> 3));
    windowSize = base + (base / 8) * (wd & 7);
  }
  const dictBytes = [0, 1, 2, 4][dictFlag];
  const fcsBytes = [singleSegment, 2, 4, 8][fcsFlag];
  if (p + dictBytes + fcsBytes > n) throw new CodecError('entropy models: the zstd frame header is truncated');
  let dictId = 0;
  for (let i = dictBytes - 1; i >= 0; i--) dictId = dictId * 256 + bytes[p + i];
  p += dictBytes;
  // A dictionary is never part of a gspc file: a frame that needs one cannot be decoded.
  if (dictId !== 0) throw new CodecError(`entropy models: the zstd frame needs dictionary ${dictId}`);
  let contentSize = -1;
  if (fcsBytes) {
    contentSize = 0;
    for (let i = fcsBytes - 1; i >= 0; i--) contentSize = contentSize * 256 + bytes[p + i];
    if (fcsBytes === 2) contentSize += 256;
    p += fcsBytes;
  }
  if (singleSegment) windowSize = contentSize;
  else if (windowSize > MAX_ZSTD_WINDOW) {
    throw new CodecError(`entropy models: the zstd frame asks for a ${windowSize}-byte window (at most ${MAX_ZSTD_WINDOW})`);
  }
  const blocks = [];
  for (;;) {
    if (p + 3 > n) throw new CodecError('entropy models: the zstd frame ends inside a block header');
    const head = bytes[p] | (bytes[p + 1] << 8) | (bytes[p + 2] << 16);
    const last = head & 1;
    const type = (head >> 1) & 3;
    const size = head >>> 3;
    if (type === 3) throw new CodecError('entropy models: a zstd block of the reserved type');
    if (size > ZSTD_BLOCK_MAX) {
      throw new CodecError(`entropy models: a zstd block of ${size} bytes (at most ${ZSTD_BLOCK_MAX})`);
    }
    const body = type === 1 ? 1 : size;
    if (p + 3 + body > n) throw new CodecError('entropy models: the zstd frame ends inside a block');
    blocks.push([p, p + 3 + body]);
    p += 3 + body;
    if (last) break;
  }
  if (checksum) {
    if (p + 4 > n) throw new CodecError('entropy models: the zstd frame ends inside its checksum');
    p += 4;
  }
  if (p !== n) throw new CodecError(`entropy models hold ${n - p} bytes of unused data after their zstd frame`);
  return { contentSize, windowSize, windowByte, checksum, blocks, headerEnd: blocks[0][0], end: p };
}

/** The smallest Window_Descriptor byte whose window is at least `bytes`. */
function windowDescriptorFor(bytes) {
  let exponent = 0;
  while (2 ** (10 + exponent) < bytes) exponent++;
  return exponent << 3;
}

/**
 * The content of the zstd frame `bytes`, refused (CodecError) when it is not exactly one data frame or when
 * its content passes `limit` bytes: a declared size is compared before decompressing, an undeclared one
 * after each block.
 */
export function decompressFrame(bytes, limit, what = 'entropy models') {
  const layout = readFrameLayout(bytes);
  if (layout.contentSize > limit) {
    throw new CodecError(
      `${what} declare ${layout.contentSize} bytes of content from a ${bytes.length}-byte zstd frame (at most ${limit})`,
    );
  }
  let frame = bytes;
  // fzstd allocates the window the frame declares. No back-reference of a frame whose content stays within
  // `limit` reaches further than `limit`, so a larger declared window is lowered to what the limit needs
  // (never below the 128 KiB block size, which the window also bounds).
  const needed = Math.max(limit, ZSTD_BLOCK_MAX);
  if (layout.windowByte >= 0 && layout.windowSize > needed) {
    frame = bytes.slice();
    frame[layout.windowByte] = windowDescriptorFor(needed);
  }
  const parts = [];
  let total = 0;
  let overflow = false;
  const stream = new Decompress((chunk) => {
    if (!chunk.length) return;
    total += chunk.length;
    if (total > limit) overflow = true;
    else parts.push(chunk.slice());
  });
  const { blocks } = layout;
  try {
    for (let i = 0; i < blocks.length; i++) {
      const start = i === 0 ? 0 : blocks[i][0];
      const end = i === blocks.length - 1 ? layout.end : blocks[i][1];
      stream.push(frame.subarray(start, end), i === blocks.length - 1);
      if (overflow) break;
    }
  } catch (err) {
    throw new CodecError(`${what}: corrupt zstd frame (${err.message})`);
  }
  if (overflow) {
    throw new CodecError(`${what} decompress to more than ${limit} bytes from a ${bytes.length}-byte zstd frame (the frame does not declare its size)`);
  }
  if (layout.contentSize >= 0 && total !== layout.contentSize) {
    throw new CodecError(`${what}: the zstd frame declares ${layout.contentSize} bytes and holds ${total}`);
  }
  const out = new Uint8Array(total);
  let at = 0;
  for (const part of parts) {
    out.set(part, at);
    at += part.length;
  }
  if (layout.checksum) {
    const stored = u32le(bytes, layout.end - 4);
    if (xxh64Low32(out) !== stored) throw new CodecError(`${what}: the zstd frame's content checksum does not match`);
  }
  return out;
}

// XXH64 (the checksum of RFC 8878 3.1.1), low 32 bits. BigInt: it runs only for frames that carry a
// checksum, which gspc's writer does not write.
const P1 = 11400714785074694791n;
const P2 = 14029467366897019727n;
const P3 = 1609587929392839161n;
const P4 = 9650029242287828579n;
const P5 = 2870177450012600261n;
const M64 = (1n << 64n) - 1n;
const rotl = (x, r) => ((x << r) | (x >> (64n - r))) & M64;
const round = (acc, lane) => (rotl((acc + lane * P2) & M64, 31n) * P1) & M64;
const merge = (acc, v) => (((acc ^ round(0n, v)) * P1 + P4) & M64);

function xxh64Low32(data) {
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
  const n = data.length;
  let p = 0;
  let h;
  if (n >= 32) {
    let v1 = (P1 + P2) & M64;
    let v2 = P2;
    let v3 = 0n;
    let v4 = (M64 + 1n - P1) & M64;
    for (; p + 32 <= n; p += 32) {
      v1 = round(v1, view.getBigUint64(p, true));
      v2 = round(v2, view.getBigUint64(p + 8, true));
      v3 = round(v3, view.getBigUint64(p + 16, true));
      v4 = round(v4, view.getBigUint64(p + 24, true));
    }
    h = (rotl(v1, 1n) + rotl(v2, 7n) + rotl(v3, 12n) + rotl(v4, 18n)) & M64;
    h = merge(h, v1);
    h = merge(h, v2);
    h = merge(h, v3);
    h = merge(h, v4);
  } else {
    h = P5;
  }
  h = (h + BigInt(n)) & M64;
  for (; p + 8 <= n; p += 8) h = ((rotl(h ^ round(0n, view.getBigUint64(p, true)), 27n) * P1) + P4) & M64;
  if (p + 4 <= n) {
    h = ((rotl(h ^ ((BigInt(view.getUint32(p, true)) * P1) & M64), 23n) * P2) + P3) & M64;
    p += 4;
  }
  for (; p < n; p++) h = (rotl(h ^ ((BigInt(data[p]) * P5) & M64), 11n) * P1) & M64;
  h ^= h >> 33n;
  h = (h * P2) & M64;
  h ^= h >> 29n;
  h = (h * P3) & M64;
  h ^= h >> 32n;
  return Number(h & 0xffffffffn);
}
