// A strict msgpack reader for the rules of spec section 4 (header) and 10.0 (payloads).
//
// Written here rather than taken from @msgpack/msgpack: the spec refuses what a general-purpose decoder
// accepts silently. An integer and an integral float must stay apart (`n` written as 300.0 is refused,
// 10.11), a map may not hold a key twice (a general decoder keeps the last), map keys are strings only,
// extension types (the timestamp included) are refused, nesting stops at 32 levels, and every count and
// length is compared with the bytes left before anything is allocated (section 7).
//
// Values: nil -> null, boolean -> boolean, integer -> BigInt (exact over -2^63 .. 2^64 - 1 and never
// mistaken for a float), float 32/64 -> number, str -> string, bin -> Uint8Array (a view into the input,
// not a copy), array -> Array, map -> Map with string keys (insertion order kept).

import { MAX_DEPTH } from './limits.mjs';

/** Malformed or disallowed msgpack; callers turn it into BadHeader or CodecError with their context. */
export class MsgpackError extends Error {}

const UTF8 = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true });
const TWO32 = 2 ** 32;

/** A cursor over msgpack bytes `bytes[pos .. end)`. */
export class MsgReader {
  constructor(bytes, pos = 0, end = bytes.length) {
    this.bytes = bytes;
    this.view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    this.pos = pos;
    this.end = end;
  }

  get remaining() {
    return this.end - this.pos;
  }

  _need(n, what) {
    if (n > this.end - this.pos) {
      throw new MsgpackError(`msgpack ${what} needs ${n} bytes at offset ${this.pos}, ${this.end - this.pos} remain`);
    }
  }

  _u8() {
    this._need(1, 'value');
    return this.bytes[this.pos++];
  }

  _uint(size) {
    this._need(size, 'length');
    const v = this.view;
    const p = this.pos;
    this.pos += size;
    if (size === 1) return v.getUint8(p);
    if (size === 2) return v.getUint16(p);
    return v.getUint32(p);
  }

  /** Length of a str/bin/array/map body starting at the cursor after the type byte `b`, or -1. */
  _count(b) {
    if (b <= 0x7f || b >= 0xe0) return -1;
    if (b <= 0x8f) return b & 0x0f; // fixmap
    if (b <= 0x9f) return b & 0x0f; // fixarray
    if (b <= 0xbf) return b & 0x1f; // fixstr
    switch (b) {
      case 0xc4: case 0xd9: return this._uint(1); // bin8, str8
      case 0xc5: case 0xda: case 0xdc: case 0xde: return this._uint(2); // bin16, str16, array16, map16
      case 0xc6: case 0xdb: case 0xdd: case 0xdf: return this._uint(4); // bin32, str32, array32, map32
      default: return -1;
    }
  }

  /** The element count of an array at the cursor (checked against the bytes left); MsgpackError otherwise. */
  readArrayHeader() {
    const b = this._u8();
    if (!((b >= 0x90 && b <= 0x9f) || b === 0xdc || b === 0xdd)) {
      this.pos--;
      throw new MsgpackError(`msgpack ${typeName(b)} where an array is expected`);
    }
    const n = this._count(b);
    // Each element takes at least one byte (section 7): refuse a count the bytes cannot hold.
    this._need(n, `array of ${n} elements`);
    return n;
  }

  /** A bin at the cursor, as a view into the input; MsgpackError when the next value is not a bin. */
  readBin() {
    const b = this._u8();
    if (b !== 0xc4 && b !== 0xc5 && b !== 0xc6) {
      this.pos--;
      throw new MsgpackError(`msgpack ${typeName(b)} where a bin is expected`);
    }
    const n = this._count(b);
    this._need(n, `bin of ${n} bytes`);
    const out = this.bytes.subarray(this.pos, this.pos + n);
    this.pos += n;
    return out;
  }

  /**
   * An integer at the cursor as a number: exact up to 2^53 in magnitude, rounded beyond (callers compare it
   * with bounds far below 2^53, so rounding cannot turn a refused value into an accepted one). MsgpackError
   * when the next value is not a msgpack integer (a float or a boolean is not one).
   */
  readIntNumber() {
    const b = this._u8();
    if (b <= 0x7f) return b;
    if (b >= 0xe0) return b - 0x100;
    const v = this.view;
    const p = this.pos;
    switch (b) {
      case 0xcc: this._need(1, 'uint8'); this.pos += 1; return v.getUint8(p);
      case 0xcd: this._need(2, 'uint16'); this.pos += 2; return v.getUint16(p);
      case 0xce: this._need(4, 'uint32'); this.pos += 4; return v.getUint32(p);
      case 0xcf: this._need(8, 'uint64'); this.pos += 8; return v.getUint32(p) * TWO32 + v.getUint32(p + 4);
      case 0xd0: this._need(1, 'int8'); this.pos += 1; return v.getInt8(p);
      case 0xd1: this._need(2, 'int16'); this.pos += 2; return v.getInt16(p);
      case 0xd2: this._need(4, 'int32'); this.pos += 4; return v.getInt32(p);
      case 0xd3: this._need(8, 'int64'); this.pos += 8; return v.getInt32(p) * TWO32 + v.getUint32(p + 4);
      default:
        this.pos--;
        throw new MsgpackError(`msgpack ${typeName(b)} where an integer is expected`);
    }
  }

  /** The next value, `depth` being its nesting level (the outermost value is level 1). */
  readValue(depth = 1) {
    const b = this._u8();
    if (b <= 0x7f) return BigInt(b);
    if (b >= 0xe0) return BigInt(b - 0x100);
    if (b <= 0x8f) return this._map(b & 0x0f, depth);
    if (b <= 0x9f) return this._array(b & 0x0f, depth);
    if (b <= 0xbf) return this._str(b & 0x1f);
    const v = this.view;
    const p = this.pos;
    switch (b) {
      case 0xc0: return null;
      case 0xc2: return false;
      case 0xc3: return true;
      case 0xc4: case 0xc5: case 0xc6: {
        const n = this._count(b);
        this._need(n, `bin of ${n} bytes`);
        const out = this.bytes.subarray(this.pos, this.pos + n);
        this.pos += n;
        return out;
      }
      case 0xca: this._need(4, 'float32'); this.pos += 4; return v.getFloat32(p);
      case 0xcb: this._need(8, 'float64'); this.pos += 8; return v.getFloat64(p);
      case 0xcc: this._need(1, 'uint8'); this.pos += 1; return BigInt(v.getUint8(p));
      case 0xcd: this._need(2, 'uint16'); this.pos += 2; return BigInt(v.getUint16(p));
      case 0xce: this._need(4, 'uint32'); this.pos += 4; return BigInt(v.getUint32(p));
      case 0xcf: this._need(8, 'uint64'); this.pos += 8; return v.getBigUint64(p);
      case 0xd0: this._need(1, 'int8'); this.pos += 1; return BigInt(v.getInt8(p));
      case 0xd1: this._need(2, 'int16'); this.pos += 2; return BigInt(v.getInt16(p));
      case 0xd2: this._need(4, 'int32'); this.pos += 4; return BigInt(v.getInt32(p));
      case 0xd3: this._need(8, 'int64'); this.pos += 8; return v.getBigInt64(p);
      case 0xd9: case 0xda: case 0xdb: return this._str(this._count(b));
      case 0xdc: case 0xdd: return this._array(this._count(b), depth);
      case 0xde: case 0xdf: return this._map(this._count(b), depth);
      case 0xc1:
        throw new MsgpackError(`msgpack byte 0xc1 at offset ${p - 1} is never used`);
      default: {
        // 0xc7-0xc9 ext 8/16/32, 0xd4-0xd8 fixext: read the type only to name it.
        const head = b <= 0xc9 ? 1 << (b - 0xc7) : 0;
        this._need(head + 1, 'extension');
        const code = v.getInt8(p + head);
        throw new MsgpackError(`msgpack extension type ${code} at offset ${p - 1} is not allowed`);
      }
    }
  }

  _str(n) {
    this._need(n, `str of ${n} bytes`);
    const raw = this.bytes.subarray(this.pos, this.pos + n);
    this.pos += n;
    try {
      return UTF8.decode(raw);
    } catch {
      throw new MsgpackError(`msgpack str at offset ${this.pos - n} is not UTF-8`);
    }
  }

  _array(n, depth) {
    if (depth > MAX_DEPTH) throw new MsgpackError(`msgpack nests deeper than ${MAX_DEPTH} levels`);
    this._need(n, `array of ${n} elements`);
    const out = new Array(n);
    for (let i = 0; i < n; i++) out[i] = this.readValue(depth + 1);
    return out;
  }

  _map(n, depth) {
    if (depth > MAX_DEPTH) throw new MsgpackError(`msgpack nests deeper than ${MAX_DEPTH} levels`);
    this._need(2 * n, `map of ${n} pairs`);
    const out = new Map();
    for (let i = 0; i < n; i++) {
      const at = this.pos;
      const key = this.readValue(depth + 1);
      if (typeof key !== 'string') {
        throw new MsgpackError(`msgpack map key ${String(key)} at offset ${at} is not a str`);
      }
      if (out.has(key)) throw new MsgpackError(`msgpack map key '${key}' appears twice`);
      out.set(key, this.readValue(depth + 1));
    }
    return out;
  }
}

/** A short name of the msgpack type whose first byte is `b`, for messages. */
export function typeName(b) {
  if (b <= 0x7f || b >= 0xe0 || (b >= 0xcc && b <= 0xd3)) return 'integer';
  if (b <= 0x8f || b === 0xde || b === 0xdf) return 'map';
  if (b <= 0x9f || b === 0xdc || b === 0xdd) return 'array';
  if (b <= 0xbf || (b >= 0xd9 && b <= 0xdb)) return 'str';
  if (b === 0xc0) return 'nil';
  if (b === 0xc2 || b === 0xc3) return 'boolean';
  if (b >= 0xc4 && b <= 0xc6) return 'bin';
  if (b === 0xca || b === 0xcb) return 'float';
  return 'extension';
}

/** Exactly one msgpack value filling `bytes` (spec 10.0: bytes after it are refused). */
export function decodeOne(bytes) {
  const r = new MsgReader(bytes);
  const value = r.readValue(1);
  if (r.remaining) throw new MsgpackError(`${r.remaining} bytes after the msgpack value`);
  return value;
}

/** The msgpack type of a decoded value, in the spec's words, for messages. */
export function kindOf(value) {
  if (value === null) return 'nil';
  if (typeof value === 'bigint') return 'integer';
  if (typeof value === 'number') return 'float';
  if (typeof value === 'boolean') return 'boolean';
  if (typeof value === 'string') return 'str';
  if (value instanceof Uint8Array) return 'bin';
  if (Array.isArray(value)) return 'array';
  if (value instanceof Map) return 'map';
  return typeof value;
}

/**
 * A decoded value as plain JavaScript: maps become objects, integers numbers (BigInt beyond 2^53), bins stay
 * Uint8Array. For callers that do not need to tell an integer from an integral float.
 */
export function toPlain(value) {
  if (typeof value === 'bigint') {
    return value >= -(2n ** 53n) && value <= 2n ** 53n ? Number(value) : value;
  }
  if (Array.isArray(value)) return value.map(toPlain);
  if (value instanceof Map) {
    const out = {};
    for (const [k, v] of value) Object.defineProperty(out, k, { value: toPlain(v), enumerable: true, writable: true, configurable: true });
    return out;
  }
  return value;
}
