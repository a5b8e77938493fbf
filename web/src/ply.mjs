// INRIA 3DGS PLY (spec 10.8, "Output"): binary little-endian, one `vertex` element of binary32 properties
// x y z, nx ny nz (zero), f_dc_0..2, f_rest_0..3K-1 (channel-major: red's K coefficients, then green's,
// then blue's), opacity, scale_0..2, rot_0..3 (w, x, y, z). The header text is byte for byte what gspc's
// Python decoder writes (plyfile, no comments), so both decoders' files compare equal.

/** The PLY header for `count` Gaussians with `numRest` (K) SH rest coefficients per channel. */
export function plyHeader(count, numRest) {
  const names = ['x', 'y', 'z', 'nx', 'ny', 'nz', 'f_dc_0', 'f_dc_1', 'f_dc_2'];
  for (let i = 0; i < 3 * numRest; i++) names.push(`f_rest_${i}`);
  names.push('opacity', 'scale_0', 'scale_1', 'scale_2', 'rot_0', 'rot_1', 'rot_2', 'rot_3');
  const lines = ['ply', 'format binary_little_endian 1.0', `element vertex ${count}`];
  for (const name of names) lines.push(`property float ${name}`);
  lines.push('end_header', '');
  return new TextEncoder().encode(lines.join('\n'));
}

/** Floats per vertex: 17 plus 3K. */
export const plyFloatsPerVertex = (numRest) => 17 + 3 * numRest;

/**
 * The PLY file of a decoded scene ({count, shDegree, means, quats, logScales, opacities, shDc, shRest}) as
 * a sequence of Uint8Array parts (the header, then rows in batches of `batch`), so that a large scene is
 * written without one buffer of its whole size.
 */
export function* plyParts(scene, batch = 65536) {
  yield plyHeader(scene.count, (scene.shDegree + 1) ** 2 - 1);
  yield* plyRows(scene, batch);
}

/** The rows of a decoded scene's PLY without the header, in batches of `batch` rows: tiles one after another. */
export function* plyRows(scene, batch = 65536) {
  const { count, means, quats, logScales, opacities, shDc, shRest } = scene;
  const k = (scene.shDegree + 1) ** 2 - 1;
  const stride = plyFloatsPerVertex(k);
  for (let start = 0; start < count; start += batch) {
    const rows = Math.min(batch, count - start);
    const buffer = new ArrayBuffer(4 * stride * rows);
    const view = new DataView(buffer);
    const put = (row, column, value) => view.setFloat32(4 * (stride * row + column), value, true);
    for (let r = 0; r < rows; r++) {
      const g = start + r;
      for (let a = 0; a < 3; a++) put(r, a, means[3 * g + a]);
      // nx ny nz stay zero
      for (let c = 0; c < 3; c++) put(r, 6 + c, shDc[3 * g + c]);
      // shRest is coefficient-major (K x 3 per Gaussian); the PLY is channel-major.
      for (let c = 0; c < 3; c++) {
        for (let j = 0; j < k; j++) put(r, 9 + c * k + j, shRest[3 * k * g + 3 * j + c]);
      }
      const tail = 9 + 3 * k;
      put(r, tail, opacities[g]);
      for (let a = 0; a < 3; a++) put(r, tail + 1 + a, logScales[3 * g + a]);
      for (let a = 0; a < 4; a++) put(r, tail + 4 + a, quats[4 * g + a]);
    }
    yield new Uint8Array(buffer);
  }
}

/** The whole PLY file of a decoded scene as one Uint8Array. */
export function writePly(scene) {
  const parts = [...plyParts(scene)];
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let at = 0;
  for (const p of parts) {
    out.set(p, at);
    at += p.length;
  }
  return out;
}
