// The range loader against an in-memory server: which ranges it asks for, and that every byte
// reaches the sink once, in order.

import assert from 'node:assert/strict';
import test from 'node:test';
import { FIRST_REQUEST_BYTES, parseContentRange, streamSpc, TransferError } from '../src/ranges.js';
import { fakeGlb, fakeServer } from './helpers.js';

/** A file whose header block is `headerSize` long (u32 at offset 16) followed by layers. */
function fakeFile(headerSize, layerEnds) {
  const file = new Uint8Array(layerEnds.at(-1));
  for (let i = 0; i < file.length; i++) file[i] = (i * 7 + 3) & 255;
  new DataView(file.buffer).setUint32(16, headerSize, true);
  return file;
}

function collector() {
  const chunks = [];
  return { chunks, sink: async (c) => { chunks.push(c.slice()); }, bytes: () => Buffer.concat(chunks) };
}

const plan = (layerEnds) => (head) => {
  assert.ok(head.length >= new DataView(head.buffer, head.byteOffset).getUint32(16, true),
    'the planner gets the whole header block');
  return { layers: layerEnds.map((endOffset, index) => ({ index, endOffset })) };
};

test('one range per layer after the first request, every byte once', async () => {
  const ends = [100_000, 180_000, 400_000];
  const file = fakeFile(300, ends);
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  const result = await streamSpc('/x.spc', { sink: out.sink, planLayers: plan(ends), fetchImpl });
  assert.deepEqual(log, [[0, FIRST_REQUEST_BYTES - 1], [FIRST_REQUEST_BYTES, 99_999],
    [100_000, 179_999], [180_000, 399_999]]);
  assert.deepEqual(result, { mode: 'ranges', fileSize: 400_000, bytes: 400_000 });
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('maxLayer stops the requests at that layer end', async () => {
  const ends = [100_000, 180_000, 400_000];
  const file = fakeFile(300, ends);
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  const result = await streamSpc('/x.spc', { sink: out.sink, planLayers: plan(ends), fetchImpl, maxLayer: 1 });
  assert.equal(result.bytes, 180_000);
  assert.equal(log.at(-1)[1], 179_999);
  assert.ok(Buffer.from(file.subarray(0, 180_000)).equals(out.bytes()));
});

test('layers inside the first request need no further request', async () => {
  const ends = [1_000, 3_000, 300_000];
  const file = fakeFile(200, ends);
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  await streamSpc('/x.spc', { sink: out.sink, planLayers: plan(ends), fetchImpl });
  assert.deepEqual(log, [[0, FIRST_REQUEST_BYTES - 1], [FIRST_REQUEST_BYTES, 299_999]]);
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('a header block longer than the first request is completed before planning', async () => {
  const ends = [150_000, 200_000];
  const file = fakeFile(10_000, ends);
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  await streamSpc('/x.spc', { sink: out.sink, planLayers: plan(ends), fetchImpl });
  assert.deepEqual(log[1], [FIRST_REQUEST_BYTES, 9_999]);
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('a server without ranges is read as one stream, planned on its head first', async () => {
  for (const [headerSize, chunk] of [[300, 1000], [300, 7], [10_000, 1000], [10_000, 30]]) {
    const ends = [100_000, 200_000];
    const file = fakeFile(headerSize, ends);
    const { fetchImpl, log } = fakeServer(file, { ranges: false, chunk });
    const out = collector();
    const planned = [];
    const planLayers = (head) => {
      planned.push(out.bytes().length);  // what the sink had been given before the plan
      return plan(ends)(head);
    };
    const result = await streamSpc('/x.spc', { sink: out.sink, planLayers, fetchImpl });
    assert.equal(result.mode, 'stream');
    assert.equal(log.length, 1);
    assert.deepEqual(planned, [0], 'planned once, on the whole header block, before any byte went on');
    assert.ok(Buffer.from(file).equals(out.bytes()));
  }
});

test('a file shorter than a first request, from a server without ranges, is planned once', async () => {
  const file = fakeFile(100, [1_500]);
  const { fetchImpl } = fakeServer(file, { ranges: false, chunk: 400 });
  const out = collector();
  const heads = [];
  const result = await streamSpc('/x.spc', { sink: out.sink, fetchImpl,
    planLayers: (head) => { heads.push(head.length); return plan([1_500])(head); } });
  assert.equal(result.bytes, 1_500);
  assert.deepEqual(heads, [1_500]);
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('a gzip-wrapped file without layer offsets is read as one stream (in two requests)', async () => {
  const file = fakeFile(300, [200_000]);
  file[0] = 0x1f;
  file[1] = 0x8b;
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  const planner = () => ({ layers: [{ index: 0, endOffset: null }] });
  const result = await streamSpc('/x.spc', { sink: out.sink, planLayers: planner, fetchImpl });
  assert.equal(result.mode, 'stream');
  assert.deepEqual(log, [[0, FIRST_REQUEST_BYTES - 1], [FIRST_REQUEST_BYTES, 199_999]]);
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('a gzip-wrapped file with layer offsets is fetched layer by layer', async () => {
  const ends = [50_000, 120_000];
  const file = fakeFile(300, ends);
  file[0] = 0x1f;
  file[1] = 0x8b;
  const { fetchImpl, log } = fakeServer(file);
  const out = collector();
  const planner = () => ({ layers: ends.map((endOffset, index) => ({ index, endOffset })) });
  const result = await streamSpc('/x.spc', { sink: out.sink, planLayers: planner, fetchImpl, maxLayer: 0 });
  assert.equal(result.mode, 'ranges');
  assert.deepEqual(log.at(-1), [FIRST_REQUEST_BYTES, 49_999]);
  assert.ok(Buffer.from(file.subarray(0, 50_000)).equals(out.bytes()));
  // all layers: the bytes after the last layer end (the gzip trailer) are fetched too
  const all = collector();
  const trailer = () => ({ layers: [{ index: 0, endOffset: 50_000 }, { index: 1, endOffset: 119_990 }] });
  await streamSpc('/x.spc', { sink: all.sink, planLayers: trailer, fetchImpl });
  assert.deepEqual(log.at(-1), [119_990, 119_999]);
  assert.ok(Buffer.from(file).equals(all.bytes()));
});

test('bytes that are no header go to the sink whole, for the decoder to reject', async () => {
  const file = new Uint8Array(100_000).fill(65);
  const { fetchImpl } = fakeServer(file);
  const out = collector();
  const planner = () => { throw new Error('not an spc'); };
  await streamSpc('/x.spc', { sink: out.sink, planLayers: planner, fetchImpl });
  assert.ok(Buffer.from(file).equals(out.bytes()));
});

test('a wrong Content-Range or an HTTP error is a TransferError', async () => {
  const liar = async () => new Response('xx', { status: 206, headers: { 'Content-Range': 'bytes 5-6/100' } });
  await assert.rejects(streamSpc('/x', { sink: async () => {}, planLayers: plan([10]), fetchImpl: liar }),
    TransferError);
  const missing = async () => new Response('no', { status: 404 });
  await assert.rejects(streamSpc('/x', { sink: async () => {}, planLayers: plan([10]), fetchImpl: missing }),
    /HTTP 404/);
});

test('parseContentRange', () => {
  assert.deepEqual(parseContentRange('bytes 0-47/1000'), { first: 0, last: 47, size: 1000 });
  assert.equal(parseContentRange('bytes */1000'), null);
  assert.equal(parseContentRange(null), null);
});

test('an .spc inside a .glb streams by ranges from where it lies, with the node rotation', async () => {
  const { streamScene } = await import('../src/ranges.js');
  const ends = [60_000, 90_000, 200_000];
  const spc = fakeFile(300, ends);
  const glb = fakeGlb(spc);
  for (const ranges of [true, false]) {
    const { fetchImpl, log } = fakeServer(glb, { ranges });
    const out = collector();
    const result = await streamScene('/scene.glb', { sink: out.sink, planLayers: plan(ends), fetchImpl });
    assert.ok(Buffer.from(spc).equals(out.bytes()), `every byte of the .spc, once (ranges: ${ranges})`);
    assert.deepEqual(result.rotation, [1, 0, 0, 0]);
    assert.equal(result.fileSize, spc.length);
    if (ranges) {
      const start = glb.length - Math.ceil((16 + spc.length) / 4) * 4 + 16;
      assert.deepEqual(log.slice(-3), [[start + FIRST_REQUEST_BYTES, start + 59_999],
        [start + 60_000, start + 89_999], [start + 90_000, start + 199_999]]);
    }
  }
});

test('a .glb without the embedded .spc is refused in one line', async () => {
  const { streamScene } = await import('../src/ranges.js');
  const other = fakeGlb(new Uint8Array(8));
  const name = Buffer.from(other).indexOf('SPCODEC_');
  other.set(new TextEncoder().encode('ELSEWHO_'), name);  // another vendor's extension
  const { fetchImpl } = fakeServer(other);
  await assert.rejects(streamScene('/x.glb', { sink: async () => {}, planLayers: plan([8]), fetchImpl }),
    (err) => err.code === 'bad-glb' && /holds no SPCODEC_gaussian_splatting_compression_spc/.test(err.message));
});
