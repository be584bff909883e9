// A camera that frames a scene (the decoder's arrays become PlayCanvas's in the package's
// PlayCanvas loader, web/loaders/playcanvas.js).

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
