// The size a residual image declares in its own header (JPEG XL, WebP, AVIF), read without decoding it: a
// decoder refuses an image of another size than its record names (spec 10.7), and checks the declared size
// before it decodes any pixel (10.10), also when it decodes no image at all. Written from the codecs'
// specifications (ISO/IEC 18181-1 SizeHeader, the WebP container's VP8/VP8L/VP8X headers, ISOBMFF boxes of
// HEIF/AVIF).

import { CodecError } from './errors.mjs';

const JXL_CONTAINER = [0, 0, 0, 0x0c, 0x4a, 0x58, 0x4c, 0x20, 0x0d, 0x0a, 0x87, 0x0a];
const JXL_RATIOS = [null, [1, 1], [12, 10], [4, 3], [3, 2], [16, 9], [5, 4], [2, 1]];

const ascii = (bytes, at, n) => String.fromCharCode(...bytes.subarray(at, at + n));

function u32be(b, p) {
  return ((b[p] << 24) | (b[p + 1] << 16) | (b[p + 2] << 8) | b[p + 3]) >>> 0;
}

/** ISOBMFF boxes of `bytes[start, end)`: [type, bodyStart, boxEnd] each, stopping at a malformed one. */
function* boxes(bytes, start, end) {
  let p = start;
  while (p + 8 <= end) {
    let size = u32be(bytes, p);
    const type = ascii(bytes, p + 4, 4);
    let head = 8;
    if (size === 1) {
      if (p + 16 > end) return;
      size = u32be(bytes, p + 8) * 2 ** 32 + u32be(bytes, p + 12);
      head = 16;
    } else if (size === 0) {
      size = end - p;
    }
    if (size < head || p + size > end) return;
    yield [type, p + head, p + size];
    p += size;
  }
}

/** The codestream of a bare JPEG XL stream, or of the container's first jxlc or jxlp box. */
function jxlCodestream(bytes) {
  if (!JXL_CONTAINER.every((b, i) => bytes[i] === b)) return bytes;
  for (const [type, body, end] of boxes(bytes, 0, bytes.length)) {
    if (type === 'jxlc') return bytes.subarray(body, end);
    if (type === 'jxlp') return bytes.subarray(body + 4, end); // after the part index
  }
  throw new CodecError('residual jxl container holds no codestream box');
}

function jxlSize(bytes) {
  const code = jxlCodestream(bytes);
  if (code[0] !== 0xff || code[1] !== 0x0a) throw new CodecError('residual jxl payload does not start with a JPEG XL signature');
  let bit = 16;
  const read = (n) => {
    let v = 0;
    for (let i = 0; i < n; i++, bit++) {
      if (bit >> 3 >= code.length) throw new CodecError('residual jxl codestream ends inside its size header');
      v += ((code[bit >> 3] >> (bit & 7)) & 1) * 2 ** i; // least significant bit first
    }
    return v;
  };
  const u32Size = () => read([9, 13, 18, 30][read(2)]) + 1;
  const small = read(1);
  const height = small ? (read(5) + 1) * 8 : u32Size();
  const ratio = read(3);
  let width;
  if (ratio) width = Math.floor((height * JXL_RATIOS[ratio][0]) / JXL_RATIOS[ratio][1]);
  else width = small ? (read(5) + 1) * 8 : u32Size();
  return [width, height];
}

function webpSize(b) {
  if (b.length < 30 || ascii(b, 0, 4) !== 'RIFF' || ascii(b, 8, 4) !== 'WEBP') {
    throw new CodecError('residual webp payload is not a RIFF WEBP file');
  }
  const kind = ascii(b, 12, 4);
  const p = 20;
  if (kind === 'VP8 ' && b[p + 3] === 0x9d && b[p + 4] === 0x01 && b[p + 5] === 0x2a) {
    return [(b[p + 6] | (b[p + 7] << 8)) & 0x3fff, (b[p + 8] | (b[p + 9] << 8)) & 0x3fff];
  }
  if (kind === 'VP8L' && b[p] === 0x2f) {
    const bits = (b[p + 1] | (b[p + 2] << 8) | (b[p + 3] << 16) | (b[p + 4] << 24)) >>> 0;
    return [(bits & 0x3fff) + 1, ((bits >>> 14) & 0x3fff) + 1];
  }
  if (kind === 'VP8X') {
    return [(b[p + 4] | (b[p + 5] << 8) | (b[p + 6] << 16)) + 1, (b[p + 7] | (b[p + 8] << 8) | (b[p + 9] << 16)) + 1];
  }
  throw new CodecError(`residual webp payload has no size header (first chunk '${kind}')`);
}

/** The largest width and height of the image spatial extents (ispe) in meta/iprp/ipco. */
function avifSize(b) {
  let width = -1;
  let height = -1;
  for (const [t1, a1, e1] of boxes(b, 0, b.length)) {
    if (t1 !== 'meta') continue;
    for (const [t2, a2, e2] of boxes(b, a1 + 4, e1)) {
      // meta is a full box: 4 bytes of version and flags before its children
      if (t2 !== 'iprp') continue;
      for (const [t3, a3, e3] of boxes(b, a2, e2)) {
        if (t3 !== 'ipco') continue;
        for (const [t4, a4, e4] of boxes(b, a3, e3)) {
          if (t4 === 'ispe' && e4 - a4 >= 12) {
            width = Math.max(width, u32be(b, a4 + 4));
            height = Math.max(height, u32be(b, a4 + 8));
          }
        }
      }
    }
  }
  if (width < 0) throw new CodecError('residual avif payload has no image size (ispe) box');
  return [width, height];
}

const READERS = { jxl: jxlSize, webp: webpSize, avif: avifSize };

/** [width, height] that an image of `codec` ('jxl', 'webp', 'avif') declares; CodecError if none. */
export function declaredSize(codec, bytes) {
  const reader = READERS[codec];
  if (!reader) throw new CodecError(`residual image codec '${codec}' is not one gspc reads`);
  return reader(bytes);
}
