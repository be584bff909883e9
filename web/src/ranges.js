// Fetching an .spc layer by layer with HTTP range requests.
//
// The header block tells every byte range of the file (spec section 3): the fixed header's
// `header_size` (u32 at offset 16) says how long the header block is, and the layer table says
// where each layer ends. So the loader asks for the first bytes, completes the header block if
// needed, reads the layer ends with the decoder's `inspect`, then requests one range per layer,
// and stops after the last layer it was asked for. Every byte goes through the streaming decoder,
// which checks it. A gzip-wrapped file is fetched the same way when its wrapper records where each
// layer ends ([R-83]; `inspect` reports those offsets), else read as one stream, as is a file from
// a server that ignores ranges (200 instead of 206), whose head is planned on all the same (the
// caller learns the up axis and the scene's box before any layer).
//
// An .spc embedded in a .glb (`spcodec embed`) streams the same way from where it lies in the file
// (`streamScene`): its offset comes from the .glb's header and JSON chunk.
//
// Nothing here touches the DOM or the renderer: it runs under node with a fake fetch in the tests.

import { GLB_PREAMBLE_BYTES, jsonEnd, locateSpc } from './glb.js';

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
 * @param {number} [options.base]  the byte of the file at `url` where the .spc starts (one inside
 *   a .glb; default 0): `planLayers` and `sink` see the .spc's bytes, `onRequest` the file's offsets
 * @param {number|null} [options.length]  the .spc's length from `base` (default: to the file's end)
 * @returns {Promise<{mode: 'ranges'|'stream', fileSize: number|null, bytes: number}>}
 */
export async function streamSpc(url, { sink, planLayers, maxLayer = Infinity, fetchImpl = fetch,
  onRequest = () => {}, base = 0, length = null }) {
  const fetchRange = (from, to, log) => request(fetchImpl, url, from, to, log, base);
  const firstLast = Math.min(FIRST_REQUEST_BYTES, length ?? Infinity) - 1;
  const first = await fetchRange(0, firstLast, onRequest);
  if (first.status === 200) {  // the server ignores ranges: the whole file comes, planned on its head
    const planned = headFirst(sink, planLayers);
    const bytes = await pump(first, planned.sink, length ?? Infinity, base);
    await planned.flush();
    return { mode: 'stream', fileSize: length ?? lengthOf(first), bytes };
  }
  const size = length ?? first.range.size;
  let head = await readAll(first);
  const headerSize = declaredHeaderSize(head);
  if (headerSize > head.length && headerSize <= size) {  // an unusually long header block
    const more = await readAll(await fetchRange(head.length, headerSize - 1, onRequest));
    head = concat(head, more);
  }
  const layers = tryPlan(planLayers, head);
  await sink(head);
  let offset = head.length;
  if (!layers || layers.some((layer) => layer.endOffset == null)) {
    // No layer ends (a gzip wrapper without recorded layer offsets, or bytes the decoder will
    // reject): read the rest as one stream.
    if (offset < size) {
      offset += await pump(await fetchRange(offset, size - 1, onRequest), sink, Infinity);
    }
    return { mode: 'stream', fileSize: size, bytes: offset };
  }
  for (const layer of layers) {
    if (layer.index > maxLayer) break;
    if (layer.endOffset <= offset) continue;  // already received with the first request
    const response = await fetchRange(offset, layer.endOffset - 1, onRequest);
    offset += await pump(response, sink, layer.endOffset - offset);
  }
  if (maxLayer >= layers.length - 1 && offset < size) {
    // bytes after the last layer: a gzip wrapper's end and trailer, whose CRC the decoder checks
    offset += await pump(await fetchRange(offset, size - 1, onRequest), sink, Infinity);
  }
  return { mode: 'ranges', fileSize: size, bytes: offset };
}

/**
 * What the header says (its layers; for the caller, the up axis and the scene's box in the
 * metadata), before the bytes go on: it applies to the layers in them. Null when the bytes are
 * too short for a header block or not an .spc: the decoder says why as the rest arrives.
 * @param {(header: Uint8Array) => {layers: {index: number, endOffset: number|null}[]}} planLayers
 * @param {Uint8Array} head
 */
function tryPlan(planLayers, head) {
  try {
    return planLayers(head).layers;
  } catch {
    return null;
  }
}

/**
 * A sink that holds the first bytes of a whole-file answer until they reach as far as a first
 * range request would (the header block, when longer), plans on them as the range path does,
 * then passes them and everything after straight on; `flush` plans on what came when the file
 * was shorter.
 * @param {(chunk: Uint8Array) => Promise<void>} sink
 * @param {(header: Uint8Array) => {layers: {index: number, endOffset: number|null}[]}} planLayers
 */
function headFirst(sink, planLayers) {
  /** @type {Uint8Array[]|null} the chunks held so far; null once planned */
  let held = [];
  let count = 0;
  let need = FIRST_REQUEST_BYTES;  // until the fixed header is in and says more
  const release = async () => {
    const chunks = /** @type {Uint8Array[]} */ (held);
    held = null;
    const head = chunks.length === 1 ? chunks[0] : chunks.reduce(concat, new Uint8Array(0));
    tryPlan(planLayers, head);
    await sink(head);
  };
  return {
    sink: async (chunk) => {
      if (held === null) return sink(chunk);
      const before = count;
      held.push(chunk);
      count += chunk.length;
      if (before < FIXED_HEADER_BYTES && count >= FIXED_HEADER_BYTES) {
        need = headBytes(held.length === 1 ? held[0] : held.reduce(concat, new Uint8Array(0)));
      }
      if (count >= need) await release();
    },
    flush: async () => {
      if (held !== null && count) await release();
    },
  };
}

/** The most a whole-file answer's head is held for planning: a header block longer than this
 * (the limits allow far less in practice) is planned on what came, as a cut one would be. */
const MAX_HELD_HEAD = 1 << 20;

/** How many bytes of a file's start the planner needs: a first request's, or the whole header
 * block of a plain .spc whose header says it is longer (at most MAX_HELD_HEAD). */
function headBytes(start) {
  return Math.max(FIRST_REQUEST_BYTES, Math.min(declaredHeaderSize(start), MAX_HELD_HEAD));
}

/** The header block's length a plain .spc's fixed header declares (`header_size`, spec 3.1);
 * 0 for a gzip-wrapped file or bytes too short to say. */
function declaredHeaderSize(start) {
  const gzip = start.length >= 2 && start[0] === GZIP_MAGIC[0] && start[1] === GZIP_MAGIC[1];
  if (gzip || start.length < FIXED_HEADER_BYTES) return 0;
  return new DataView(start.buffer, start.byteOffset, start.byteLength).getUint32(16, true);
}

/** Bytes `first..last` of the stream that starts at byte `base` of the file at `url`. Offsets
 * in the answer and in `onRequest` are the file's. */
async function request(fetchImpl, url, first, last, onRequest, base = 0) {
  const [from, to] = [base + first, base + last];
  const headers = { Range: `bytes=${from}-${to}` };
  const response = await fetchImpl(url, { headers, cache: 'no-store' });
  const range = parseContentRange(response.headers.get('Content-Range'));
  onRequest({ first: from, last: to, status: response.status, contentRange: range });
  if (response.status === 206) {
    if (!range || range.first !== from || range.last > to) {
      throw new TransferError(`${url}: the server answered bytes ${from}-${to} with ` +
        `Content-Range ${response.headers.get('Content-Range')}`);
    }
    response.range = range;
    return response;
  }
  if (response.status === 200 && first === 0) return response;
  throw new TransferError(`${url}: HTTP ${response.status} for bytes ${from}-${to}`);
}

/**
 * Stream the .spc at `url`, or the one a .glb embeds (`spcodec embed`; told by the URL's .glb
 * extension): as {@link streamSpc}, after reading the .glb's header and JSON chunk for where the
 * .spc lies (told to `options.onGlb(where)` before any of it streams). Resolves with what
 * streamSpc does and the glTF node's `rotation` (x, y, z, w; null for a plain .spc, whose up axis
 * is in its metadata).
 * @param {string} url
 * @param {Parameters<typeof streamSpc>[1] &
 *   {onGlb?: (where: ReturnType<typeof locateSpc>) => void}} options
 */
export async function streamScene(url, options) {
  const path = new URL(url, 'http://x/').pathname.toLowerCase();
  if (!path.endsWith('.glb')) return { ...(await streamSpc(url, options)), rotation: null };
  const { fetchImpl = fetch, onRequest = () => {} } = options;
  const preamble = await readAll(await request(fetchImpl, url, 0, GLB_PREAMBLE_BYTES - 1, onRequest));
  const head = await readAll(await request(fetchImpl, url, 0, jsonEnd(preamble) - 1, onRequest));
  const where = locateSpc(head.subarray(0, jsonEnd(preamble)));
  options.onGlb?.(where);
  const result = await streamSpc(url, { ...options, base: where.offset, length: where.length });
  return { ...result, rotation: where.rotation };
}

function lengthOf(response) {
  const length = Number(response.headers.get('Content-Length'));
  return Number.isFinite(length) && length > 0 ? length : null;
}

/** Send a response's body to `sink` chunk by chunk, at most `limit` bytes after the first `skip`;
 * returns the count sent. */
async function pump(response, sink, limit, skip = 0) {
  let count = 0;
  let finished = false;
  const reader = response.body.getReader();
  try {
    while (count < limit) {
      let { done, value } = await reader.read();
      if (done) {
        finished = true;
        break;
      }
      if (skip > 0) {
        const dropped = Math.min(skip, value.length);
        value = value.subarray(dropped);
        skip -= dropped;
        if (!value.length) continue;
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
