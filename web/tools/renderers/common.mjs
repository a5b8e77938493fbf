// What the renderer pages of compare-renderers.mjs share: reading an INRIA PLY into columns, the OpenCV
// camera's three.js-style matrices, and timing frames.

/** The vertex columns of a binary little-endian PLY of float properties: {count, columns: {name: Float32Array}}. */
export function readPly(bytes) {
  const text = new TextDecoder().decode(bytes.subarray(0, Math.min(bytes.length, 65536)));
  const end = text.indexOf('end_header\n') + 'end_header\n'.length;
  const lines = text.slice(0, end).split('\n');
  const count = Number(lines.find((l) => l.startsWith('element vertex')).split(' ')[2]);
  const names = lines.filter((l) => l.startsWith('property')).map((l) => l.split(' ')[2]);
  const rows = new Float32Array(bytes.buffer.slice(bytes.byteOffset + end, bytes.byteOffset + end + 4 * count * names.length));
  const columns = {};
  names.forEach((name, j) => {
    const column = new Float32Array(count);
    for (let i = 0; i < count; i++) column[i] = rows[i * names.length + j];
    columns[name] = column;
  });
  return { count, columns };
}

/**
 * For an OpenCV camera (world-to-camera `w2c`, 16 numbers row-major; pinhole fx, fy, cx, cy; w x h pixels):
 * the camera-to-world matrix of a camera looking down -z with y up, and the pinhole's projection matrix,
 * both row-major, with clip planes near and far.
 */
export function glCamera(w2c, fx, fy, cx, cy, w, h, near, far) {
  const r = [0, 1, 2].map((i) => w2c.slice(4 * i, 4 * i + 3));
  const t = [w2c[3], w2c[7], w2c[11]];
  // c2w = [R^T | -R^T t], then y and z turned: columns 1 and 2 negated.
  const rt = [0, 1, 2].map((i) => [0, 1, 2].map((j) => r[j][i]));
  const c = rt.map((row) => -(row[0] * t[0] + row[1] * t[1] + row[2] * t[2]));
  const c2w = [rt[0][0], -rt[0][1], -rt[0][2], c[0], rt[1][0], -rt[1][1], -rt[1][2], c[1], rt[2][0], -rt[2][1], -rt[2][2], c[2], 0, 0, 0, 1];
  const n = near;
  const f = far;
  const projection = [(2 * fx) / w, 0, 1 - (2 * cx) / w, 0, 0, (2 * fy) / h, (2 * cy) / h - 1, 0, 0, 0, -(f + n) / (f - n), (-2 * f * n) / (f - n), 0, 0, -1, 0];
  return { c2w, projection };
}

/** Mean ms per frame over `n` animation frames, `step()` moving the camera a little before each. */
export async function frameTime(n, step, gl) {
  const pixel = new Uint8Array(4);
  const t0 = performance.now();
  for (let i = 0; i < n; i++) {
    step();
    await new Promise((r) => requestAnimationFrame(r));
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel); // waits for the frame's drawing
  }
  return (performance.now() - t0) / n;
}
