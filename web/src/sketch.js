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

/**
 * Evaluate every cluster's models at its points into `out` ([R-41]..[R-44], [R-30]..[R-34]).
 *
 * Each output is summed in binary64, term by term in monomial order, which is exactly what the
 * reference decoder does for clusters of fewer than 32 points (its larger clusters use a matrix
 * product, whose rounding differs within the tolerance of section 15). The monomials are built
 * a degree at a time from those of the degree below, as the reference builds them.
 * @param {SketchPlan} plan
 * @param {CloudArrays} out
 */
export function fillSketch(plan, out) {
  const { layout, positions, coefficients, sh } = plan;
  const outputs = modelOutputs(sh);
  const restWidth = outputs[4];
  const phi = new Float64Array(monomialCount(MAX_DEGREE));
  const value = new Float64Array(Math.max(4, restWidth));
  /** @type {Float64Array[]} coefficient matrices of the current cluster, as binary64 */
  const models = [0, 1, 2, 3, 4].map((a) => new Float64Array(monomialCount(MAX_DEGREE) * Math.max(outputs[a], 1)));
  const words = u16Words(coefficients, 0, coefficients.length >>> 1);
  out.positions.set(positions);
  let row = 0;
  for (let c = 0; c < layout.count; c++) {
    const n = layout.pointCount[c];
    let top = 0;
    for (let a = 0; a < 5; a++) {
      const d = layout.degrees[5 * c + a];
      if (d === SH_REST_ABSENT) continue;
      loadModel(words, layout.coefficientOffset[5 * c + a] / 2, monomialCount(d) * outputs[a], models[a], c);
      if (d > top) top = d;
    }
    const cx = layout.center[3 * c];
    const cy = layout.center[3 * c + 1];
    const cz = layout.center[3 * c + 2];
    const hx = layout.halfExtent[3 * c];
    const hy = layout.halfExtent[3 * c + 1];
    const hz = layout.halfExtent[3 * c + 2];
    for (let i = 0; i < n; i++, row++) {
      const x = (positions[3 * row] - cx) / hx;
      const y = (positions[3 * row + 1] - cy) / hy;
      const z = (positions[3 * row + 2] - cz) / hz;
      if (!(Math.abs(x) <= MAX_NORMALIZED && Math.abs(y) <= MAX_NORMALIZED && Math.abs(z) <= MAX_NORMALIZED)) {
        fail('bad-value', `cluster ${c}: a position lies outside twice its frame ([R-42])`);
      }
      monomials(x, y, z, top, phi);
      for (let a = 0; a < 5; a++) {
        const d = layout.degrees[5 * c + a];
        const width = outputs[a];
        if (d === SH_REST_ABSENT) continue; // its SH rest stays zero
        evaluate(phi, monomialCount(d), models[a], width, value);
        store(a, value, width, row, out, c);
      }
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
 * The monomials of degree <= d at (x, y, z) in graded lexicographic order ([R-41]): the degree-t
 * block is x times the whole degree t-1 block, then y times its last t entries (those without x),
 * then z times its last entry.
 * @param {number} x
 * @param {number} y
 * @param {number} z
 * @param {number} d
 * @param {Float64Array} phi
 */
function monomials(x, y, z, d, phi) {
  phi[0] = 1;
  let prev = 0;
  let stop = 1;
  for (let t = 1; t <= d; t++) {
    const width = stop - prev;
    for (let j = 0; j < width; j++) phi[stop + j] = phi[prev + j] * x;
    for (let j = 0; j < t; j++) phi[stop + width + j] = phi[stop - t + j] * y;
    phi[stop + width + t] = phi[stop - 1] * z;
    prev = stop;
    stop += width + t + 1;
  }
}

/**
 * value[o] = sum over m of phi[m] * c[m, o], summed in monomial order ([R-43]).
 * @param {Float64Array} phi
 * @param {number} m monomials
 * @param {Float64Array} c row-major (m, width)
 * @param {number} width
 * @param {Float64Array} value
 */
function evaluate(phi, m, c, width, value) {
  for (let o = 0; o < width; o++) value[o] = 0;
  for (let k = 0; k < m; k++) {
    const p = phi[k];
    const base = k * width;
    for (let o = 0; o < width; o++) value[o] += p * c[base + o];
  }
}

/**
 * Map one evaluated model to parameters and store them ([R-30]..[R-34]).
 * @param {number} attribute 0 scale, 1 rotation, 2 opacity, 3 colour DC, 4 SH rest
 * @param {Float64Array} value
 * @param {number} width
 * @param {number} row
 * @param {CloudArrays} out
 * @param {number} cluster
 */
function store(attribute, value, width, row, out, cluster) {
  for (let o = 0; o < width; o++) {
    const v = value[o];
    if (!Number.isFinite(v)) fail('bad-value', `cluster ${cluster}: a model is not finite at its points`);
    if (attribute !== 1 && attribute !== 2 && Math.abs(v) > FLOAT32_MAX) {
      fail('bad-value', `cluster ${cluster}: a model overflows float32`);
    }
  }
  if (attribute === 0) {
    out.scales[3 * row] = value[0];
    out.scales[3 * row + 1] = value[1];
    out.scales[3 * row + 2] = value[2];
  } else if (attribute === 1) {
    writeRotation(value[0], value[1], value[2], value[3], out.rotations, 4 * row);
  } else if (attribute === 2) {
    out.opacities[row] = decodeOpacity(value[0]);
  } else if (attribute === 3) {
    out.shDC[3 * row] = value[0];
    out.shDC[3 * row + 1] = value[1];
    out.shDC[3 * row + 2] = value[2];
  } else {
    const base = row * width;
    for (let o = 0; o < width; o++) out.shRest[base + o] = value[o];
  }
}
