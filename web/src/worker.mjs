// A Web Worker (module) that fetches a .gspc file and decodes it tile by tile as its bytes arrive, posting
// each tile's arrays to the page (transferred, not copied), so that the page stays responsive and draws
// the first tiles while the last are on their way. The page side is decodeInWorker.mjs.
//
// In: {type: 'decode', url, mode: 'stream' (one GET, read as it arrives) or 'range' (HTTP range requests),
// region: null or [6 numbers]}. Out, in this order: 'progress' (bytes received) any time, 'head' once,
// 'tile' per tile, then 'done' or, at the first problem, 'error' {name, message} and nothing more. A tile's
// side views (`views`, spec 10.15) come with their cameras and residual records but not the residual images'
// bytes, which the page does not use: each is a view into the bytes read, which a message would copy whole.

import { GspcError } from './errors.mjs';
import { SourceError, fetchRangeSource, fetchStreamSource } from './sources.mjs';
import { openGspc } from './stream.mjs';

// Progress messages at most this often: a fast download would otherwise post one per network chunk.
const PROGRESS_INTERVAL_MS = 100;

function progressPoster() {
  let last = 0;
  return (received, size) => {
    const now = Date.now();
    if (now - last < PROGRESS_INTERVAL_MS && received !== size) return;
    last = now;
    postMessage({ type: 'progress', received, size });
  };
}

function headMessage(reader) {
  const scene = reader.header.scene ?? {};
  return {
    type: 'head',
    version: reader.version,
    size: reader.size,
    tiled: reader.index !== null,
    count: reader.count,
    shDegree: reader.shDegree,
    tiles: reader.tiles,
    coordinates: scene.coordinates ?? null,
    background: reader.header.sideInfo.background,
  };
}

/** The message for an error: a file's or a download's problem as it is, anything else as an internal one. */
export function errorMessage(err) {
  if (err instanceof GspcError || err instanceof SourceError) return { type: 'error', name: err.name, message: err.message };
  const text = err && err.message ? err.message : String(err);
  return { type: 'error', name: 'InternalError', message: `internal error: ${text}` };
}

/** A side view without its residual image's bytes (its record kept). */
function withoutImage({ camera, residual }) {
  if (!residual) return { camera, residual };
  const { image, ...record } = residual;
  return { camera, residual: record };
}

async function run({ url, mode = 'stream', region = null }) {
  const onProgress = progressPoster();
  const source = mode === 'range' ? await fetchRangeSource(url, { onProgress }) : await fetchStreamSource(url, { onProgress });
  const reader = await openGspc(source);
  postMessage(headMessage(reader));
  for await (const tile of reader.decode({ region })) {
    const buffers = ['means', 'quats', 'logScales', 'opacities', 'shDc', 'shRest'].map((k) => tile[k].buffer);
    postMessage({ type: 'tile', tile: { ...tile, views: tile.views.map(withoutImage) } }, buffers);
  }
  postMessage({ type: 'done', whole: region === null });
}

self.onmessage = ({ data }) => {
  if (!data || data.type !== 'decode') return;
  run(data).catch((err) => postMessage(errorMessage(err)));
};
