// Test helpers that write what the decoder reads: msgpack values and gspc containers (spec sections 2, 4,
// 5), for hand-made files that exercise one rule each.

import { crc32 } from '../src/crc32.mjs';

/** A float to write as msgpack float 64 even when integral. */
export class F64 {
  constructor(value) {
    this.value = value;
  }
}

function encodeInto(out, v) {
  const bytes = (...b) => out.push(...b);
  const be = (value, size) => {
    for (let i = size - 1; i >= 0; i--) out.push(Number((BigInt(value) >> BigInt(8 * i)) & 0xffn));
  };
  if (v === null) return bytes(0xc0);
  if (v === false || v === true) return bytes(v ? 0xc3 : 0xc2);
  if (v instanceof F64 || (typeof v === 'number' && !Number.isInteger(v))) {
    const view = new DataView(new ArrayBuffer(8));
    view.setFloat64(0, v instanceof F64 ? v.value : v);
    return bytes(0xcb, ...new Uint8Array(view.buffer));
  }
  if (typeof v === 'number' || typeof v === 'bigint') {
    const n = BigInt(v);
    if (n >= 0n && n < 128n) return bytes(Number(n));
    if (n < 0n && n >= -32n) return bytes(Number(n) & 0xff);
    if (n >= 0n) {
      if (n < 2n ** 8n) return bytes(0xcc, Number(n));
      if (n < 2n ** 16n) return bytes(0xcd), be(n, 2);
      if (n < 2n ** 32n) return bytes(0xce), be(n, 4);
      return bytes(0xcf), be(n, 8);
    }
    if (n >= -(2n ** 31n)) return bytes(0xd2), be(n & 0xffffffffn, 4);
    return bytes(0xd3), be(n & (2n ** 64n - 1n), 8);
  }
  if (typeof v === 'string') {
    const s = new TextEncoder().encode(v);
    if (s.length < 32) bytes(0xa0 | s.length);
    else bytes(0xdb), be(s.length, 4);
    for (const b of s) out.push(b);
    return undefined;
  }
  if (v instanceof Uint8Array) {
    bytes(0xc6);
    be(v.length, 4);
    for (const b of v) out.push(b);
    return undefined;
  }
  if (Array.isArray(v)) {
    if (v.length < 16) bytes(0x90 | v.length);
    else bytes(0xdd), be(v.length, 4);
    for (const x of v) encodeInto(out, x);
    return undefined;
  }
  const entries = v instanceof Map ? [...v] : Object.entries(v);
  if (entries.length < 16) bytes(0x80 | entries.length);
  else bytes(0xdf), be(entries.length, 4);
  for (const [k, x] of entries) {
    encodeInto(out, k);
    encodeInto(out, x);
  }
  return undefined;
}

/** `value` as msgpack: integers in the shortest form, non-integral numbers and F64 as float 64. */
export function msgpack(value) {
  const out = [];
  encodeInto(out, value);
  return Uint8Array.from(out);
}

const align8 = (x) => Math.ceil(x / 8) * 8;

/**
 * A gspc file: `meta` and `chunks` ({type, payload, index = 0, flags = 1}) in a container of version
 * `major`.`minor` (spec sections 2-5).
 */
export function gspcFile(meta, chunks = [], { major = 1, minor = 4 } = {}) {
  const table = chunks.map((c) => ({ type: c.type, flags: c.flags ?? 1, index: c.index ?? 0, length: c.payload.length, crc: crc32(c.payload) }));
  const header = msgpack({ chunks: table, meta });
  let size = align8(20 + header.length);
  for (const c of chunks) size = align8(size + c.payload.length);
  const out = new Uint8Array(size + 8);
  const view = new DataView(out.buffer);
  out.set([0x89, 0x47, 0x53, 0x50, 0x43, 0x0d, 0x0a, 0x1a]);
  view.setUint16(8, major, true);
  view.setUint16(10, minor, true);
  view.setUint32(12, header.length, true);
  view.setUint32(16, crc32(header), true);
  out.set(header, 20);
  let at = align8(20 + header.length);
  for (const c of chunks) {
    out.set(c.payload, at);
    at = align8(at + c.payload.length);
  }
  out.set([0x47, 0x45, 0x4e, 0x44], size);
  view.setUint32(size + 4, crc32(out.subarray(0, size + 4)), true);
  return out;
}

/** `content` as a zstd frame of raw blocks (RFC 8878), declaring its size when `declare` is set. */
export function zstdRaw(content, { declare = true } = {}) {
  const out = [0x28, 0xb5, 0x2f, 0xfd];
  if (declare) {
    // Single segment, a 4-byte Frame_Content_Size.
    out.push(0xa0, ...[0, 8, 16, 24].map((s) => (content.length >>> s) & 0xff));
  } else {
    out.push(0x00, 0x70); // no size, a window of 2^24
  }
  const block = 2 ** 17;
  let at = 0;
  do {
    const size = Math.min(block, content.length - at);
    const last = at + size >= content.length ? 1 : 0;
    const head = (size << 3) | last; // type 0: raw
    out.push(head & 0xff, (head >> 8) & 0xff, (head >> 16) & 0xff);
    for (const b of content.subarray(at, at + size)) out.push(b);
    at += size;
  } while (at < content.length);
  return Uint8Array.from(out);
}

/** A zstd frame of `blocks` RLE blocks of 128 KiB each (4 bytes apiece), with no declared size. */
export function zstdRleBomb(blocks) {
  const out = [0x28, 0xb5, 0x2f, 0xfd, 0x00, 0x70];
  for (let i = 0; i < blocks; i++) {
    const head = (2 ** 17 << 3) | (1 << 1) | (i === blocks - 1 ? 1 : 0);
    out.push(head & 0xff, (head >> 8) & 0xff, (head >> 16) & 0xff, 0x90);
  }
  return Uint8Array.from(out);
}

/** An ECM payload [m, c, models, words] (spec 10.0) with the model list `models` ([mode, specs] per column). */
export function ecm(m, c, models, words = new Uint8Array(0)) {
  return msgpack([m, c, m === 0 ? new Uint8Array(0) : zstdRaw(msgpack(models)), words]);
}

/** An ECM of m x c whose every column decodes to `value` (15 constant models, no words). */
export const constantEcm = (m, c, value = 0) => ecm(m, c, Array.from({ length: c }, () => [0, Array(15).fill([1, value])]));

/**
 * meta and chunks of a scene of `n` identical Gaussians at SH degree 0 (attribute codec version 1), every
 * matrix constant: the smallest file of n Gaussians. `attributes` overrides keys of meta.attributes.
 */
export function constantScene(n, attributes = {}) {
  const meta = {
    attributes: {
      version: 1,
      n,
      sh_degree: 0,
      position: { bits: 12, lo: [new F64(0), new F64(0), new F64(0)], step: [new F64(0.01), new F64(0.01), new F64(0.01)] },
      opacity_levels: 20,
      scale_step: new F64(0.5),
      rotation_levels: 36,
      dc_step: new F64(0.25),
      sh_steps: [],
      ...attributes,
    },
    side_info: { background: [1, 1, 1] },
  };
  const chunks = [
    { type: 'POSN', payload: msgpack([constantEcm(n, 1), new Uint8Array(0)]) },
    { type: 'OPAC', payload: constantEcm(n, 1, 10) },
    { type: 'SCAL', payload: constantEcm(n, 3, -4) },
    { type: 'ROTN', payload: constantEcm(n, 4, 0) },
    { type: 'SHDC', payload: constantEcm(n, 3, 1) },
  ];
  return { meta, chunks };
}

/** A box (6 binary64 floats: low x, y, z, high x, y, z) for a tile map. */
export const box = (...values) => values.map((v) => new F64(v));

/**
 * meta and chunks of a tiled scene (spec 10.14): tile k a constant scene of counts[k] Gaussians at the
 * origin (constantScene), its box [-1, 1] on every axis, its chunks of index k after the TIDX chunk.
 * `tile(k, map)` may change tile k's index map ({box, attributes}) before it is written.
 */
export function tiledScene(counts, tile = (k, map) => map) {
  const tiles = counts.map((n) => constantScene(n));
  const index = tiles.map(({ meta }, k) => tile(k, { box: box(-1, -1, -1, 1, 1, 1), attributes: meta.attributes }));
  const meta = { side_info: tiles[0].meta.side_info };
  const chunks = [{ type: 'TIDX', payload: msgpack(index) }];
  tiles.forEach(({ chunks: own }, k) => chunks.push(...own.map((c) => ({ ...c, index: k }))));
  return { meta, chunks };
}

// --- side information (spec 10.9, 10.15) -----------------------------------------------------------------

/** Numbers as binary32 little-endian bytes. */
export const f32 = (...values) => new Uint8Array(Float32Array.from(values).buffer);
/** A world-to-camera pose (3 x 4, row-major): the identity, 4 units back. */
export const POSE = f32(1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 4);

/** A lossless WebP's first bytes, declaring `width` x `height` (VP8L header; no pixels). */
export function webpHeader(width, height) {
  const b = new Uint8Array(32);
  const v = new DataView(b.buffer);
  b.set(new TextEncoder().encode('RIFF'), 0);
  v.setUint32(4, 24, true);
  b.set(new TextEncoder().encode('WEBPVP8L'), 8);
  v.setUint32(16, 12, true);
  b[20] = 0x2f;
  v.setUint32(21, (width - 1) | ((height - 1) << 14), true);
  return b;
}

/**
 * A payload in the SIDE layout (spec 10.9; a SIDE or TSID chunk's) of `views` ({image?, gain?, width?,
 * height?}): with one shared camera of `width` x `height`, or with `perView` each view's own camera (its
 * `width` and `height`, the shared values where absent).
 */
export function sidePayload(views, { width = 24, height = 20, scale = 1, codec = 1, fx = 30, perView = false } = {}) {
  const parts = [];
  const head = new Uint8Array(8);
  new DataView(head.buffer).setUint32(0, views.length, true);
  head.set([perView ? 1 : 0, codec, 8, scale], 4);
  const cameraBytes = (w, h) => {
    const cam = new Uint8Array(24);
    const cv = new DataView(cam.buffer);
    cv.setUint32(0, w, true);
    cv.setUint32(4, h, true);
    cam.set(f32(fx, 30, 12, 10), 8);
    return cam;
  };
  parts.push(head);
  if (!perView) parts.push(cameraBytes(width, height));
  const images = [];
  for (const v of views) {
    if (perView) parts.push(cameraBytes(v.width ?? width, v.height ?? height));
    const entry = new Uint8Array(52 + (v.image ? 4 : 0));
    entry.set(POSE, 0);
    const ev = new DataView(entry.buffer);
    ev.setUint32(48, v.image ? v.image.length : 0, true);
    if (v.image) ev.setFloat32(52, v.gain ?? 50, true);
    parts.push(entry);
    if (v.image) images.push(v.image);
  }
  return Uint8Array.from([...parts, ...images].flatMap((p) => [...p]));
}
