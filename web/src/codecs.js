/**
 * Section codecs (spec section 4.2): none, zlib and zstd, always inflated into exactly the
 * declared raw length ([R-22]..[R-25]).
 */
import { adler32 } from './checksums.js';
import { SpcError } from './errors.js';
import { DeflateError, OutputLimitError, RawInflater, padded } from './inflate.js';
import { inflateZstd } from './zstd.js';

export const CODEC_NONE = 0;
export const CODEC_ZLIB = 1;
export const CODEC_ZSTD = 2;

/** @type {Record<number, string>} */
export const CODEC_NAMES = { 0: 'none', 1: 'zlib', 2: 'zstd' };

/**
 * The raw payload of a section from its (CRC-checked) stored bytes.
 * @param {number} codec
 * @param {Uint8Array} stored
 * @param {number} rawLength
 * @returns {Uint8Array}
 */
export function decompress(codec, stored, rawLength) {
  if (codec === CODEC_NONE) {
    if (stored.length !== rawLength) {
      throw new SpcError('length-mismatch', `uncompressed section stores ${stored.length} bytes ` +
        `but declares ${rawLength}`);
    }
    return stored;
  }
  if (codec === CODEC_ZLIB) return inflateZlib(stored, rawLength);
  if (codec === CODEC_ZSTD) return inflateZstd(stored, rawLength);
  throw new SpcError('unknown-codec', `unknown codec id ${codec}`);
}

/**
 * @param {string} message
 * @returns {never}
 */
function corrupt(message) {
  throw new SpcError('decompression-failed', message);
}

/**
 * One zlib stream (RFC 1950, no preset dictionary) inflated into exactly `rawLength` bytes.
 *
 * As has it, at most `rawLength + 1` bytes are produced: a stream that needs to write a
 * byte past that is `length-mismatch` at that point (whatever follows). Otherwise the stream is
 * decoded to its end, and then, in this order: corrupt data, a stream cut short or a wrong
 * Adler-32 are `decompression-failed`, a length other than `rawLength` is `length-mismatch`, and
 * bytes after the stream are `decompression-failed`. (This is the order in which zlib, bounded
 * the same way, reports them to the reference decoder.)
 * @param {Uint8Array} stored
 * @param {number} rawLength
 * @returns {Uint8Array}
 */
export function inflateZlib(stored, rawLength) {
  if (stored.length < 2) corrupt('the zlib stream ends early');
  const cmf = stored[0];
  const flg = stored[1];
  if ((cmf & 15) !== 8) corrupt('zlib stream uses an unknown compression method');
  if ((cmf >>> 4) > 7) corrupt('zlib stream declares an invalid window size');
  if (((cmf << 8) | flg) % 31 !== 0) corrupt('zlib header check bits are wrong');
  if (flg & 0x20) corrupt('zlib stream needs a preset dictionary');
  const inflater = new RawInflater(rawLength + 1);
  inflater.setInput(padded(stored), stored.length, 2);
  try {
    inflater.run();
  } catch (err) {
    if (err instanceof OutputLimitError) tooLong(rawLength);
    if (err instanceof DeflateError) corrupt(`zlib stream is corrupt (${err.message})`);
    throw err;
  }
  const out = inflater.out.subarray(0, inflater.outLength);
  const at = inflater.endByte;
  if (at + 4 > stored.length) corrupt('the zlib stream ends early');
  const want = ((stored[at] << 24) | (stored[at + 1] << 16) | (stored[at + 2] << 8) | stored[at + 3]) >>> 0;
  if (adler32(out) !== want) corrupt('zlib stream fails its Adler-32 check');
  if (out.length > rawLength) tooLong(rawLength);
  if (out.length < rawLength) {
    throw new SpcError('length-mismatch', `section inflates to ${out.length} bytes, declared ${rawLength}`);
  }
  if (at + 4 !== stored.length) corrupt('bytes follow the end of the zlib stream');
  return out;
}

/**
 * @param {number} rawLength
 * @returns {never}
 */
function tooLong(rawLength) {
  throw new SpcError('length-mismatch', `section inflates past its declared raw length of ${rawLength} bytes`);
}
