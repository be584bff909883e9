/**
 * zstd sections (codec 2, [R-22]..[R-25]): exactly one RFC 8878 frame that declares its content
 * size, decoded by this module's own decoder.
 *
 * The spec says which frames are valid, rule by rule ([R-22], "zstd frame"): RFC 8878 with
 * libzstd 1.5.7's checks, every Huffman and sequence bitstream consumed exactly, every block
 * within Block_Maximum_Size, and offsets bounded by the start of the frame, not by its window. A
 * general-purpose decoder does not check all of that (fzstd accepts offsets before the start of
 * the output and literal lengths past the literals; libzstd's fast Huffman loop does not check
 * where a literal stream ends), so this decoder implements the rules itself: the frame header,
 * every block header against the block maximum, the literals section (Huffman tree, one or four
 * streams), the sequences section (FSE tables, the sequence bitstream), the execution of every
 * sequence, the content size and the XXH64 content checksum. Every failure is
 * `decompression-failed`, except a declared content size other than the raw length
 * (`length-mismatch`, from the header, before decoding).
 */
import { xxh64Low32 } from './checksums.js';
import { SpcError, allocate } from './errors.js';

const FRAME_MAGIC = 0xFD2FB528;
export const ZSTD_MAX_WINDOW = 2 ** 27;
const BLOCK_SIZE_MAX = 128 * 1024;

/**
 * @param {string} message
 * @returns {never}
 */
function corrupt(message) {
  throw new SpcError('decompression-failed', message);
}

/**
 * The facts of a zstd frame header that the format constrains.
 * @typedef {object} FrameHeader
 * @property {number} headerSize bytes of the frame header (magic included)
 * @property {number} contentSize declared content size (-1 when absent)
 * @property {number} windowSize
 * @property {boolean} checksum
 * @property {number} dictId 0 when the frame needs no dictionary
 * @property {boolean} singleSegment
 */

/**
 * @param {Uint8Array} data
 * @returns {FrameHeader}
 */
export function readFrameHeader(data) {
  if (data.length < 5) corrupt('the zstd frame header is cut short');
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
  if (view.getUint32(0, true) !== FRAME_MAGIC) corrupt('section is not a zstd frame');
  const descriptor = data[4];
  const fcsFlag = descriptor >>> 6;
  const singleSegment = (descriptor >>> 5) & 1;
  if (descriptor & 0x08) corrupt('zstd frame header has its reserved bit set');
  const checksum = ((descriptor >>> 2) & 1) === 1;
  const dictBytes = [0, 1, 2, 4][descriptor & 3];
  const fcsBytes = [singleSegment ? 1 : 0, 2, 4, 8][fcsFlag];
  let pos = 5;
  let windowSize = 0;
  const headerSize = 5 + (singleSegment ? 0 : 1) + dictBytes + fcsBytes;
  if (data.length < headerSize) corrupt('the zstd frame header is cut short');
  if (!singleSegment) {
    const wd = data[pos++];
    const windowLog = 10 + (wd >>> 3);
    const base = 2 ** windowLog;
    windowSize = base + (base / 8) * (wd & 7);
  }
  let dictId = 0;
  for (let i = 0; i < dictBytes; i++) dictId += data[pos + i] * 2 ** (8 * i);
  pos += dictBytes;
  let contentSize = -1;
  if (fcsBytes) {
    contentSize = 0;
    for (let i = 0; i < fcsBytes; i++) contentSize += data[pos + i] * 2 ** (8 * i);
    if (fcsBytes === 2) contentSize += 256;
  }
  if (singleSegment) windowSize = contentSize;
  return { headerSize, contentSize, windowSize, checksum, dictId, singleSegment: singleSegment === 1 };
}

/**
 * Walk the block headers of the frame that starts `data`; return where the frame ends. Every
 * block's Block_Size (for an RLE block, the size it regenerates) is at most the block maximum.
 * @param {Uint8Array} data
 * @param {FrameHeader} header
 * @returns {number}
 */
function frameEnd(data, header) {
  const blockMax = Math.min(header.windowSize, BLOCK_SIZE_MAX);
  let pos = header.headerSize;
  for (;;) {
    if (pos + 3 > data.length) corrupt('the zstd frame ends early');
    const h = data[pos] | (data[pos + 1] << 8) | (data[pos + 2] << 16);
    pos += 3;
    const type = (h >>> 1) & 3;
    const size = h >>> 3;
    if (type === 3) corrupt('zstd block of the reserved type');
    if (size > blockMax) corrupt('zstd block larger than the block maximum');
    pos += type === 1 ? 1 : size;
    if (h & 1) break;
  }
  pos += header.checksum ? 4 : 0;
  if (pos > data.length) corrupt('the zstd frame ends early');
  return pos;
}

// ------------------------------------------------------------------------------ bitstreams
/** Index of the highest set bit of a positive 32-bit integer. */
function highbit(v) {
  return 31 - Math.clz32(v);
}

/**
 * A zstd bitstream (RFC 8878 4.1): written forward, read backward from the bit below the final
 * 1-bit of its last byte. `pos` counts the bits not read yet; a read past the first bit gives
 * zeros and leaves `pos` negative ("overflow").
 */
class BackwardBits {
  /**
   * @param {Uint8Array} data
   * @param {number} start
   * @param {number} end one past the last byte of the stream
   */
  constructor(data, start, end) {
    if (end <= start) corrupt('empty zstd bitstream');
    const last = data[end - 1];
    if (last === 0) corrupt('zstd bitstream without its final bit');
    this.data = data;
    this.start = start;
    this.end = end;
    this.pos = (end - start - 1) * 8 + highbit(last);
  }

  /** The byte at `i` bytes from the start of the stream, 0 outside it. */
  byte(i) {
    return i >= 0 && this.start + i < this.end ? this.data[this.start + i] : 0;
  }

  /**
   * The next `n` bits (0 <= n <= 31), the first read being the most significant.
   * @param {number} n
   * @returns {number}
   */
  read(n) {
    if (n === 0) return 0;
    const lo = this.pos - n;
    this.pos = lo;
    return this.bitsAt(lo, n);
  }

  /** `n` bits starting at bit index `lo` (may be negative: zeros below the stream). */
  bitsAt(lo, n) {
    if (lo >= 0) {
      const i = lo >>> 3;
      const shift = lo & 7;
      if (n + shift <= 24) {
        const d = this.data;
        const s = this.start + i;
        const v = s + 2 < this.end ? d[s] | (d[s + 1] << 8) | (d[s + 2] << 16)
          : this.byte(i) | (this.byte(i + 1) << 8) | (this.byte(i + 2) << 16);
        return (v >>> shift) & ((1 << n) - 1);
      }
    }
    // general case: up to 31 bits at any position, with zeros below the stream
    let value = 0;
    for (let k = n - 1; k >= 0; k--) {
      const b = lo + k;
      const bit = b < 0 ? 0 : (this.byte(b >>> 3) >>> (b & 7)) & 1;
      value = value * 2 + bit;
    }
    return value;
  }
}

// ------------------------------------------------------------------------------ FSE tables
/**
 * A normalized distribution (RFC 8878 4.1.1), read as libzstd's FSE_readNCount reads it, from
 * `data[start, end)`.
 * @param {Uint8Array} data
 * @param {number} start
 * @param {number} end
 * @param {number} maxSymbol the largest symbol the table may describe
 * @returns {{counts: Int16Array, maxSymbol: number, tableLog: number, size: number}}
 */
function readDistribution(data, start, end, maxSymbol) {
  const avail = (end - start) * 8;
  let bit = 0;
  const peek = (n) => {
    let v = 0;
    for (let k = 0; k < n; k++) {
      const b = bit + k;
      const byte = b >>> 3;
      if (start + byte < end) v |= ((data[start + byte] >>> (b & 7)) & 1) << k;
    }
    return v;
  };
  if (end <= start) corrupt('zstd FSE table description missing');
  const tableLog = (peek(4)) + 5;
  bit = 4;
  if (tableLog > 15) corrupt('zstd FSE accuracy log too large');
  const counts = new Int16Array(maxSymbol + 1);
  let remaining = (1 << tableLog) + 1;
  let threshold = 1 << tableLog;
  let nbBits = tableLog + 1;
  let symbol = 0;
  let previous0 = false;
  let tooMany = false;
  for (;;) {
    if (previous0) {
      let repeat = peek(2);
      bit += 2;
      while (repeat === 3) {
        symbol += 3;
        repeat = peek(2);
        bit += 2;
      }
      symbol += repeat;
      if (symbol > maxSymbol) {
        tooMany = true;
        break;
      }
    }
    const max = 2 * threshold - 1 - remaining;
    let count;
    const low = peek(nbBits - 1);
    if (low < max) {
      count = low;
      bit += nbBits - 1;
    } else {
      count = peek(nbBits);
      if (count >= threshold) count -= max;
      bit += nbBits;
    }
    count--;
    if (count >= 0) remaining -= count;
    else remaining += count;
    counts[symbol++] = count;
    previous0 = count === 0;
    if (remaining < threshold) {
      if (remaining <= 1) break;
      nbBits = highbit(remaining) + 1;
      threshold = 1 << (nbBits - 1);
    }
    if (symbol > maxSymbol) break;
  }
  if (remaining !== 1) corrupt('zstd FSE distribution does not sum to its table size');
  if (tooMany) corrupt('zstd FSE distribution runs past its largest symbol');
  if (bit > avail) corrupt('zstd FSE table description runs past its data');
  return { counts, maxSymbol: symbol - 1, tableLog, size: (bit + 7) >>> 3 };
}

/**
 * An FSE decoding table: per state, the symbol, the bits to read and the base of the next state.
 * @typedef {{log: number, symbol: Uint8Array, bits: Uint8Array, base: Uint16Array}} FseTable
 */

/**
 * @param {Int16Array | number[]} counts
 * @param {number} maxSymbol
 * @param {number} tableLog
 * @returns {FseTable}
 */
function buildFse(counts, maxSymbol, tableLog) {
  const size = 1 << tableLog;
  const symbol = new Uint8Array(size);
  const bits = new Uint8Array(size);
  const base = new Uint16Array(size);
  const next = new Uint16Array(maxSymbol + 1);
  let high = size - 1;
  for (let s = 0; s <= maxSymbol; s++) {
    if (counts[s] === -1) {
      symbol[high--] = s;
      next[s] = 1;
    } else {
      next[s] = Math.max(counts[s], 0);
    }
  }
  const step = (size >>> 1) + (size >>> 3) + 3;
  const mask = size - 1;
  let position = 0;
  for (let s = 0; s <= maxSymbol; s++) {
    for (let i = 0; i < counts[s]; i++) {
      symbol[position] = s;
      do position = (position + step) & mask; while (position > high);
    }
  }
  if (position !== 0) corrupt('zstd FSE distribution is inconsistent');
  for (let u = 0; u < size; u++) {
    const state = next[symbol[u]]++;
    const nb = tableLog - highbit(state);
    bits[u] = nb;
    base[u] = (state << nb) - size;
  }
  return { log: tableLog, symbol, bits, base };
}

// ------------------------------------------------------------------------------ Huffman
/**
 * A Huffman decoding table for literals: `symbol` and `bits` indexed by the next `log` bits.
 * @typedef {{log: number, symbol: Uint8Array, bits: Uint8Array}} HuffmanTable
 */

/**
 * A Huffman tree description (RFC 8878 4.2.1), read as libzstd's HUF_readStats reads it, from
 * `data[start, end)`.
 * @param {Uint8Array} data
 * @param {number} start
 * @param {number} end
 * @returns {{table: HuffmanTable, size: number}}
 */
function readHuffmanTree(data, start, end) {
  if (end <= start) corrupt('zstd Huffman tree description missing');
  const weights = new Uint8Array(256);
  let count;
  let size = data[start];
  if (size >= 128) {
    count = size - 127;
    size = (count + 1) >>> 1;
    if (start + 1 + size > end) corrupt('zstd Huffman tree description runs past the literals');
    for (let n = 0; n < count; n += 2) {
      const b = data[start + 1 + n / 2];
      weights[n] = b >>> 4;
      weights[n + 1] = b & 15;
    }
  } else {
    if (start + 1 + size > end) corrupt('zstd Huffman tree description runs past the literals');
    count = decodeWeights(data, start + 1, start + 1 + size, weights);
  }
  const rank = new Uint32Array(13);
  let total = 0;
  for (let n = 0; n < count; n++) {
    if (weights[n] > 12) corrupt('zstd Huffman weight above 12');
    rank[weights[n]]++;
    total += (1 << weights[n]) >>> 1;
  }
  if (total === 0) corrupt('zstd Huffman tree without weights');
  const log = highbit(total) + 1;
  if (log > 12) corrupt('zstd Huffman tree deeper than 12 bits');
  const rest = (1 << log) - total;
  if (rest !== 1 << highbit(rest)) corrupt('zstd Huffman weights do not complete a tree');
  const lastWeight = highbit(rest) + 1;
  weights[count] = lastWeight;
  rank[lastWeight]++;
  if (rank[1] < 2 || rank[1] & 1) corrupt('zstd Huffman tree with an odd count of weight-1 symbols');
  const symbols = count + 1;
  // canonical codes: by weight, then symbol; the lowest weights take the lowest codes
  const tableSize = 1 << log;
  const symbol = new Uint8Array(tableSize);
  const bits = new Uint8Array(tableSize);
  let next = 0;
  for (let w = 1; w <= log; w++) {
    const nb = log + 1 - w;
    const span = 1 << (log - nb);
    for (let s = 0; s < symbols; s++) {
      if (weights[s] !== w) continue;
      symbol.fill(s, next, next + span);
      bits.fill(nb, next, next + span);
      next += span;
    }
  }
  if (next !== tableSize) corrupt('zstd Huffman weights do not complete a tree');
  return { table: { log, symbol, bits }, size: size + 1 };
}

/**
 * Huffman weights coded with FSE (RFC 8878 4.2.1.2): two interleaved states, read until the
 * bitstream overflows, as libzstd's FSE_decompress does. Returns the number of weights.
 * @param {Uint8Array} data
 * @param {number} start
 * @param {number} end
 * @param {Uint8Array} out
 * @returns {number}
 */
function decodeWeights(data, start, end, out) {
  const dist = readDistribution(data, start, end, 255);
  if (dist.tableLog > 6) corrupt('zstd Huffman weights with an FSE accuracy log above 6');
  // libzstd decodes the weights in a fixed workspace, sized for accuracy log 6 and symbols up
  // to 11: a distribution that needs more (a symbol above 11 at accuracy log 6, above 91 at 5)
  // is refused, whether or not the symbol is ever decoded
  if (dist.maxSymbol > (dist.tableLog === 6 ? 11 : 91)) {
    corrupt('zstd Huffman weight distribution with too large a symbol');
  }
  const table = buildFse(dist.counts, dist.maxSymbol, dist.tableLog);
  const bits = new BackwardBits(data, start + dist.size, end);
  let state1 = bits.read(table.log);
  let state2 = bits.read(table.log);
  if (bits.pos < 0) corrupt('zstd Huffman weights: the initial states are cut short');
  let n = 0;
  for (;;) {
    if (n > 253) corrupt('zstd Huffman tree with more than 255 weights');
    out[n++] = table.symbol[state1];
    state1 = table.base[state1] + bits.read(table.bits[state1]);
    if (bits.pos < 0) {
      out[n++] = table.symbol[state2];
      break;
    }
    if (n > 253) corrupt('zstd Huffman tree with more than 255 weights');
    out[n++] = table.symbol[state2];
    state2 = table.base[state2] + bits.read(table.bits[state2]);
    if (bits.pos < 0) {
      out[n++] = table.symbol[state1];
      break;
    }
  }
  return n;
}

/**
 * Decode one Huffman-coded stream into `out[from, to)`: exactly that many literals, ending
 * exactly at the stream's first bit (RFC 8878 4.2.2).
 * @param {Uint8Array} data
 * @param {number} start
 * @param {number} end
 * @param {HuffmanTable} table
 * @param {Uint8Array} out
 * @param {number} from
 * @param {number} to
 */
function decodeHuffmanStream(data, start, end, table, out, from, to) {
  const bits = new BackwardBits(data, start, end);
  const { log, symbol, bits: lengths } = table;
  let pos = bits.pos;
  for (let i = from; i < to; i++) {
    const v = bits.bitsAt(pos - log, log);
    out[i] = symbol[v];
    pos -= lengths[v];
    if (pos < 0) corrupt('zstd Huffman stream read past its start');
  }
  if (pos !== 0) corrupt('zstd Huffman stream does not end where its literals end');
}

// ------------------------------------------------------------------------------ sequences
const LL_BASE = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 18, 20, 22, 24, 28, 32,
  40, 48, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768, 65536];
const LL_BITS = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 3, 3, 4, 6, 7, 8,
  9, 10, 11, 12, 13, 14, 15, 16];
const ML_BASE = [3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25,
  26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 37, 39, 41, 43, 47, 51, 59, 67, 83, 99, 131, 259, 515,
  1027, 2051, 4099, 8195, 16387, 32771, 65539];
const ML_BITS = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
  0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 3, 3, 4, 4, 5, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16];
const LL_MAX = 35;
const ML_MAX = 52;
const OF_MAX = 31;

/** The predefined distributions (RFC 8878 3.1.1.3.2.2), as tables. */
const PREDEFINED = {
  ll: buildFse([4, 3, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 1, 1, 1, 2, 2, 2, 2, 2, 2, 2, 2, 2, 3, 2, 1,
    1, 1, 1, 1, -1, -1, -1, -1], 35, 6),
  of: buildFse([1, 1, 1, 1, 1, 1, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, -1, -1,
    -1, -1, -1], 28, 5),
  ml: buildFse([1, 4, 3, 2, 2, 2, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1,
    1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, -1, -1, -1, -1, -1, -1, -1], 52, 6),
};

/**
 * One of the three tables of a sequences section (RFC 8878 3.1.1.3.2.1), read at `pos`.
 * @param {number} mode 0 predefined, 1 RLE, 2 FSE-compressed, 3 repeat
 * @param {Uint8Array} data
 * @param {number} pos
 * @param {number} end
 * @param {number} maxSymbol
 * @param {number} maxLog
 * @param {FseTable} predefined
 * @param {FseTable | null} previous
 * @returns {{table: FseTable, size: number}}
 */
function readSequenceTable(mode, data, pos, end, maxSymbol, maxLog, predefined, previous) {
  if (mode === 0) return { table: predefined, size: 0 };
  if (mode === 1) {
    if (pos >= end) corrupt('zstd RLE sequence table cut short');
    if (data[pos] > maxSymbol) corrupt('zstd RLE sequence code out of range');
    const table = { log: 0, symbol: new Uint8Array([data[pos]]), bits: new Uint8Array(1),
      base: new Uint16Array(1) };
    return { table, size: 1 };
  }
  if (mode === 3) {
    if (!previous) corrupt('zstd repeated sequence table without a previous one');
    return { table: previous, size: 0 };
  }
  const dist = readDistribution(data, pos, end, maxSymbol);
  if (dist.tableLog > maxLog) corrupt('zstd sequence table accuracy log too large');
  return { table: buildFse(dist.counts, dist.maxSymbol, dist.tableLog), size: dist.size };
}

// ------------------------------------------------------------------------------ blocks
/**
 * What a frame carries from block to block.
 * @typedef {object} FrameState
 * @property {Uint8Array} out the frame's output
 * @property {number} produced bytes written to `out`
 * @property {number} blockMax Block_Maximum_Size
 * @property {HuffmanTable | null} huffman the last Huffman tree of the frame
 * @property {boolean} sequencesSeen a block with sequences was decoded (repeat tables allowed)
 * @property {FseTable[]} tables the last literal-length, offset and match-length tables
 * @property {number[]} rep the repeated offsets
 * @property {Uint8Array} literals scratch buffer for a block's literals
 */

/**
 * The literals section of a compressed block (RFC 8878 3.1.1.3.1), decoded into
 * `state.literals` or referenced in place; libzstd's checks, and Huffman streams read exactly.
 * @param {Uint8Array} data
 * @param {number} pos
 * @param {number} end
 * @param {FrameState} state
 * @returns {{literals: Uint8Array, size: number}}
 */
function decodeLiterals(data, pos, end, state) {
  const srcSize = end - pos;
  if (srcSize < 2) corrupt('zstd compressed block too short');
  const b0 = data[pos];
  const type = b0 & 3;
  const sizeFormat = (b0 >>> 2) & 3;
  const capacity = Math.min(state.blockMax, state.out.length - state.produced);
  if (type === 0 || type === 1) {
    let headerSize;
    let litSize;
    if (sizeFormat === 1) {
      headerSize = 2;
      litSize = (b0 >>> 4) | (data[pos + 1] << 4);
    } else if (sizeFormat === 3) {
      headerSize = 3;
      if (srcSize < (type === 0 ? 3 : 4)) corrupt('zstd literals header cut short');
      litSize = (b0 >>> 4) | (data[pos + 1] << 4) | (data[pos + 2] << 12);
    } else {
      headerSize = 1;
      litSize = b0 >>> 3;
    }
    if (type === 1 && sizeFormat === 1 && srcSize < 3) corrupt('zstd literals header cut short');
    if (litSize > state.blockMax) corrupt('zstd literals larger than the block maximum');
    if (litSize > capacity) corrupt('zstd literals larger than the room left');
    if (type === 0) {
      if (headerSize + litSize > srcSize) corrupt('zstd raw literals run past the block');
      return { literals: data.subarray(pos + headerSize, pos + headerSize + litSize),
        size: headerSize + litSize };
    }
    const literals = state.literals.subarray(0, litSize);
    literals.fill(data[pos + headerSize]);
    return { literals, size: headerSize + 1 };
  }
  // Huffman-coded literals: type 2 with a tree, type 3 with the previous one
  if (type === 3 && !state.huffman) corrupt('zstd treeless literals without a previous tree');
  if (srcSize < 5) corrupt('zstd literals header cut short');
  const word = (data[pos] | (data[pos + 1] << 8) | (data[pos + 2] << 16) | (data[pos + 3] << 24)) >>> 0;
  let headerSize;
  let litSize;
  let compressedSize;
  if (sizeFormat <= 1) {
    headerSize = 3;
    litSize = (word >>> 4) & 0x3FF;
    compressedSize = (word >>> 14) & 0x3FF;
  } else if (sizeFormat === 2) {
    headerSize = 4;
    litSize = (word >>> 4) & 0x3FFF;
    compressedSize = word >>> 18;
  } else {
    headerSize = 5;
    litSize = (word >>> 4) & 0x3FFFF;
    compressedSize = (word >>> 22) + data[pos + 4] * 1024;
  }
  const single = sizeFormat === 0;
  if (litSize > state.blockMax) corrupt('zstd literals larger than the block maximum');
  if (!single && litSize < 6) corrupt('zstd four literal streams for fewer than 6 literals');
  if (compressedSize + headerSize > srcSize) corrupt('zstd Huffman literals run past the block');
  if (litSize > capacity) corrupt('zstd literals larger than the room left');
  let start = pos + headerSize;
  const stop = start + compressedSize;
  if (type === 2) {
    if (!single && compressedSize === 0) corrupt('zstd Huffman literals without data');
    const tree = readHuffmanTree(data, start, stop);
    if (tree.size >= compressedSize) corrupt('zstd Huffman literals without a stream');
    state.huffman = tree.table;
    start += tree.size;
  }
  const table = /** @type {HuffmanTable} */ (state.huffman);
  const literals = state.literals.subarray(0, litSize);
  if (single) {
    decodeHuffmanStream(data, start, stop, table, literals, 0, litSize);
  } else {
    if (stop - start < 10) corrupt('zstd four literal streams in fewer than 10 bytes');
    const l1 = data[start] | (data[start + 1] << 8);
    const l2 = data[start + 2] | (data[start + 3] << 8);
    const l3 = data[start + 4] | (data[start + 5] << 8);
    const s1 = start + 6;
    const s2 = s1 + l1;
    const s3 = s2 + l2;
    const s4 = s3 + l3;
    if (s4 > stop) corrupt('zstd literal streams run past the literals');
    const segment = (litSize + 3) >>> 2;
    decodeHuffmanStream(data, s1, s2, table, literals, 0, segment);
    decodeHuffmanStream(data, s2, s3, table, literals, segment, 2 * segment);
    decodeHuffmanStream(data, s3, s4, table, literals, 2 * segment, 3 * segment);
    decodeHuffmanStream(data, s4, stop, table, literals, 3 * segment, litSize);
  }
  return { literals, size: headerSize + compressedSize };
}

/**
 * A compressed block (RFC 8878 3.1.1.3): literals, sequences, their execution into `state.out`.
 * @param {Uint8Array} data
 * @param {number} pos
 * @param {number} end
 * @param {FrameState} state
 */
function decodeCompressedBlock(data, pos, end, state) {
  const { literals, size } = decodeLiterals(data, pos, end, state);
  pos += size;
  const out = state.out;
  const blockStart = state.produced;
  const limit = Math.min(blockStart + state.blockMax, out.length);
  if (end - pos < 1) corrupt('zstd sequences section missing');
  let count = data[pos++];
  if (count > 0x7F) {
    if (count === 0xFF) {
      if (pos + 2 > end) corrupt('zstd sequence count cut short');
      count = (data[pos] | (data[pos + 1] << 8)) + 0x7F00;
      pos += 2;
    } else {
      if (pos >= end) corrupt('zstd sequence count cut short');
      count = ((count - 0x80) << 8) + data[pos++];
    }
  }
  let op = blockStart;
  let lit = 0;
  if (count > 0) {
    if (pos + 1 > end) corrupt('zstd sequence modes cut short');
    const modes = data[pos++];
    if (modes & 3) corrupt('zstd sequence modes with reserved bits set');
    const seen = state.sequencesSeen;
    const ll = readSequenceTable(modes >>> 6, data, pos, end, LL_MAX, 9, PREDEFINED.ll,
      seen ? state.tables[0] : null);
    pos += ll.size;
    const of = readSequenceTable((modes >>> 4) & 3, data, pos, end, OF_MAX, 8, PREDEFINED.of,
      seen ? state.tables[1] : null);
    pos += of.size;
    const ml = readSequenceTable((modes >>> 2) & 3, data, pos, end, ML_MAX, 9, PREDEFINED.ml,
      seen ? state.tables[2] : null);
    pos += ml.size;
    state.tables = [ll.table, of.table, ml.table];
    state.sequencesSeen = true;
    const bits = new BackwardBits(data, pos, end);
    const llT = ll.table;
    const ofT = of.table;
    const mlT = ml.table;
    let llState = bits.read(llT.log);
    let ofState = bits.read(ofT.log);
    let mlState = bits.read(mlT.log);
    const rep = state.rep.slice();
    for (let n = count; n > 0; n--) {
      const llCode = llT.symbol[llState];
      const ofCode = ofT.symbol[ofState];
      const mlCode = mlT.symbol[mlState];
      let offsetValue = ofCode === 0 ? 1 : 2 ** ofCode + bits.read(ofCode);
      const matchLength = ML_BASE[mlCode] + bits.read(ML_BITS[mlCode]);
      const literalLength = LL_BASE[llCode] + bits.read(LL_BITS[llCode]);
      if (n > 1) {
        llState = llT.base[llState] + bits.read(llT.bits[llState]);
        mlState = mlT.base[mlState] + bits.read(mlT.bits[mlState]);
        ofState = ofT.base[ofState] + bits.read(ofT.bits[ofState]);
      }
      if (bits.pos < 0) corrupt('zstd sequence bitstream read past its start');
      let offset;
      if (offsetValue > 3) {
        offset = offsetValue - 3;
        rep[2] = rep[1];
        rep[1] = rep[0];
        rep[0] = offset;
      } else {
        const index = offsetValue - 1 + (literalLength === 0 ? 1 : 0);
        if (index === 0) {
          offset = rep[0];
        } else {
          offset = index === 3 ? rep[0] - 1 : rep[index];
          if (offset === 0) corrupt('zstd repeated offset of 0');
          if (index !== 1) rep[2] = rep[1];
          rep[1] = rep[0];
          rep[0] = offset;
        }
      }
      offsetValue = 0;
      if (op + literalLength + matchLength > limit) corrupt('zstd sequence writes past the block');
      if (literalLength > literals.length - lit) corrupt('zstd sequence reads past the literals');
      if (literalLength > 0) {
        if (literalLength > 32) out.set(literals.subarray(lit, lit + literalLength), op);
        else for (let i = 0; i < literalLength; i++) out[op + i] = literals[lit + i];
        op += literalLength;
        lit += literalLength;
      }
      if (offset > op) corrupt('zstd match reaches before the start of the frame');
      let from = op - offset;
      if (offset >= matchLength) {
        if (matchLength > 32) out.copyWithin(op, from, from + matchLength);
        else for (let i = 0; i < matchLength; i++) out[op + i] = out[from + i];
        op += matchLength;
      } else {
        for (let i = 0; i < matchLength; i++) out[op++] = out[from++];
      }
    }
    if (bits.pos !== 0) corrupt('zstd sequence bitstream does not end where its sequences end');
    state.rep = rep;
  } else if (pos !== end) {
    corrupt('zstd block has bytes after an empty sequences section');
  }
  const rest = literals.length - lit;
  if (op + rest > limit) corrupt('zstd literals write past the block');
  out.set(literals.subarray(lit), op);
  state.produced = op + rest;
}

/**
 * Inflate a zstd section into exactly `rawLength` bytes ([R-22], [R-24], [R-25]).
 * @param {Uint8Array} stored
 * @param {number} rawLength
 * @returns {Uint8Array}
 */
export function inflateZstd(stored, rawLength) {
  const header = readFrameHeader(stored);
  if (header.contentSize < 0) corrupt('zstd frame does not declare its content size');
  if (header.contentSize !== rawLength) {
    throw new SpcError('length-mismatch', `zstd frame declares ${header.contentSize} bytes, ` +
      `the section ${rawLength}`);
  }
  if (header.windowSize > ZSTD_MAX_WINDOW) corrupt('zstd frame needs a window above 128 MiB');
  if (header.dictId !== 0) corrupt('zstd frame needs a dictionary');
  const end = frameEnd(stored, header);
  if (end !== stored.length) corrupt('bytes follow the zstd frame');
  const blockMax = Math.min(header.windowSize, BLOCK_SIZE_MAX);
  /** @type {FrameState} */
  const state = {
    out: allocate(Uint8Array, rawLength),
    produced: 0,
    blockMax,
    huffman: null,
    sequencesSeen: false,
    tables: [],
    rep: [1, 4, 8],
    literals: new Uint8Array(blockMax),
  };
  let pos = header.headerSize;
  for (;;) {
    const h = stored[pos] | (stored[pos + 1] << 8) | (stored[pos + 2] << 16);
    pos += 3;
    const type = (h >>> 1) & 3;
    const size = h >>> 3;
    const room = rawLength - state.produced;
    if (type === 0) {
      if (size > room) corrupt('zstd frame inflates past its content size');
      state.out.set(stored.subarray(pos, pos + size), state.produced);
      state.produced += size;
      pos += size;
    } else if (type === 1) {
      if (size > room) corrupt('zstd frame inflates past its content size');
      state.out.fill(stored[pos], state.produced, state.produced + size);
      state.produced += size;
      pos += 1;
    } else {
      decodeCompressedBlock(stored, pos, pos + size, state);
      pos += size;
    }
    if (h & 1) break;
  }
  if (state.produced !== rawLength) {
    corrupt(`zstd frame inflates to ${state.produced} bytes, declared ${rawLength}`);
  }
  const out = state.out;
  if (header.checksum) {
    const want = (stored[pos] | (stored[pos + 1] << 8) | (stored[pos + 2] << 16) | (stored[pos + 3] << 24)) >>> 0;
    if (xxh64Low32(out) !== want) corrupt('zstd content checksum mismatch');
  }
  return out;
}
