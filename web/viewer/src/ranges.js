// Fetching an .spc layer by layer with HTTP range requests.
//
// The header block tells every byte range of the file (spec section 3): the fixed header's
// `header_size` (u32 at offset 16) says how long the header block is, and the layer table says
// where each layer ends. So the loader asks for the first bytes, completes the header block if
// needed, reads the layer ends with the decoder's `inspect`, then requests one range per layer,
// and stops after the last layer it was asked for. Every byte goes through the streaming decoder,
// which checks it. A gzip-wrapped file is fetched the same way when its wrapper records where each
// layer ends ([R-83]; `inspect` reports those offsets), else read as one stream, as is a file from
// a server that ignores ranges (200 instead of 206).
//
// Nothing here touches the DOM or the renderer: it runs under node with a fake fetch in the tests.

/** Bytes asked for first: the header block of files with up to about 90 sections (a longer one
 * takes a second request). Small, so that layer 0 arrives with a request of its own. */
export const FIRST_REQUEST_BYTES = 4096;
const FIXED_HEADER_BYTES = 48;
const GZIP_MAGIC = [0x1f, 0x8b];

/** A failure of the transfer itself (not of the file's bytes, which the decoder reports). */
export class TransferError extends Error {
  constructor(message) {
    super(message);
    this.name = 'TransferError';
  }
}

/**
 * Parse `Content-Range: bytes first-last/size`.
 * @param {string|null} header
 * @returns {{first: number, last: number, size: number}|null}
 */
export function parseContentRange(header) {
  const match = /^\s*bytes\s+(\d+)-(\d+)\/(\d+)\s*$/i.exec(header ?? '');
  if (!match) return null;
  return { first: Number(match[1]), last: Number(match[2]), size: Number(match[3]) };
}

/**
 * Stream an .spc from `url`, feeding every byte to `sink(chunk)` in file order.
 *
 * @param {string} url
 * @param {object} options
 * @param {(chunk: Uint8Array) => Promise<void>} options.sink  receives the bytes, in order
 * @param {(header: Uint8Array) => {layers: {index: number, endOffset: number|null}[]}} options.planLayers
 *   reads the layer ends from the first bytes, a complete header block (the decoder's `inspect`)
 * @param {number} [options.maxLayer]  last layer to fetch (default: all)
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(event: object) => void} [options.onRequest]  told of each request and its answer
 * @returns {Promise<{mode: 'ranges'|'stream', fileSize: number|null, bytes: number}>}
 */
export async function streamSpc(url, { sink, planLayers, maxLayer = Infinity, fetchImpl = fetch,
  onRequest = () => {} }) {
  const first = await request(fetchImpl, url, 0, FIRST_REQUEST_BYTES - 1, onRequest);
  if (first.status === 200) {
    return { mode: 'stream', fileSize: lengthOf(first), bytes: await pump(first, sink, Infinity) };
  }
  const { size } = first.range;
  let head = await readAll(first);
  const gzip = head.length >= 2 && head[0] === GZIP_MAGIC[0] && head[1] === GZIP_MAGIC[1];
  if (!gzip && head.length >= FIXED_HEADER_BYTES) {
    const headerSize = new DataView(head.buffer, head.byteOffset, head.byteLength).getUint32(16, true);
    if (headerSize > head.length && headerSize <= size) {  // an unusually long header block
      const more = await readAll(await request(fetchImpl, url, head.length, headerSize - 1, onRequest));
      head = concat(head, more);
    }
  }
  await sink(head);
  let offset = head.length;
  let layers = null;
  try {
    layers = planLayers(head).layers;
  } catch {
    // Too short for a header block, or not an .spc: the decoder says why as the rest arrives.
  }
  if (!layers || layers.some((layer) => layer.endOffset == null)) {
    // No layer ends (a gzip wrapper without recorded layer offsets, or bytes the decoder will
    // reject): read the rest as one stream.
    if (offset < size) {
      offset += await pump(await request(fetchImpl, url, offset, size - 1, onRequest), sink, Infinity);
    }
    return { mode: 'stream', fileSize: size, bytes: offset };
  }
  for (const layer of layers) {
    if (layer.index > maxLayer) break;
    if (layer.endOffset <= offset) continue;  // already received with the first request
    const response = await request(fetchImpl, url, offset, layer.endOffset - 1, onRequest);
    offset += await pump(response, sink, layer.endOffset - offset);
  }
  if (maxLayer >= layers.length - 1 && offset < size) {
    // bytes after the last layer: a gzip wrapper's end and trailer, whose CRC the decoder checks
    offset += await pump(await request(fetchImpl, url, offset, size - 1, onRequest), sink, Infinity);
  }
  return { mode: 'ranges', fileSize: size, bytes: offset };
}

async function request(fetchImpl, url, first, last, onRequest) {
  const headers = { Range: `bytes=${first}-${last}` };
  const response = await fetchImpl(url, { headers, cache: 'no-store' });
  const range = parseContentRange(response.headers.get('Content-Range'));
  onRequest({ first, last, status: response.status, contentRange: range });
  if (response.status === 206) {
    if (!range || range.first !== first || range.last > last) {
      throw new TransferError(`${url}: the server answered bytes ${first}-${last} with ` +
        `Content-Range ${response.headers.get('Content-Range')}`);
    }
    response.range = range;
    return response;
  }
  if (response.status === 200 && first === 0) return response;
  throw new TransferError(`${url}: HTTP ${response.status} for bytes ${first}-${last}`);
}

function lengthOf(response) {
  const length = Number(response.headers.get('Content-Length'));
  return Number.isFinite(length) && length > 0 ? length : null;
}

/** Send a response's body to `sink` chunk by chunk, at most `limit` bytes; returns the count. */
async function pump(response, sink, limit) {
  let count = 0;
  let finished = false;
  const reader = response.body.getReader();
  try {
    while (count < limit) {
      const { done, value } = await reader.read();
      if (done) {
        finished = true;
        break;
      }
      const chunk = value.length > limit - count ? value.subarray(0, limit - count) : value;
      count += chunk.length;
      await sink(chunk);
    }
  } finally {
    if (!finished) await reader.cancel();  // more than asked for, or the sink failed
    reader.releaseLock();
  }
  return count;
}

async function readAll(response) {
  return new Uint8Array(await response.arrayBuffer());
}

function concat(a, b) {
  const out = new Uint8Array(a.length + b.length);
  out.set(a, 0);
  out.set(b, a.length);
  return out;
}
