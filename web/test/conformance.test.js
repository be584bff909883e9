/**
 * The conformance vectors (conformance/manifest.json), in-process: every outcome, for every
 * max_layer, is the Gaussian count or error code the manifest names. (The values are judged by
 * `spcodec conformance` through the CLI, in tests/test_web_decoder.py; this is the quick check.)
 */
import assert from 'node:assert/strict';
import { existsSync, readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { test } from 'node:test';
import { fileURLToPath } from 'node:url';

import { decode } from '../src/index.js';
import { outcome } from './helpers.js';

const SUITE = join(dirname(fileURLToPath(import.meta.url)), '..', '..', 'conformance');
const MANIFEST = join(SUITE, 'manifest.json');

test('every conformance vector decodes to its outcome', { skip: !existsSync(MANIFEST) && 'no conformance/manifest.json in this checkout' }, async () => {
  const manifest = JSON.parse(readFileSync(MANIFEST, 'utf8'));
  const wrong = [];
  let decodes = 0;
  for (const vector of manifest.vectors) {
    const bytes = new Uint8Array(readFileSync(join(SUITE, vector.input.path)));
    for (const want of vector.outcomes) {
      const maxLayer = want.max_layer ?? undefined;
      const got = await outcome(() => decode(bytes, { maxLayer }), `${vector.id} max_layer ${want.max_layer}`);
      decodes++;
      const ok = want.error
        ? [want.error, ...(want.also_accepted ?? [])].includes(got.code)
        : got.code === 'ok' && got.value.count === want.gaussians;
      if (!ok) wrong.push(`${vector.id} (max_layer ${want.max_layer}): want ${want.error ?? want.gaussians}, got ${got.code === 'ok' ? got.value.count : got.code}`);
    }
  }
  assert.deepEqual(wrong, [], `${wrong.length} of ${decodes} decodes differ`);
  assert.ok(decodes > 100);
});
