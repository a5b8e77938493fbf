// The attribute section (spec 10.0-10.6, 10.10, 10.13): which chunks a scene needs, the Gaussian count's
// bound, and the decoding of each attribute chunk into binary32 arrays in curve order.
//
// `decodeAttributes(section, payloads)` is a function of the section's parameters and the chunks' payloads
// only, so a reader can run it on any set of chunks that form one attribute section.

import { CodecError } from './errors.mjs';
import { decodeEcm, readBinArray, readEcm } from './ecm.mjs';
import { largestComponent, opacityDecoder, rotationComponent, rotationStep } from './dequantise.mjs';
import { maxCodedGaussians, maxModelEntries } from './limits.mjs';
import { TableBudget } from './models.mjs';
import { decodePositions } from './positions.mjs';
import { decodePrecision, rowsByClass } from './precision.mjs';

/** Chunk types of the attribute section (spec 6). */
export const ATTRIBUTE_TYPES = ['POSN', 'PREC', 'OPAC', 'SCAL', 'ROTN', 'SHDC', 'SHRS'];

/** The attribute payloads of a container's chunks by type; each must have index 0 (spec 10.10). */
export function attributePayloads(chunks) {
  const out = {};
  for (const ch of chunks) {
    if (!ATTRIBUTE_TYPES.includes(ch.type)) continue;
    if (ch.index !== 0) throw new CodecError(`chunk ${ch.type} has index ${ch.index}; attribute chunks have index 0`);
    out[ch.type] = ch.payload;
  }
  return out;
}

/**
 * What can be checked of the payloads before decoding (spec 10.10): the chunks the section needs are
 * present and no other, and the Gaussian count is within what their bytes may declare.
 */
export function checkAttributeChunks(section, payloads) {
  const { n, shDegree, precision, version } = section;
  if (shDegree === 0 && payloads.SHRS) throw new CodecError('chunk SHRS in a file of SH degree 0');
  if (!precision && payloads.PREC) throw new CodecError(`chunk PREC in a file of attribute codec version ${version}`);
  for (const t of ATTRIBUTE_TYPES) {
    const needed = (t !== 'SHRS' || shDegree > 0) && (t !== 'PREC' || precision);
    if (needed && !payloads[t]) throw new CodecError(`chunk ${t} is missing`);
  }
  let bytes = 0;
  for (const t of ATTRIBUTE_TYPES) if (payloads[t]) bytes += payloads[t].length;
  const most = maxCodedGaussians(bytes);
  if (n > most) throw new CodecError(`${n} Gaussians from ${bytes} payload bytes (at most ${most}, spec 10.10)`);
}

/**
 * The matrices of chunk `type` with `columns` columns: one of `n` rows below version 4; at version 4 one per
 * class (a msgpack array of C bins), class k's of classRows[k].length rows, all counted against the
 * chunk's table bound before any table is built.
 */
function readParts(type, payload, section, columns, classRows, tile) {
  if (!section.precision) return [readEcm(payload, section.n, columns, type, null, tile)];
  const bins = readBinArray(payload, classRows.length, type);
  const budget = new TableBudget(maxModelEntries(payload.length), `${type}'s matrices together`);
  return bins.map((bin, k) => readEcm(bin, classRows[k].length, columns, `${type} class ${k}`, budget, tile));
}

/** Decode every part of a chunk, calling `visit(k, rows, j, q)` per class k and column j. */
function decodeParts(type, parts, classRows, visit) {
  parts.forEach((ecm, k) => decodeEcm(ecm, (j, q) => visit(k, classRows[k], j, q), parts.length > 1 ? `${type} class ${k}` : type));
}

function decodeOpacities(payload, section, classRows, tile) {
  const out = new Float32Array(section.n);
  const parts = readParts('OPAC', payload, section, 1, classRows, tile);
  decodeParts('OPAC', parts, classRows, (k, rows, _, q) => {
    const logit = opacityDecoder(section.classes[k].opacityLevels);
    const count = parts[k].rows;
    for (let i = 0; i < count; i++) out[rows[i]] = logit(q[i]);
  });
  return out;
}

/** SCAL and SHDC: `n` x 3 values q x step, step the class's `stepOf(class)`. */
function decodeScaled(type, payload, section, classRows, tile, stepOf) {
  const out = new Float32Array(3 * section.n);
  const parts = readParts(type, payload, section, 3, classRows, tile);
  decodeParts(type, parts, classRows, (k, rows, j, q) => {
    const step = stepOf(section.classes[k]);
    const count = parts[k].rows;
    for (let i = 0; i < count; i++) out[3 * rows[i] + j] = q[i] * step;
  });
  return out;
}

function decodeRotations(payload, section, classRows, tile) {
  const out = new Float32Array(4 * section.n);
  const parts = readParts('ROTN', payload, section, 4, classRows, tile);
  parts.forEach((ecm, k) => {
    const count = ecm.rows;
    const levels = section.classes[k].rotationLevels;
    const step = rotationStep(levels);
    const largest = new Uint8Array(count);
    const others = new Float64Array(3 * count);
    const what = parts.length > 1 ? `ROTN class ${k}` : 'ROTN';
    decodeEcm(
      ecm,
      (j, q) => {
        for (let i = 0; i < count; i++) {
          const v = q[i];
          if (j === 0) {
            if (!(v >= 0 && v <= 3)) throw new CodecError(`${what} row ${i}: largest-component index ${v} is outside 0..3`);
            largest[i] = v;
          } else {
            if (!(v >= 0 && v <= levels)) throw new CodecError(`${what} row ${i}: rotation level ${v} is outside 0..${levels}`);
            others[3 * i + j - 1] = rotationComponent(v, step);
          }
        }
      },
      what,
    );
    const rows = classRows[k];
    for (let i = 0; i < count; i++) {
      const r1 = others[3 * i];
      const r2 = others[3 * i + 1];
      const r3 = others[3 * i + 2];
      const big = largest[i];
      const base = 4 * rows[i];
      // The three stored components fill the other indices in increasing order.
      let c = 0;
      for (let a = 0; a < 4; a++) {
        if (a === big) out[base + a] = largestComponent(r1, r2, r3);
        else out[base + a] = others[3 * i + c++];
      }
    }
  });
  return out;
}

/** SHRS below version 4 (spec 10.6): flags, then the flagged Gaussians' coefficients. */
function decodeRestFlagged(payload, section, tile, out) {
  const { n, numRest } = section;
  const [flagsBin, valuesBin] = readBinArray(payload, 2, 'SHRS');
  const flagsEcm = readEcm(flagsBin, n, 1, 'SHRS flags', null, tile);
  let flagged = null;
  decodeEcm(
    flagsEcm,
    (_, q) => {
      let count = 0;
      for (let i = 0; i < n; i++) {
        if (q[i] !== 0 && q[i] !== 1) throw new CodecError(`SHRS flag ${q[i]} of row ${i} is not 0 or 1`);
        count += q[i];
      }
      flagged = new Int32Array(count);
      let at = 0;
      for (let i = 0; i < n; i++) if (q[i] === 1) flagged[at++] = i;
    },
    'SHRS flags',
  );
  const columns = 3 * numRest;
  const steps = section.classes[0].shSteps;
  const ecm = readEcm(valuesBin, flagged.length, columns, 'SHRS values', null, tile);
  decodeEcm(
    ecm,
    (j, q) => {
      const step = steps[Math.floor(j / 3)];
      for (let i = 0; i < flagged.length; i++) out[columns * flagged[i] + j] = q[i] * step;
    },
    'SHRS values',
  );
}

/** SHRS at version 4 (spec 10.13): per class and band, the rows of that class of at least that degree. */
function decodeRestBanded(payload, section, precision, tile, out) {
  const { numRest, shDegree } = section;
  const numClasses = section.classes.length;
  const bins = readBinArray(payload, numClasses * shDegree, 'SHRS');
  const budget = new TableBudget(maxModelEntries(payload.length), "SHRS's matrices together");
  const parts = [];
  const bands = Array.from({ length: shDegree }, (_, b) => rowsByClass(precision, numClasses, b + 1));
  for (let k = 0; k < numClasses; k++) {
    for (let b = 1; b <= shDegree; b++) {
      const rows = bands[b - 1][k];
      const what = `SHRS class ${k} band ${b}`;
      parts.push({ k, b, rows, what, ecm: readEcm(bins[k * shDegree + b - 1], rows.length, 3 * (2 * b + 1), what, budget, tile) });
    }
  }
  const columns = 3 * numRest;
  for (const { k, b, rows, what, ecm } of parts) {
    const first = b * b - 1; // the band's first coefficient
    const steps = section.classes[k].shSteps;
    decodeEcm(
      ecm,
      (j, q) => {
        const coefficient = first + Math.floor(j / 3);
        const step = steps[coefficient];
        const column = 3 * first + j;
        for (let i = 0; i < rows.length; i++) out[columns * rows[i] + column] = q[i] * step;
      },
      what,
    );
  }
}

/**
 * SHRS at version 5 (spec 10.16): E entries at class 0's steps, then one entry per Gaussian of degree >= 1
 * in decoded order; a Gaussian of degree d takes its entry's bands 1..d.
 */
function decodeRestByCodebook(payload, section, precision, tile, out) {
  const { n, numRest, codebook } = section;
  const [entriesBin, indexBin] = readBinArray(payload, 2, 'SHRS');
  const budget = new TableBudget(maxModelEntries(payload.length), "SHRS's matrices together");
  const columns = 3 * numRest;
  const entriesEcm = readEcm(entriesBin, codebook, columns, 'SHRS entries', budget, tile);
  let coded = 0;
  for (let i = 0; i < n; i++) if (precision.degreeOf[i] >= 1) coded++;
  const indexEcm = readEcm(indexBin, coded, 1, 'SHRS indices', budget, tile);
  const steps = section.classes[0].shSteps;
  const entries = new Float32Array(codebook * columns);
  decodeEcm(
    entriesEcm,
    (j, q) => {
      const step = steps[Math.floor(j / 3)];
      for (let e = 0; e < codebook; e++) entries[columns * e + j] = q[e] * step;
    },
    'SHRS entries',
  );
  decodeEcm(
    indexEcm,
    (_, q) => {
      let r = 0;
      for (let i = 0; i < n; i++) {
        const d = precision.degreeOf[i];
        if (d === 0) continue;
        const e = q[r++];
        if (!(e >= 0 && e < codebook)) throw new CodecError(`SHRS codebook index ${e} is outside 0..${codebook - 1}`);
        const width = 3 * ((d + 1) * (d + 1) - 1); // bands 1..d
        out.set(entries.subarray(columns * e, columns * e + width), columns * i);
      }
    },
    'SHRS indices',
  );
}

/**
 * Decode an attribute section: `section` from readAttributeSection, `payloads` the attribute chunks'
 * payloads by type, `tile` null or the TileBudget of a tile of a tiled file (spec 10.14). Returns {count,
 * shDegree, means (n x 3), quats (n x 4: w, x, y, z), logScales (n x 3), opacities (n, logits), shDc
 * (n x 3), shRest (n x K x 3)}, binary32 arrays in curve order.
 */
export function decodeAttributes(section, payloads, tile = null) {
  checkAttributeChunks(section, payloads);
  const { n, shDegree, numRest } = section;
  const precision = section.precision
    ? decodePrecision(payloads.PREC, n, section.classes.length, shDegree, tile)
    : null;
  // Below version 4 every row is in class 0.
  const classRows = precision ? rowsByClass(precision, section.classes.length) : [Int32Array.from({ length: n }, (_, i) => i)];
  const means = decodePositions(payloads.POSN, section.grid, n, tile);
  const opacities = decodeOpacities(payloads.OPAC, section, classRows, tile);
  const logScales = decodeScaled('SCAL', payloads.SCAL, section, classRows, tile, (c) => c.scaleStep);
  const quats = decodeRotations(payloads.ROTN, section, classRows, tile);
  const shDc = decodeScaled('SHDC', payloads.SHDC, section, classRows, tile, (c) => c.dcStep);
  const shRest = new Float32Array(n * numRest * 3);
  if (shDegree > 0) {
    if (section.codebook) decodeRestByCodebook(payloads.SHRS, section, precision, tile, shRest);
    else if (precision) decodeRestBanded(payloads.SHRS, section, precision, tile, shRest);
    else decodeRestFlagged(payloads.SHRS, section, tile, shRest);
  }
  return { count: n, shDegree, means, quats, logScales, opacities, shDc, shRest };
}
