/**
 * The sketch layer (spec section 6): the cluster table, the Draco runs of positions, and the
 * polynomial models evaluated at each Gaussian's normalized position.
 */
import { fail } from './errors.js';
import { HALF_TO_FLOAT, isFiniteHalf, u16Words } from './half.js';
import { checkLimit } from './limits.js';
import { decodeOpacity, writeRotation } from './attributes.js';
import { decodePoints } from './draco.js';

const RECORD_SIZE = 40;
export const MAX_DEGREE = 10;
export const SH_REST_ABSENT = 255;
const MAX_NORMALIZED = 2;
const FLOAT32_MAX = 3.4028234663852886e38;

/** Model outputs per attribute (scale, rotation, opacity, colour DC); SH rest depends on degree. */
const BASE_OUTPUTS = [3, 4, 1, 3];

/**
 * Number of monomials of total degree <= d in three variables ([R-41]).
 * @param {number} d
 */
export function monomialCount(d) {
  return ((d + 1) * (d + 2) * (d + 3)) / 6;
}

/**
 * Outputs of each of the five models for a scene of SH degree `sh` ([R-44]).
 * @param {number} sh
 * @returns {number[]}
 */
export function modelOutputs(sh) {
  return [...BASE_OUTPUTS, 3 * ((sh + 1) ** 2 - 1)];
}

/**
 * The parsed cluster table, as columns.
 * @typedef {object} SketchLayout
 * @property {number} count clusters
 * @property {Uint32Array} pointCount
 * @property {Float32Array} center 3 per cluster
 * @property {Float32Array} halfExtent 3 per cluster
 * @property {Uint8Array} degrees 5 per cluster
 * @property {Float64Array} coefficientOffset byte offset of each model (5 per cluster, -1: absent)
 * @property {{start: number, stop: number, points: number}[]} runs Draco blobs and their points
 */

/**
 * Parse and validate the cluster table against the other two sketch sections ([R-40], [R-45],
 * [R-46]). Each rule is checked over all records before the next, in the reference's order.
 * @param {Uint8Array} table SKETCH_CLUSTERS payload
 * @param {number} positionsLength raw length of SKETCH_POSITIONS
 * @param {number} coefficientsLength raw length of SKETCH_COEFFICIENTS
 * @param {number} gaussianCount layer 0's Gaussian count
 * @param {number} sh the scene's SH degree
 * @param {import('./limits.js').Limits} limits
 * @returns {SketchLayout}
 */
export function parseSketch(table, positionsLength, coefficientsLength, gaussianCount, sh, limits) {
  if (table.length < 4) fail('bad-section', 'SKETCH_CLUSTERS payload is malformed (too short)');
  const view = new DataView(table.buffer, table.byteOffset, table.byteLength);
  const count = view.getUint32(0, true);
  checkLimit('cluster count', count, limits.maxClusters);
  if (table.length - 4 !== count * RECORD_SIZE) {
    fail('bad-section', `cluster table holds ${table.length - 4} record bytes for ${count} clusters`);
  }
  const pointCount = new Uint32Array(count);
  const dracoLength = new Uint32Array(count);
  const center = new Float32Array(3 * count);
  const halfExtent = new Float32Array(3 * count);
  const degrees = new Uint8Array(5 * count);
  let reserved = 0;
  for (let c = 0; c < count; c++) {
    const at = 4 + RECORD_SIZE * c;
    pointCount[c] = view.getUint32(at, true);
    dracoLength[c] = view.getUint32(at + 4, true);
    for (let k = 0; k < 3; k++) {
      center[3 * c + k] = view.getFloat32(at + 8 + 4 * k, true);
      halfExtent[3 * c + k] = view.getFloat32(at + 20 + 4 * k, true);
    }
    for (let k = 0; k < 5; k++) degrees[5 * c + k] = table[at + 32 + k];
    reserved |= table[at + 37] | table[at + 38] | table[at + 39];
  }
  const layout = { count, pointCount, center, halfExtent, degrees, coefficientOffset: new Float64Array(5 * count), runs: [] };
  if (count === 0) {
    if (gaussianCount || positionsLength || coefficientsLength) {
      fail('bad-section', 'an empty cluster table with non-empty sketch data');
    }
    return layout;
  }
  if (reserved) fail('reserved-nonzero', "a cluster record's reserved bytes are not zero");
  if (pointCount.includes(0) || dracoLength[0] === 0) {
    fail('bad-value', 'a cluster has zero points, or the first cluster starts no Draco blob');
  }
  for (let i = 0; i < 3 * count; i++) {
    if (!Number.isFinite(center[i]) || !Number.isFinite(halfExtent[i]) || !(halfExtent[i] > 0)) {
      fail('bad-value', 'a cluster frame is not finite or has a non-positive half extent');
    }
  }
  for (let c = 0; c < count; c++) {
    for (let k = 0; k < 4; k++) {
      if (degrees[5 * c + k] > MAX_DEGREE) fail('bad-value', `a polynomial degree exceeds ${MAX_DEGREE}`);
    }
  }
  if (sh === 0) {
    for (let c = 0; c < count; c++) {
      if (degrees[5 * c + 4] !== SH_REST_ABSENT) fail('bad-value', 'an SH-rest model in a scene of SH degree 0');
    }
  }
  for (let c = 0; c < count; c++) {
    const d = degrees[5 * c + 4];
    if (d > MAX_DEGREE && d !== SH_REST_ABSENT) {
      fail('bad-value', `an SH-rest degree is neither 0..${MAX_DEGREE} nor 255`);
    }
  }
  let points = 0;
  for (let c = 0; c < count; c++) points += pointCount[c];
  if (points !== gaussianCount) {
    fail('bad-section', "cluster point counts do not add up to the sketch layer's Gaussian count");
  }
  let byte = 0;
  for (let c = 0; c < count; c++) {
    if (dracoLength[c] > 0) {
      layout.runs.push({ start: byte, stop: byte + dracoLength[c], points: 0 });
      byte += dracoLength[c];
    }
    layout.runs[layout.runs.length - 1].points += pointCount[c];
  }
  if (byte !== positionsLength) fail('bad-section', 'Draco blob lengths do not add up to the SKETCH_POSITIONS length');
  const outputs = modelOutputs(sh);
  let offset = 0;
  for (let c = 0; c < count; c++) {
    for (let a = 0; a < 5; a++) {
      const d = degrees[5 * c + a];
      if (d === SH_REST_ABSENT) {
        layout.coefficientOffset[5 * c + a] = -1;
        continue;
      }
      layout.coefficientOffset[5 * c + a] = offset;
      offset += 2 * monomialCount(d) * outputs[a];
    }
  }
  if (offset !== coefficientsLength) {
    fail('bad-section', 'model sizes do not add up to the SKETCH_COEFFICIENTS length');
  }
  return layout;
}

/**
 * Layer 0 parsed and its Draco blobs decoded: everything but evaluation.
 * @typedef {object} SketchPlan
 * @property {SketchLayout} layout
 * @property {Float32Array} positions every sketch Gaussian's position, in output order
 * @property {Uint8Array} coefficients
 * @property {number} sh
 * @property {number} gaussianCount
 */

/**
 * Parse layer 0's payloads and decode its Draco runs ([R-40]..[R-47], [R-49]).
 * @param {Map<number, Uint8Array>} payloads
 * @param {import('./header.js').Header} header
 * @param {import('./limits.js').Limits} limits
 * @param {import('./draco.js').DracoModule} draco
 * @param {{clusters: number, positions: number, coefficients: number}} types section type ids
 * @returns {SketchPlan}
 */
export function prepareSketch(payloads, header, limits, draco, types) {
  const table = /** @type {Uint8Array} */ (payloads.get(types.clusters));
  const blobs = /** @type {Uint8Array} */ (payloads.get(types.positions));
  const coefficients = /** @type {Uint8Array} */ (payloads.get(types.coefficients));
  const sh = header.shDegree;
  const layout = parseSketch(table, blobs.length, coefficients.length, header.layers[0].gaussianCount, sh, limits);
  let total = 0;
  for (const run of layout.runs) total += run.points;
  const decoded = layout.runs.map((run, b) =>
    decodePoints(draco, blobs.subarray(run.start, run.stop), run.points, `sketch Draco blob ${b}`));
  const positions = new Float32Array(3 * total);
  let at = 0;
  for (const part of decoded) {
    positions.set(part, at);
    at += part.length;
  }
  return { layout, positions, coefficients, sh, gaussianCount: total };
}

/**
 * The output arrays a layer is decoded into (views of the scene's arrays).
 * @typedef {object} CloudArrays
 * @property {Float32Array} positions
 * @property {Float32Array} scales
 * @property {Float32Array} rotations
 * @property {Float32Array} opacities
 * @property {Float32Array} shDC
 * @property {Float32Array} shRest
 */

/** Points of a cluster evaluated together (bounds the scratch memory: 286 monomials x this). */
const CHUNK = 512;

/**
 * Evaluate every cluster's models at its points into `out` ([R-41]..[R-44], [R-30]..[R-34]).
 *
 * Each output is summed in binary64, term by term in monomial order, which is exactly what the
 * reference decoder does for clusters of fewer than 32 points (its larger clusters use a matrix
 * product, whose rounding differs within the tolerance of section 15). The monomials are built
 * a degree at a time from those of the degree below, as the reference builds them. Points are
 * taken in chunks and each sum runs over the chunk's points in the inner loop, which keeps the
 * loops long and the per-term overhead low.
 * @param {SketchPlan} plan
 * @param {CloudArrays} out
 */
export function fillSketch(plan, out) {
  const { layout, positions, coefficients, sh } = plan;
  const outputs = modelOutputs(sh);
  const maxMonomials = monomialCount(MAX_DEGREE);
  const phi = new Float64Array(maxMonomials * CHUNK);
  const xyz = new Float64Array(3 * CHUNK);
  const sums = new Float64Array(CHUNK);
  /** coefficient matrices of the current cluster, as binary64 */
  const models = outputs.map((o) => new Float64Array(maxMonomials * Math.max(o, 1)));
  const words = u16Words(coefficients, 0, coefficients.length >>> 1);
  out.positions.set(positions);
  let first = 0;
  for (let c = 0; c < layout.count; c++) {
    let top = 0;
    for (let a = 0; a < 5; a++) {
      const d = layout.degrees[5 * c + a];
      if (d === SH_REST_ABSENT) continue;
      loadModel(words, layout.coefficientOffset[5 * c + a] / 2, monomialCount(d) * outputs[a], models[a], c);
      if (d > top) top = d;
    }
    const end = first + layout.pointCount[c];
    for (let row = first; row < end; row += CHUNK) {
      const n = Math.min(CHUNK, end - row);
      normalize(positions, row, n, layout, c, xyz);
      monomials(xyz, n, top, phi);
      for (let a = 0; a < 5; a++) {
        const d = layout.degrees[5 * c + a];
        if (d === SH_REST_ABSENT) continue; // its SH rest stays zero
        const width = outputs[a];
        const m = monomialCount(d);
        const model = models[a];
        for (let o = 0; o < width; o++) {
          sumTerms(phi, n, model, m, width, o, sums);
          store(a, o, width, sums, n, row, out, c);
        }
      }
    }
    first = end;
  }
}

/**
 * sums[i] = sum over k < m of phi[k][i] * model[k, o], for n points: added term by term in k order
 * from zero, four points at a time with the running sums in registers.
 * @param {Float64Array} phi monomial columns (k * n + i)
 * @param {number} n
 * @param {Float64Array} model row-major (m, width)
 * @param {number} m
 * @param {number} width
 * @param {number} o
 * @param {Float64Array} sums
 */
function sumTerms(phi, n, model, m, width, o, sums) {
  let i = 0;
  for (; i + 4 <= n; i += 4) {
    let s0 = 0;
    let s1 = 0;
    let s2 = 0;
    let s3 = 0;
    for (let k = 0, col = i, at = o; k < m; k++, col += n, at += width) {
      const c = model[at];
      s0 += phi[col] * c;
      s1 += phi[col + 1] * c;
      s2 += phi[col + 2] * c;
      s3 += phi[col + 3] * c;
    }
    sums[i] = s0;
    sums[i + 1] = s1;
    sums[i + 2] = s2;
    sums[i + 3] = s3;
  }
  for (; i < n; i++) {
    let s0 = 0;
    for (let k = 0, col = i, at = o; k < m; k++, col += n, at += width) s0 += phi[col] * model[at];
    sums[i] = s0;
  }
}

/**
 * Normalized positions of `n` points from `row` on of cluster `c` ([R-42]), into xyz as three
 * columns; a coordinate beyond 2 is `bad-value`.
 * @param {Float32Array} positions
 * @param {number} row
 * @param {number} n
 * @param {SketchLayout} layout
 * @param {number} c
 * @param {Float64Array} xyz
 */
function normalize(positions, row, n, layout, c, xyz) {
  for (let axis = 0; axis < 3; axis++) {
    const center = layout.center[3 * c + axis];
    const half = layout.halfExtent[3 * c + axis];
    for (let i = 0; i < n; i++) {
      const v = (positions[3 * (row + i) + axis] - center) / half;
      if (!(Math.abs(v) <= MAX_NORMALIZED)) {
        fail('bad-value', `cluster ${c}: a position lies outside twice its frame ([R-42])`);
      }
      xyz[axis * CHUNK + i] = v;
    }
  }
}

/**
 * One model's binary16 coefficients as binary64, refusing non-finite ones ([R-44]).
 * @param {Uint16Array} words
 * @param {number} start
 * @param {number} size
 * @param {Float64Array} into
 * @param {number} cluster
 */
function loadModel(words, start, size, into, cluster) {
  for (let k = 0; k < size; k++) {
    const h = words[start + k];
    if (!isFiniteHalf(h)) fail('bad-value', `cluster ${cluster} has a non-finite model coefficient`);
    into[k] = HALF_TO_FLOAT[h];
  }
}

/**
 * The monomials of degree <= d at n points, in graded lexicographic order ([R-41]), as columns
 * of `phi` (monomial k of point i at k * n + i): the degree-t block is x times the whole degree
 * t-1 block, then y times its last t entries (those without x), then z times its last entry.
 * @param {Float64Array} xyz three columns of CHUNK normalized coordinates
 * @param {number} n
 * @param {number} d
 * @param {Float64Array} phi
 */
function monomials(xyz, n, d, phi) {
  phi.fill(1, 0, n);
  let prev = 0;
  let stop = 1;
  for (let t = 1; t <= d; t++) {
    const width = stop - prev;
    for (let j = 0; j < width; j++) times(phi, (prev + j) * n, xyz, 0, (stop + j) * n, n);
    for (let j = 0; j < t; j++) times(phi, (stop - t + j) * n, xyz, CHUNK, (stop + width + j) * n, n);
    times(phi, (stop - 1) * n, xyz, 2 * CHUNK, (stop + width + t) * n, n);
    prev = stop;
    stop += width + t + 1;
  }
}

/**
 * phi[to + i] = phi[from + i] * xyz[axis + i] for i < n.
 * @param {Float64Array} phi
 * @param {number} from
 * @param {Float64Array} xyz
 * @param {number} axis
 * @param {number} to
 * @param {number} n
 */
function times(phi, from, xyz, axis, to, n) {
  for (let i = 0; i < n; i++) phi[to + i] = phi[from + i] * xyz[axis + i];
}

/**
 * Map output `o` of one evaluated model, at n points, to parameters and store them
 * ([R-30]..[R-34]). A rotation is stored when its last component (o = 3) is in.
 * @param {number} attribute 0 scale, 1 rotation, 2 opacity, 3 colour DC, 4 SH rest
 * @param {number} o
 * @param {number} width
 * @param {Float64Array} sums
 * @param {number} n
 * @param {number} row first output row
 * @param {CloudArrays} out
 * @param {number} cluster
 */
function store(attribute, o, width, sums, n, row, out, cluster) {
  for (let i = 0; i < n; i++) {
    const v = sums[i];
    if (!Number.isFinite(v)) fail('bad-value', `cluster ${cluster}: a model is not finite at its points`);
    if (attribute !== 1 && attribute !== 2 && Math.abs(v) > FLOAT32_MAX) {
      fail('bad-value', `cluster ${cluster}: a model overflows float32`);
    }
  }
  if (attribute === 0) {
    for (let i = 0; i < n; i++) out.scales[3 * (row + i) + o] = sums[i];
  } else if (attribute === 1) {
    // the coded quaternion is gathered in binary64 until its last component, then normalized
    const q = ROTATION_SCRATCH;
    for (let i = 0; i < n; i++) q[4 * i + o] = sums[i];
    if (o === 3) {
      for (let i = 0; i < n; i++) writeRotation(q[4 * i], q[4 * i + 1], q[4 * i + 2], q[4 * i + 3], out.rotations, 4 * (row + i));
    }
  } else if (attribute === 2) {
    for (let i = 0; i < n; i++) out.opacities[row + i] = decodeOpacity(sums[i]);
  } else if (attribute === 3) {
    for (let i = 0; i < n; i++) out.shDC[3 * (row + i) + o] = sums[i];
  } else {
    for (let i = 0; i < n; i++) out.shRest[width * (row + i) + o] = sums[i];
  }
}

const ROTATION_SCRATCH = new Float64Array(4 * CHUNK);
