// streamLayers: the layers of a real .spc (and of the same .spc inside a .glb) delivered in order
// as their bytes arrive, with the rotation that stands the scene upright; a file's preview
// (spec 7.4) before them, as soon as its section is in.

import assert from 'node:assert/strict';
import test from 'node:test';
import zlib from 'node:zlib';

import { decode, decodePreview, inspect, rotatePositions, streamLayers, upRotation } from '../src/index.js';
import { assertSameClouds, fakeGlb, fakeServer, fixture } from './helpers.js';
import { assemble, takeApart } from './mutate.js';

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

test('a server that ignores ranges still gives the header first: onInfo before any layer', async () => {
  const file = fixture('sh3-zlib-quant16');
  for (const chunk of [97, 5000]) {
    const { fetchImpl } = fakeServer(file, { ranges: false, chunk });
    const events = [];
    const result = await streamLayers('/scene.spc', { fetchImpl,
      onInfo: (info) => { events.push(`info ${info.layers.length}`); },
      onLayer: (l) => { events.push(`layer ${l.index}`); } });
    assert.equal(result.mode, 'stream');
    assert.deepEqual(events, ['info 4', 'layer 0', 'layer 1', 'layer 2', 'layer 3']);
    assert.equal(result.info.layers.length, 4);
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

test('a preview arrives before layer 0 completes, once, and is the decodePreview of the file', async () => {
  const file = fixture('sh1-preview');
  const [layer0] = inspect(file).layers;
  const expected = await decodePreview(file);
  for (const [chunk, ranges] of [[97, true], [5000, true], [1, false], [64, false]]) {
    const seen = [];
    const result = await streamLayers('/s.spc', { fetchImpl: fakeServer(file, { chunk, ranges }).fetchImpl,
      onPreview: (p) => { seen.push({ what: 'preview', ...p }); },
      onLayer: (l) => { seen.push({ what: l.index, ...l }); } });
    const what = `chunks of ${chunk}, ${ranges ? 'ranges' : 'one stream'}`;
    assert.deepEqual(seen.map((s) => s.what), ['preview', 0, 1, 2], what);
    const [preview] = seen;
    assert.ok(preview.bytesLoaded < layer0.end_offset, `${what}: before layer 0's last byte`);
    assert.ok(preview.bytesLoaded >= expected.section.end, `${what}: not before its own bytes`);
    assert.equal(preview.takeoverLayer, 1);
    assert.equal(preview.layerCount, 3);
    assert.equal(preview.bytes, expected.section.end - expected.section.offset);
    assert.deepEqual(preview.rotation, seen[1].rotation);
    assertSameClouds(preview.cloud, expected, what);
    assert.equal(result.preview, true);
    assert.equal(result.previewError, null);
  }
});

test('a gzip-wrapped file streams its preview first too; preview: false skips it', async () => {
  const file = new Uint8Array(zlib.gzipSync(fixture('sh1-preview')));
  const seen = [];
  await streamLayers('/s.spc', { fetchImpl: fakeServer(file, { chunk: 50 }).fetchImpl,
    onPreview: () => { seen.push('preview'); }, onLayer: (l) => { seen.push(l.index); } });
  assert.deepEqual(seen, ['preview', 0, 1, 2]);
  const skipped = [];
  const result = await streamLayers('/s.spc', { fetchImpl: fakeServer(file).fetchImpl, preview: false,
    onPreview: () => { skipped.push('preview'); }, onLayer: (l) => { skipped.push(l.index); } });
  assert.deepEqual(skipped, [0, 1, 2]);
  assert.equal(result.preview, false);
});

test('a preview that does not decode is reported and the layers stream as without one', async () => {
  const parts = takeApart(fixture('sh1-preview'));
  const section = parts.sections.find((s) => s.type === 0x0002);
  section.stored = section.stored.slice();
  section.stored[2] = 1;  // reserved field (CRC recomputed: the preview's check is what fails)
  const file = assemble(parts);
  const errors = [];
  const layers = [];
  const result = await streamLayers('/s.spc', { fetchImpl: fakeServer(file, { chunk: 97 }).fetchImpl,
    onPreview: () => assert.fail('no preview'), onPreviewError: (e) => { errors.push(e.code); },
    onLayer: (l) => { layers.push(l.index); } });
  assert.deepEqual(errors, ['reserved-nonzero']);
  assert.deepEqual(layers, [0, 1, 2]);
  assert.equal(result.preview, false);
  assert.equal(result.previewError.code, 'reserved-nonzero');
  const none = await streamLayers('/s.spc', { fetchImpl: fakeServer(fixture('sh3-zlib-quant16')).fetchImpl,
    onPreview: () => assert.fail('no preview'), onPreviewError: () => assert.fail('no error') });
  assert.equal(none.preview, false);
  assert.equal(none.previewError, null);
});
