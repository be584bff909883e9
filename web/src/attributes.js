/**
 * Coded values to Gaussian parameters (spec section 5, [R-30]..[R-32]). Both are computed in
 * binary64 and rounded to binary32 when stored into a Float32Array, as the spec defines them.
 */

export const OPACITY_MIN = 1e-4;
export const QUAT_MIN_NORM = 1e-8;

/**
 * Opacity: the logit of the coded (activated) value clamped to [1e-4, 1 - 1e-4] ([R-32]).
 * @param {number} a
 * @returns {number}
 */
export function decodeOpacity(a) {
  const c = a < OPACITY_MIN ? OPACITY_MIN : a > 1 - OPACITY_MIN ? 1 - OPACITY_MIN : a;
  return Math.log(c / (1 - c));
}

/**
 * Rotation: the coded quaternion divided by its norm, or the identity when the norm is below
 * 1e-8 ([R-31]); written as (w, x, y, z) at `out[at..at+4)`.
 * The norm is the square root of the squares summed in component order; when that overflows
 * (finite components above ~1e154, which no binary16 source reaches) the quaternion is first
 * divided by its largest component.
 * @param {number} w
 * @param {number} x
 * @param {number} y
 * @param {number} z
 * @param {Float32Array} out
 * @param {number} at
 */
export function writeRotation(w, x, y, z, out, at) {
  let norm = Math.sqrt(w * w + x * x + y * y + z * z);
  if (norm === Infinity) {
    const big = Math.max(Math.abs(w), Math.abs(x), Math.abs(y), Math.abs(z));
    w /= big; x /= big; y /= big; z /= big;
    norm = Math.sqrt(w * w + x * x + y * y + z * z);
  }
  if (norm < QUAT_MIN_NORM) {
    out[at] = 1;
    out[at + 1] = 0;
    out[at + 2] = 0;
    out[at + 3] = 0;
    return;
  }
  out[at] = w / norm;
  out[at + 1] = x / norm;
  out[at + 2] = y / norm;
  out[at + 3] = z / norm;
}
