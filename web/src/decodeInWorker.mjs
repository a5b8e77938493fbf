// The page's side of worker.mjs: decode a .gspc file at a URL in a Web Worker, tile by tile, with callbacks
// as the head, each tile and the bytes arrive. Every way the decode can end badly (the file, the download,
// the worker failing to load) rejects the promise with one Error whose message is one line.

/** A failure reported by the decoder's worker: `name` is the decoder's error class (FormatError's, ...). */
export class DecodeFailure extends Error {
  constructor(name, message) {
    super(message);
    this.name = name;
  }
}

/**
 * Decode the .gspc file at `url` in a worker. `options`: onHead(head), onTile(tile), onProgress(received,
 * size), mode ('stream' or 'range'), region (null or 6 numbers), workerUrl (default: worker.mjs beside this
 * module). Resolves with {whole} (whether every part of the file was checked) once the last tile is posted.
 */
export function decodeInWorker(url, options = {}) {
  const { onHead = () => {}, onTile = () => {}, onProgress = () => {}, mode = 'stream', region = null } = options;
  const workerUrl = options.workerUrl ?? new URL('./worker.mjs', import.meta.url);
  return new Promise((resolve, reject) => {
    const worker = new Worker(workerUrl, { type: 'module' });
    const finish = (fn, value) => {
      worker.terminate();
      fn(value);
    };
    worker.onmessage = ({ data }) => {
      try {
        if (data.type === 'progress') onProgress(data.received, data.size);
        else if (data.type === 'head') onHead(data);
        else if (data.type === 'tile') onTile(data.tile);
        else if (data.type === 'done') finish(resolve, { whole: data.whole });
        else if (data.type === 'error') finish(reject, new DecodeFailure(data.name, data.message));
      } catch (err) {
        finish(reject, err);
      }
    };
    worker.onerror = (event) => {
      event.preventDefault();
      const why = event.message || 'its script could not be loaded (is web/node_modules installed?)';
      finish(reject, new DecodeFailure('WorkerError', `the decoder's worker failed: ${why}`));
    };
    worker.onmessageerror = () => finish(reject, new DecodeFailure('WorkerError', "a message from the decoder's worker could not be read"));
    worker.postMessage({ type: 'decode', url: new URL(url, globalThis.location?.href).href, mode, region });
  });
}
