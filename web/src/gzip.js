/**
 * The optional gzip wrapper (spec section 8, [R-80]..[R-84]), inflated incrementally.
 *
 * A prefix of a wrapped file inflates to a prefix of the inner file ([R-81]), so the reader hands
 * out whatever inner bytes the input so far yields; the member's CRC-32 is verified once its four
 * bytes are here and ISIZE once the trailer is complete ([R-81], [R-82]), and anything after the
 * member is `trailing-data`.
 * Output is inflated in pieces of at most {@link PIECE} bytes, and up to a watermark the caller
 * sets, with a callback after each, so the caller can read the inner header as soon as it is
 * whole and lower the cap to the inner `file_size` before a gzip bomb gets further ([R-84]).
 */
import { crc32 } from './checksums.js';
import { SpcError } from './errors.js';
import { DeflateError, OutputLimitError, RawInflater } from './inflate.js';

export const GZIP_MAGIC0 = 0x1F;
export const GZIP_MAGIC1 = 0x8B;
const FHCRC = 2;
const FEXTRA = 4;
const FNAME = 8;
const FCOMMENT = 16;
const PIECE = 1 << 20;

/**
 * @param {Uint8Array} data
 * @returns {boolean} whether `data` starts with the gzip magic
 */
export function isGzip(data) {
  return data.length >= 2 && data[0] === GZIP_MAGIC0 && data[1] === GZIP_MAGIC1;
}

/**
 * @param {string} message
 * @returns {never}
 */
function badGzip(message) {
  throw new SpcError('bad-gzip', message);
}

/**
 * Check a gzip member header as zlib does; return its length, or -1 when `data` does not hold all
 * of it yet. A header no continuation can make valid is `bad-gzip` at once ([R-82]).
 * @param {Uint8Array} data
 * @returns {number}
 */
function headerLength(data) {
  const incomplete = -1;
  if (data.length < 10) {
    if (data.length >= 3 && data[2] !== 8) badGzip('gzip member uses an unknown compression method');
    if (data.length >= 4 && data[3] & 0xE0) badGzip('gzip header has unknown flags set');
    return incomplete;
  }
  if (data[2] !== 8) badGzip('gzip member uses an unknown compression method');
  const flags = data[3];
  if (flags & 0xE0) badGzip('gzip header has unknown flags set');
  let pos = 10;
  if (flags & FEXTRA) {
    if (pos + 2 > data.length) return incomplete;
    pos += 2 + (data[pos] | (data[pos + 1] << 8));
    if (pos > data.length) return incomplete;
  }
  for (const flag of [FNAME, FCOMMENT]) {
    if (flags & flag) {
      const zero = data.indexOf(0, pos);
      if (zero < 0) return incomplete;
      pos = zero + 1;
    }
  }
  if (flags & FHCRC) {
    if (pos + 2 > data.length) return incomplete;
    const want = data[pos] | (data[pos + 1] << 8);
    if ((crc32(data.subarray(0, pos)) & 0xFFFF) !== want) badGzip('gzip header CRC mismatch');
    pos += 2;
  }
  return pos;
}

/**
 * The `SP` subfield's layer offsets ([R-83]) from a FEXTRA field, or null.
 * @param {Uint8Array | null} extra
 * @returns {number[] | null}
 */
function layerEndsFromExtra(extra) {
  if (!extra) return null;
  const view = new DataView(extra.buffer, extra.byteOffset, extra.byteLength);
  for (let pos = 0; pos + 4 <= extra.length;) {
    const size = view.getUint16(pos + 2, true);
    const body = extra.subarray(pos + 4, pos + 4 + size);
    if (extra[pos] === 0x53 && extra[pos + 1] === 0x50 && body.length >= 2) {
      const count = body[0] | (body[1] << 8);
      if (body.length !== 2 + 8 * count) return null;
      const ends = [];
      for (let i = 0; i < count; i++) {
        const at = pos + 6 + 8 * i;
        ends.push(view.getUint32(at, true) + view.getUint32(at + 4, true) * 2 ** 32);
      }
      return ends;
    }
    pos += 4 + size;
  }
  return null;
}

/**
 * Inflates a gzip wrapper fed in chunks.
 */
export class GzipReader {
  /**
   * @param {number} cap largest inner size allowed (lower it with {@link setCap})
   * @param {(reader: GzipReader) => void} [afterPiece] called after each piece of output
   */
  constructor(cap, afterPiece) {
    this.afterPiece = afterPiece ?? (() => {});
    /** @type {Uint8Array} header bytes gathered so far */
    this.head = new Uint8Array(0);
    this.headerLength = -1;
    this.inflater = new RawInflater(cap, { growable: true });
    /** @type {Uint8Array} trailer bytes gathered so far */
    this.trailer = new Uint8Array(0);
    /** the member, trailer included, has been read and verified */
    this.complete = false;
    /** inflating pauses (and calls back) when the output reaches this size, and every PIECE bytes */
    this.watermark = Infinity;
  }

  /** The inner bytes inflated so far (a view; it changes as the reader grows). */
  get inner() {
    return this.inflater.out.subarray(0, this.inflater.outLength);
  }

  get innerLength() {
    return this.inflater.outLength;
  }

  get cap() {
    return this.inflater.cap;
  }

  /**
   * Lower the output cap. The inflater refuses output past it with OutputLimitError.
   * @param {number} cap
   */
  setCap(cap) {
    this.inflater.cap = cap;
    if (this.inflater.outLength > cap) throw new OutputLimitError(`output passes ${cap} bytes`);
  }

  /**
   * Add wrapper bytes and inflate all they allow (a prefix of the wrapper is a valid input).
   * @param {Uint8Array} chunk
   */
  push(chunk) {
    if (this.complete) {
      if (chunk.length) throw new SpcError('trailing-data', 'bytes follow the gzip member');
      return;
    }
    if (this.headerLength < 0) {
      const head = new Uint8Array(this.head.length + chunk.length);
      head.set(this.head);
      head.set(chunk, this.head.length);
      const length = headerLength(head);
      if (length < 0) {
        this.head = head;
        return;
      }
      this.headerLength = length;
      chunk = head.subarray(length);
      this.head = new Uint8Array(0);
    }
    if (!this.inflater.done) {
      this.inflater.append(chunk);
      this.inflate();
      if (!this.inflater.done) return;
      chunk = this.inflater.input.subarray(this.inflater.endByte, this.inflater.inputLength);
    }
    this.readTrailer(chunk);
  }

  /** Inflate the pending input in pieces, calling back after each. */
  inflate() {
    const inf = this.inflater;
    for (;;) {
      const pos = inf.pos;
      const before = inf.outLength;
      let done;
      const pause = this.watermark > before ? Math.min(this.watermark, before + PIECE) : before + PIECE;
      try {
        done = inf.run(pause);
      } catch (err) {
        if (err instanceof DeflateError) badGzip(`gzip wrapper is corrupt (${err.message})`);
        throw err;
      }
      if (inf.outLength !== before) this.afterPiece(this);
      if (done || (inf.pos === pos && inf.outLength === before)) return;
    }
  }

  /** @param {Uint8Array} bytes bytes after the deflate stream */
  readTrailer(bytes) {
    const need = 8 - this.trailer.length;
    const trailer = new Uint8Array(this.trailer.length + Math.min(need, bytes.length));
    trailer.set(this.trailer);
    trailer.set(bytes.subarray(0, need), this.trailer.length);
    const hadCrc = this.trailer.length >= 4;
    this.trailer = trailer;
    if (trailer.length < 4) return;
    const view = new DataView(trailer.buffer);
    const inner = this.inner;
    // the CRC-32 is checked as soon as its four bytes are here, ISIZE when it is ([R-81], [R-82])
    if (!hadCrc && view.getUint32(0, true) !== crc32(inner)) badGzip('gzip wrapper fails its CRC-32 check');
    if (trailer.length < 8) return;
    if (view.getUint32(4, true) !== inner.length % 2 ** 32) badGzip('gzip wrapper ISIZE mismatch');
    this.complete = true;
    if (bytes.length > need) throw new SpcError('trailing-data', 'bytes follow the gzip member');
  }
}

/**
 * The `SP` layer offsets of a gzip file's header ([R-83]), or null when it has none or its FEXTRA
 * field is not all there. The subfield is advisory: nothing else of the header is checked here.
 * @param {Uint8Array} data
 * @returns {number[] | null}
 */
export function gzipLayerEnds(data) {
  if (data.length < 12 || !isGzip(data) || !(data[3] & FEXTRA)) return null;
  const xlen = data[10] | (data[11] << 8);
  if (12 + xlen > data.length) return null;
  return layerEndsFromExtra(data.subarray(12, 12 + xlen));
}
