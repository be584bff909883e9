// A camera that frames a scene (the decoder's arrays become PlayCanvas's in the package's
// PlayCanvas loader, web/loaders/playcanvas.js): on the box a file's metadata gives of the whole
// scene, or on the decoded centres as they arrive.

import { rotatePositions } from '../../src/orientation.js';

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
  return sphereOf(lo, hi);
}

/** The sphere framing uses for the box `lo`..`hi`: its centre, half its diagonal. */
function sphereOf(lo, hi) {
  const centre = lo.map((v, i) => (v + hi[i]) / 2);
  const radius = Math.max(1e-6, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
  return { centre, radius };
}

/**
 * The whole scene's bounds from a file's metadata (`bounds`, spec, written by `spcodec
 * encode`): its `robust` box, the 2nd..98th percentile of each axis of every layer's centres (what
 * robustBounds takes of the centres seen), else its full `min`/`max` box; in the file's own
 * coordinates. Null for metadata without a well-formed box: metadata is untrusted.
 * @param {unknown} metadata  the file's metadata object (or null)
 * @returns {{centre: number[], radius: number}|null}
 */
export function metadataBounds(metadata) {
  const box = /** @type {any} */ (metadata)?.bounds;
  for (const corners of [box?.robust, box]) {
    const lo = corners?.min, hi = corners?.max;
    if (isPoint(lo) && isPoint(hi) && lo.every((v, i) => v <= hi[i])) return sphereOf(lo, hi);
  }
  return null;
}

function isPoint(value) {
  return Array.isArray(value) && value.length === 3 && value.every(Number.isFinite);
}

/**
 * Bounds turned by the quaternion `rotation` (x, y, z, w) that stands the scene upright: the
 * centre moves, the radius stays (a turned sphere is the same sphere).
 * @param {{centre: number[], radius: number}} bounds
 * @param {number[]|null} rotation
 */
export function turnBounds(bounds, rotation) {
  if (!rotation) return bounds;
  return { centre: [...rotatePositions(Float64Array.from(bounds.centre), rotation)],
    radius: bounds.radius };
}

/** Most sampled centres a framing keeps (robustBounds reads 20,000 of them). */
const MAX_SAMPLES = 40000;

/** How far, as a share of the framed radius, the scene may reach out of the framed sphere before
 * the camera moves: small shifts of the percentile box as layers arrive leave it where it is. */
const REFIT_SLACK = 0.1;

/**
 * The default framing of a scene that arrives in parts (the preview, then layer by layer) when its
 * file's metadata gives no box of the whole scene (older files, or files not written by the
 * encoder: see metadataBounds): the header has counts and offsets, the sketch clusters' frames
 * cover layer 0 only, and layer 0 may hold one corner of it, so each part's centres join an
 * evenly spaced sample of all of them, and the framing follows that sample's robust bounds when
 * they reach out of the sphere framed so far.
 */
export class SceneFraming {
  constructor() {
    /** @type {number[]} sampled centres, xyz */
    this.samples = [];
    /** keep every `stride`-th centre (a power of two, doubled as the sample fills) */
    this.stride = 1;
    /** centres seen so far, all parts together */
    this.seen = 0;
    /** @type {{centre: number[], radius: number}|null} the bounds framed last */
    this.framed = null;
  }

  /**
   * Add one part's centres.
   * @param {Float32Array} positions xyz
   * @param {(sampled: Float32Array) => Float32Array} [toWorld]  into the world the camera sees
   *   (applied to the sampled centres only: a layer may hold millions)
   * @returns {{centre: number[], radius: number}|null} the bounds to frame now, or null when
   *   those framed already hold the scene seen so far
   */
  add(positions, toWorld = (sampled) => sampled) {
    this.makeRoom(Math.floor(positions.length / 3));
    for (const v of toWorld(this.sample(positions))) this.samples.push(v);
    const bounds = robustBounds(Float32Array.from(this.samples));
    if (!bounds || (this.framed && holds(this.framed, bounds, REFIT_SLACK))) return null;
    this.framed = bounds;
    return bounds;
  }

  /** The centres of a part whose index among all seen is a multiple of the stride. */
  sample(positions) {
    const n = Math.floor(positions.length / 3);
    const first = (this.stride - this.seen % this.stride) % this.stride;
    this.seen += n;
    const kept = new Float32Array(3 * Math.max(0, Math.ceil((n - first) / this.stride)));
    for (let i = first, k = 0; i < n; i += this.stride, k += 3) kept.set(positions.subarray(i * 3, i * 3 + 3), k);
    return kept;
  }

  /** Double the stride, and drop every other centre kept (those left are at multiples of the new
   * stride), until `count` more centres fit in the sample. */
  makeRoom(count) {
    while (this.samples.length / 3 + count / this.stride > MAX_SAMPLES) {
      this.samples = this.samples.filter((_, j) => Math.floor(j / 3) % 2 === 0);
      this.stride *= 2;
    }
  }
}

/** Whether sphere `outer`, grown by `slack` of its radius, holds sphere `inner`. */
function holds(outer, inner, slack = 0) {
  const apart = Math.hypot(...inner.centre.map((c, i) => c - outer.centre[i]));
  return apart + inner.radius <= outer.radius * (1 + slack);
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
