/**
 * The preview of a 1.1 file (spec 7.4): decodePreview gives the reference decoder's Gaussians, from
 * a plain or gzip-wrapped file or a prefix holding its section; its faults are reported with the
 * codes of in the reference's order; and none of it changes the scene's decode ([R-102]).
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';
import zlib from 'node:zlib';

import { SpcError, decode, decodePreview, findPreview, inspect } from '../src/index.js';
import { crc32 } from '../src/checksums.js';
import { decompress } from '../src/codecs.js';
import { readHeader } from '../src/header.js';
import { DEFAULT_LIMITS } from '../src/limits.js';
import { assertMatches, assertSameClouds, expectedPly, fixture } from './helpers.js';
import { assemble, repairHeaderCrc, takeApart } from './mutate.js';

const PREVIEW = 0x0002;
/** A 1.1 file of three layers whose preview (a sketch-only file) is shown until layer 1. */
const NAME = 'sh1-preview';
const FILE = fixture(NAME);

/** @param {Uint8Array} bytes a plain file */
function previewSection(bytes) {
  return findPreview(readHeader(bytes, DEFAULT_LIMITS));
}

/** The raw PREVIEW payload of a plain file. */
function payloadOf(bytes) {
  const sec = /** @type {any} */ (previewSection(bytes));
  return decompress(sec.codec, bytes.subarray(sec.offset, sec.end), sec.rawLength).slice();
}

const EMBEDDED = payloadOf(FILE).subarray(4);

/**
 * A PREVIEW payload.
 * @param {number} takeover
 * @param {number} reserved
 * @param {Uint8Array} file
 */
function payload(takeover, reserved, file) {
  const out = new Uint8Array(4 + file.length);
  const view = new DataView(out.buffer);
  view.setUint16(0, takeover, true);
  view.setUint16(2, reserved, true);
  out.set(file, 4);
  return out;
}

/**
 * FILE with its PREVIEW section's payload replaced, stored with codec none unless `zlib`; the
 * offsets and every CRC are recomputed, so the check aimed at is the one that fails.
 * @param {Uint8Array} raw
 * @param {{zlib?: boolean}} [options]
 */
function withPayload(raw, options = {}) {
  const parts = takeApart(FILE);
  const sec = parts.sections.find((s) => s.type === PREVIEW);
  sec.codec = options.zlib ? 1 : 0;
  sec.stored = options.zlib ? new Uint8Array(zlib.deflateSync(raw)) : raw;
  sec.rawLength = raw.length;
  return assemble(parts);
}

/** FILE with its section list edited (CRCs and offsets recomputed). */
function withSections(edit) {
  const parts = takeApart(FILE);
  parts.sections = edit(parts.sections);
  return assemble(parts);
}

/** The embedded file with `edit` applied to its parts. */
function embeddedWith(edit) {
  const parts = takeApart(EMBEDDED.slice());
  edit(parts);
  return assemble(parts);
}

/**
 * A gzip member of `inner` whose deflate data is flushed to a byte boundary after `at` bytes, so
 * that its first `cut` bytes inflate to exactly inner[0, at).
 * @param {Uint8Array} inner
 * @param {number} at
 */
function gzipFlushedAt(inner, at) {
  const head = zlib.deflateRawSync(inner.subarray(0, at), { finishFlush: zlib.constants.Z_SYNC_FLUSH });
  const tail = zlib.deflateRawSync(inner.subarray(at));
  const out = new Uint8Array(10 + head.length + tail.length + 8);
  out.set([0x1F, 0x8B, 8, 0, 0, 0, 0, 0, 0, 0xFF]);
  out.set(head, 10);
  out.set(tail, 10 + head.length);
  const trailer = new DataView(out.buffer, out.length - 8);
  trailer.setUint32(0, crc32(inner), true);
  trailer.setUint32(4, inner.length, true);
  return { bytes: out, cut: 10 + head.length };
}

/** @param {Promise<unknown>} promise @param {string} code @param {string} what */
async function rejectsWith(promise, code, what) {
  await assert.rejects(promise, (err) => {
    assert.ok(err instanceof SpcError, `${what}: ${err}`);
    assert.equal(err.code, code, `${what}: ${err.message}`);
    return true;
  });
}

test('the preview decodes to the reference decoder\'s Gaussians (decoder/preview.py)', async () => {
  const preview = await decodePreview(FILE);
  assert.ok(preview);
  assert.equal(preview.takeoverLayer, 1);
  const expected = expectedPly(`${NAME}.preview`);
  assert.equal(preview.count, expected.count);
  assertMatches(preview, expected);
  const sec = inspect(FILE).sections.find((s) => s.type === 'PREVIEW');
  assert.deepEqual(preview.section, { offset: sec.offset, end: sec.offset + sec.length });
  assert.equal(sec.layer, 0);
  assert.equal(inspect(FILE).version, '1.1');
});

test('the preview is the scene decode of the embedded file', async () => {
  const preview = await decodePreview(FILE);
  const embedded = await decode(EMBEDDED);
  assertSameClouds(preview, embedded, 'preview');
  assert.equal(preview.layers.length, embedded.layers.length);
  assert.notEqual(preview.count, (await decode(FILE)).count, 'not the scene');
  const zlibbed = await decodePreview(withPayload(payloadOf(FILE), { zlib: true }));
  assertSameClouds(zlibbed, embedded, 'a zlib-coded PREVIEW section');
});

test('gzip-wrapped input, and prefixes that hold the section', async () => {
  const embedded = await decode(EMBEDDED);
  const wrapped = new Uint8Array(zlib.gzipSync(FILE));
  const fromGzip = await decodePreview(wrapped);
  assertSameClouds(fromGzip, embedded, 'gzip-wrapped');
  assert.deepEqual(fromGzip.section, (await decodePreview(FILE)).section, 'inner offsets');
  const { end } = fromGzip.section;
  assertSameClouds(await decodePreview(FILE.subarray(0, end)), embedded, 'prefix to its end');
  const layer0 = inspect(FILE).layers[0].end_offset;
  assertSameClouds(await decodePreview(FILE.subarray(0, layer0)), embedded, 'prefix to layer 0');
  const flushed = gzipFlushedAt(FILE, end);
  assertSameClouds(await decodePreview(flushed.bytes), embedded, 'flushed gzip, whole');
  assertSameClouds(await decodePreview(flushed.bytes.subarray(0, flushed.cut)), embedded,
    'gzip prefix that inflates to the section end');
});

test('a file without a preview gives null', async () => {
  for (const name of ['sh3-zlib-quant16', 'sh3-gzip-mixed', 'sh0-unknown-optional']) {
    assert.equal(await decodePreview(fixture(name)), null, name);
  }
  const header = fixture('sh3-zlib-quant16').subarray(0, inspect(fixture('sh3-zlib-quant16')).header_size);
  assert.equal(await decodePreview(header), null, 'the header block alone says so');
});

test('[R-102] the scene decodes as the same file without its preview, broken or doubled', async () => {
  const scene = await decode(FILE);
  const without = withSections((list) => list.filter((s) => s.type !== PREVIEW));
  assert.equal(await decodePreview(without), null);
  const bare = await decode(without);
  assertSameClouds(scene, bare, 'with vs without the preview');
  assert.deepEqual(scene.layers.map((l) => l.count), bare.layers.map((l) => l.count));
  const broken = {
    'reserved field set': withPayload(payload(1, 7, EMBEDDED)),
    'takeover past the last layer': withPayload(payload(9, 0, EMBEDDED)),
    'garbage payload': withPayload(new Uint8Array([1, 2])),
    'two in layer 0': withSections((list) => [list[0], list[1], { ...list[1] }, ...list.slice(2)]),
    'one in layer 2 too': withSections((list) => [...list, { ...list[1], layer: 2 }]),
  };
  for (const [what, bytes] of Object.entries(broken)) {
    const got = await decode(bytes);
    assertSameClouds(got, bare, what);
  }
  // a required PREVIEW is a required section of unknown type to the scene decode ([R-21])
  const required = withSections((list) => list.map((s) => (s.type === PREVIEW ? { ...s, flags: 1 } : s)));
  await rejectsWith(decode(required), 'unknown-required-section', 'required PREVIEW');
  // and its CRC is verified with its layer ([R-7])
  const bad = FILE.slice();
  bad[previewSection(FILE).offset + 20] ^= 1;
  await rejectsWith(decode(bad), 'section-crc', 'scene, corrupt PREVIEW');
});

test('only the PREVIEW of layer 0 is a preview', async () => {
  const embedded = await decode(EMBEDDED);
  const laterToo = withSections((list) => [...list,
    { ...list[1], layer: 2, stored: new Uint8Array([0xFF]), rawLength: 1 }]);
  assertSameClouds(await decodePreview(laterToo), embedded, 'a broken one in layer 2 is ignored');
  const onlyLater = withSections((list) => [...list.filter((s) => s.type !== PREVIEW), { ...list[1], layer: 2 }]);
  assert.equal(await decodePreview(onlyLater), null);
});

test('[R-103] every fault of the preview, with its code', async () => {
  const sec = /** @type {any} */ (previewSection(FILE));
  const headerFlip = FILE.slice();
  headerFlip[33] ^= 1;
  const storedFlip = FILE.slice();
  storedFlip[sec.offset + 30] ^= 1;
  const withZlibGarbage = withSections((list) => list.map((s) => (s.type === PREVIEW
    ? { ...s, codec: 1, stored: new Uint8Array([0x78, 0x9C, 1, 2, 3, 4, 5]) } : s)));
  const lengthWrong = withSections((list) => list.map((s) => (s.type === PREVIEW
    ? { ...s, rawLength: s.rawLength + 1 } : s)));
  const nested = embeddedWith((p) => {
    p.sections.splice(0, 0, { type: PREVIEW, codec: 0, flags: 0, layer: 0, rawLength: 4, stored: payload(0, 0, new Uint8Array(0)) });
  });
  const embeddedHeaderFlip = EMBEDDED.slice();
  embeddedHeaderFlip[24] ^= 1;
  const embeddedVersion = EMBEDDED.slice();
  embeddedVersion[8] = 2;
  repairHeaderCrc(embeddedVersion);
  const embeddedLayerFlip = EMBEDDED.slice();
  embeddedLayerFlip[embeddedLayerFlip.length - 3] ^= 1;
  const wrappedEmbedded = new Uint8Array(zlib.gzipSync(EMBEDDED));
  const layers = inspect(FILE).layers.length;
  const cases = {
    // steps 1-5 for the input
    'bad-magic': [new Uint8Array([0x50, 0x4B, 3, 4])],
    'header-crc': [headerFlip],
    'truncated': [FILE.subarray(0, 100), FILE.subarray(0, sec.offset), FILE.subarray(0, sec.end - 1),
      gzipFlushedAt(FILE, sec.end - 1).bytes.subarray(0, gzipFlushedAt(FILE, sec.end - 1).cut)],
    'duplicate-section': [withSections((list) => [list[0], list[1], { ...list[1] }, ...list.slice(2)])],
    'section-crc': [storedFlip],
    'decompression-failed': [withZlibGarbage],
    'length-mismatch': [lengthWrong],
    'bad-section': [
      withPayload(new Uint8Array(0)), withPayload(new Uint8Array([1, 0, 0])),  // shorter than 4
      withPayload(payload(1, 0, wrappedEmbedded)),  // gzip-wrapped
      withPayload(payload(1, 0, new Uint8Array([...EMBEDDED, 0]))),  // longer than its file_size
      withPayload(payload(1, 0, nested)),  // a preview of its own
    ],
    'reserved-nonzero': [withPayload(payload(1, 1, EMBEDDED)), withPayload(payload(1, 0x8000, EMBEDDED))],
    'bad-value': [withPayload(payload(layers, 0, EMBEDDED)), withPayload(payload(0xFFFF, 0, EMBEDDED))],
  };
  // the embedded file's own faults keep their codes: its header block, then its decode
  const embeddedCases = {
    'bad-magic': [new Uint8Array([0x89, 0x53, 0x50, 0x44, ...EMBEDDED.subarray(4)]), new Uint8Array([0])],
    'truncated': [EMBEDDED.subarray(0, 30), EMBEDDED.subarray(0, 1), new Uint8Array(0)],
    'header-crc': [embeddedHeaderFlip],
    'unsupported-version': [embeddedVersion],
    'section-crc': [embeddedLayerFlip],
    'bad-section': [EMBEDDED.subarray(0, EMBEDDED.length - 1)],  // a prefix: shorter than file_size
  };
  for (const [code, inputs] of Object.entries(cases)) {
    for (const [i, bytes] of inputs.entries()) await rejectsWith(decodePreview(bytes), code, `${code} #${i}`);
  }
  for (const [code, files] of Object.entries(embeddedCases)) {
    for (const [i, file] of files.entries()) {
      await rejectsWith(decodePreview(withPayload(payload(1, 0, file))), code, `embedded ${code} #${i}`);
    }
  }
  // every one of them leaves the scene alone
  for (const bytes of [...cases['bad-section'], ...cases['reserved-nonzero'], ...cases['bad-value']]) {
    assert.equal((await decode(bytes)).count, (await decode(FILE)).count);
  }
});

test('[R-103] with several faults, the first check in the order is the one reported', async () => {
  const order = [
    ['reserved-nonzero', payload(9, 1, new Uint8Array([0x1F, 0x8B, 0]))],  // reserved before T
    ['bad-value', payload(9, 0, new Uint8Array([0x1F, 0x8B, 0]))],         // T before gzip
    ['bad-section', payload(0, 0, new Uint8Array([0x1F, 0x8B, 0]))],       // gzip before the header
    ['bad-section', payload(0, 0, new Uint8Array([...EMBEDDED, ...EMBEDDED]))],  // length before decode
  ];
  for (const [code, raw] of order) await rejectsWith(decodePreview(withPayload(raw)), code, code);
  // duplicate-section before truncated: the header says so before any section byte is needed
  const doubled = withSections((list) => [list[0], list[1], { ...list[1] }, ...list.slice(2)]);
  await rejectsWith(decodePreview(doubled.subarray(0, inspect(doubled).header_size)), 'duplicate-section', 'header only');
  // the header block's faults before anything of the preview
  const prefix = FILE.subarray(0, inspect(FILE).header_size - 1);
  await rejectsWith(decodePreview(prefix), 'truncated', 'inside the header block');
});
