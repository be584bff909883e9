/**
 * Shared helpers of the node tests: fixtures, a PLY reader, a seeded random source, and the
 * oracle that every input either decodes to consistent finite arrays or raises SpcError.
 */
import assert from 'node:assert/strict';
import { readdirSync, readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

import { ERROR_CODES, SpcError, StreamDecoder, decode, inspect } from '../src/index.js';

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

/** @param {string} name */
export function expectedPly(name) {
  return readPly(new Uint8Array(readFileSync(join(FIXTURES, `${name}.ply`))));
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
