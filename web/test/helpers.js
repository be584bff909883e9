/**
 * Shared helpers of the node tests: fixtures, a PLY reader, a seeded random source, and the
 * oracle that every input either decodes to consistent finite arrays or raises SpcError.
 */
import assert from 'node:assert/strict';
import { readdirSync, readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { ERROR_CODES, SpcError, StreamDecoder, decode, inspect } from '../src/index.js';
import { plyBytes } from '../src/ply.js';

export const FIXTURES = join(dirname(fileURLToPath(import.meta.url)), 'fixtures');

/** @returns {string[]} fixture names (without .spc) */
export function fixtureNames() {
  return readdirSync(FIXTURES).filter((f) => f.endsWith('.spc')).map((f) => f.slice(0, -4)).sort();
}

/** @param {string} name */
export function fixture(name) {
  return new Uint8Array(readFileSync(join(FIXTURES, `${name}.spc`)));
}

/**
 * A binary little-endian float PLY: property names and records.
 * @param {Uint8Array} bytes
 */
export function readPly(bytes) {
  const end = Buffer.from(bytes).indexOf('end_header\n') + 'end_header\n'.length;
  const lines = new TextDecoder().decode(bytes.subarray(0, end)).split('\n');
  const count = Number(lines.find((l) => l.startsWith('element vertex')).split(' ')[2]);
  const names = lines.filter((l) => l.startsWith('property float')).map((l) => l.split(' ')[2]);
  const body = bytes.slice(end);
  return { names, count, data: new Float32Array(body.buffer, body.byteOffset, count * names.length) };
}

/** @param {string} name a fixture, or `NAME.preview` for the preview of one that has it */
export function expectedPly(name) {
  return readPly(new Uint8Array(readFileSync(join(FIXTURES, `${name}.ply`))));
}

/** Sketch attributes may differ from the reference by rounding of the model sums ([R-96]). */
const TOLERANCE = 1e-5;

/**
 * Compare decoded Gaussians with rows [from, from + count) of the expected PLY: positions exactly,
 * other properties to a tight tolerance.
 */
export function assertMatches(scene, expected, from = 0) {
  const got = readPly(plyBytes(scene));
  assert.deepEqual(got.names, expected.names);
  const width = got.names.length;
  for (let i = 0; i < got.count; i++) {
    for (let j = 0; j < width; j++) {
      const a = got.data[i * width + j];
      const b = expected.data[(from + i) * width + j];
      if (j < 3) assert.equal(a, b, `Gaussian ${i} ${got.names[j]}`);
      else if (Math.abs(a - b) > TOLERANCE * (1 + Math.abs(b))) {
        assert.fail(`Gaussian ${i} ${got.names[j]}: ${a} vs ${b}`);
      }
    }
  }
}

/**
 * Assert that two clouds hold the same Gaussians, bit for bit.
 * @param {import('../src/decoder.js').Cloud} a
 * @param {import('../src/decoder.js').Cloud} b
 * @param {string} what
 */
export function assertSameClouds(a, b, what) {
  assert.equal(a.count, b.count, `${what}: count`);
  assert.equal(a.shDegree, b.shDegree, `${what}: SH degree`);
  for (const key of ['positions', 'scales', 'rotations', 'opacities', 'shDC', 'shRest']) {
    assert.deepEqual(Array.from(a[key]), Array.from(b[key]), `${what}: ${key}`);
  }
}

/** Mulberry32: a small seeded PRNG, so a failing case can be rerun. */
export function rng(seed) {
  let a = seed >>> 0;
  const next = () => {
    a = (a + 0x6D2B79F5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
  return {
    next,
    /** integer in [lo, hi) */
    int: (lo, hi) => lo + Math.floor(next() * (hi - lo)),
    pick: (items) => items[Math.floor(next() * items.length)],
    chance: (p) => next() < p,
  };
}

/**
 * Random chunk sizes that cover `length` bytes.
 * @param {number} length
 * @param {ReturnType<typeof rng>} r
 */
export function chunkSizes(length, r) {
  const sizes = [];
  for (let at = 0; at < length;) {
    const n = Math.min(length - at, r.pick([1, 2, 7, 48, 100, 1000, 4096, 65536]));
    sizes.push(n);
    at += n;
  }
  return sizes;
}

/**
 * Feed `bytes` to a StreamDecoder in the given chunk sizes; returns the layers and the number of
 * bytes pushed when each was handed out.
 * @param {Uint8Array} bytes
 * @param {number[]} sizes
 * @param {object} [options]
 */
export async function streamDecode(bytes, sizes, options) {
  const dec = new StreamDecoder(options);
  const layers = [];
  let at = 0;
  for (const n of sizes) {
    at += n;
    for (const layer of await dec.push(bytes.subarray(at - n, at))) layers.push({ ...layer, pushed: at });
  }
  await dec.close();
  return { layers, decoder: dec };
}

/**
 * Assert that a decoded cloud has arrays of consistent lengths and only finite values.
 * @param {import('../src/decoder.js').Cloud} cloud
 */
export function checkCloud(cloud) {
  const n = cloud.count;
  const k = (cloud.shDegree + 1) ** 2 - 1;
  assert.equal(cloud.positions.length, 3 * n);
  assert.equal(cloud.scales.length, 3 * n);
  assert.equal(cloud.rotations.length, 4 * n);
  assert.equal(cloud.opacities.length, n);
  assert.equal(cloud.shDC.length, 3 * n);
  assert.equal(cloud.shRest.length, 3 * k * n);
  for (const key of ['positions', 'scales', 'rotations', 'opacities', 'shDC', 'shRest']) {
    for (const v of cloud[key]) if (!Number.isFinite(v)) assert.fail(`${key} holds ${v}`);
  }
}

/**
 * Run `fn`; return 'ok' and its value, or the SpcError's code. Anything else fails the test.
 * @template T
 * @param {() => Promise<T> | T} fn
 * @param {string} what
 * @returns {Promise<{code: string, value?: T}>}
 */
export async function outcome(fn, what) {
  try {
    return { code: 'ok', value: await fn() };
  } catch (err) {
    if (err instanceof SpcError && err.code in ERROR_CODES) return { code: err.code };
    throw new Error(`${what}: threw ${err?.constructor?.name}: ${err?.stack ?? err}`);
  }
}

/**
 * The fuzz oracle for one input: decode, decode(maxLayer), inspect and the stream decoder either
 * succeed with consistent finite output or raise SpcError; the stream decoder accepts exactly
 * what decode accepts, with the same Gaussians.
 * @param {Uint8Array} data
 * @param {ReturnType<typeof rng>} r
 * @param {string} what
 */
export async function checkInput(data, r, what) {
  const whole = await outcome(() => decode(data), `${what} decode`);
  if (whole.value) checkCloud(whole.value);
  const k = r.int(0, 4);
  const partial = await outcome(() => decode(data, { maxLayer: k }), `${what} decode(maxLayer ${k})`);
  if (partial.value) checkCloud(partial.value);
  const info = await outcome(() => inspect(data), `${what} inspect`);
  if (info.value) JSON.stringify(info.value);
  const stream = await outcome(() => streamDecode(data, chunkSizes(data.length, r)), `${what} stream`);
  assert.equal(stream.code === 'ok', whole.code === 'ok',
    `${what}: decode says ${whole.code}, the stream decoder ${stream.code}`);
  if (whole.value && stream.value) {
    const counts = stream.value.layers.map((l) => l.cloud.count);
    assert.deepEqual(counts, whole.value.layers.map((l) => l.count), `${what}: stream layers differ`);
  }
  return whole.code;
}

/** A fake `fetch` serving `file` with single byte ranges, as `spcodec serve` does. */
export function fakeServer(file, { ranges = true, chunk = 1000 } = {}) {
  const log = [];
  const fetchImpl = async (url, { headers }) => {
    const match = /^bytes=(\d+)-(\d+)$/.exec(headers.Range);
    let first = Number(match[1]);
    let last = Math.min(Number(match[2]), file.length - 1);
    let status = 206;
    if (!ranges) {
      first = 0;
      last = file.length - 1;
      status = 200;
    }
    log.push([first, last]);
    const body = file.subarray(first, last + 1);
    const h = new Headers({ 'Content-Length': String(body.length) });
    if (status === 206) h.set('Content-Range', `bytes ${first}-${last}/${file.length}`);
    const stream = new ReadableStream({
      start(controller) {
        for (let i = 0; i < body.length; i += chunk) controller.enqueue(body.slice(i, i + chunk));
        controller.close();
      },
    });
    return new Response(stream, { status, headers: h });
  };
  return { fetchImpl, log };
}

/** A .glb as `spcodec embed` writes it: header, JSON chunk naming the .spc's buffer view, and the
 * binary chunk with `spc` at `padding` bytes into it. */
export function fakeGlb(spc, padding = 16) {
  const json = new TextEncoder().encode(JSON.stringify({
    asset: { version: '2.0' }, nodes: [{ mesh: 0, rotation: [1, 0, 0, 0] }],
    meshes: [{ primitives: [{ attributes: {}, mode: 0, extensions: { KHR_gaussian_splatting: {
      extensions: { SPCODEC_gaussian_splatting_compression_spc: { bufferView: 0 } } } } }] }],
    buffers: [{ byteLength: padding + spc.length }],
    bufferViews: [{ buffer: 0, byteOffset: padding, byteLength: spc.length }],
  }));
  const jsonPadded = new Uint8Array(Math.ceil(json.length / 4) * 4).fill(0x20);
  jsonPadded.set(json);
  const binLength = Math.ceil((padding + spc.length) / 4) * 4;
  const file = new Uint8Array(12 + 8 + jsonPadded.length + 8 + binLength);
  const view = new DataView(file.buffer);
  view.setUint32(0, 0x46546c67, true); view.setUint32(4, 2, true); view.setUint32(8, file.length, true);
  view.setUint32(12, jsonPadded.length, true); view.setUint32(16, 0x4e4f534a, true);
  file.set(jsonPadded, 20);
  const bin = 20 + jsonPadded.length;
  view.setUint32(bin, binLength, true); view.setUint32(bin + 4, 0x004e4942, true);
  file.set(spc, bin + 8 + padding);
  return file;
}

/** A fake three.js for the Spark loaders: Groups that keep what is added (and drop what is
 * removed) and the rotation they are given, and a Vector3 a camera can be read through. */
export const fakeThree = {
  Group: class {
    name = '';
    children = /** @type {any[]} */ ([]);
    quaternion = { xyzw: /** @type {number[]} */ ([]), set(...xyzw) { this.xyzw = xyzw; } };
    add(...objects) { this.children.push(...objects); }
    remove(object) { this.children = this.children.filter((c) => c !== object); }
  },
  Vector3: class { x = 0; y = 0; z = 0; },
};
