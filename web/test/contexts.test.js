// Context-coded indices (spec 7.5): the gather against a plain reading of on random
// columns and tables, and each rule of the section's parser ([R-105]).

import assert from 'node:assert/strict';
import test from 'node:test';
import { columnEntries, parseContexts } from '../src/contexts.js';
import { readIndices } from '../src/patch.js';

/** A small deterministic generator (xorshift32), so a failure names its seed. */
function rng(seed) {
  let s = seed >>> 0 || 1;
  return (n) => {
    s ^= s << 13; s >>>= 0; s ^= s >>> 17; s ^= s << 5; s >>>= 0;
    return s % n;
  };
}

/** Random codebooks (count, groups), columns of ranks, and a valid payload with chains. */
function randomCase(seed) {
  const r = rng(seed);
  const codebooks = Array.from({ length: 1 + r(5) }, () => ({ count: 1 + r(256), groups: 1 + r(3) }));
  const entries = columnEntries(codebooks);
  const n = r(50);
  const columns = new Uint8Array(entries.length * n);
  entries.forEach((e, c) => { for (let i = 0; i < n; i++) columns[c * n + i] = r(e); });
  const bytes = [0];
  for (let target = 1; target < entries.length; target++) {
    if (r(2)) continue;
    const context = r(target);
    bytes.push(target, context);
    for (let k = 0; k < entries[context] * entries[target]; k++) bytes.push(r(entries[target]));
    bytes[0]++;
  }
  return { codebooks, entries, n, columns, raw: Uint8Array.from(bytes) };
}

test('ranks resolve as [R-107] reads: targets in order, contexts as resolved indices', () => {
  for (let seed = 1; seed <= 300; seed++) {
    const { codebooks, n, columns, raw } = randomCase(seed);
    const records = parseContexts(raw, codebooks);
    const stored = columns.slice();
    const got = readIndices(columns, n, codebooks, records);
    assert.deepEqual(columns, stored, `seed ${seed}: the stored columns are read, not written`);
    const want = Array.from(columns);
    for (const rec of records) {
      for (let i = 0; i < n; i++) {
        want[rec.target * n + i] = rec.table[want[rec.context * n + i] * rec.width + want[rec.target * n + i]];
      }
    }
    assert.deepEqual(Array.from(got), want, `seed ${seed}`);
    if (records.length && n) assert.notEqual(got, columns, 'the stored columns are not changed in place');
  }
});

test('a rank past its codebook is bad-value, checked in the pass that resolves it ([R-52])', () => {
  let checked = 0;
  for (let seed = 1; seed <= 300 && checked < 40; seed++) {
    const { codebooks, entries, n, columns, raw } = randomCase(seed);
    const records = parseContexts(raw, codebooks).filter((rec) => entries[rec.target] < 256);
    if (!records.length || !n) continue;
    const rec = records[seed % records.length];
    const bad = columns.slice();
    bad[rec.target * n + (seed % n)] = entries[rec.target];
    assert.throws(() => readIndices(bad, n, codebooks, records), (err) => err.code === 'bad-value', `seed ${seed}`);
    checked++;
  }
  assert.ok(checked >= 20, `only ${checked} cases had a target column below 256 entries`);
});

test('every structural defect is bad-section, a table value out of range bad-value', () => {
  const books = [{ count: 5, groups: 3 }, { count: 3, groups: 1 }];   // columns 0-2: 5, 3: 3
  const rec = (t, c, rows, width, v = 0) => [t, c, ...new Array(rows * width).fill(v)];
  const cases = [
    [[], 'bad-section'],
    [[1, 1], 'bad-section'],
    [[1, ...rec(1, 0, 5, 5).slice(0, -1)], 'bad-section'],
    [[1, ...rec(1, 0, 5, 5), 0], 'bad-section'],
    [[1, ...rec(4, 0, 5, 5)], 'bad-section'],
    [[1, ...rec(1, 1, 5, 5)], 'bad-section'],
    [[1, ...rec(1, 2, 5, 5)], 'bad-section'],
    [[2, ...rec(2, 0, 5, 5), ...rec(1, 0, 5, 5)], 'bad-section'],
    [[2, ...rec(1, 0, 5, 5), ...rec(1, 0, 5, 5)], 'bad-section'],
    [[1, ...rec(3, 0, 5, 3, 2).slice(0, -1), 3], 'bad-value'],
  ];
  for (const [bytes, code] of cases) {
    assert.throws(() => parseContexts(Uint8Array.from(bytes), books), (err) => err.code === code,
      `${bytes.slice(0, 4)}: ${code}`);
  }
  assert.deepEqual(parseContexts(Uint8Array.of(0), books), []);
});
