#!/usr/bin/env node
/**
 * The Node half of bench/bench_web_decode.py: times, from memory and interleaved, for each scene
 *
 *   - the JavaScript decoder (web/): decode() of the whole .spc, and the StreamDecoder fed 64 KiB
 *     chunks;
 *   - reading the same scene's INRIA PLY in JavaScript into the same typed arrays (a tight reader:
 *     one Float32Array view of the body, deinterleaved by column);
 *   - SPZ's own loader (@adobe/spz, the WebAssembly build of the SPZ reference library that
 *     PlayCanvas's splat-transform also uses) on the scene's .spz, where the scene has one;
 *   - the decoder's inflater against fflate's (web/'s dev dependency) on the scene's zlib sections.
 *
 *   node bench/web/decode_bench.mjs CONFIG.json
 *
 * CONFIG: {"repeat": N, "scenes": [{"name", "spc", "ply", "spz" (or null)}]}. Prints one JSON
 * document: the best time of N for each measurement, in seconds.
 */
import { readFileSync } from 'node:fs';

import { StreamDecoder, decode, inspect } from '../../web/src/index.js';
import { inflateZlib } from '../../web/src/codecs.js';

/**
 * An INRIA 3DGS PLY (binary little-endian float properties) into the decoder's typed arrays.
 * @param {Uint8Array} bytes
 */
export function readInriaPly(bytes) {
  const marker = 'end_header\n';
  let end = -1;
  for (let i = 0; i < Math.min(bytes.length, 1 << 16); i++) {
    if (bytes[i] === 0x65 && new TextDecoder().decode(bytes.subarray(i, i + marker.length)) === marker) {
      end = i + marker.length;
      break;
    }
  }
  if (end < 0) throw new Error('not a PLY');
  const lines = new TextDecoder().decode(bytes.subarray(0, end)).split('\n');
  const count = Number(lines.find((l) => l.startsWith('element vertex')).split(' ')[2]);
  const names = lines.filter((l) => l.startsWith('property')).map((l) => {
    const [, type, name] = l.split(' ');
    if (type !== 'float') throw new Error(`property ${name} is ${type}`);
    return name;
  });
  const width = names.length;
  // a view of the body where it is 4-byte aligned, else one copy of it
  const raw = (bytes.byteOffset + end) % 4 === 0 ? bytes.subarray(end) : bytes.slice(end);
  const body = new Float32Array(raw.buffer, raw.byteOffset, count * width);
  const col = (name) => names.indexOf(name);
  const rest = names.filter((n) => n.startsWith('f_rest_')).length;
  const k = rest / 3;
  const out = {
    count,
    positions: new Float32Array(3 * count),
    scales: new Float32Array(3 * count),
    rotations: new Float32Array(4 * count),
    opacities: new Float32Array(count),
    shDC: new Float32Array(3 * count),
    shRest: new Float32Array(rest * count),
  };
  const groups = [
    [out.positions, ['x', 'y', 'z'].map(col)],
    [out.scales, ['scale_0', 'scale_1', 'scale_2'].map(col)],
    [out.rotations, ['rot_0', 'rot_1', 'rot_2', 'rot_3'].map(col)],
    [out.opacities, [col('opacity')]],
    [out.shDC, ['f_dc_0', 'f_dc_1', 'f_dc_2'].map(col)],
    // coefficient-major then channel, as the decoder lays out SH: f_rest is channel-major
    [out.shRest, Array.from({ length: rest }, (_, j) => col(`f_rest_${(j % 3) * k + Math.floor(j / 3)}`))],
  ];
  for (const [target, columns] of groups) {
    const m = columns.length;
    for (let i = 0; i < count; i++) {
      const row = i * width;
      for (let j = 0; j < m; j++) target[i * m + j] = body[row + columns[j]];
    }
  }
  return out;
}

/** @param {() => Promise<unknown> | unknown} fn */
async function bestOf(fn, repeat) {
  await fn(); // warm up: JIT, WebAssembly instantiation
  let best = Infinity;
  for (let i = 0; i < repeat; i++) {
    const start = performance.now();
    await fn();
    best = Math.min(best, performance.now() - start);
  }
  return best / 1000;
}

async function streamed(bytes) {
  const dec = new StreamDecoder();
  let count = 0;
  for (let at = 0; at < bytes.length; at += 65536) {
    for (const layer of await dec.push(bytes.subarray(at, at + 65536))) count += layer.cloud.count;
  }
  await dec.close();
  return count;
}

/** The stored bytes and raw lengths of a file's zlib sections. */
function zlibSections(spc) {
  return inspect(spc).sections.filter((s) => s.codec === 'zlib')
    .map((s) => [spc.subarray(s.offset, s.offset + s.length), s.raw_length]);
}

async function loadFflate() {
  try {
    return await import('../../web/node_modules/fflate/esm/index.mjs');
  } catch {
    return null;
  }
}

async function loadSpzModule() {
  try {
    const { default: createSpzModule } = await import('@adobe/spz');
    const quiet = () => {};
    return await createSpzModule({ print: quiet, printErr: quiet });
  } catch (err) {
    return { missing: String(err?.message ?? err) };
  }
}

const config = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const spz = await loadSpzModule();
const fflate = await loadFflate();
const results = [];
for (const scene of config.scenes) {
  const spc = new Uint8Array(readFileSync(scene.spc));
  const ply = new Uint8Array(readFileSync(scene.ply));
  const decoded = await decode(spc);
  const row = {
    name: scene.name,
    gaussians: decoded.count,
    ply_gaussians: readInriaPly(ply).count,
    js_decode_s: await bestOf(() => decode(spc), config.repeat),
    js_stream_s: await bestOf(() => streamed(spc), config.repeat),
    js_ply_read_s: await bestOf(() => readInriaPly(ply), config.repeat),
    spz_s: null,
    spz_gaussians: null,
    zlib_raw_bytes: 0,
    js_inflate_s: null,
    fflate_inflate_s: null,
  };
  const sections = zlibSections(spc);
  row.zlib_raw_bytes = sections.reduce((sum, [, raw]) => sum + raw, 0);
  row.js_inflate_s = await bestOf(() => sections.forEach(([stored, raw]) => inflateZlib(stored, raw)), config.repeat);
  if (fflate) {
    row.fflate_inflate_s = await bestOf(() => sections.forEach(([stored, raw]) =>
      fflate.unzlibSync(stored, { out: new Uint8Array(raw) })), config.repeat);
  }
  if (scene.spz && !spz.missing) {
    const bytes = new Uint8Array(readFileSync(scene.spz));
    const load = () => spz.loadSpzFromBuffer(bytes, { to: spz.CoordinateSystem.UNSPECIFIED });
    row.spz_gaussians = load().numPoints;
    row.spz_s = await bestOf(load, config.repeat);
  }
  results.push(row);
}
process.stdout.write(`${JSON.stringify({ node: process.version, spz_loader: spz.missing ? null : '@adobe/spz 0.2.3', spz_missing: spz.missing ?? null, results })}\n`);
