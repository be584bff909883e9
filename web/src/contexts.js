/**
 * Context-coded patch indices (spec 7.5, format 1.2): the PATCH_INDEX_CONTEXTS section of layer 1.
 * Every patch layer's ranks are resolved where its indices are checked (patch.js `readIndices`).
 *
 * A target column stores a rank per Gaussian; its index is `table[contextIndex * E_target + rank]`,
 * columns resolved in increasing order so that a context that is itself a target is already an
 * index when it is read.
 */
import { fail } from './errors.js';

/**
 * One record: `target` is coded given the indices of `context`.
 * @typedef {object} IndexContext
 * @property {number} target column number in order
 * @property {number} context an earlier column
 * @property {number} width entries of the target's codebook (the table's row length)
 * @property {Uint8Array} table E_context x E_target, row-major
 */

/**
 * Entry count of every index column in order.
 * @param {{count: number, groups: number}[]} codebooks
 * @returns {number[]}
 */
export function columnEntries(codebooks) {
  /** @type {number[]} */
  const out = [];
  for (const cb of codebooks) for (let g = 0; g < cb.groups; g++) out.push(cb.count);
  return out;
}

/**
 * Parse and validate PATCH_INDEX_CONTEXTS ([R-105]): the structure first (bad-section), then the
 * table values (bad-value).
 * @param {Uint8Array} raw
 * @param {{count: number, groups: number}[]} codebooks
 * @returns {IndexContext[]}
 */
export function parseContexts(raw, codebooks) {
  const entries = columnEntries(codebooks);
  if (raw.length < 1) fail('bad-section', 'PATCH_INDEX_CONTEXTS is empty: it holds no record count');
  const count = raw[0];
  /** @type {IndexContext[]} */
  const out = [];
  let pos = 1;
  let previous = -1;
  for (let i = 0; i < count; i++) {
    if (pos + 2 > raw.length) fail('bad-section', `PATCH_INDEX_CONTEXTS ends inside record ${i}`);
    const target = raw[pos];
    const context = raw[pos + 1];
    if (target >= entries.length || context >= entries.length) {
      fail('bad-section', `context record ${i} names column ${Math.max(target, context)}; the file has ${entries.length} index columns`);
    }
    if (context >= target) fail('bad-section', `context record ${i}: column ${target} is given column ${context}, which is not an earlier column`);
    if (target <= previous) fail('bad-section', `context record ${i}: target column ${target} does not follow ${previous}`);
    const width = entries[target];
    const size = entries[context] * width;
    if (pos + 2 + size > raw.length) fail('bad-section', `PATCH_INDEX_CONTEXTS ends inside the table of record ${i}`);
    out.push({ target, context, width, table: raw.subarray(pos + 2, pos + 2 + size) });
    pos += 2 + size;
    previous = target;
  }
  if (pos !== raw.length) fail('bad-section', `PATCH_INDEX_CONTEXTS has ${raw.length - pos} trailing bytes`);
  out.forEach((rec, i) => {
    for (let k = 0; k < rec.table.length; k++) {
      if (rec.table[k] >= rec.width) {
        fail('bad-value', `context record ${i}: a table value exceeds column ${rec.target}'s ${rec.width} codebook entries`);
      }
    }
  });
  return out;
}
