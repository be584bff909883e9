/**
 * Mutation fuzzing: whatever the bytes, the decoder answers with Gaussians or an SpcError carrying
 * one of the spec's codes, never another exception, never a hang; the stream decoder accepts
 * exactly what decode() accepts.
 *
 * The mutants (test/mutate.js) are bit flips, cuts, appended bytes, header fields with the header
 * CRC repaired, damaged stored bytes and edited payloads with section CRCs repaired, section lists
 * reshuffled, huge claims, and gzip wrappers of all of these. The seed is printed with a failure;
 * SPC_FUZZ_ITERATIONS=20000 runs longer.
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import { checkInput, fixture, fixtureNames, rng } from './helpers.js';
import { MUTATORS, gzipMutant } from './mutate.js';

const ITERATIONS = Number(process.env.SPC_FUZZ_ITERATIONS ?? 1500);
const TIME_BOUND_MS = 3000;

const bases = fixtureNames().filter((n) => fixture(n)[0] === 0x89).map((n) => [n, fixture(n)]);

test(`fuzz: ${ITERATIONS} mutants only ever raise SpcError`, { timeout: 600_000 }, async () => {
  const seed = Number(process.env.SPC_FUZZ_SEED ?? 20250101);
  const r = rng(seed);
  const kinds = Object.keys(MUTATORS);
  const codes = new Map();
  for (let i = 0; i < ITERATIONS; i++) {
    const [name, bytes] = r.pick(bases);
    const kind = r.pick(kinds);
    let mutant = MUTATORS[kind](bytes, r);
    const wrapped = r.chance(0.15);
    if (wrapped) mutant = gzipMutant(mutant, r);
    const what = `mutant ${i} (seed ${seed}, ${kind}${wrapped ? '+gzip' : ''} of ${name})`;
    const start = performance.now();
    const code = await checkInput(mutant, r, what);
    const ms = performance.now() - start;
    assert.ok(ms < TIME_BOUND_MS, `${what} took ${ms.toFixed(0)} ms`);
    codes.set(code, (codes.get(code) ?? 0) + 1);
  }
  // the mutants must reach past the CRC checks: most spec codes show up
  const seen = [...codes.keys()];
  for (const code of ['ok', 'header-crc', 'section-crc', 'truncated', 'trailing-data', 'bad-layout',
    'bad-section', 'bad-value', 'limit-exceeded', 'decompression-failed', 'draco-failed']) {
    assert.ok(seen.includes(code), `no mutant produced ${code}: ${JSON.stringify(Object.fromEntries(codes))}`);
  }
});
