// streamLayers: the layers of a real .spc (and of the same .spc inside a .glb) delivered in order
// as their bytes arrive, with the rotation that stands the scene upright.

import assert from 'node:assert/strict';
import test from 'node:test';

import { decode, rotatePositions, streamLayers, upRotation } from '../src/index.js';
import { fakeGlb, fakeServer, fixture } from './helpers.js';

test('every layer arrives in order and adds up to the whole decode', async () => {
  const file = fixture('sh3-zlib-quant16');
  const whole = await decode(file);
  for (const chunk of [97, 5000]) {
    const { fetchImpl, log } = fakeServer(file, { chunk });
    const layers = [];
    const result = await streamLayers('/scene.spc', { fetchImpl, onLayer: (l) => { layers.push(l); } });
    assert.deepEqual(layers.map((l) => l.index), [0, 1, 2, 3]);
    assert.equal(layers.reduce((n, l) => n + l.cloud.count, 0), whole.count);
    assert.deepEqual(result.rotation, upRotation('-y'));  // the file says nothing: -y
    assert.equal(result.mode, 'ranges');
    assert.ok(log.length >= layers.length, 'one range request per layer after the header');
    assert.ok(layers.every((l, i) => i === 0 || l.bytesLoaded >= layers[i - 1].bytesLoaded));
  }
});

test('the up axis comes from the file, else from the caller; a .glb says it by its node', async () => {
  const file = fixture('sh2-zlib-draco');
  const { fetchImpl } = fakeServer(file);
  const told = await streamLayers('/s.spc', { fetchImpl, up: '+z' });
  assert.deepEqual(told.rotation, upRotation('+z'));
  const glb = fakeGlb(file);  // its node turns by (1, 0, 0, 0): half a turn about x
  const seen = [];
  const inGlb = await streamLayers('/s.glb', { fetchImpl: fakeServer(glb).fetchImpl, up: '+z',
    onLayer: (l) => { seen.push(l.rotation); } });
  assert.deepEqual(inGlb.rotation, [1, 0, 0, 0]);
  assert.ok(seen.length && seen.every((r) => r.join() === '1,0,0,0'));
  const up = rotatePositions(Float32Array.of(0, -1, 0), inGlb.rotation);
  assert.ok(Math.abs(up[1] - 1) < 1e-9);
});

test('maxLayer stops early; a corrupt layer rejects after the good ones were delivered', async () => {
  const file = fixture('sh3-zlib-quant16');
  const early = [];
  await streamLayers('/s.spc', { fetchImpl: fakeServer(file).fetchImpl, maxLayer: 1,
    onLayer: (l) => { early.push(l.index); } });
  assert.deepEqual(early, [0, 1]);
  const bad = file.slice();
  bad[bad.length - 5] ^= 0xff;  // inside the last layer
  const got = [];
  await assert.rejects(streamLayers('/s.spc', { fetchImpl: fakeServer(bad).fetchImpl,
    onLayer: (l) => { got.push(l.index); } }), (err) => typeof err.code === 'string');
  assert.deepEqual(got, [0, 1, 2]);
});
