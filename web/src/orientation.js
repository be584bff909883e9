// Which way is up: the rotation that stands a scene upright in a +Y-up world (glTF's, and
// PlayCanvas's and three.js's), from the up axis an .spc stores in its metadata
// (`spcodec encode --up`), and the same rotation applied to positions.

const H = Math.SQRT1_2;
const UP_TO_Y = {  // (x, y, z, w) quaternions turning a signed axis into +Y (as spcodec's glTF)
  '+y': [0, 0, 0, 1], '-y': [1, 0, 0, 0], '+z': [-H, 0, 0, H], '-z': [H, 0, 0, H],
  '+x': [0, 0, H, H], '-x': [0, 0, -H, H],
};

/**
 * The rotation (x, y, z, w) that stands a scene upright in a +Y-up world: from its up axis, a
 * signed axis name (`-y`, `+z`, `z`) or a vector ("0,0,1"); null or '' means -y, the encoder's
 * default (COLMAP-derived scenes). The same rotations `spcodec decode -o x.glb` puts on its node.
 * @param {string|number[]|null|undefined} up
 * @returns {number[]}
 */
export function upRotation(up) {
  if (up == null || up === '') return UP_TO_Y['-y'];
  if (typeof up === 'string' && !up.includes(',')) {
    const key = /^[+-]/.test(up) ? up.toLowerCase() : `+${up.toLowerCase()}`;
    if (!(key in UP_TO_Y)) throw new Error(`unknown up axis "${up}": one of +x -x +y -y +z -z`);
    return UP_TO_Y[key];
  }
  const v = normalize(typeof up === 'string' ? up.split(',').map(Number) : up);
  if (v.length !== 3 || !v.every(Number.isFinite)) throw new Error(`up needs 3 numbers, got "${up}"`);
  if (v[1] < -1 + 1e-9) return UP_TO_Y['-y'];
  // the shortest arc from v to +Y: axis v x Y, half-angle quaternion
  const axis = [-v[2], 0, v[0]];  // v x (0, 1, 0)
  const w = 1 + v[1];
  const length = Math.hypot(axis[0], axis[1], axis[2], w);
  return [axis[0] / length, axis[1] / length, axis[2] / length, w / length];
}

/**
 * `positions` (xyz) turned by the unit quaternion `q` (x, y, z, w): where a rotated entity shows
 * them, for framing the camera.
 * @param {Float32Array} positions
 * @param {number[]} q
 * @returns {Float32Array}
 */
export function rotatePositions(positions, q) {
  const [x, y, z, w] = q;
  const out = new Float32Array(positions.length);
  for (let i = 0; i < positions.length; i += 3) {
    const vx = positions[i], vy = positions[i + 1], vz = positions[i + 2];
    // v + 2w (q x v) + 2 q x (q x v)
    const cx = y * vz - z * vy, cy = z * vx - x * vz, cz = x * vy - y * vx;
    out[i] = vx + 2 * (w * cx + y * cz - z * cy);
    out[i + 1] = vy + 2 * (w * cy + z * cx - x * cz);
    out[i + 2] = vz + 2 * (w * cz + x * cy - y * cx);
  }
  return out;
}


function normalize(v) {
  const length = Math.hypot(...v) || 1;
  return v.map((x) => x / length);
}
