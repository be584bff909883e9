/**
 * Patch layers (spec section 7): codebooks (carried by layer 1, used by every patch layer),
 * positions in one of four modes, and index columns looked up in the codebooks.
 */
import { decodeOpacity, writeRotation } from './attributes.js';
import { decodePoints } from './draco.js';
import { fail } from './errors.js';
import { HALF_TO_FLOAT, isFiniteHalf, u16Words } from './half.js';

/** Width of each patch attribute by id ([R-50]): scale, rotation, opacity, DC, SH bands 1-3. */
const WIDTHS = [3, 4, 1, 3, 9, 15, 21];
const ROTATION = 1;
const OPACITY = 2;
const MAX_ENTRIES = 256;

export const POSITION_MODES = ['FLOAT16', 'QUANT16', 'FLOAT32', 'DRACO'];

/**
 * One attribute's codebook.
 * @typedef {object} Codebook
 * @property {number} attribute id, 0..6
 * @property {number} dim entry dimension D
 * @property {number} count entries E
 * @property {number} groups indices per Gaussian, width / D
 * @property {Float32Array} entries E x D coded values
 * @property {Float32Array} mapped the entries as parameters where that can be done per entry
 *   (whole-quaternion rotations normalized, opacities as logits), else the entries
 */

/**
 * Parse and validate PATCH_CODEBOOKS ([R-50], [R-51]): first the structure (bad-section), then
 * the attribute list, then each codebook's values (bad-value).
 * @param {Uint8Array} raw
 * @param {number} sh the scene's SH degree
 * @returns {Codebook[]}
 */
export function parseCodebooks(raw, sh) {
  if (raw.length < 1) fail('bad-section', 'PATCH_CODEBOOKS payload is malformed (empty)');
  const n = raw[0];
  /** @type {{attribute: number, dim: number, count: number, at: number}[]} */
  const books = [];
  let pos = 1;
  for (let i = 0; i < n; i++) {
    if (pos + 4 > raw.length) fail('bad-section', 'PATCH_CODEBOOKS payload is malformed (cut short)');
    const dim = raw[pos + 1];
    const count = raw[pos + 2] | (raw[pos + 3] << 8);
    const size = 2 * count * dim;
    if (pos + 4 + size > raw.length) fail('bad-section', 'PATCH_CODEBOOKS payload is malformed (cut short)');
    books.push({ attribute: raw[pos], dim, count, at: pos + 4 });
    pos += 4 + size;
  }
  if (pos !== raw.length) fail('bad-section', `PATCH_CODEBOOKS payload has ${raw.length - pos} trailing bytes`);
  const expected = Array.from({ length: 4 + sh }, (_, i) => i);
  const ids = books.map((b) => b.attribute);
  if (ids.length !== expected.length || ids.some((id, i) => id !== expected[i])) {
    fail('bad-section', `codebooks are for attributes [${ids}], expected [${expected}] for SH degree ${sh}`);
  }
  return books.map((b) => {
    const width = WIDTHS[b.attribute];
    if (b.dim === 0 || width % b.dim) {
      fail('bad-value', `attribute ${b.attribute} codebook entry dimension ${b.dim} does not divide ${width}`);
    }
    if (b.count < 1 || b.count > MAX_ENTRIES) {
      fail('bad-value', `attribute ${b.attribute} codebook has ${b.count} entries, allowed 1..${MAX_ENTRIES}`);
    }
    const bits = u16Words(raw, b.at, b.count * b.dim);
    const entries = new Float32Array(bits.length);
    for (let k = 0; k < bits.length; k++) {
      if (!isFiniteHalf(bits[k])) fail('bad-value', `attribute ${b.attribute} codebook has a non-finite entry`);
      entries[k] = HALF_TO_FLOAT[bits[k]];
    }
    return { attribute: b.attribute, dim: b.dim, count: b.count, groups: width / b.dim, entries, mapped: mapEntries(b.attribute, b.dim, entries) };
  });
}

/**
 * Apply the coded-value mapping to whole entries where it is per entry ([R-56]).
 * @param {number} attribute
 * @param {number} dim
 * @param {Float32Array} entries
 * @returns {Float32Array}
 */
function mapEntries(attribute, dim, entries) {
  if (attribute === ROTATION && dim === 4) {
    const out = new Float32Array(entries.length);
    for (let e = 0; e < entries.length; e += 4) {
      writeRotation(entries[e], entries[e + 1], entries[e + 2], entries[e + 3], out, e);
    }
    return out;
  }
  if (attribute === OPACITY) return entries.map(decodeOpacity);
  return entries;
}

/**
 * One patch layer's positions and index columns, validated against their bytes.
 * @typedef {object} PatchPlan
 * @property {number} gaussianCount
 * @property {number} mode
 * @property {Float32Array} positions xyz per Gaussian
 * @property {Uint8Array} indices the PATCH_ATTRIBUTES payload: one column of N indices per group
 */

/**
 * Parse and validate PATCH_POSITIONS for a layer of `count` Gaussians ([R-53]..[R-55], [R-58]).
 * @param {Uint8Array} raw
 * @param {number} count
 * @param {import('./draco.js').DracoModule} draco
 * @param {number} layer index, for messages
 * @returns {{mode: number, positions: Float32Array}}
 */
export function parsePositions(raw, count, draco, layer) {
  if (raw.length < 4 || (raw[0] === 1 && raw.length < 28)) {
    fail('bad-section', 'PATCH_POSITIONS payload is malformed (cut short)');
  }
  if (raw[1] | raw[2] | raw[3]) fail('reserved-nonzero', 'PATCH_POSITIONS reserved bytes are not zero');
  const mode = raw[0];
  if (mode > 3) fail('bad-value', `unknown patch position mode ${mode}`);
  if (mode === 3) {
    const blob = raw.subarray(4);
    if (count === 0) { // there is no Draco point cloud of zero points ([R-58])
      if (blob.length) fail('bad-section', `PATCH_POSITIONS holds ${blob.length} Draco bytes for a layer of 0 Gaussians`);
      return { mode, positions: new Float32Array(0) };
    }
    return { mode, positions: decodePoints(draco, blob, count, `patch layer ${layer} positions`) };
  }
  const start = mode === 1 ? 28 : 4;
  const width = mode === 2 ? 4 : 2;
  if (raw.length - start !== count * 3 * width) {
    fail('bad-section', `PATCH_POSITIONS holds ${raw.length - start} data bytes for ${count} Gaussians ` +
      `in mode ${POSITION_MODES[mode]}`);
  }
  const positions = new Float32Array(3 * count);
  if (mode === 1) {
    decodeQuant16(raw, count, positions);
  } else if (mode === 0) {
    const bits = u16Words(raw, start, 3 * count);
    for (let axis = 0; axis < 3; axis++) {
      for (let n = 0; n < count; n++) {
        const h = bits[axis * count + n];
        if (!isFiniteHalf(h)) fail('bad-value', 'a patch position is not finite');
        positions[3 * n + axis] = HALF_TO_FLOAT[h];
      }
    }
  } else {
    const view = new DataView(raw.buffer, raw.byteOffset + start, 12 * count);
    for (let axis = 0; axis < 3; axis++) {
      for (let n = 0; n < count; n++) {
        const v = view.getFloat32(4 * (axis * count + n), true);
        if (!Number.isFinite(v)) fail('bad-value', 'a patch position is not finite');
        positions[3 * n + axis] = v;
      }
    }
  }
  return { mode, positions };
}

/**
 * QUANT16 ([R-54], [R-55]): zigzag deltas summed mod 2^16 per axis, then origin + q * step in
 * binary64, rounded to binary32.
 * @param {Uint8Array} raw
 * @param {number} count
 * @param {Float32Array} positions
 */
function decodeQuant16(raw, count, positions) {
  const view = new DataView(raw.buffer, raw.byteOffset, raw.byteLength);
  const origin = [0, 1, 2].map((k) => view.getFloat32(4 + 4 * k, true));
  const step = [0, 1, 2].map((k) => view.getFloat32(16 + 4 * k, true));
  for (let k = 0; k < 3; k++) {
    if (!Number.isFinite(origin[k]) || !Number.isFinite(step[k]) || !(step[k] >= 0)) {
      fail('bad-value', 'QUANT16 origin or step is not finite and non-negative');
    }
  }
  for (let k = 0; k < 3; k++) {
    if (!Number.isFinite(Math.fround(origin[k] + 65535 * step[k]))) {
      fail('bad-value', 'QUANT16 positions can overflow float32');
    }
  }
  const codes = u16Words(raw, 28, 3 * count);
  for (let axis = 0; axis < 3; axis++) {
    const o = origin[axis];
    const s = step[axis];
    let q = 0;
    for (let n = 0; n < count; n++) {
      const z = codes[axis * count + n];
      q = (q + ((z >>> 1) ^ -(z & 1))) & 0xFFFF;
      positions[3 * n + axis] = o + q * s;
    }
  }
}

/**
 * The index columns of a layer: PATCH_ATTRIBUTES checked against the codebooks ([R-52]), and with
 * context records ([R-105]) the target columns' ranks resolved into indices ([R-107]) in the pass
 * that checks them, so that a file with contexts reads each stored byte once, as one without
 * does. Targets go in increasing order, so a context that is itself a target is already an index.
 * Returns `raw` itself when there are no records, else a new array.
 * @param {Uint8Array} raw the PATCH_ATTRIBUTES payload
 * @param {number} count Gaussians of the layer
 * @param {{attribute?: number, count: number, groups: number}[]} codebooks
 * @param {import('./contexts.js').IndexContext[]} [contexts]
 * @returns {Uint8Array}
 */
export function readIndices(raw, count, codebooks, contexts = []) {
  const groups = codebooks.reduce((sum, cb) => sum + cb.groups, 0);
  if (raw.length !== count * groups) {
    fail('bad-section', `PATCH_ATTRIBUTES holds ${raw.length} bytes, expected ${count} Gaussians x ${groups} indices`);
  }
  const out = contexts.length && count ? new Uint8Array(raw.length) : raw;
  const records = new Map(contexts.map((rec) => [rec.target, rec]));
  let column = 0;
  for (const cb of codebooks) {
    const exceeds = () => fail('bad-value', `an attribute ${cb.attribute} index exceeds the codebook's ${cb.count} entries`);
    for (let g = 0; g < cb.groups; g++, column++) {
      const at = column * count;
      const rec = records.get(column);
      if (rec) {
        const { table, width } = rec;
        const ranks = raw.subarray(at, at + count);
        const given = out.subarray(rec.context * count, (rec.context + 1) * count);
        const resolved = out.subarray(at, at + count);
        for (let i = 0; i < count; i++) {
          const rank = ranks[i];
          if (rank >= width) exceeds();
          resolved[i] = table[given[i] * width + rank];
        }
        continue;
      }
      if (cb.count < MAX_ENTRIES) {
        for (let i = at; i < at + count; i++) if (raw[i] >= cb.count) exceeds();
      }
      if (out !== raw) out.set(raw.subarray(at, at + count), at);
    }
  }
  return out;
}

/**
 * Positions plus codebook lookups into `out` ([R-56]).
 * @param {PatchPlan} plan
 * @param {Codebook[]} codebooks
 * @param {import('./sketch.js').CloudArrays} out
 * @param {number} sh
 */
export function fillPatch(plan, codebooks, out, sh) {
  const n = plan.gaussianCount;
  const restWidth = 3 * ((sh + 1) ** 2 - 1);
  out.positions.set(plan.positions);
  let row = 0;
  for (const cb of codebooks) {
    const { dim, groups, mapped } = cb;
    const attribute = cb.attribute;
    /** @type {Float32Array} */
    let target;
    let stride;
    let offset = 0;
    if (attribute === 0) { target = out.scales; stride = 3; }
    else if (attribute === ROTATION) { target = out.rotations; stride = 4; }
    else if (attribute === OPACITY) { target = out.opacities; stride = 1; }
    else if (attribute === 3) { target = out.shDC; stride = 3; }
    else {
      const band = attribute - 3;
      target = out.shRest;
      stride = restWidth;
      offset = 3 * (band * band - 1);
    }
    // Gaussian by Gaussian, so the output is written in order; each group's index column is
    // read sequentially alongside.
    const base = row * n;
    const indices = plan.indices;
    if (dim === 1) {
      for (let i = 0; i < n; i++) {
        const dst = i * stride + offset;
        for (let g = 0; g < groups; g++) target[dst + g] = mapped[indices[base + g * n + i]];
      }
    } else {
      for (let i = 0; i < n; i++) {
        let dst = i * stride + offset;
        for (let g = 0; g < groups; g++) {
          const src = indices[base + g * n + i] * dim;
          for (let k = 0; k < dim; k++) target[dst++] = mapped[src + k];
        }
      }
    }
    row += groups;
    if (attribute === ROTATION && dim !== 4) {
      const r = out.rotations;
      for (let i = 0; i < 4 * n; i += 4) writeRotation(r[i], r[i + 1], r[i + 2], r[i + 3], r, i);
    }
  }
}
