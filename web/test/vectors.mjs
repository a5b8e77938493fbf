// The conformance vectors of spec/vectors (spec section 13) and their manifest, for the tests.

import { readFileSync } from 'node:fs';
import { createHash } from 'node:crypto';
import { fileURLToPath } from 'node:url';

export const VECTORS = fileURLToPath(new URL('../../spec/vectors/', import.meta.url));
export const MANIFEST = JSON.parse(readFileSync(`${VECTORS}MANIFEST.json`, 'utf8'));

export const readVector = (name) => new Uint8Array(readFileSync(`${VECTORS}${name}`));

export const sha256 = (bytes) => createHash('sha256').update(bytes).digest('hex');

/** The bytes of a typed array (its own range of its buffer). */
export const bytesOf = (array) => new Uint8Array(array.buffer, array.byteOffset, array.byteLength);

/** A plain value in the manifest's JSON form: Uint8Array as {"$bin": hex}. */
export function asManifestJson(value) {
  if (value instanceof Uint8Array) return { $bin: Buffer.from(value).toString('hex') };
  if (Array.isArray(value)) return value.map(asManifestJson);
  if (typeof value === 'bigint') return Number(value);
  if (value !== null && typeof value === 'object') {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, asManifestJson(v)]));
  }
  return value;
}
