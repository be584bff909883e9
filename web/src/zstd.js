/**
 * zstd sections (codec 2, [R-22]..[R-25]): exactly one frame that declares its content size.
 *
 * fzstd decodes the blocks; everything the format requires beyond that is checked here first,
 * because fzstd does not: the frame header (reserved bit, dictionary, window at most 2^27,
 * declared content size equal to the section's raw length), every block header (type, size
 * against the block maximum), where the frame ends (nothing may follow it), and, after decoding,
 * the number of bytes produced and the content checksum (XXH64) when the frame declares one.
 */
import { Decompress } from 'fzstd';

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
  return { headerSize, contentSize, windowSize, checksum, dictId };
}

/**
 * Walk the block headers of the frame that starts `data`; return where the frame ends.
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
  const out = allocate(Uint8Array, rawLength);
  let produced = 0;
  const decoder = new Decompress((chunk) => {
    if (produced + chunk.length > rawLength) corrupt('zstd frame inflates past its content size');
    out.set(chunk, produced);
    produced += chunk.length;
  });
  try {
    decoder.push(stored, true);
  } catch (err) {
    if (err instanceof SpcError) throw err;
    corrupt(`zstd frame is corrupt (${err instanceof Error ? err.message : String(err)})`);
  }
  if (produced !== rawLength) corrupt(`zstd frame inflates to ${produced} bytes, declared ${rawLength}`);
  if (header.checksum) {
    const at = end - 4;
    const want = (stored[at] | (stored[at + 1] << 8) | (stored[at + 2] << 16) | (stored[at + 3] << 24)) >>> 0;
    if (xxh64Low32(out) !== want) corrupt('zstd content checksum mismatch');
  }
  return out;
}
