// Which way is up (spec 10.8, `scene.coordinates`): a file states the axis convention of its arrays with
// three letters (x, y, z: R/L, U/D, B/F); one that states none is in OpenCV's RDF, as INRIA PLY files are.
// The viewer keeps the arrays as they are and turns its camera instead: the camera's up is the file's up
// axis. A left-handed convention is a mirror image in any renderer's right-handed world, so its scenes are
// mirrored back through x first (positions, rotations and the SH coefficients odd in x).

export const DEFAULT_CONVENTION = 'RDF';
// Each letter's direction in RUB (three.js's x right, y up, z back): [axis, sign].
const DIRECTIONS = { R: [0, 1], L: [0, -1], U: [1, 1], D: [1, -1], B: [2, 1], F: [2, -1] };
// SH rest coefficients (INRIA order, bands 1-3) whose basis function is odd in x: y z x | xy yz z2 xz x2-y2 |
// y(3x2-y2) xyz y(4z2-x2-y2) z(2z2-3x2-3y2) x(4z2-x2-y2) z(x2-y2) x(x2-3y2).
const ODD_IN_X = [2, 3, 6, 9, 12, 14];

/** The convention a file's head names (`coordinates`, null when it states none). */
export const conventionOf = (coordinates) => coordinates ?? DEFAULT_CONVENTION;

/** For each of the convention's axes x, y, z: [RUB axis, sign]. */
function directions(name) {
  return [...name].map((letter) => DIRECTIONS[letter]);
}

/** Whether the convention's axes are right-handed (as a renderer's world is). */
export function isRightHanded(name) {
  const m = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
  directions(name).forEach(([axis, sign], i) => {
    m[axis][i] = sign;
  });
  const det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  return det > 0;
}

/** The convention once its x axis is mirrored (R <-> L): right-handed where `name` is left-handed. */
export const mirroredX = (name) => (name[0] === 'R' ? 'L' : 'R') + name.slice(1);

/** A unit vector, in the convention's own coordinates, along RUB axis `axis` (0 right, 1 up, 2 back). */
function along(name, axis) {
  const v = [0, 0, 0];
  directions(name).forEach(([a, sign], i) => {
    if (a === axis) v[i] = sign;
  });
  return v;
}

/** The up direction and the back direction (towards a viewer in front of the scene), in file coordinates. */
export const upOf = (name) => along(name, 1);
export const backOf = (name) => along(name, 2);

/** A decoded tile's arrays mirrored through x in place: positions, rotations (w, x, -y, -z) and SH rest. */
export function mirrorTileX(tile) {
  const { count, means, quats, shRest } = tile;
  const numRest = (tile.shDegree + 1) ** 2 - 1;
  for (let i = 0; i < count; i++) {
    means[3 * i] = -means[3 * i];
    quats[4 * i + 2] = -quats[4 * i + 2];
    quats[4 * i + 3] = -quats[4 * i + 3];
    for (const j of ODD_IN_X) {
      if (j >= numRest) break;
      for (let c = 0; c < 3; c++) shRest[3 * (numRest * i + j) + c] = -shRest[3 * (numRest * i + j) + c];
    }
  }
}

/** `box` (low x, y, z, high x, y, z) mirrored through x. */
export const mirrorBoxX = (box) => [-box[3], box[1], box[2], -box[0], box[4], box[5]];

/**
 * The centre and radius to frame boxes weighted by their Gaussians: per axis the weighted 10th percentile
 * of the low sides and 90th of the high ones, so that a few far tiles (a capture's background) do not shrink
 * the scene to a dot.
 */
export function frameOf(boxes, counts) {
  const total = counts.reduce((a, b) => a + b, 0) || 1;
  const quantile = (values, q) => {
    const order = values.map((v, i) => [v, counts[i]]).sort((a, b) => a[0] - b[0]);
    let seen = 0;
    for (const [v, w] of order) {
      seen += w;
      if (seen >= q * total) return v;
    }
    return order[order.length - 1][0];
  };
  const lo = [0, 1, 2].map((a) => quantile(boxes.map((b) => b[a]), 0.1));
  const hi = [0, 1, 2].map((a) => quantile(boxes.map((b) => b[a + 3]), 0.9));
  const centre = lo.map((l, a) => (l + hi[a]) / 2);
  const radius = Math.max(1e-6, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
  return { centre, radius };
}

/** A first view of a framed scene: from its back side and a little above, the whole frame in sight. */
export function initialView(name, { centre, radius }, fovDegrees) {
  const up = upOf(name);
  const back = backOf(name);
  const dir = back.map((b, i) => b + 0.4 * up[i]);
  const length = Math.hypot(...dir);
  const distance = radius / Math.sin(((fovDegrees / 2) * Math.PI) / 180);
  const position = centre.map((c, i) => c + (dir[i] / length) * distance);
  return { position, target: centre, up };
}
