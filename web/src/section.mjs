// The attribute codec's parameters, meta["attributes"] (spec 10.0), as a checked record: count, SH degree,
// position grid (10.1) and each precision class's quantisers (10.13). Every key is checked here, against
// the msgpack tree as read (integers are BigInt there, floats numbers: 300.0 Gaussians is refused).

import { CodecError, show } from './errors.mjs';
import {
  MAX_BITS_CONTRACTED,
  MAX_BITS_PLAIN,
  MAX_CLASSES,
  MAX_CODEBOOK,
  MAX_CODEC_INT,
  MAX_CONTRACTED,
  MAX_COORDINATE,
  MAX_GAUSSIANS,
  MAX_SH_DEGREE,
  MAX_STEP,
  RESOLUTION,
} from './limits.mjs';

export const PLAIN_VERSION = 1;
export const CONTRACTED_VERSION = 2;
export const FAR_VERSION = 3;
export const PRECISION_VERSION = 4;
export const CODEBOOK_VERSION = 5;

const fail = (field, value, want) => new CodecError(`attribute codec header's ${field} is ${show(value)}, not ${want}`);

function get(map, key, where) {
  if (!map.has(key)) throw new CodecError(`attribute codec header is malformed (it lacks ${where})`);
  return map.get(key);
}

function bigint(map, key, where) {
  const v = get(map, key, where);
  if (typeof v !== 'bigint') throw fail(where, v, 'an integer');
  return v;
}

/** A msgpack integer in lo..hi, as a number (exact: every bound here is below 2^53). */
function int(map, key, where, lo, hi) {
  const v = bigint(map, key, where);
  if (v < BigInt(lo) || v > BigInt(hi)) throw fail(where, v, `an integer in ${lo}..${hi}`);
  return Number(v);
}

function float(map, key, where) {
  const v = get(map, key, where);
  if (typeof v !== 'number') throw fail(where, v, 'a float');
  return v;
}

function floats(map, key, where, length) {
  const v = get(map, key, where);
  if (!Array.isArray(v) || !v.every((x) => typeof x === 'number')) throw fail(where, v, 'an array of floats');
  if (v.length !== length) throw fail(where, v, `an array of ${length} floats`);
  return v;
}

function positive(values, where, most = Infinity) {
  if (!values.every((v) => Number.isFinite(v) && v > 0 && v <= most)) {
    const bound = most === Infinity ? '' : `, at most ${most === 2 ** 64 ? '2^64' : most}`;
    throw fail(where, values.length === 1 ? values[0] : values, `finite and > 0${bound}`);
  }
}

function within(values, where, most) {
  if (!values.every((v) => Number.isFinite(v) && Math.abs(v) <= most)) {
    throw fail(where, values, `finite and within +-${most === MAX_COORDINATE ? '2^64' : most}`);
  }
}

/**
 * The `position` map at attribute codec `version` (spec 10.0, 10.1): {bits, lo, step, contraction (null or
 * {centre, radius}), far (null or {count, shift})}; the far count's upper bound (N - 1) is the section's.
 */
function readGrid(grid, version) {
  if (!(grid instanceof Map)) throw fail('position', grid, 'a map');
  const contracted = grid.has('centre') || grid.has('radius');
  const hasFar = grid.has('far_count') || grid.has('far_shift');
  let v = version;
  if (v >= PRECISION_VERSION) v = hasFar ? FAR_VERSION : contracted ? CONTRACTED_VERSION : PLAIN_VERSION;
  if ((v !== PLAIN_VERSION) !== contracted) {
    throw new CodecError('attribute codec version and position grid disagree on contraction');
  }
  if ((v === FAR_VERSION) !== hasFar) throw new CodecError('attribute codec version and position grid disagree on a far set');
  const most = v === PLAIN_VERSION ? MAX_BITS_PLAIN : MAX_BITS_CONTRACTED;
  const bits = int(grid, 'bits', 'position.bits', 1, most);
  const lo = floats(grid, 'lo', 'position.lo', 3);
  const step = floats(grid, 'step', 'position.step', 3);
  let contraction = null;
  let far = null;
  if (v !== PLAIN_VERSION) {
    const centre = floats(grid, 'centre', 'position.centre', 3);
    const radius = float(grid, 'radius', 'position.radius');
    within(centre, 'position.centre', MAX_COORDINATE);
    positive([radius], 'position.radius', MAX_COORDINATE);
    contraction = { centre, radius };
  }
  if (v === FAR_VERSION) {
    const count = bigint(grid, 'far_count', "far set's far_count");
    const shift = bigint(grid, 'far_shift', "far set's far_shift");
    if (shift < 1n || shift > BigInt(bits - 1)) {
      throw new CodecError(`attribute codec header has an impossible far set (far_shift ${shift} with ${bits} bits)`);
    }
    far = { count, shift: Number(shift) };
  }
  positive(step, 'position.step');
  // Bounds of 10.1: the grid's far corner lo + (2^bits - 1) step, computed as grid points are.
  const bound = contraction ? MAX_CONTRACTED : MAX_COORDINATE;
  within(lo, 'position.lo', bound);
  const corner = lo.map((l, a) => l + (2 ** bits - 1) * step[a]);
  if (!corner.every((t) => Math.abs(t) <= bound)) {
    throw new CodecError(
      `attribute codec header's position grid reaches ${show(corner)} (lo + (2^bits - 1) step), beyond ` +
        `+-${contraction ? bound : '2^64'} (spec 10.1)`,
    );
  }
  // Resolution (10.1): on every axis the grid spans at least 2^-24 of its corners (and, contracted, R times
  // its span at least 2^-24 of the centre), or binary32 would hold every Gaussian on one coordinate there.
  for (let a = 0; a < 3; a++) {
    const span = (2 ** bits - 1) * step[a];
    const far = Math.max(Math.abs(lo[a]), Math.abs(corner[a]));
    if (span < RESOLUTION * far) {
      throw new CodecError(
        `attribute codec header's position grid spans ${span} on axis ${a}, under 2^-24 of its corner ${far} (spec 10.1)`,
      );
    }
    if (contraction && contraction.radius * span < RESOLUTION * Math.abs(contraction.centre[a])) {
      throw new CodecError(
        `attribute codec header's position grid spans ${contraction.radius * span} on axis ${a} in world space, ` +
          `under 2^-24 of position.centre[${a}] = ${contraction.centre[a]} (spec 10.1)`,
      );
    }
  }
  return { version: v, bits, lo, step, contraction, far };
}

/** One class's five quantiser keys (spec 10.0) from `map`, `prefix` naming it ('' or 'classes[i].'). */
function readClass(map, k, prefix) {
  const opacity = bigint(map, 'opacity_levels', `${prefix}opacity_levels`);
  const rotation = bigint(map, 'rotation_levels', `${prefix}rotation_levels`);
  const scaleStep = float(map, 'scale_step', `${prefix}scale_step`);
  const dcStep = float(map, 'dc_step', `${prefix}dc_step`);
  const sh = get(map, 'sh_steps', `${prefix}sh_steps`);
  if (!Array.isArray(sh)) throw fail(`${prefix}sh_steps`, sh, 'an array of floats');
  if (sh.length !== k) throw new CodecError(`attribute codec header has ${sh.length} ${prefix}sh_steps (needs ${k})`);
  const shSteps = floats(map, 'sh_steps', `${prefix}sh_steps`, k);
  // Levels up to 2^48, as every integer of the codec (10.0): each enters binary64 exactly.
  const most = BigInt(MAX_CODEC_INT);
  if (!(opacity >= 1n && opacity <= most && rotation >= 1n && rotation <= most)) {
    throw new CodecError(`attribute codec header has impossible quantiser levels (${opacity}, ${rotation}); each is 1..2^48`);
  }
  const opacityLevels = Number(opacity);
  const rotationLevels = Number(rotation);
  // At most 2^64 (10.0): a decoded integer times its step stays a finite binary32.
  positive([scaleStep], `${prefix}scale_step`, MAX_STEP);
  positive([dcStep], `${prefix}dc_step`, MAX_STEP);
  positive(shSteps, `${prefix}sh_steps`, MAX_STEP);
  return { opacityLevels, scaleStep, rotationLevels, dcStep, shSteps };
}

/**
 * meta["attributes"] (spec 10.0) as {version, n, shDegree, numRest (K), grid, classes (class 0 first),
 * precision (versions 4 and 5), codebook (version 5: its entries E, else 0)}. CodecError naming the first
 * bad field.
 */
export function readAttributeSection(meta) {
  if (!(meta instanceof Map)) throw fail('section', meta, 'a map');
  const version = get(meta, 'version', 'version');
  if (typeof version !== 'bigint' || version < 1n || version > 5n) {
    throw new CodecError(`attribute codec version ${show(version)} is not supported (this decoder reads 1..5)`);
  }
  const v = Number(version);
  const n = int(meta, 'n', 'n', 1, MAX_GAUSSIANS);
  const shDegree = int(meta, 'sh_degree', 'sh_degree', 0, MAX_SH_DEGREE);
  const grid = readGrid(get(meta, 'position', 'position'), v);
  const numRest = (shDegree + 1) ** 2 - 1;
  const classes = [readClass(meta, numRest, '')];
  const precision = v >= PRECISION_VERSION;
  if (precision) {
    const maps = get(meta, 'classes', 'classes');
    if (!Array.isArray(maps)) throw fail('classes', maps, 'an array of maps');
    if (maps.length > MAX_CLASSES - 1) throw fail('classes', `${maps.length} maps`, `at most ${MAX_CLASSES - 1} maps`);
    maps.forEach((m, i) => {
      if (!(m instanceof Map)) throw fail(`classes[${i}]`, m, 'a map');
      classes.push(readClass(m, numRest, `classes[${i}].`));
    });
  }
  if (grid.far && !(grid.far.count >= 1n && grid.far.count <= BigInt(n - 1))) {
    throw new CodecError(`attribute codec header has an impossible far set (far_count ${grid.far.count} of ${n})`);
  }
  if (grid.far) grid.far.count = Number(grid.far.count);
  // 10.16: the SH rest by a codebook of E entries, 1 .. min(2^16, n); never at SH degree 0.
  let codebook = 0;
  if (v === CODEBOOK_VERSION) {
    if (shDegree === 0) throw new CodecError('attribute codec version 5 (an SH codebook) at SH degree 0');
    codebook = int(meta, 'codebook', 'codebook', 1, Math.min(MAX_CODEBOOK, n));
  }
  return { version: v, n, shDegree, numRest, grid, classes, precision, codebook };
}
