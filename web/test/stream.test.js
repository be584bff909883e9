/**
 * The StreamDecoder: fed in any chunk sizes it hands out each layer as soon as its bytes are in,
 * with the Gaussians decode() gives; stopping inside a layer is truncated at close().
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import { SpcError, StreamDecoder, decode, inspect } from '../src/index.js';
import { chunkSizes, fixture, fixtureNames, rng, streamDecode } from './helpers.js';

/** @param {import('../src/decoder.js').Cloud} a @param {import('../src/decoder.js').Cloud} b */
function sameArrays(a, b, what) {
  for (const key of ['positions', 'scales', 'rotations', 'opacities', 'shDC', 'shRest']) {
    assert.deepEqual(Array.from(a[key]), Array.from(b[key]), `${what}: ${key}`);
  }
}

for (const name of fixtureNames()) {
  test(`${name}: streamed in random chunks, layers equal decode() and arrive on time`, async () => {
    const bytes = fixture(name);
    const full = await decode(bytes);
    const ends = inspect(bytes).layers;
    for (let seed = 0; seed <= 5; seed++) {
      // seed 0: one byte at a time through the header, then random sizes
      const sizes = seed ? chunkSizes(bytes.length, rng(seed))
        : [...new Array(200).fill(1), ...chunkSizes(bytes.length - 200, rng(99))];
      const { layers } = await streamDecode(bytes, sizes);
      assert.equal(layers.length, full.layers.length);
      for (const layer of layers) {
        const info = full.layers[layer.index];
        const start = info.start;
        const slice = {
          positions: full.positions.subarray(3 * start, 3 * (start + info.count)),
          scales: full.scales.subarray(3 * start, 3 * (start + info.count)),
          rotations: full.rotations.subarray(4 * start, 4 * (start + info.count)),
          opacities: full.opacities.subarray(start, start + info.count),
          shDC: full.shDC.subarray(3 * start, 3 * (start + info.count)),
          shRest: full.shRest.subarray(full.shRest.length / Math.max(full.count, 1) * start,
            full.shRest.length / Math.max(full.count, 1) * (start + info.count)),
        };
        sameArrays(layer.cloud, slice, `${name} layer ${layer.index}`);
        assert.equal(layer.kind, info.kind);
        assert.equal(layer.innerByteEnd, info.innerByteEnd);
        const end = ends[layer.index].end_offset;
        if (end !== null && bytes[0] !== 0x1F) {
          // a plain file: the layer comes with the chunk holding its last byte, not later
          assert.ok(layer.pushed >= end, 'not before its bytes');
          assert.ok(layer.pushed - end < 65536, 'with the chunk that completed it');
        }
      }
    }
  });
}

test('a gzip-wrapped file hands out layer 0 before the wrapper has arrived', async () => {
  const bytes = fixture('sh3-gzip-mixed');
  const ends = inspect(bytes).layers.map((l) => l.end_offset);
  const dec = new StreamDecoder();
  const first = await dec.push(bytes.subarray(0, ends[0]));
  assert.deepEqual(first.map((l) => l.index), [0], 'layer 0 from the prefix up to its SP offset');
  const rest = await dec.push(bytes.subarray(ends[0]));
  assert.deepEqual(rest.map((l) => l.index), [1, 2, 3, 4]);
  await dec.close();
});

test('close(): stopping at a layer boundary is valid, inside a layer truncated', async () => {
  const bytes = fixture('sh3-zlib-quant16');
  const ends = inspect(bytes).layers.map((l) => l.end_offset);
  const atBoundary = new StreamDecoder();
  assert.equal((await atBoundary.push(bytes.subarray(0, ends[1]))).length, 2);
  await atBoundary.close();
  const inside = new StreamDecoder();
  await inside.push(bytes.subarray(0, ends[1] + 10));
  await assert.rejects(inside.close(), { code: 'truncated' });
  const withMax = new StreamDecoder({ maxLayer: 2 });
  await withMax.push(bytes.subarray(0, ends[1]));
  await assert.rejects(withMax.close(), { code: 'truncated' }, 'maxLayer asks for layer 2');
  const headerOnly = new StreamDecoder();
  await headerOnly.push(bytes.subarray(0, 40));
  await assert.rejects(headerOnly.close(), { code: 'truncated' });
});

test('maxLayer stops the stream decoder after that layer', async () => {
  const bytes = fixture('sh2-zlib-draco');
  const { layers, decoder } = await streamDecode(bytes, [bytes.length], { maxLayer: 1 });
  assert.deepEqual(layers.map((l) => l.index), [0, 1]);
  assert.equal(decoder.complete, true);
});

test('bad bytes fail early, and every later call fails the same way', async () => {
  const dec = new StreamDecoder();
  await assert.rejects(dec.push(new Uint8Array([0x42])), { code: 'bad-magic' });
  await assert.rejects(dec.push(new Uint8Array([0x89])), (err) => err instanceof SpcError && err.code === 'bad-magic');
  await assert.rejects(dec.close(), { code: 'bad-magic' });
  // a hostile header_size is refused from the fixed header, before waiting for the block
  const bytes = fixture('sh0-none-float16').slice(0, 48);
  new DataView(bytes.buffer).setUint32(16, 0xFFFFFFF0, true);
  await assert.rejects(new StreamDecoder().push(bytes), { code: 'bad-layout' });
});

test('trailing bytes after the file are refused', async () => {
  const bytes = fixture('sh0-none-float16');
  const dec = new StreamDecoder();
  await dec.push(bytes);
  await assert.rejects(dec.push(new Uint8Array([0])), { code: 'trailing-data' });
});
