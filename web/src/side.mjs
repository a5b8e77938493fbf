// Side information (spec 10.7-10.10, 10.15): meta["side_info"], and the views of either layout (1.1's SIDE
// chunk or 1.0's `views` records with one RESI chunk per residual), read into one list of checked records;
// and a tile's own views (format 1.6's TSID chunk, in the SIDE layout). Every rule that refuses a file is
// checked here, also when no image is decoded: cameras, gains, shapes, the pixel limits, and each residual
// image's declared size.

import { CodecError, show } from './errors.mjs';
import { declaredSize } from './imageHeaders.mjs';
import {
  DEFAULT_REFINE_ITERATIONS,
  MAX_CAMERA_SIDE,
  MAX_GAIN_EXCLUSIVE,
  MAX_REFINE_ITERATIONS,
  MAX_RESIDUAL_SCALE,
  MAX_RESTORER_NAME,
  MAX_VIEWS,
  MAX_VIEW_PIXELS,
  MIN_GAIN_EXCLUSIVE,
  tileViewPixelBudget,
  viewPixelBudget,
} from './limits.mjs';

export const RESIDUAL_CODECS = ['jxl', 'webp', 'avif'];
const FLAG_PER_VIEW_CAMERA = 1;
const HEAD_BYTES = 8;
const CAMERA_BYTES = 24; // width, height, fx, fy, cx, cy
const VIEW_BYTES = 52; // pose (12 x binary32), image length
const GAIN_BYTES = 4;

const fail = (where, value, want) => new CodecError(`the .gspc header's ${where} is ${show(value)}, not ${want}`);
const isInt = (v) => typeof v === 'bigint';

/**
 * meta["side_info"] (spec 10.8): {background [r, g, b], restorer, refineIterations, legacyViews (the 1.0
 * layout's records, typed)}.
 */
export function readSideInfo(meta) {
  if (!meta.has('side_info')) throw new CodecError("the .gspc header lacks side_info section");
  const side = meta.get('side_info');
  if (!(side instanceof Map)) throw fail('side_info section', side, 'a map');
  if (!side.has('background')) throw new CodecError("the .gspc header lacks side_info.background");
  const bg = side.get('background');
  if (!Array.isArray(bg) || bg.length !== 3) throw fail('side_info.background', bg, 'a list of 3 numbers');
  const background = bg.map((v) => {
    const x = isInt(v) ? Number(v) : v;
    if (!(typeof x === 'number' && Number.isFinite(x) && x >= 0 && x <= 1)) throw fail('side_info.background', bg, 'RGB in [0, 1]');
    return x;
  });
  let restorer = 'none';
  if (side.has('restorer')) {
    restorer = side.get('restorer');
    const length = typeof restorer === 'string' ? [...restorer].length : 0;
    if (!(length >= 1 && length <= MAX_RESTORER_NAME)) throw fail('side_info.restorer', restorer, 'a restorer name');
  }
  let refineIterations = DEFAULT_REFINE_ITERATIONS;
  if (side.has('refine_iterations')) {
    const v = side.get('refine_iterations');
    if (!(isInt(v) && v >= 0n && v <= BigInt(MAX_REFINE_ITERATIONS))) {
      throw fail('side_info.refine_iterations', v, `an integer in 0..${MAX_REFINE_ITERATIONS}`);
    }
    refineIterations = Number(v);
  }
  let legacyViews = [];
  if (side.has('views')) {
    const views = side.get('views');
    if (!Array.isArray(views)) throw fail('side_info.views', views, 'an array');
    legacyViews = views.map((v, k) => withView(k, () => legacyView(v)));
  }
  return { background, restorer, refineIterations, legacyViews };
}

function withView(k, build) {
  try {
    return build();
  } catch (err) {
    if (err instanceof CodecError) throw new CodecError(`side-information view ${k}: ${err.message}`);
    throw err;
  }
}

/** A camera from its stored binary32 values (spec 10.8): finite, fx and fy > 0, sides 1..65536. */
function camera(width, height, intrinsics, pose) {
  for (const [side, v] of [['width', width], ['height', height]]) {
    if (!(Number.isInteger(v) && v >= 1 && v <= MAX_CAMERA_SIDE)) {
      throw new CodecError(`camera ${side} ${show(v)} is not an integer in 1..${MAX_CAMERA_SIDE}`);
    }
  }
  const values = [...intrinsics, ...pose];
  if (!values.every(Number.isFinite)) throw new CodecError('camera has NaN or Inf values');
  const [fx, fy, cx, cy] = intrinsics;
  if (!(fx > 0 && fy > 0)) throw new CodecError(`camera has focal lengths fx=${fx}, fy=${fy}; both must be > 0`);
  return { width, height, fx, fy, cx, cy, pose: Float32Array.from(pose) };
}

function floats32(bytes, count) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  return Array.from({ length: count }, (_, i) => view.getFloat32(4 * i, true));
}

function residualRecord(codec, bits, gain, height, width, scale) {
  if (!RESIDUAL_CODECS.includes(codec)) throw new CodecError(`residual codec ${show(codec)} is not one of ${RESIDUAL_CODECS.join(', ')}`);
  if (bits !== 8 && bits !== 16) throw new CodecError(`residual bits ${show(bits)} are not 8 or 16`);
  if (!(Number.isInteger(scale) && scale >= 1 && scale <= MAX_RESIDUAL_SCALE)) {
    throw new CodecError(`residual scale ${show(scale)} is not an integer in 1..${MAX_RESIDUAL_SCALE}`);
  }
  // As the binary32 that samples are divided by (10.7): 1e-50 would round to 0, 1e39 to infinity.
  if (!(typeof gain === 'number' && gain > MIN_GAIN_EXCLUSIVE && gain < MAX_GAIN_EXCLUSIVE)) {
    throw new CodecError(`residual gain ${show(gain)} is not a positive finite float`);
  }
  return {
    codec,
    bits,
    gain: Math.fround(gain),
    offset: 2 ** (bits - 1),
    scale,
    fullShape: [height, width],
    shape: [Math.ceil(height / scale), Math.ceil(width / scale)],
  };
}

/** A 1.0 record's integer field: a msgpack integer (not a float of integral value), as a number. */
function intOf(v, what) {
  if (!isInt(v)) throw new CodecError(`${what} ${show(v)} is not an integer`);
  return v >= -(2n ** 53n) && v <= 2n ** 53n ? Number(v) : Infinity;
}
const sameShape = (a, b) => Array.isArray(a) && a.length === 2 && a.every((x, i) => isInt(x) && Number(x) === b[i]);

/** A 1.0 layout `views` entry (spec 10.8) with its optional residual record (10.7). */
function legacyView(v) {
  if (!(v instanceof Map)) throw new CodecError(`view ${show(v)} is not a map`);
  const cam = v.get('camera');
  if (!(cam instanceof Map)) throw new CodecError(`camera ${show(cam)} is not a map`);
  for (const key of ['width', 'height', 'intrinsics', 'pose']) if (!cam.has(key)) throw new CodecError(`camera lacks '${key}'`);
  const intrinsics = cam.get('intrinsics');
  const pose = cam.get('pose');
  if (!(intrinsics instanceof Uint8Array && intrinsics.length === 16)) throw new CodecError(`camera intrinsics ${show(intrinsics)} are not 16 bytes`);
  if (!(pose instanceof Uint8Array && pose.length === 48)) throw new CodecError(`camera pose ${show(pose)} are not 48 bytes`);
  const width = intOf(cam.get('width'), 'camera width');
  const height = intOf(cam.get('height'), 'camera height');
  const record = { camera: camera(width, height, floats32(intrinsics, 4), floats32(pose, 12)), residual: null };
  if (!v.has('residual')) return record;
  const m = v.get('residual');
  if (!(m instanceof Map)) throw new CodecError(`residual record ${show(m)} is not a map`);
  for (const key of ['codec', 'bits', 'gain', 'shape', 'offset']) if (!m.has(key)) throw new CodecError(`residual record lacks '${key}'`);
  const scale = m.has('scale') ? intOf(m.get('scale'), 'residual scale') : 1;
  const bits = intOf(m.get('bits'), 'residual bits');
  const residual = residualRecord(m.get('codec'), bits, m.get('gain'), height, width, scale);
  const offset = m.get('offset');
  if (!(isInt(offset) && Number(offset) === residual.offset)) {
    throw new CodecError(`residual offset ${show(offset)} is not 2^(bits - 1) = ${residual.offset}`);
  }
  // The record covers its camera: full_shape, or shape where it is absent, is the camera's [height, width],
  // and shape is the camera's size at 1/scale (10.7).
  const shape = m.get('shape');
  const covered = m.has('full_shape') ? m.get('full_shape') : shape;
  if (!sameShape(covered, residual.fullShape) || !sameShape(shape, residual.shape)) {
    throw new CodecError(
      `residual shape ${show(shape)} (full shape ${show(m.has('full_shape') ? m.get('full_shape') : 'absent')}) does not ` +
        `cover its ${width}x${height} camera at 1/${scale}`,
    );
  }
  record.residual = residual;
  return record;
}

/**
 * A payload in the SIDE layout (spec 10.9) as {views, images (view number -> bytes)}: a SIDE chunk's, or a
 * TSID chunk's (10.15: the same layout, refused by the same rules); `name` names the chunk in messages.
 * The pixel limits and the images' declared sizes are checked by the callers (checkViewPixels, withImages).
 */
export function readSideChunk(payload, name = 'SIDE') {
  const view = new DataView(payload.buffer, payload.byteOffset, payload.byteLength);
  const size = payload.length;
  if (size < HEAD_BYTES) throw new CodecError(`${name} chunk is truncated`);
  const count = view.getUint32(0, true);
  const flags = payload[4];
  const codecId = payload[5];
  const bits = payload[6];
  const scale = payload[7];
  if (!(count >= 1 && count <= MAX_VIEWS)) throw new CodecError(`${name} chunk has ${count} views (allowed 1..${MAX_VIEWS})`);
  if (flags & ~FLAG_PER_VIEW_CAMERA) throw new CodecError(`${name} chunk has unknown flags 0x${flags.toString(16)}`);
  if (codecId >= RESIDUAL_CODECS.length || (bits !== 8 && bits !== 16) || !(scale >= 1 && scale <= MAX_RESIDUAL_SCALE)) {
    throw new CodecError(`${name} chunk names codec ${codecId}, ${bits} bits, scale ${scale}: not allowed`);
  }
  const perView = flags & FLAG_PER_VIEW_CAMERA;
  const tableBytes = HEAD_BYTES + (perView ? 0 : CAMERA_BYTES) + count * (VIEW_BYTES + (perView ? CAMERA_BYTES : 0));
  // Every view takes its bytes: refuse a count the chunk cannot hold before building a record per view.
  if (tableBytes > size) throw new CodecError(`${name} chunk is truncated: ${count} views need ${tableBytes} bytes, it has ${size}`);
  let p = HEAD_BYTES;
  const readCamera = () => {
    const out = [view.getUint32(p, true), view.getUint32(p + 4, true), floats32(payload.subarray(p + 8, p + 24), 4)];
    p += CAMERA_BYTES;
    return out;
  };
  const shared = perView ? null : readCamera();
  const views = [];
  const lengths = [];
  for (let k = 0; k < count; k++) {
    const [width, height, intrinsics] = perView ? readCamera() : shared;
    const pose = floats32(payload.subarray(p, p + 48), 12);
    const length = view.getUint32(p + 48, true);
    p += VIEW_BYTES;
    let gain = null;
    if (length) {
      if (p + GAIN_BYTES > size) throw new CodecError(`${name} chunk is truncated`);
      gain = view.getFloat32(p, true);
      p += GAIN_BYTES;
    }
    views.push(
      withView(k, () => ({
        camera: camera(width, height, intrinsics, pose),
        residual: gain === null ? null : residualRecord(RESIDUAL_CODECS[codecId], bits, gain, height, width, scale),
      })),
    );
    lengths.push(length);
  }
  const imageBytes = lengths.reduce((a, b) => a + b, 0);
  if (p + imageBytes !== size) {
    throw new CodecError(`${name} chunk images need ${imageBytes} bytes after the view table, found ${size - p}`);
  }
  const images = new Map();
  lengths.forEach((length, k) => {
    if (length) {
      images.set(k, payload.subarray(p, p + length));
      p += length;
    }
  });
  return { views, images };
}

/**
 * Each view's pixels against 2^24, and all views' together against `budget` (spec 10.8: viewPixelBudget of
 * the file's size; 10.15: a tile's tileViewPixelBudget). `of` says what the budget is of, for the message.
 */
export function checkViewPixels(views, budget, of) {
  let total = 0;
  views.forEach((v, k) => {
    const pixels = v.camera.width * v.camera.height;
    if (pixels > MAX_VIEW_PIXELS) {
      throw new CodecError(`side-information view ${k} is ${v.camera.width}x${v.camera.height} = ${pixels} pixels; the limit is ${MAX_VIEW_PIXELS}`);
    }
    total += pixels;
  });
  if (total > budget) {
    throw new CodecError(`side-information views ask for ${total} pixels in ${of}; the limit is ${budget}`);
  }
}

/**
 * The views with their residual images (`images`: view number -> bytes), each image's signature and
 * declared size checked against its record (spec 10.7, "Which decoder checks what"): [{camera, residual
 * (null or the record with its `image` bytes)}].
 */
function withImages(views, images) {
  return views.map((v, k) => {
    if (!v.residual) return v;
    const image = images.get(k);
    const [w, h] = declaredSize(v.residual.codec, image);
    const [rows, columns] = v.residual.shape;
    if (w !== columns || h !== rows) {
      throw new CodecError(
        `side-information view ${k}: residual ${v.residual.codec} image declares ${w}x${h} pixels, its record expects ${columns}x${rows}`,
      );
    }
    return { camera: v.camera, residual: { ...v.residual, image } };
  });
}

/**
 * The side-information views of a file of `fileSize` bytes from either layout: `sideInfo` from
 * readSideInfo, `chunks` the container's chunks. Returns [{camera, residual (null or the record with its
 * `image` bytes)}], every record, the pixel limits and each image's declared size checked.
 */
export function readSideViews(sideInfo, chunks, fileSize) {
  const resi = new Map(chunks.filter((c) => c.type === 'RESI').map((c) => [c.index, c.payload]));
  const packed = chunks.filter((c) => c.type === 'SIDE');
  let views;
  let images;
  if (packed.length) {
    if (sideInfo.legacyViews.length || resi.size) {
      throw new CodecError('the file holds side information both in a SIDE chunk and in the 1.0 form');
    }
    const bad = packed.find((c) => c.index !== 0);
    if (bad) throw new CodecError(`chunk SIDE has index ${bad.index}, not 0`);
    ({ views, images } = readSideChunk(packed[0].payload));
  } else {
    views = sideInfo.legacyViews;
    const withResidual = new Set(views.flatMap((v, k) => (v.residual ? [k] : [])));
    const mismatch = [...resi.keys(), ...withResidual].filter((k) => resi.has(k) !== withResidual.has(k));
    if (mismatch.length) {
      const k = Math.min(...mismatch);
      throw new CodecError(`side-information view ${k} has a RESI chunk or a residual record, not both`);
    }
    images = resi;
  }
  checkViewPixels(views, viewPixelBudget(fileSize), `a ${fileSize}-byte file`);
  return withImages(views, images);
}

/**
 * Tile `number`'s side information (format 1.6, spec 10.15): its TSID chunk's `payload`, in the SIDE layout
 * and refused by the SIDE rules (10.9), its views' pixels within the tile's share of the file's floor:
 * `tileBytes` (Q_k) its attribute and TSID payload bytes, `allBytes` (Q) all tiles'. Returns the views as
 * readSideViews does; errors name the tile.
 */
export function readTileSideViews(number, payload, tileBytes, allBytes) {
  try {
    const { views, images } = readSideChunk(payload, `TSID#${number}`);
    checkViewPixels(views, tileViewPixelBudget(tileBytes, allBytes), `tile ${number} (${tileBytes} of the tiles' ${allBytes} bytes)`);
    return withImages(views, images);
  } catch (err) {
    if (err instanceof CodecError) throw new CodecError(`tile ${number}'s side information: ${err.message}`);
    throw err;
  }
}
