/**
 * IEEE 754 binary16 values, converted exactly (every binary16 is a binary32) through a table.
 */

/** All 65536 binary16 bit patterns as binary32 values. */
export const HALF_TO_FLOAT = (() => {
  const t = new Float32Array(65536);
  for (let h = 0; h < 65536; h++) {
    const sign = h & 0x8000 ? -1 : 1;
    const exp = (h >>> 10) & 0x1F;
    const mant = h & 0x3FF;
    if (exp === 0) t[h] = sign * mant * 2 ** -24;
    else if (exp === 31) t[h] = mant ? NaN : sign * Infinity;
    else t[h] = sign * (1 + mant / 1024) * 2 ** (exp - 15);
  }
  return t;
})();

/**
 * @param {number} h binary16 bit pattern
 * @returns {boolean} whether it encodes a finite value
 */
export function isFiniteHalf(h) {
  return (h & 0x7C00) !== 0x7C00;
}

/**
 * `count` little-endian u16 words (binary16 bit patterns, QUANT16 codes) starting at byte
 * `offset` of `bytes`: a view when aligned, else a copy. (The package assumes a little-endian
 * host, as every WebAssembly and browser platform is.)
 * @param {Uint8Array} bytes
 * @param {number} offset
 * @param {number} count
 * @returns {Uint16Array}
 */
export function u16Words(bytes, offset, count) {
  const start = bytes.byteOffset + offset;
  if (start % 2 === 0) return new Uint16Array(bytes.buffer, start, count);
  const copy = new Uint8Array(count * 2);
  copy.set(bytes.subarray(offset, offset + count * 2));
  return new Uint16Array(copy.buffer);
}
