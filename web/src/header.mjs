// The codecs' part of the header, meta (spec 10.8): the attribute section (10.0), side_info and the
// informative scene summary, each checked before any payload is decoded.

import { CodecError, show } from './errors.mjs';
import { MAX_SH_DEGREE } from './limits.mjs';
import { readAttributeSection } from './section.mjs';
import { readSideInfo } from './side.mjs';

/** The sixteen axis conventions `scene.coordinates` may name (spec 10.8): x, y, z in that order. */
export const CONVENTIONS = new Set(
  ['LDB', 'RDB', 'LUB', 'RUB', 'LDF', 'RDF', 'LUF', 'RUF', 'LFD', 'RFD', 'LFU', 'RFU', 'LBD', 'RBD', 'LBU', 'RBU'],
);

/** meta["scene"] (informative, 10.8): checked when present; decoders use attributes.n. */
function readScene(meta) {
  if (!meta.has('scene')) return null;
  const scene = meta.get('scene');
  if (!(scene instanceof Map)) throw new CodecError(`the .gspc header's scene section is ${show(scene)}, not a map`);
  const out = {};
  for (const [key, most] of [['num_gaussians', null], ['sh_degree', MAX_SH_DEGREE]]) {
    if (!scene.has(key)) continue;
    const v = scene.get(key);
    if (!(typeof v === 'bigint' && v >= 0n && (most === null || v <= BigInt(most)))) {
      throw new CodecError(`the .gspc header's scene.${key} is ${show(v)}, not an integer ${most === null ? '>= 0' : `in 0..${most}`}`);
    }
    out[key] = Number(v);
  }
  // Informative (10.8): a value that names no convention is ignored as if absent.
  const coordinates = scene.get('coordinates');
  if (typeof coordinates === 'string' && CONVENTIONS.has(coordinates)) out.coordinates = coordinates;
  return out;
}

/**
 * The checked records of a container's meta tree (Map, BigInt integers): {attributes (readAttributeSection;
 * null in a tiled file, whose tiles hold theirs, spec 10.14), sideInfo (readSideInfo), scene (null or its
 * counts and coordinate convention), encoder (null or the writer's name)}. `tiled`: the file has a tile index.
 */
export function readFileHeader(meta, tiled = false) {
  let attributes = null;
  if (tiled) {
    if (meta.has('attributes')) throw new CodecError("a tiled file's header has an attributes section; its tiles hold theirs");
  } else {
    if (!meta.has('attributes')) throw new CodecError('the .gspc header lacks attributes section');
    attributes = readAttributeSection(meta.get('attributes'));
  }
  const sideInfo = readSideInfo(meta);
  const scene = readScene(meta);
  const encoder = typeof meta.get('encoder') === 'string' ? meta.get('encoder') : null;
  return { attributes, sideInfo, scene, encoder };
}
