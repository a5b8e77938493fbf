// The gspc container (spec sections 2-8): preamble, msgpack header with the chunk table, 8-aligned chunk
// payloads and the trailer. `readContainer` runs the ten checks of section 8 in their order on a whole
// file. Its steps are separate functions over byte ranges (the preamble's 20 bytes, the header's bytes, one
// chunk's payload and padding, the trailer), so that a reader of a partial file can run each as its bytes
// arrive.

import {
  BadHeader,
  BadMagic,
  BadPadding,
  ChecksumMismatch,
  DuplicateChunk,
  LimitExceeded,
  TrailingBytes,
  Truncated,
  UnknownRequiredChunk,
  UnsupportedVersion,
  show,
} from './errors.mjs';
import { crc32 } from './crc32.mjs';
import { MAX_CHUNKS, MAX_CHUNK_LENGTH, MAX_HEADER_LENGTH, MAX_U32 } from './limits.mjs';
import { MsgReader, MsgpackError, kindOf, toPlain } from './msgpack.mjs';

export const MAGIC = Uint8Array.of(0x89, 0x47, 0x53, 0x50, 0x43, 0x0d, 0x0a, 0x1a);
export const END_MARKER = Uint8Array.of(0x47, 0x45, 0x4e, 0x44); // "GEND"
export const PREAMBLE_BYTES = 20;
export const TRAILER_BYTES = 8;
export const MAJOR = 1;
/** Chunk types of format 1.8 (spec section 6). */
export const KNOWN_TYPES = new Set(['POSN', 'OPAC', 'SCAL', 'ROTN', 'SHDC', 'SHRS', 'PREC', 'TIDX', 'RESI', 'SIDE', 'TSID']);

const FLAG_REQUIRED = 1;
const TYPE_PATTERN = /^[A-Za-z0-9]{4}$/;
const ENTRY_KEYS = ['type', 'flags', 'index', 'length', 'crc'];

export const align8 = (x) => Math.ceil(x / 8) * 8;

function hex(bytes) {
  return Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');
}

function hex32(x) {
  return x.toString(16).padStart(8, '0');
}

/**
 * Checks 1-3 of section 8 on the first bytes of a file (all 20 preamble bytes, or fewer when the file is
 * shorter): {major, minor, headerLength, headerCrc}. `size` is the file's size.
 */
export function readPreamble(head, size = head.length) {
  const n = Math.min(size, head.length);
  if (n < MAGIC.length) {
    if (MAGIC.subarray(0, n).every((b, i) => b === head[i])) {
      throw new Truncated(`file ends at offset ${n}, inside the magic`);
    }
    throw new BadMagic(`not a gspc file: the first ${n} bytes ${hex(head.subarray(0, n))} are not the gspc magic`);
  }
  if (!MAGIC.every((b, i) => b === head[i])) {
    throw new BadMagic(`not a gspc file: bytes 0-7 are ${hex(head.subarray(0, 8))}, the gspc magic is ${hex(MAGIC)}`);
  }
  if (n < 12) throw new Truncated(`file ends at offset ${n}, inside the version (offset 8)`);
  const view = new DataView(head.buffer, head.byteOffset, head.byteLength);
  const major = view.getUint16(8, true);
  const minor = view.getUint16(10, true);
  if (major !== MAJOR) {
    const which = major > MAJOR ? 'a newer' : 'an older';
    throw new UnsupportedVersion(
      `gspc format version ${major}.${minor} is ${which} major version; this reader reads ${MAJOR}.x`,
    );
  }
  if (n < PREAMBLE_BYTES) throw new Truncated(`file ends at offset ${n}, inside the preamble (20 bytes)`);
  const headerLength = view.getUint32(12, true);
  const headerCrc = view.getUint32(16, true);
  if (headerLength > MAX_HEADER_LENGTH) {
    throw new LimitExceeded(`header_length ${headerLength} at offset 12 exceeds the limit ${MAX_HEADER_LENGTH}`);
  }
  if (headerLength > size - PREAMBLE_BYTES) {
    throw new Truncated(
      `file ends at offset ${size}, inside the header: header_length ${headerLength} at offset 12 needs ` +
        `${PREAMBLE_BYTES + headerLength} bytes`,
    );
  }
  if (headerLength === 0) throw new BadHeader('header_length at offset 12 is 0; the header must be a msgpack map');
  return { major, minor, headerLength, headerCrc };
}

function headerValue(bytes) {
  const r = new MsgReader(bytes);
  let top;
  try {
    top = r.readValue(1);
  } catch (err) {
    if (err instanceof MsgpackError) throw new BadHeader(`header is not valid msgpack: ${err.message}`);
    throw err;
  }
  if (r.remaining) {
    throw new BadHeader(`header holds ${r.remaining} bytes after its msgpack map (offset ${PREAMBLE_BYTES})`);
  }
  return top;
}

function u32Field(entry, key, where, type) {
  const v = entry.get(key);
  if (typeof v !== 'bigint' || v < 0n || v > BigInt(MAX_U32)) {
    throw new BadHeader(`${where} (${type}) has ${key} ${show(v)}, not an integer in 0..${MAX_U32}`);
  }
  return Number(v);
}

/**
 * Checks 4-7 of section 8 on the header's bytes (`headerBytes`, exactly header_length of them):
 * {meta (the msgpack tree: Map, BigInt), entries (type, index, flags, required, length, crc, offset),
 * dataStart, trailerAt, fileSize (the size the header declares)}.
 */
export function readHeader(preamble, headerBytes) {
  const { headerLength, headerCrc } = preamble;
  const got = crc32(headerBytes);
  if (got !== headerCrc) {
    throw new ChecksumMismatch(
      `header (offset 20, ${headerLength} bytes) has CRC-32 ${hex32(got)}, the preamble says ${hex32(headerCrc)}`,
    );
  }
  const top = headerValue(headerBytes);
  if (!(top instanceof Map)) throw new BadHeader(`header is a msgpack ${kindOf(top)}, not a map`);
  for (const [key, kind] of [['chunks', 'array'], ['meta', 'map']]) {
    if (!top.has(key)) throw new BadHeader(`header has no '${key}' key`);
    if (kindOf(top.get(key)) !== kind) {
      throw new BadHeader(`header '${key}' is a ${kindOf(top.get(key))}, not a ${kind}`);
    }
  }
  const table = top.get('chunks');
  if (table.length > MAX_CHUNKS) {
    throw new LimitExceeded(`chunk table has ${table.length} entries; the limit is ${MAX_CHUNKS}`);
  }
  const dataStart = align8(PREAMBLE_BYTES + headerLength);
  let offset = dataStart;
  const entries = table.map((e, i) => {
    const where = `chunk table entry ${i}`;
    if (!(e instanceof Map)) throw new BadHeader(`${where} is a ${kindOf(e)}, not a map`);
    for (const key of ENTRY_KEYS) if (!e.has(key)) throw new BadHeader(`${where} has no '${key}'`);
    const type = e.get('type');
    if (typeof type !== 'string' || !TYPE_PATTERN.test(type)) {
      throw new BadHeader(`${where} has type ${show(type)}, not 4 ASCII letters or digits`);
    }
    const flags = u32Field(e, 'flags', where, type);
    const index = u32Field(e, 'index', where, type);
    const crc = u32Field(e, 'crc', where, type);
    const length = e.get('length');
    if (typeof length !== 'bigint' || length < 0n) {
      throw new BadHeader(`${where} (${type}) has length ${show(length)}, not a non-negative integer`);
    }
    if (length > BigInt(MAX_CHUNK_LENGTH)) {
      throw new LimitExceeded(`${where} (${type}) has length ${length}; the limit is ${MAX_CHUNK_LENGTH}`);
    }
    const entry = { type, index, flags, required: (flags & FLAG_REQUIRED) !== 0, length: Number(length), crc, offset };
    entry.name = `${type}#${index}`;
    offset = align8(offset + entry.length);
    return entry;
  });
  const seen = new Map();
  entries.forEach((e, i) => {
    if (seen.has(e.name)) {
      throw new DuplicateChunk(`chunk ${e.name} appears twice in the chunk table (entries ${seen.get(e.name)} and ${i})`);
    }
    seen.set(e.name, i);
  });
  entries.forEach((e, i) => {
    if (e.required && !KNOWN_TYPES.has(e.type)) {
      throw new UnknownRequiredChunk(
        `required chunk ${e.name} (table entry ${i}, payload at offset ${e.offset}) has a type this reader ` +
          'does not know; a newer gspc is needed',
      );
    }
  });
  const trailerAt = offset;
  return { meta: top.get('meta'), entries, dataStart, trailerAt, fileSize: trailerAt + TRAILER_BYTES };
}

/** The region of a file that offset `pos` falls in, for messages about where a file ends. */
export function regionAt(pos, headerLength, entries, trailerAt) {
  if (pos < PREAMBLE_BYTES + headerLength) return 'header';
  for (const e of entries) {
    if (pos < e.offset) return `padding before chunk ${e.name}`;
    if (pos < e.offset + e.length) return `chunk ${e.name} payload`;
  }
  return pos < trailerAt ? 'padding before the trailer' : 'trailer';
}

/** Check 8 of section 8: the file's size against the layout the header declares. */
export function checkFileSize(size, preamble, layout) {
  if (size < layout.fileSize) {
    const region = regionAt(size, preamble.headerLength, layout.entries, layout.trailerAt);
    throw new Truncated(`file ends at offset ${size}, inside the ${region}; the header declares ${layout.fileSize} bytes`);
  }
  if (size > layout.fileSize) {
    throw new TrailingBytes(`${size - layout.fileSize} bytes follow the trailer, which ends at offset ${layout.fileSize}`);
  }
}

/** Bytes `start .. end` of the file are zero; `bytes` holds the file's bytes from offset `base` on. */
function checkZero(bytes, start, end, after, base = 0) {
  for (let i = start; i < end; i++) {
    const b = bytes[i - base];
    if (b !== 0) {
      throw new BadPadding(`padding byte at offset ${i} after the ${after} is 0x${b.toString(16).padStart(2, '0')}, not 0`);
    }
  }
}

/** Check 9 for the header padding: `file` holds at least the bytes up to `layout.dataStart`. */
export function checkHeaderPadding(file, preamble, layout) {
  checkZero(file, PREAMBLE_BYTES + preamble.headerLength, layout.dataStart, 'header');
}

/**
 * Check 9 for one chunk: `file` holds the file's bytes from offset `base` on, the chunk's payload and
 * padding among them. Returns the payload (a view, not a copy).
 */
export function checkChunk(file, entry, base = 0) {
  const payload = file.subarray(entry.offset - base, entry.offset - base + entry.length);
  const got = crc32(payload);
  if (got !== entry.crc) {
    throw new ChecksumMismatch(
      `chunk ${entry.name} (payload at offset ${entry.offset}, ${entry.length} bytes) has CRC-32 ${hex32(got)}, ` +
        `the chunk table says ${hex32(entry.crc)}`,
    );
  }
  checkZero(file, entry.offset + entry.length, align8(entry.offset + entry.length), `chunk ${entry.name}`, base);
  return payload;
}

/** Check 10: the end marker and the CRC-32 of the whole file (`fileCrc`: of bytes 0 .. size - 5). */
export function checkTrailer(trailer, trailerAt, fileCrc, size) {
  if (!END_MARKER.every((b, i) => b === trailer[i])) {
    throw new BadMagic(`end marker at offset ${trailerAt} is ${hex(trailer.subarray(0, 4))}, expected ${hex(END_MARKER)} (GEND)`);
  }
  const stored = new DataView(trailer.buffer, trailer.byteOffset + 4, 4).getUint32(0, true);
  if (stored !== fileCrc) {
    throw new ChecksumMismatch(
      `whole file (bytes 0-${size - 5}) has CRC-32 ${hex32(fileCrc)}, the trailer at offset ${size - 4} says ${hex32(stored)}`,
    );
  }
}

/**
 * Parse and verify a whole gspc file (every check of spec section 8, in its order). Returns
 * {version: [major, minor], meta (plain JavaScript: objects, numbers), metaTree (the msgpack tree as read:
 * Map, BigInt integers, number floats), chunks, skipped}: `chunks` are the chunks of known types in file
 * order, `skipped` the verified unknown optional ones, each {type, index, required, flags, length, offset,
 * payload}. Throws a FormatError subclass naming what is wrong and where.
 */
export function readContainer(bytes) {
  const size = bytes.length;
  const preamble = readPreamble(bytes.subarray(0, PREAMBLE_BYTES), size);
  const layout = readHeader(preamble, bytes.subarray(PREAMBLE_BYTES, PREAMBLE_BYTES + preamble.headerLength));
  checkFileSize(size, preamble, layout);
  checkHeaderPadding(bytes, preamble, layout);
  const chunks = [];
  const skipped = [];
  for (const e of layout.entries) {
    const payload = checkChunk(bytes, e);
    const chunk = { type: e.type, index: e.index, required: e.required, flags: e.flags, length: e.length, offset: e.offset, payload };
    (KNOWN_TYPES.has(e.type) ? chunks : skipped).push(chunk);
  }
  checkTrailer(bytes.subarray(layout.trailerAt, size), layout.trailerAt, crc32(bytes.subarray(0, size - 4)), size);
  return {
    version: [preamble.major, preamble.minor],
    meta: toPlain(layout.meta),
    metaTree: layout.meta,
    chunks,
    skipped,
  };
}
