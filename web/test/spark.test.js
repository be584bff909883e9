// The Spark loader (loaders/spark.js) hands Spark the decoded arrays, not a PLY: what it gives
// Spark's encoders must be the reference decoder's Gaussians (the fixtures' PLYs, written by the
// Python decoder) in Spark's conventions: linear scales, activated opacity, colour from the SH DC
// term, quaternions x y z w, SH rest per band coefficient-major then R, G, B. A fake Spark module
// records every call; where web/examples has Spark installed, the real one packs the layers too
// and its unpacked splats must be the decoder's within Spark's quantization steps.

import assert from 'node:assert/strict';
import { existsSync } from 'node:fs';
import { dirname, join } from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import { loadSpc } from '../loaders/spark.js';
import { decode, upRotation } from '../src/index.js';
import { expectedPly, fakeServer, fakeThree, fixture } from './helpers.js';

/** Every SH degree, an empty sketch and empty patch layers, gzip, Draco, one-layer files. */
const FIXTURES = ['sh0-none-float16', 'sh1-zstd-float32', 'sh2-empty-sketch', 'sh2-zlib-draco',
  'sh3-gzip-mixed', 'sh3-sketch-only', 'sh3-zlib-quant16'];
const SH_C0 = 0.28209479177387814;
const BANDS = [[0, 3], [3, 8], [8, 15]];  // SH coefficients [first, end) of bands 1, 2, 3
const EXAMPLES = join(dirname(fileURLToPath(import.meta.url)), '..', 'examples', 'node_modules');

/** A fake Spark module whose encoders record their arguments, by the array they write into. */
function fakeSpark() {
  const splats = new Map();  // packedArray -> [index, x, y, z, ..., encoding] per call
  const sh = new Map();  // SH words -> [index, coefficients copy, encoding] per call
  const encodeSh = (words, index, coefficients, encoding) => {
    if (!sh.has(words)) sh.set(words, []);
    sh.get(words).push([index, Array.from(coefficients), encoding]);
  };
  const spark = {
    defines: { DEFAULT_SPLAT_ENCODING: { rgbMin: 0, rgbMax: 1, lnScaleMin: -12, lnScaleMax: 9,
      sh1Max: 1, sh2Max: 1, sh3Max: 1, lodOpacity: false } },
    utils: {
      setPackedSplat(packed, index, ...values) {
        if (!splats.has(packed)) splats.set(packed, []);
        splats.get(packed).push([index, ...values]);
      },
      encodeSh1Rgb: encodeSh, encodeSh2Rgb: encodeSh, encodeSh3Rgb: encodeSh,
      getTextureSize: (n) => ({ maxSplats: n + 7 }),  // odd on purpose: the loader must use it
    },
    PackedSplats: class { constructor(options) { this.options = options; } },
    SplatMesh: class {
      name = '';
      constructor(options) { this.options = options; this.initialized = Promise.resolve(this); }
    },
  };
  return { spark, splats, sh };
}

/** `a` within a relative 1e-5 of `b` (the JS decoder against the reference, [R-96]). */
function close(a, b, what) {
  assert.ok(Math.abs(a - b) <= 1e-5 * (1 + Math.abs(b)), `${what}: ${a} vs ${b}`);
}

for (const name of FIXTURES) {
  test(`${name}: Spark gets the decoded layers in its conventions, SH included`, async () => {
    const bytes = fixture(name);
    const scene = await decode(bytes);
    const ply = expectedPly(name);
    const column = (property) => ply.names.indexOf(property);
    const row = (r, property) => ply.data[r * ply.names.length + column(property)];
    const k = (scene.shDegree + 1) ** 2 - 1;
    const { spark, splats, sh } = fakeSpark();
    const shown = [];
    const result = await loadSpc('/x.spc', { THREE: fakeThree, spark,
      fetchImpl: fakeServer(bytes).fetchImpl, onLayer: (layer) => shown.push(layer) });

    const filled = scene.layers.filter((layer) => layer.count > 0);
    assert.equal(result.meshes.length, filled.length);
    assert.deepEqual(shown.map((l) => l.mesh === null), scene.layers.map((l) => l.count === 0));
    assert.deepEqual(result.group.children, result.meshes);
    assert.deepEqual(result.group.quaternion.xyzw, upRotation(null));
    const encoding = spark.defines.DEFAULT_SPLAT_ENCODING;
    result.meshes.forEach((mesh, m) => {
      const layer = filled[m];
      const { packedSplats, splatEncoding } = mesh.options;
      const init = packedSplats.options;
      assert.ok(packedSplats instanceof spark.PackedSplats);
      assert.deepEqual(splatEncoding, encoding);
      assert.equal(init.splatEncoding, splatEncoding);
      assert.equal(init.numSplats, layer.count);
      assert.equal(init.packedArray.length, 4 * (layer.count + 7));
      assert.deepEqual(Object.keys(init.extra), ['sh1', 'sh2', 'sh3'].slice(0, scene.shDegree));
      const calls = splats.get(init.packedArray);
      assert.equal(calls.length, layer.count);
      calls.forEach(([index, x, y, z, sx, sy, sz, qx, qy, qz, qw, opacity, red, green, blue, enc], i) => {
        const r = layer.start + i;
        const what = `${name} layer ${layer.index} Gaussian ${i}`;
        assert.equal(index, i);
        assert.equal(enc, splatEncoding);
        [x, y, z].forEach((v, a) => close(v, row(r, 'xyz'[a]), `${what} position`));
        [sx, sy, sz].forEach((v, a) => close(Math.log(v), row(r, `scale_${a}`), `${what} scale`));
        [qw, qx, qy, qz].forEach((v, a) => close(v, row(r, `rot_${a}`), `${what} rotation`));
        close(Math.log(opacity / (1 - opacity)), row(r, 'opacity'), `${what} opacity`);
        [red, green, blue].forEach((v, c) => close((v - 0.5) / SH_C0, row(r, `f_dc_${c}`), `${what} colour`));
      });
      BANDS.slice(0, scene.shDegree).forEach(([first, end], b) => {
        const bandCalls = sh.get(init.extra[`sh${b + 1}`]);
        assert.equal(init.extra[`sh${b + 1}`].length, (layer.count + 7) * (b === 0 ? 2 : 4));
        assert.equal(bandCalls.length, layer.count);
        bandCalls.forEach(([index, coefficients, enc], i) => {
          assert.equal(index, i);
          assert.equal(enc, splatEncoding);
          assert.equal(coefficients.length, 3 * (end - first));
          coefficients.forEach((v, e) => {
            const j = first + Math.floor(e / 3);
            close(v, row(layer.start + i, `f_rest_${(e % 3) * k + j}`), `${name} SH band ${b + 1}`);
          });
        });
      });
    });
  });
}

test('the loader says what it needs when Spark is not passed as a module', async () => {
  const { spark } = fakeSpark();
  await assert.rejects(loadSpc('/x.spc', /** @type {any} */ ({ THREE: fakeThree,
    SplatMesh: spark.SplatMesh })), /loadSpc needs \{ THREE, spark \}/);
});

const realSpark = join(EXAMPLES, '@sparkjsdev', 'spark', 'dist', 'spark.module.js');
const realThree = join(EXAMPLES, 'three', 'build', 'three.module.js');
const missing = existsSync(realSpark) && existsSync(realThree) ? false
  : 'Spark and three.js are not installed in web/examples (npm ci there)';

test('real Spark: its unpacked splats are the decoded ones within its quantization', { skip: missing },
  async () => {
    const spark = await import(realSpark);
    const THREE = await import(realThree);
    for (const name of ['sh1-zstd-float32', 'sh3-zlib-quant16']) {
      const bytes = fixture(name);
      const scene = await decode(bytes);
      const { fetchImpl } = fakeServer(bytes);
      const { group, meshes } = await loadSpc('/x.spc', { THREE, spark, fetchImpl });
      assert.ok(meshes.every((mesh) => mesh instanceof spark.SplatMesh && mesh.isInitialized));
      assert.deepEqual(group.children, meshes);
      meshes.forEach((mesh, m) => {
        const layer = scene.layers[m];
        const packed = mesh.packedSplats;
        assert.equal(packed.numSplats, layer.count);
        assert.equal(packed.getNumSh(), scene.shDegree);
        assert.deepEqual(packed.splatEncoding, spark.defines.DEFAULT_SPLAT_ENCODING);
        for (let i = 0; i < layer.count; i++) {
          const g = layer.start + i;
          const got = packed.getSplat(i);
          const what = `${name} layer ${m} Gaussian ${i}`;
          const p = scene.positions.subarray(3 * g, 3 * g + 3);
          [got.center.x, got.center.y, got.center.z].forEach((v, a) =>  // float16
            assert.ok(Math.abs(v - p[a]) <= 1e-3 * (1 + Math.abs(p[a])), `${what} position`));
          const lnStep = 21 / 254;  // 254 steps over ln -12..9
          [got.scales.x, got.scales.y, got.scales.z].forEach((v, a) => assert.ok(
            Math.abs(Math.log(v) - scene.scales[3 * g + a]) <= lnStep / 2 + 1e-4, `${what} scale`));
          const opacity = 1 / (1 + Math.exp(-scene.opacities[g]));
          assert.ok(Math.abs(got.opacity - opacity) <= 0.5 / 255 + 1e-6, `${what} opacity`);
          [got.color.r, got.color.g, got.color.b].forEach((v, c) => {  // 8 bits over 0..1
            const colour = Math.min(1, Math.max(0, 0.5 + SH_C0 * scene.shDC[3 * g + c]));
            assert.ok(Math.abs(v - colour) <= 0.5 / 255 + 1e-6, `${what} colour`);
          });
          const q = scene.rotations.subarray(4 * g, 4 * g + 4);
          const dot = got.quaternion.w * q[0] + got.quaternion.x * q[1] + got.quaternion.y * q[2]
            + got.quaternion.z * q[3];
          assert.ok(Math.abs(dot) > 0.999, `${what} rotation: |dot| ${Math.abs(dot)}`);
        }
      });
    }
  });
