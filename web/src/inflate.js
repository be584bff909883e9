/**
 * A strict, bounded, resumable inflater for raw deflate data (RFC 1951).
 *
 * The format needs four things from deflate that general-purpose JavaScript inflaters do not give
 * ([R-22], [R-24], [R-82]): output bounded by a cap (a section may not inflate past its raw length,
 * a gzip wrapper past the inner file's size), the exact end of the stream (bytes after a zlib stream
 * or a gzip member are an error), zlib's validation of the code tables (over-subscribed or
 * incomplete codes, distances before the start of the output, stored-block length complements), and
 * resumption when input arrives in chunks (the gzip wrapper of a file that is still downloading).
 *
 * Huffman codes are decoded through single-level tables indexed by the next `bits` input bits
 * (bit-reversed), whose entries are `symbol << 4 | code length`; 0 marks an unused code.
 * Input buffers carry at least {@link INPUT_PADDING} zero bytes after their data, so the hot loop
 * reads ahead without bounds checks (a symbol is at most 48 bits); running past the real data is
 * caught after each symbol by comparing the bit position with the input length, and the symbol is
 * then undone: the decoder waits for more input, or fails when the input has ended.
 */

import { allocate } from './errors.js';

export const INPUT_PADDING = 16;

const LEN_BASE = new Uint16Array([3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43,
  51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258]);
const LEN_EXTRA = new Uint8Array([0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4,
  4, 4, 5, 5, 5, 5, 0]);
const DIST_BASE = new Uint16Array([1, 2, 3, 4, 5, 7, 9, 13, 17, 25, 33, 49, 65, 97, 129, 193, 257,
  385, 513, 769, 1025, 1537, 2049, 3073, 4097, 6145, 8193, 12289, 16385, 24577]);
const DIST_EXTRA = new Uint8Array([0, 0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7, 8, 8, 9, 9,
  10, 10, 11, 11, 12, 12, 13, 13]);
const CODE_LENGTH_ORDER = [16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15];

/** Thrown for corrupt deflate data; callers turn it into their own error code. */
export class DeflateError extends Error {}

/** Thrown when the output would pass the inflater's cap. */
export class OutputLimitError extends Error {}

/**
 * A decoding table for one Huffman code.
 * @typedef {{table: Uint16Array, bits: number}} HuffmanTable
 */

/**
 * Build the decoding table of a canonical Huffman code, with zlib's validity rules: an
 * over-subscribed code is invalid; an incomplete one is valid only for literal/length and distance
 * codes of a single one-bit code (zlib's one exception); a code without symbols for distances
 * (any match then fails) and for code lengths (each symbol is then one bit meaning length 0).
 * @param {Uint8Array} lengths code length of each symbol (0: unused)
 * @param {'codes'|'lens'|'dists'} kind
 * @returns {HuffmanTable}
 */
function buildTable(lengths, kind) {
  const count = new Uint16Array(16);
  for (let i = 0; i < lengths.length; i++) count[lengths[i]]++;
  let maxBits = 15;
  while (maxBits > 0 && count[maxBits] === 0) maxBits--;
  if (maxBits === 0) {
    // zlib accepts a code length code without symbols when it reads it: each code-length symbol
    // is then one bit, of either value, meaning length 0, so the block fails only once all its
    // lengths are read, for want of an end-of-block code ([R-22], [R-81])
    if (kind === 'codes') return { table: new Uint16Array([1, 1]), bits: 1 };
    if (kind !== 'dists') throw new DeflateError(`empty ${kind} code`);
    return { table: new Uint16Array(2), bits: 1 };
  }
  let left = 1;
  for (let len = 1; len <= 15; len++) {
    left = left * 2 - count[len];
    if (left < 0) throw new DeflateError(`over-subscribed ${kind} code`);
  }
  if (left > 0 && (kind === 'codes' || maxBits !== 1)) {
    throw new DeflateError(`incomplete ${kind} code`);
  }
  // canonical codes: next[len] is the first code of that length
  const next = new Uint16Array(16);
  count[0] = 0;
  for (let len = 1, code = 0; len <= 15; len++) {
    code = (code + count[len - 1]) << 1;
    next[len] = code;
  }
  const size = 1 << maxBits;
  const table = new Uint16Array(size);
  for (let sym = 0; sym < lengths.length; sym++) {
    const len = lengths[sym];
    if (len === 0) continue;
    const code = next[len]++;
    let rev = 0;
    for (let i = 0; i < len; i++) rev |= ((code >>> i) & 1) << (len - 1 - i);
    const entry = (sym << 4) | len;
    for (let i = rev; i < size; i += 1 << len) table[i] = entry;
  }
  return { table, bits: maxBits };
}

const FIXED_LENS = (() => {
  const l = new Uint8Array(288);
  l.fill(8, 0, 144);
  l.fill(9, 144, 256);
  l.fill(7, 256, 280);
  l.fill(8, 280, 288);
  return buildTable(l, 'lens');
})();
const FIXED_DISTS = buildTable(new Uint8Array(32).fill(5), 'dists');

const STATE_HEADER = 0; // at a block header
const STATE_STORED = 1; // inside a stored block
const STATE_HUFFMAN = 2; // inside a compressed block
const STATE_DONE = 3; // after the final block

/** Raised internally when more input is needed to go on. */
const NEED_INPUT = Symbol('need input');

/**
 * A raw deflate decoder that can be fed input in pieces.
 *
 * Output goes to `out[0 .. outLength)`; with `growable` the buffer grows (doubling) up to `cap`,
 * otherwise it is allocated at `cap` bytes up front. Writing past `cap` throws
 * {@link OutputLimitError}; corrupt data throws {@link DeflateError}.
 */
export class RawInflater {
  /**
   * @param {number} cap largest output allowed
   * @param {{growable?: boolean, initialCapacity?: number}} [options]
   */
  constructor(cap, options = {}) {
    this.cap = cap;
    this.growable = Boolean(options.growable);
    const first = this.growable ? Math.min(cap, options.initialCapacity ?? 1 << 16) : cap;
    /** @type {Uint8Array} */
    this.out = allocate(Uint8Array, first);
    this.outLength = 0;
    /** @type {Uint8Array} input bytes, followed by at least INPUT_PADDING zeros */
    this.input = new Uint8Array(INPUT_PADDING);
    this.inputLength = 0;
    /** bit position in `input` */
    this.pos = 0;
    /** the input is complete: running out of it is an error, not a pause */
    this.inputEnded = false;
    this.state = STATE_HEADER;
    this.lastBlock = false;
    this.storedLeft = 0;
    /** @type {HuffmanTable | null} */
    this.lens = null;
    /** @type {HuffmanTable | null} */
    this.dists = null;
    /** run() pauses once the output reaches this many bytes */
    this.pauseOutput = Infinity;
  }

  /** True once the final block has been decoded. */
  get done() {
    return this.state === STATE_DONE;
  }

  /** Byte offset in the current input buffer just after the deflate stream (when done). */
  get endByte() {
    return (this.pos + 7) >>> 3;
  }

  /**
   * Use `data` (plus padding) as the whole input, without copying when it is already padded.
   * @param {Uint8Array} padded a buffer holding the data followed by INPUT_PADDING zeros
   * @param {number} length bytes of data
   * @param {number} startByte where the deflate stream starts
   */
  setInput(padded, length, startByte) {
    this.input = padded;
    this.inputLength = length;
    this.pos = startByte * 8;
    this.inputEnded = true;
  }

  /**
   * Append input, dropping bytes already consumed (deflate needs no input history).
   * @param {Uint8Array} chunk
   */
  append(chunk) {
    const keepFrom = this.pos >>> 3;
    const keep = this.inputLength - keepFrom;
    const need = keep + chunk.length + INPUT_PADDING;
    if (need > this.input.length) {
      const bigger = new Uint8Array(Math.max(need, 2 * keep + 1024));
      bigger.set(this.input.subarray(keepFrom, this.inputLength));
      this.input = bigger;
    } else if (keepFrom > 0) {
      this.input.copyWithin(0, keepFrom, this.inputLength);
    }
    this.pos -= keepFrom * 8;
    this.inputLength = keep;
    this.input.set(chunk, this.inputLength);
    this.inputLength += chunk.length;
    this.input.fill(0, this.inputLength, this.inputLength + INPUT_PADDING);
  }

  /**
   * Decode as far as the input allows, or until the output reaches `pauseOutput` bytes (give or
   * take one match); returns true once the final block has been decoded.
   * @param {number} [pauseOutput]
   * @returns {boolean}
   */
  run(pauseOutput = Infinity) {
    this.pauseOutput = pauseOutput;
    while (this.state !== STATE_DONE) {
      const start = this.pos;
      try {
        if (this.state === STATE_HEADER) this.readBlockHeader();
        else if (this.state === STATE_STORED) this.copyStored();
        else this.decodeHuffman();
      } catch (err) {
        if (err !== NEED_INPUT) throw err;
        if (this.state === STATE_HEADER) this.pos = start; // re-read the whole header later
        return false;
      }
    }
    return true;
  }

  /** Bits available in the input. */
  get availableBits() {
    return this.inputLength * 8;
  }

  /** Stop for more input, or fail when there is none to come. */
  starve() {
    if (this.inputEnded) throw new DeflateError('the deflate data ends early');
    throw NEED_INPUT;
  }

  /** `n` (<= 16) bits at the current position, consumed. */
  bits(n) {
    const p = this.pos;
    const i = p >>> 3;
    const inp = this.input;
    const v = ((inp[i] | (inp[i + 1] << 8) | (inp[i + 2] << 16)) >>> (p & 7)) & ((1 << n) - 1);
    this.pos = p + n;
    return v;
  }

  /** A symbol of the given code, consumed. */
  symbol(code) {
    const p = this.pos;
    const i = p >>> 3;
    const inp = this.input;
    const v = (inp[i] | (inp[i + 1] << 8) | (inp[i + 2] << 16)) >>> (p & 7);
    const e = code.table[v & ((1 << code.bits) - 1)];
    if (e === 0) throw new DeflateError('invalid Huffman code');
    this.pos = p + (e & 15);
    return e >>> 4;
  }

  readBlockHeader() {
    if (this.pos + 3 > this.availableBits) this.starve();
    this.lastBlock = this.bits(1) === 1;
    const type = this.bits(2);
    if (type === 0) {
      this.pos = (this.pos + 7) & ~7;
      if (this.pos + 32 > this.availableBits) this.starve();
      const len = this.bits(16);
      const nlen = this.bits(16);
      if ((len ^ 0xFFFF) !== nlen) throw new DeflateError('invalid stored block lengths');
      this.storedLeft = len;
      this.state = STATE_STORED;
    } else if (type === 1) {
      this.lens = FIXED_LENS;
      this.dists = FIXED_DISTS;
      this.state = STATE_HUFFMAN;
    } else if (type === 2) {
      this.readDynamicTables();
      this.state = STATE_HUFFMAN;
    } else {
      throw new DeflateError('invalid block type');
    }
  }

  readDynamicTables() {
    if (this.pos + 14 > this.availableBits) this.starve();
    const nlen = this.bits(5) + 257;
    const ndist = this.bits(5) + 1;
    const ncode = this.bits(4) + 4;
    if (nlen > 286 || ndist > 30) throw new DeflateError('too many length or distance symbols');
    if (this.pos + 3 * ncode > this.availableBits) this.starve();
    const codeLengths = new Uint8Array(19);
    for (let i = 0; i < ncode; i++) codeLengths[CODE_LENGTH_ORDER[i]] = this.bits(3);
    const codes = buildTable(codeLengths, 'codes');
    const lengths = new Uint8Array(nlen + ndist);
    for (let i = 0; i < nlen + ndist;) {
      // each symbol is judged once its code and extra bits are all here, as zlib does ([R-81])
      const sym = this.symbol(codes);
      if (this.pos > this.availableBits) this.starve();
      if (sym < 16) {
        lengths[i++] = sym;
        continue;
      }
      let value = 0;
      let repeat;
      if (sym === 16) {
        repeat = 3 + this.bits(2);
      } else if (sym === 17) {
        repeat = 3 + this.bits(3);
      } else {
        repeat = 11 + this.bits(7);
      }
      if (this.pos > this.availableBits) this.starve();
      if (sym === 16) {
        if (i === 0) throw new DeflateError('invalid bit length repeat');
        value = lengths[i - 1];
      }
      if (i + repeat > nlen + ndist) throw new DeflateError('invalid bit length repeat');
      lengths.fill(value, i, i + repeat);
      i += repeat;
    }
    if (this.pos > this.availableBits) this.starve();
    if (lengths[256] === 0) throw new DeflateError('invalid code: missing end-of-block');
    this.lens = buildTable(lengths.subarray(0, nlen), 'lens');
    this.dists = buildTable(lengths.subarray(nlen), 'dists');
  }

  copyStored() {
    const bytePos = this.pos >>> 3;
    const available = this.inputLength - bytePos;
    const n = Math.min(this.storedLeft, available, Math.max(0, this.pauseOutput - this.outLength));
    if (n > 0) {
      this.reserve(n);
      this.out.set(this.input.subarray(bytePos, bytePos + n), this.outLength);
      this.outLength += n;
      this.pos += n * 8;
      this.storedLeft -= n;
    }
    if (this.storedLeft > 0) {
      if (this.outLength >= this.pauseOutput) throw NEED_INPUT;
      this.starve();
    }
    this.state = this.lastBlock ? STATE_DONE : STATE_HEADER;
  }

  /**
   * Make room for `n` more output bytes: grow the buffer, or refuse past the cap.
   * @param {number} n
   */
  reserve(n) {
    const need = this.outLength + n;
    if (need <= this.out.length) return;
    if (need > this.cap) throw new OutputLimitError(`output passes ${this.cap} bytes`);
    const bigger = allocate(Uint8Array, Math.min(this.cap, Math.max(need, this.out.length * 2)));
    bigger.set(this.out.subarray(0, this.outLength));
    this.out = bigger;
  }

  /** The hot loop: literals and matches until the end of the block or of the input. */
  decodeHuffman() {
    const inp = this.input;
    const lt = this.lens.table;
    const lmask = (1 << this.lens.bits) - 1;
    const dt = this.dists.table;
    const dmask = (1 << this.dists.bits) - 1;
    const totalBits = this.inputLength * 8;
    const pauseOutput = this.pauseOutput;
    let out = this.out;
    let outCap = out.length;
    let op = this.outLength;
    let pos = this.pos;
    try {
      for (;;) {
        if (op >= pauseOutput) throw NEED_INPUT;
        const start = pos;
        let i = pos >>> 3;
        let v = (inp[i] | (inp[i + 1] << 8) | (inp[i + 2] << 16)) >>> (pos & 7);
        const e = lt[v & lmask];
        pos += e === 0 ? 1 : e & 15; // an unused code of zlib's one-code exception: one bit
        // a code is judged only once all its bits are here ([R-81]): zero padding past the input
        // may complete a cut code into an invalid one that the real next bits would not make
        if (pos > totalBits) {
          pos = start;
          this.starve();
        }
        if (e === 0) throw new DeflateError('invalid literal/length code');
        const sym = e >>> 4;
        if (sym < 256) {
          if (op >= outCap) {
            this.outLength = op;
            this.reserve(1);
            out = this.out;
            outCap = out.length;
          }
          out[op++] = sym;
          continue;
        }
        if (sym === 256) {
          this.state = this.lastBlock ? STATE_DONE : STATE_HEADER;
          break;
        }
        const li = sym - 257;
        if (li >= 29) throw new DeflateError('invalid literal/length code');
        let len = LEN_BASE[li];
        const lx = LEN_EXTRA[li];
        if (lx) {
          i = pos >>> 3;
          len += ((inp[i] | (inp[i + 1] << 8)) >>> (pos & 7)) & ((1 << lx) - 1);
          pos += lx;
        }
        i = pos >>> 3;
        v = (inp[i] | (inp[i + 1] << 8) | (inp[i + 2] << 16)) >>> (pos & 7);
        const d = dt[v & dmask];
        pos += d === 0 ? 1 : d & 15; // zlib's one incomplete distance code fails after one bit
        if (pos > totalBits) {
          pos = start;
          this.starve();
        }
        if (d === 0) throw new DeflateError('invalid distance code');
        const ds = d >>> 4;
        if (ds >= 30) throw new DeflateError('invalid distance code');
        let dist = DIST_BASE[ds];
        const dx = DIST_EXTRA[ds];
        if (dx) {
          i = pos >>> 3;
          dist += ((inp[i] | (inp[i + 1] << 8) | (inp[i + 2] << 16)) >>> (pos & 7)) & ((1 << dx) - 1);
          pos += dx;
        }
        if (pos > totalBits) {
          pos = start;
          this.starve();
        }
        if (dist > op) throw new DeflateError('invalid distance too far back');
        if (op + len > outCap) {
          this.outLength = op;
          this.reserve(len);
          out = this.out;
          outCap = out.length;
        }
        let from = op - dist;
        if (dist >= len && len > 16) {
          out.copyWithin(op, from, from + len);
          op += len;
        } else {
          const end = op + len;
          while (op < end) out[op++] = out[from++];
        }
      }
    } finally {
      this.pos = pos;
      this.outLength = op;
    }
  }
}

/**
 * Copy `data` into a new buffer followed by the zero padding the inflater reads past the end.
 * @param {Uint8Array} data
 * @returns {Uint8Array}
 */
export function padded(data) {
  const buf = new Uint8Array(data.length + INPUT_PADDING);
  buf.set(data);
  return buf;
}
