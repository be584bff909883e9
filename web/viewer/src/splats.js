// From the decoder's arrays to what the renderer takes, and a camera that frames a scene.
//
// PlayCanvas describes splats the way a 3DGS PLY does: one float array per PLY property (x, y, z,
// f_dc_*, opacity, scale_*, rot_*, f_rest_*). Handing it the decoded layer under those names makes
// the viewer render a layer exactly as PlayCanvas renders the PLY `spcodec decode` writes, which
// the browser tests check pixel by pixel.

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
  const split = (source, width, names) => {
    names.forEach((name, c) => {
      const column = new Float32Array(n);
      for (let i = 0; i < n; i++) column[i] = source[i * width + c];
      props.set(name, column);
    });
  };
  split(cloud.positions, 3, ['x', 'y', 'z']);
  split(cloud.shDC, 3, ['f_dc_0', 'f_dc_1', 'f_dc_2']);
  props.set('opacity', Float32Array.from(cloud.opacities));
  split(cloud.scales, 3, ['scale_0', 'scale_1', 'scale_2']);
  split(cloud.rotations, 4, ['rot_0', 'rot_1', 'rot_2', 'rot_3']);
  const k = (cloud.shDegree + 1) ** 2 - 1;
  for (let channel = 0; channel < 3; channel++) {
    for (let coef = 0; coef < k; coef++) {
      const column = new Float32Array(n);
      for (let i = 0; i < n; i++) column[i] = cloud.shRest[(i * k + coef) * 3 + channel];
      props.set(`f_rest_${channel * k + coef}`, column);
    }
  }
  return props;
}

/**
 * A PlayCanvas GSplatData holding `cloud`, prepared as PlayCanvas's PLY loader prepares a PLY
 * (Morton-reordered for locality).
 * @param {typeof import('playcanvas')} pc
 */
export function toGSplatData(pc, cloud) {
  const properties = [...plyProperties(cloud)].map(([name, storage]) =>
    ({ type: 'float', name, storage, byteSize: 4 }));
  const data = new pc.GSplatData([{ name: 'vertex', count: cloud.count, properties }]);
  data.reorderData();
  return data;
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
export function frameBounds(bounds, up = [0, -1, 0], fov = 50) {
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
