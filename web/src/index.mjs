// Public API of the gspc decoder: `decodeGspc` decodes a .gspc file's bytes to a scene's attribute arrays;
// `readContainer` verifies and lists the container alone (spec sections 2-8).

import { attributePayloads, decodeAttributes } from './attributes.mjs';
import { readContainer } from './container.mjs';
import { readFileHeader } from './header.mjs';
import { readSideViews } from './side.mjs';

export { readContainer } from './container.mjs';
export { attributePayloads, decodeAttributes } from './attributes.mjs';
export { readAttributeSection } from './section.mjs';
export { plyHeader, plyParts, writePly } from './ply.mjs';
export * from './errors.mjs';

/**
 * Decode a .gspc file (`bytes`: Uint8Array or ArrayBuffer) to its Gaussians, without restoration or
 * refinement.
 *
 * Returns {header, views, count, shDegree, means, quats, logScales, opacities, shDc, shRest}: `header` holds
 * the container's version, its meta as plain JavaScript (integers beyond 2^53 as BigInt, bins as
 * Uint8Array) and the checked codec records; `views` the
 * side-information views (camera, residual record with its still-coded image bytes, or null); the arrays are
 * Float32Array in curve order: means N x 3, quats N x 4 (w, x, y, z), logScales N x 3, opacities N (logits),
 * shDc N x 3, shRest N x K x 3 (K = (shDegree + 1)^2 - 1). Throws FormatError (a subclass naming the
 * container's problem) or CodecError.
 */
export function decodeGspc(bytes) {
  if (bytes instanceof ArrayBuffer) bytes = new Uint8Array(bytes);
  const container = readContainer(bytes);
  const records = readFileHeader(container.metaTree);
  const views = readSideViews(records.sideInfo, container.chunks, bytes.length);
  const scene = decodeAttributes(records.attributes, attributePayloads(container.chunks));
  const header = { version: container.version, meta: container.meta, ...records };
  return { header, views, ...scene };
}
