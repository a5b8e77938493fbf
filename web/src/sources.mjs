// Byte sources for reading a .gspc file in parts (spec 10.14, "Reading part of a file"): each is {size,
// read(offset, length)}, `read` resolving to exactly `length` bytes at `offset` (a Uint8Array that the
// caller must not change) and rejecting with SourceEnded where the bytes stop short of them. `size` is the
// file's size as the source states it (HTTP's Content-Length or Content-Range); the reader checks the layout
// its header declares against it (spec 8, check 8) before it reads on.

/** The bytes could not be fetched (a network failure, an HTTP status other than success). */
export class SourceError extends Error {
  constructor(message) {
    super(message);
    this.name = 'SourceError';
  }
}

/** The source ends at offset `end`, before bytes a read asked for; `reason` says why, where known. */
export class SourceEnded extends Error {
  constructor(end, reason = null) {
    super(`the bytes end at offset ${end}${reason ? ` (${reason})` : ''}`);
    this.name = 'SourceEnded';
    this.end = end;
    this.reason = reason;
  }
}

/** A source over bytes in memory (Uint8Array or ArrayBuffer). */
export function bytesSource(bytes) {
  const data = bytes instanceof ArrayBuffer ? new Uint8Array(bytes) : bytes;
  return {
    size: data.length,
    async read(offset, length) {
      if (offset + length > data.length) throw new SourceEnded(data.length);
      return data.subarray(offset, offset + length);
    },
  };
}

function sizeFrom(value, what) {
  if (value === null || !/^\d{1,15}$/.test(value.trim())) return null;
  const size = Number(value.trim());
  if (!Number.isSafeInteger(size)) throw new SourceError(`${what} ${value} is not a file size`);
  return size;
}

async function fetchOk(fetchFn, url, init, what) {
  let response;
  try {
    response = await fetchFn(url, init);
  } catch (err) {
    throw new SourceError(`cannot fetch ${url}${what}: ${err && err.message ? err.message : err}`);
  }
  if (!response.ok) throw new SourceError(`cannot fetch ${url}${what}: HTTP ${response.status} ${response.statusText}`.trim());
  return response;
}

/**
 * Bytes that arrive in order (a response body): reads wait for them. Memory grows with the bytes that have
 * arrived (doubling, never past `size`), not with the size a server announces.
 */
class GrowingBytes {
  constructor(size, onProgress) {
    this.size = size;
    this.buffer = new Uint8Array(Math.min(size ?? 65536, 65536));
    this.received = 0;
    this.ended = false;
    this.reason = null;
    this.waiters = [];
    this.onProgress = onProgress;
  }

  append(chunk) {
    const room = this.size === null ? chunk.length : Math.min(chunk.length, this.size - this.received);
    if (room <= 0) return;
    const need = this.received + room;
    if (need > this.buffer.length) {
      let capacity = Math.max(this.buffer.length * 2, need);
      if (this.size !== null) capacity = Math.min(capacity, this.size);
      const grown = new Uint8Array(capacity);
      grown.set(this.buffer.subarray(0, this.received));
      this.buffer = grown;
    }
    this.buffer.set(chunk.subarray(0, room), this.received);
    this.received = need;
    if (this.onProgress) this.onProgress(this.received, this.size);
    this.wake();
  }

  finish(reason = null) {
    this.ended = true;
    this.reason = reason;
    this.wake();
  }

  wake() {
    const waiting = this.waiters;
    this.waiters = [];
    for (const w of waiting) this.settle(w);
  }

  settle(w) {
    if (this.received >= w.end) w.resolve(this.buffer.subarray(w.offset, w.end));
    else if (this.ended) w.reject(new SourceEnded(this.received, this.reason));
    else this.waiters.push(w);
  }

  read(offset, length) {
    return new Promise((resolve, reject) => this.settle({ offset, end: offset + length, resolve, reject }));
  }
}

async function pump(body, bytes) {
  const reader = body.getReader();
  try {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      bytes.append(value);
      if (bytes.size !== null && bytes.received >= bytes.size) {
        reader.cancel().catch(() => {});
        break;
      }
    }
    bytes.finish();
  } catch (err) {
    bytes.finish(`the download stopped: ${err && err.message ? err.message : err}`);
  }
}

/** A source over a response whose body arrives as a stream. */
async function bodySource(response, onProgress) {
  // A compressed transfer's Content-Length counts the compressed bytes, not the file's.
  const encoded = (response.headers.get('content-encoding') ?? 'identity') !== 'identity';
  const size = encoded ? null : sizeFrom(response.headers.get('content-length'), 'Content-Length');
  const bytes = new GrowingBytes(size, onProgress);
  const pumping = pump(response.body, bytes);
  if (size === null) {
    // Without a stated size, the file is all the body holds: the reader starts once it has arrived.
    await pumping;
    if (bytes.reason) throw new SourceError(`cannot fetch the file: ${bytes.reason}`);
    bytes.size = bytes.received;
  }
  return { size: bytes.size, read: (offset, length) => bytes.read(offset, length) };
}

/**
 * A source over one GET of `url` whose body is read as it arrives: a reader decodes the first tiles while
 * the last are on their way. `options`: fetch (default globalThis.fetch), onProgress(received, size).
 */
export async function fetchStreamSource(url, { fetch: fetchFn = globalThis.fetch, onProgress = null } = {}) {
  const response = await fetchOk(fetchFn, url, {}, '');
  return bodySource(response, onProgress);
}

/**
 * A source over HTTP range requests to `url`: only the bytes a reader asks for are fetched (a region's
 * tiles). A server that ignores ranges (status 200) is read as one stream instead. `options`: as
 * fetchStreamSource, and `first` (bytes of the first request, which also learns the size).
 */
export async function fetchRangeSource(url, { fetch: fetchFn = globalThis.fetch, onProgress = null, first = 65536 } = {}) {
  const head = await fetchOk(fetchFn, url, { headers: { Range: `bytes=0-${first - 1}` } }, '');
  if (head.status !== 206) return bodySource(head, onProgress);
  const range = /^bytes (\d+)-(\d+)\/(\d+)$/.exec((head.headers.get('content-range') ?? '').trim());
  if (!range || Number(range[1]) !== 0) throw new SourceError(`${url} answered a range request without a usable Content-Range`);
  const size = sizeFrom(range[3], 'Content-Range size');
  const start = new Uint8Array(await head.arrayBuffer());
  let fetched = start.length;
  if (onProgress) onProgress(fetched, size);
  return {
    size,
    async read(offset, length) {
      if (offset + length > size) throw new SourceEnded(size);
      if (offset + length <= start.length) return start.subarray(offset, offset + length);
      if (length === 0) return new Uint8Array(0);
      const what = ` (bytes ${offset}-${offset + length - 1})`;
      const response = await fetchOk(fetchFn, url, { headers: { Range: `bytes=${offset}-${offset + length - 1}` } }, what);
      const bytes = new Uint8Array(await response.arrayBuffer());
      const whole = response.status === 200 && bytes.length === size;
      const part = whole ? bytes.subarray(offset, offset + length) : bytes;
      if (part.length !== length) {
        if (response.status === 206 && part.length < length) throw new SourceEnded(offset + part.length);
        throw new SourceError(`${url} answered${what} with ${bytes.length} bytes`);
      }
      fetched += length;
      if (onProgress) onProgress(Math.min(fetched, size), size);
      return part;
    },
  };
}
