// From the decoder's arrays to what the renderer takes, and a camera that frames a scene.
//
// PlayCanvas describes splats the way a 3DGS PLY does: one float array per PLY property (x, y, z,
// f_dc_*, opacity, scale_*, rot_*, f_rest_*). Handing it the decoded layer under those names makes
// the viewer render a layer as PlayCanvas renders the PLY `spcodec decode` writes, which the
// browser tests check pixel by pixel.

/**
 * The PLY-named property arrays of a decoded cloud (the decoder API's layout: positions xyz,
 * log-scales, rotations wxyz, opacity logits, SH DC, SH rest per Gaussian coefficient-major then
 * channel). f_rest is channel-major, as in the PLY.
 * @param {{count: number, shDegree: number, positions: Float32Array, scales: Float32Array,
 *   rotations: Float32Array, opacities: Float32Array, shDC: Float32Array, shRest: Float32Array}} cloud
 * @returns {Map<string, Float32Array>}
 */
export function plyProperties(cloud) {
  const n = cloud.count;
  const props = new Map();
  const columns = (names) => names.map((name) => {
    const column = new Float32Array(n);
    props.set(name, column);
    return column;
  });
  deinterleave(cloud.positions, n, columns(['x', 'y', 'z']));
  deinterleave(cloud.shDC, n, columns(['f_dc_0', 'f_dc_1', 'f_dc_2']));
  props.set('opacity', Float32Array.from(cloud.opacities));
  deinterleave(cloud.scales, n, columns(['scale_0', 'scale_1', 'scale_2']));
  deinterleave(cloud.rotations, n, columns(['rot_0', 'rot_1', 'rot_2', 'rot_3']));
  const k = (cloud.shDegree + 1) ** 2 - 1;
  const rest = columns(Array.from({ length: 3 * k }, (_, j) => `f_rest_${j}`));
  // source value j = coefficient * 3 + channel goes to PLY column channel * K + coefficient
  const targets = Array.from({ length: 3 * k }, (_, j) => rest[(j % 3) * k + Math.floor(j / 3)]);
  deinterleave(cloud.shRest, n, targets);
  return props;
}

/** Copy `n` records of `targets.length` interleaved values into one column each. Row by row:
 * reading the source in order is several times faster than a strided pass per column. */
function deinterleave(source, n, targets) {
  const width = targets.length;
  for (let i = 0, base = 0; i < n; i++, base += width) {
    for (let j = 0; j < width; j++) targets[j][i] = source[base + j];
  }
}

/**
 * A PlayCanvas GSplatData holding `cloud`. PlayCanvas's PLY loader sorts a PLY's splats along a
 * Morton curve for memory locality; our layers need no such pass: the encoder stores each patch
 * layer in Morton order (its positions are delta-coded along that curve) and the sketch cluster
 * by cluster. Drawing order is the renderer's depth sort either way.
 * @param {typeof import('playcanvas')} pc
 */
export function toGSplatData(pc, cloud) {
  const properties = [...plyProperties(cloud)].map(([name, storage]) =>
    ({ type: 'float', name, storage, byteSize: 4 }));
  return new pc.GSplatData([{ name: 'vertex', count: cloud.count, properties }]);
}

/**
 * Robust extent of splat centres: the 2nd..98th percentile box of each axis (floaters and far
 * background splats fall outside it), from at most 20,000 evenly spaced samples.
 * @param {Float32Array} positions xyz
 * @returns {{centre: number[], radius: number}|null}
 */
export function robustBounds(positions) {
  const n = Math.floor(positions.length / 3);
  if (n === 0) return null;
  const step = Math.max(1, Math.floor(n / 20000));
  const lo = [], hi = [];
  for (let axis = 0; axis < 3; axis++) {
    const values = [];
    for (let i = 0; i < n; i += step) {
      const v = positions[i * 3 + axis];
      if (Number.isFinite(v)) values.push(v);
    }
    if (!values.length) return null;
    values.sort((a, b) => a - b);
    lo.push(values[Math.floor(0.02 * (values.length - 1))]);
    hi.push(values[Math.ceil(0.98 * (values.length - 1))]);
  }
  const centre = lo.map((v, i) => (v + hi[i]) / 2);
  const radius = Math.max(1e-6, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
  return { centre, radius };
}

/**
 * A camera that looks at the bounds from outside, 20 degrees above the horizon of `up`, far
 * enough for a sphere of the bounds' radius to fill the vertical field of view.
 * @returns {{position: number[], target: number[], up: number[], fov: number}}
 */
export function frameBounds(bounds, up = [0, 1, 0], fov = 50) {
  const u = normalize(up);
  const helper = Math.abs(u[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
  const side = normalize(cross(u, helper));
  const forward = cross(side, u);  // horizontal, perpendicular to up
  const elevation = 20 * Math.PI / 180;
  const direction = forward.map((f, i) => -Math.cos(elevation) * f + Math.sin(elevation) * u[i]);
  const distance = bounds.radius / Math.sin((fov * Math.PI / 180) / 2);
  return {
    position: bounds.centre.map((c, i) => c + direction[i] * distance),
    target: [...bounds.centre], up: u, fov,
  };
}

function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

function normalize(v) {
  const length = Math.hypot(...v) || 1;
  return v.map((x) => x / length);
}
