/**
 * INRIA 3DGS PLY output: the same header and vertex layout `spcodec decode` writes (binary
 * little-endian float32; x y z, zero normals, f_dc_0..2, f_rest channel-major, opacity,
 * scale_0..2, rot_0..3).
 */

/**
 * Property names of the vertex record for a scene of SH degree `sh`.
 * @param {number} sh
 * @returns {string[]}
 */
export function plyProperties(sh) {
  const k = (sh + 1) ** 2 - 1;
  return ['x', 'y', 'z', 'nx', 'ny', 'nz', 'f_dc_0', 'f_dc_1', 'f_dc_2',
    ...Array.from({ length: 3 * k }, (_, i) => `f_rest_${i}`),
    'opacity', 'scale_0', 'scale_1', 'scale_2', 'rot_0', 'rot_1', 'rot_2', 'rot_3'];
}

/**
 * The whole PLY file for a cloud.
 * @param {import('./decoder.js').Cloud} cloud
 * @returns {Uint8Array}
 */
export function plyBytes(cloud) {
  const sh = cloud.shDegree;
  const k = (sh + 1) ** 2 - 1;
  const names = plyProperties(sh);
  const header = ['ply', 'format binary_little_endian 1.0', 'comment written by spcodec',
    `element vertex ${cloud.count}`, ...names.map((n) => `property float ${n}`), 'end_header', ''].join('\n');
  const head = new TextEncoder().encode(header);
  const width = names.length;
  const n = cloud.count;
  const body = new Float32Array(n * width);
  const { positions, scales, rotations, opacities, shDC, shRest } = cloud;
  const rest = 9;
  const after = rest + 3 * k;
  for (let i = 0; i < n; i++) {
    const o = i * width;
    body[o] = positions[3 * i];
    body[o + 1] = positions[3 * i + 1];
    body[o + 2] = positions[3 * i + 2];
    body[o + 6] = shDC[3 * i];
    body[o + 7] = shDC[3 * i + 1];
    body[o + 8] = shDC[3 * i + 2];
    const base = 3 * k * i;
    for (let c = 0; c < 3; c++) {
      for (let j = 0; j < k; j++) body[o + rest + c * k + j] = shRest[base + 3 * j + c];
    }
    body[o + after] = opacities[i];
    body[o + after + 1] = scales[3 * i];
    body[o + after + 2] = scales[3 * i + 1];
    body[o + after + 3] = scales[3 * i + 2];
    body[o + after + 4] = rotations[4 * i];
    body[o + after + 5] = rotations[4 * i + 1];
    body[o + after + 6] = rotations[4 * i + 2];
    body[o + after + 7] = rotations[4 * i + 3];
  }
  const out = new Uint8Array(head.length + body.byteLength);
  out.set(head);
  out.set(new Uint8Array(body.buffer), head.length);
  return out;
}
