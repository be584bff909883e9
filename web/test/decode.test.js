/**
 * Decoding the fixtures: the output equals the Python decoder's, prefixes decode to their layers
 * ([R-11]), and cut or padded data is refused with the spec's codes ([R-12], [R-4]).
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import { SpcError, decode, inspect } from '../src/index.js';
import { assertMatches, expectedPly, fixture, fixtureNames } from './helpers.js';

/** Where each layer ends in the bytes given (the gzip offsets for a wrapped file, when recorded). */
function layerEnds(bytes) {
  return inspect(bytes).layers.map((l) => l.end_offset);
}

for (const name of fixtureNames()) {
  test(`${name}: decodes to the Python decoder's output`, async () => {
    const bytes = fixture(name);
    const scene = await decode(bytes);
    const expected = expectedPly(name);
    assert.equal(scene.count, expected.count);
    assert.equal(scene.complete, true);
    assert.equal(scene.layers.reduce((s, l) => s + l.count, 0), scene.count);
    assertMatches(scene, expected);
  });

  test(`${name}: every layer prefix and maxLayer decodes to its layers`, async () => {
    const bytes = fixture(name);
    const full = await decode(bytes);
    const expected = expectedPly(name);
    const ends = layerEnds(bytes);
    for (let k = 0; k < full.layers.length; k++) {
      const count = full.layers[k].start + full.layers[k].count;
      const limited = await decode(bytes, { maxLayer: k });
      assert.equal(limited.count, count);
      assert.equal(limited.complete, k === full.layers.length - 1);
      assertMatches(limited, expected);
      if (ends[k] !== null) {
        const prefix = await decode(bytes.subarray(0, ends[k]));
        assert.equal(prefix.count, count, `prefix of layer ${k}`);
        assert.equal(prefix.layers.length, k + 1);
        assertMatches(prefix, expected);
      }
    }
  });

  test(`${name}: data cut inside a layer or padded is refused`, async () => {
    const bytes = fixture(name);
    const ends = new Set(layerEnds(bytes));
    const wrapped = bytes[0] === 0x1F;
    for (const cut of [1, 7, 30, 47, 48, 60, bytes.length - 1]) {
      if (ends.has(cut) || (wrapped && cut >= bytes.length - 8)) continue; // gzip trailer
      await assert.rejects(decode(bytes.subarray(0, cut)), (err) => err instanceof SpcError &&
        err.code === 'truncated', `cut at ${cut}`);
    }
    const padded = new Uint8Array(bytes.length + 1);
    padded.set(bytes);
    await assert.rejects(decode(padded), { code: 'trailing-data' });
  });
}

test('maxLayer beyond the bytes present is truncated; beyond the last layer means all', async () => {
  const bytes = fixture('sh3-zlib-quant16');
  const ends = layerEnds(bytes);
  await assert.rejects(decode(bytes.subarray(0, ends[0]), { maxLayer: 1 }), { code: 'truncated' });
  const all = await decode(bytes, { maxLayer: 99 });
  assert.equal(all.layers.length, ends.length);
  await assert.rejects(decode(bytes, { maxLayer: -1 }), RangeError);
});

test('metadata is parsed; a file without it reports null', async () => {
  const scene = await decode(fixture('sh3-zlib-quant16'));
  assert.deepEqual(scene.metadata, { encoder: 'fixture', seed: 1 });
  assert.equal(scene.metadataError, null);
  assert.equal((await decode(fixture('sh0-none-float16'))).metadata, null);
});

test('layer byte ends: inner offsets, and the gzip SP offsets for a wrapped file', async () => {
  const plain = await decode(fixture('sh3-zlib-quant16'));
  assert.deepEqual(plain.layers.map((l) => l.byteEnd), plain.layers.map((l) => l.innerByteEnd));
  const wrapped = fixture('sh3-gzip-mixed');
  const scene = await decode(wrapped);
  assert.equal(scene.layers.at(-1).byteEnd < wrapped.length, true);
  assert.deepEqual(scene.layers.map((l) => l.byteEnd), layerEnds(wrapped));
  const unrecorded = await decode(fixture('sh1-gzip-no-offsets'));
  assert.deepEqual(unrecorded.layers.map((l) => l.byteEnd), unrecorded.layers.map(() => null));
});

test('short inputs: a prefix of the magic or a lone 1F is truncated, anything else bad-magic', async () => {
  for (const bytes of [[], [0x89], [0x89, 0x53, 0x50], [0x1F]]) {
    await assert.rejects(decode(new Uint8Array(bytes)), { code: 'truncated' }, `${bytes}`);
  }
  for (const bytes of [[0x00], [0x89, 0x00], [0x1F, 0x00], [0x50, 0x4B, 0x03, 0x04]]) {
    await assert.rejects(decode(new Uint8Array(bytes)), { code: 'bad-magic' }, `${bytes}`);
  }
});

test('inspect describes the header like `spcodec info --json`', () => {
  const info = inspect(fixture('sh3-zlib-quant16'));
  assert.equal(info.version, '1.0');
  assert.equal(info.sh_degree, 3);
  assert.equal(info.gzip, false);
  assert.equal(info.layers.length, 4);
  assert.equal(info.sections[0].type, 'METADATA');
  assert.deepEqual(info.metadata, { encoder: 'fixture', seed: 1 });
  const header = fixture('sh3-zlib-quant16').subarray(0, info.header_size);
  assert.deepEqual(inspect(header).layers, info.layers, 'the header block alone is enough');
});
