/**
 * The one error type the decoder throws on bad input (spec section 12).
 *
 * Every malformed, truncated or over-limit input raises an {@link SpcError} whose `code` is one of
 * the stable codes of spec/bitstream-v1.md section 12, so an application catches one type and can
 * tell a truncated download (`truncated`) from a corrupt file (`section-crc`, ...).
 */

/** Every error code the specification defines (section 12), with a one-line meaning. */
export const ERROR_CODES = Object.freeze({
  'bad-magic': 'the data does not start with the spcodec magic or a gzip header',
  'unsupported-version': 'the major version is not 1',
  'reserved-nonzero': 'a reserved field or flag bit is not zero',
  'truncated': 'the data ends inside the header or inside a layer',
  'trailing-data': 'bytes follow the end of the last section or the gzip member',
  'header-crc': 'the header CRC-32 does not match',
  'section-crc': "a section's CRC-32 does not match its stored bytes",
  'limit-exceeded': "a declared count or size exceeds the decoder's limits",
  'bad-layout': 'the layer table or table of contents is inconsistent',
  'unknown-codec': 'a section uses a codec id this decoder does not know',
  'codec-unavailable': 'a section uses a known codec this decoder lacks',
  'unknown-required-section': 'a required section has a type this decoder does not know',
  'missing-section': 'a layer lacks a section it must contain',
  'duplicate-section': 'a layer contains a section type more than once',
  'decompression-failed': 'a compressed section is corrupt, short, or followed by bytes',
  'length-mismatch': 'a section inflates to a length other than its declared raw length',
  'bad-section': "a section's payload is inconsistent with its declared structure",
  'bad-value': 'a value is out of its allowed range or not finite',
  'draco-failed': 'a Draco position blob cannot be decoded or has the wrong point count',
  'bad-gzip': 'the gzip wrapper is corrupt',
  'bad-metadata': 'the metadata section is not a UTF-8 JSON object',
});

/** A malformed input: `code` is the spec's stable error code (section 12). */
export class SpcError extends Error {
  /**
   * @param {keyof typeof ERROR_CODES} code
   * @param {string} message one line naming the problem
   */
  constructor(code, message) {
    super(`${message} [${code}]`);
    this.name = 'SpcError';
    /** @type {string} */
    this.code = code;
  }
}

/**
 * Throw an {@link SpcError}; an expression form for `cond || fail(...)` style checks.
 * @param {keyof typeof ERROR_CODES} code
 * @param {string} message
 * @returns {never}
 */
export function fail(code, message) {
  throw new SpcError(code, message);
}

/**
 * Allocate a typed array, turning an allocation failure into `limit-exceeded`: a valid file may
 * still be larger than this JavaScript engine can hold, and that must not escape as a RangeError.
 * @template T
 * @param {new (n: number) => T} Type
 * @param {number} length
 * @returns {T}
 */
export function allocate(Type, length) {
  try {
    return new Type(length);
  } catch (err) {
    if (err instanceof RangeError) {
      throw new SpcError('limit-exceeded', `cannot allocate ${length} elements (${err.message})`);
    }
    throw err;
  }
}
