// Public API of the gspc decoder: `decodeGspc` decodes a .gspc file's bytes to a scene's attribute arrays;
// `readContainer` verifies and lists the container alone (spec sections 2-8); `openGspc` reads a file in
// parts from a byte source (sources.mjs) and decodes a tiled file tile by tile as its bytes arrive (spec
// 10.14).

export { decodeGspc } from './decode.mjs';
export { readContainer } from './container.mjs';
export { attributePayloads, decodeAttributes } from './attributes.mjs';
export { readAttributeSection } from './section.mjs';
export { plyHeader, plyParts, writePly } from './ply.mjs';
export { boxMeets, readTileIndex } from './tiles.mjs';
export { openGspc } from './stream.mjs';
export { SourceError, bytesSource, fetchRangeSource, fetchStreamSource } from './sources.mjs';
export * from './errors.mjs';
