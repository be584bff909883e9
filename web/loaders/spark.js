// .spc in three.js apps with Spark (@sparkjsdev/spark), the most used three.js splat renderer.
//
//   import * as THREE from 'three';
//   import * as spark from '@sparkjsdev/spark';
//   import { loadSpc, loadTileset } from 'spcodec/spark';
//
//   scene.add(new spark.SparkRenderer({ renderer }));
//   const { group } = await loadSpc('scene.spc', { THREE, spark, parent: scene,
//                                                  onLayer: (l) => console.log(l.index) });
//
//   // a tileset (`python -m spcodec.tiling`), by view: call tiles.update() in the render loop
//   const tiles = await loadTileset('out/tileset.json', { THREE, spark, camera, parent: scene,
//                                    height: () => renderer.domElement.height });
//
// Each layer becomes a SplatMesh of its own, added (under one group turned upright, +Y up) as soon
// as its bytes are in: Spark sorts the splats of every mesh together, so later layers refine the
// picture the first ones started. A layer reaches Spark as the decoded arrays, packed by Spark's
// own encoders (`utils.setPackedSplat`, `utils.encodeSh{1,2,3}Rgb`) into a PackedSplats with
// Spark's default encoding, the one its PLY reader gives the PLY `spcodec decode` writes (the
// browser tests compare the two pictures): no PLY is made for Spark to parse again, and SH bands
// 1..3 go along. Reads an .spc or a .glb written by `spcodec embed`, by HTTP range requests.
// three.js and Spark are passed in, so the app's own copies make the objects.

import { streamLayers } from '../src/stream.js';
import { TilesetStream } from '../src/tilestream.js';

// three.js and Spark come in as arguments, not as imports: the types below say what the loader
// uses of them, so that they check without either installed.

/**
 * What the loader uses of a three.js Object3D (`parent`, and the group it makes).
 * @typedef {{add(...objects: unknown[]): unknown}} ThreeParent
 */

/**
 * What the loader uses of the three.js module: its Group class.
 * @typedef {{Group: new () => ThreeParent & {name: string,
 *   quaternion: {set(...xyzw: number[]): unknown}}}} ThreeModule
 */

/**
 * Spark's `SplatEncoding`: the ranges its packed form quantizes colour, log-scale and SH into.
 * @typedef {{rgbMin?: number, rgbMax?: number, lnScaleMin?: number, lnScaleMax?: number,
 *   sh1Max?: number, sh2Max?: number, sh3Max?: number, lodOpacity?: boolean}} SplatEncoding
 */

/**
 * Spark's encoder of one SH band of one splat into its packed words (`utils.encodeSh1Rgb`...):
 * the band's coefficients coefficient-major, then R, G, B.
 * @typedef {(words: Uint32Array, index: number, coefficients: Float32Array,
 *   encoding?: SplatEncoding) => void} ShEncoder
 */

/**
 * What the loader uses of Spark's `utils`: its packing of splats, in Spark's conventions (centre,
 * linear scales, quaternion x y z w, opacity and colour in 0..1), and its texture capacity.
 * @typedef {{
 *   setPackedSplat(packed: Uint32Array, index: number, x: number, y: number, z: number,
 *     scaleX: number, scaleY: number, scaleZ: number, quatX: number, quatY: number, quatZ: number,
 *     quatW: number, opacity: number, r: number, g: number, b: number,
 *     encoding?: SplatEncoding): void,
 *   encodeSh1Rgb: ShEncoder, encodeSh2Rgb: ShEncoder, encodeSh3Rgb: ShEncoder,
 *   getTextureSize(numSplats: number): {maxSplats: number},
 * }} SparkUtils
 */

/**
 * The options this loader gives Spark's `PackedSplats`: the packed words, the SH bands'
 * words (`extra.sh1`.. `sh3`, as many as the scene's degree) and the encoding of both.
 * @typedef {{packedArray: Uint32Array, numSplats: number,
 *   extra: {sh1?: Uint32Array, sh2?: Uint32Array, sh3?: Uint32Array},
 *   splatEncoding: SplatEncoding}} PackedSplatsInit
 */

/**
 * What the loader uses of a SplatMesh.
 * @typedef {{name?: string, initialized: Promise<unknown>}} SparkMesh
 */

/**
 * What the loader uses of the Spark module (`import * as spark from '@sparkjsdev/spark'`).
 * @template P, M
 * @typedef {{
 *   PackedSplats: new (options: PackedSplatsInit) => P,
 *   SplatMesh: new (options: {packedSplats: P, splatEncoding: SplatEncoding}) => M,
 *   utils: SparkUtils,
 *   defines: {DEFAULT_SPLAT_ENCODING: SplatEncoding},
 * }} SparkModule
 */

/** The degree-0 SH basis constant: colour = 0.5 + SH_C0 * f_dc, as 3DGS renderers take it. */
const SH_C0 = 0.28209479177387814;

/** Spark's SH bands: coefficients [first, end) of the K per channel, and words per splat. */
const SH_BANDS = /** @type {const} */ ([
  { key: 'sh1', first: 0, end: 3, words: 2, encoder: 'encodeSh1Rgb' },
  { key: 'sh2', first: 3, end: 8, words: 4, encoder: 'encodeSh2Rgb' },
  { key: 'sh3', first: 8, end: 15, words: 4, encoder: 'encodeSh3Rgb' },
]);

/**
 * A decoded cloud in Spark's packed form, packed by Spark's own encoders.
 *
 * Spark takes scales linear (the decoder's are logs), opacity activated (the decoder's is a
 * logit), colour as 0.5 + SH_C0 * f_dc, and quaternions x y z w (the decoder's are w x y z). The
 * arrays are sized to Spark's texture capacity, which PackedSplats expects of a `packedArray`.
 *
 * @param {import('../src/decoder.js').Cloud} cloud
 * @param {SparkUtils} utils  Spark's `utils`
 * @param {SplatEncoding} encoding
 * @returns {PackedSplatsInit}
 */
export function packCloud(cloud, utils, encoding) {
  const n = cloud.count;
  const { maxSplats } = utils.getTextureSize(n);
  const packedArray = new Uint32Array(maxSplats * 4);
  const { positions: p, scales: s, rotations: q, opacities: o, shDC: dc } = cloud;
  for (let i = 0; i < n; i++) {
    const i3 = 3 * i;
    const i4 = 4 * i;
    utils.setPackedSplat(packedArray, i, p[i3], p[i3 + 1], p[i3 + 2],
      Math.exp(s[i3]), Math.exp(s[i3 + 1]), Math.exp(s[i3 + 2]),
      q[i4 + 1], q[i4 + 2], q[i4 + 3], q[i4],
      1 / (1 + Math.exp(-o[i])),
      0.5 + SH_C0 * dc[i3], 0.5 + SH_C0 * dc[i3 + 1], 0.5 + SH_C0 * dc[i3 + 2], encoding);
  }
  return { packedArray, numSplats: n, extra: packSh(cloud, utils, maxSplats, encoding),
    splatEncoding: encoding };
}

/**
 * The cloud's SH bands 1..shDegree as Spark's `extra.sh1`..`sh3` words. The decoder's SH rest is
 * already in the order Spark's encoders read (coefficient-major, then R, G, B), so each band of
 * each splat is a view of it, not a copy.
 *
 * @param {import('../src/decoder.js').Cloud} cloud
 * @param {SparkUtils} utils
 * @param {number} capacity  splats the words are sized for (Spark's texture capacity)
 * @param {SplatEncoding} encoding
 * @returns {PackedSplatsInit['extra']}
 */
function packSh(cloud, utils, capacity, encoding) {
  const k = (cloud.shDegree + 1) ** 2 - 1;
  /** @type {PackedSplatsInit['extra']} */
  const extra = {};
  for (const band of SH_BANDS.slice(0, cloud.shDegree)) {
    const words = new Uint32Array(capacity * band.words);
    const encode = utils[band.encoder];
    for (let i = 0; i < cloud.count; i++) {
      encode(words, i, cloud.shRest.subarray(3 * (k * i + band.first), 3 * (k * i + band.end)),
        encoding);
    }
    extra[band.key] = words;
  }
  return extra;
}

/**
 * Stream `url` into a THREE.Group of SplatMeshes, one per layer as it arrives.
 *
 * @template {ThreeModule} T
 * @template P
 * @template {SparkMesh} M
 * @param {string} url  an .spc, or a .glb written by `spcodec embed`
 * @param {object} options
 * @param {T} options.THREE  the three.js module
 * @param {SparkModule<P, M>} options.spark  the Spark module (`import * as spark from
 *   '@sparkjsdev/spark'`)
 * @param {ThreeParent|null} [options.parent]  an Object3D the group is added to at once (default:
 *   none)
 * @param {number} [options.maxLayer]  stop after this layer
 * @param {string} [options.up]  the up axis where the file does not store one (default -y)
 * @param {(layer: import('../src/stream.js').StreamedLayer & {mesh: M|null}) => void}
 *   [options.onLayer]  once each layer's mesh is ready (`mesh`: null for an empty layer)
 * @param {(loaded: number, total: number|null) => void} [options.onProgress]
 * @param {typeof fetch} [options.fetchImpl]
 * @returns {Promise<{group: InstanceType<T['Group']>, meshes: M[],
 *   info: ReturnType<typeof import('../src/decoder.js').inspect>|null, layers: number,
 *   bytes: number}>}
 */
export async function loadSpc(url, { THREE, spark, parent = null, maxLayer = Infinity,
  up = null, onLayer = () => {}, onProgress = () => {}, fetchImpl = fetch,
} = /** @type {any} */ ({})) {  // {}: THREE and spark are required, the check below says so
  if (!THREE || !spark?.SplatMesh || !spark.PackedSplats || !spark.utils) {
    throw new Error('loadSpc needs { THREE, spark }: three.js, and Spark as a module '
      + "(`import * as spark from '@sparkjsdev/spark'`)");
  }
  const encoding = { ...spark.defines.DEFAULT_SPLAT_ENCODING };
  const group = /** @type {InstanceType<T['Group']>} */ (new THREE.Group());
  group.name = `spc ${url}`;
  parent?.add(group);
  /** @type {M[]} */
  const meshes = [];
  const ready = [];
  const result = await streamLayers(url, {
    maxLayer, up, onProgress, fetchImpl,
    onLayer: (layer) => {
      group.quaternion.set(...layer.rotation);
      if (layer.cloud.count === 0) {
        onLayer({ ...layer, mesh: null });
        return;
      }
      const packedSplats = new spark.PackedSplats(packCloud(layer.cloud, spark.utils, encoding));
      // SplatMesh sets the encoding it is given on the PackedSplats: the same one, explicitly
      const mesh = new spark.SplatMesh({ packedSplats, splatEncoding: encoding });
      mesh.name = `layer ${layer.index}`;
      meshes.push(mesh);
      group.add(mesh);
      ready.push(mesh.initialized.then(() => onLayer({ ...layer, mesh })));
    },
  });
  await Promise.all(ready);
  return { group, meshes, info: result.info, layers: result.layers, bytes: result.bytes };
}

/**
 * What the tileset loader reads of a three.js camera (a PerspectiveCamera): where it is and looks
 * in the world, its vertical field of view in degrees, and its aspect.
 * @typedef {{fov: number, aspect: number,
 *   getWorldPosition(target: any): {x: number, y: number, z: number},
 *   getWorldDirection(target: any): {x: number, y: number, z: number}}} ThreeCamera
 */

/**
 * Stream a tileset (`python -m spcodec.tiling`'s tileset.json of .spc nodes) by view into a
 * THREE.Group of SplatMeshes, one per node, under `parent` (untransformed: its world is the
 * tileset's). The root node (the whole scene, coarse) comes first; call the returned `update()`
 * from the render loop: when the camera moved it selects again by screen-space error within
 * `budget` Gaussians (Spark draws 0.5-2.5 M a frame) and fetches what the view needs first; a
 * node's parent is hidden in the step its children in view are shown.
 *
 * @template {ThreeModule & {Vector3: new () => any}} T
 * @template P
 * @template {SparkMesh & {visible: boolean, dispose?(): void}} M
 * @param {string} url  the tileset.json
 * @param {object} options
 * @param {T} options.THREE  the three.js module
 * @param {SparkModule<P, M>} options.spark  the Spark module
 * @param {ThreeCamera} options.camera  the camera the selection follows
 * @param {number | (() => number)} options.height  the viewport's height in pixels (or a
 *   function giving it, e.g. `() => renderer.domElement.height`)
 * @param {ThreeParent|null} [options.parent]
 * @param {number} [options.budget]  Gaussians drawn at most (default 1,500,000)
 * @param {number} [options.threshold]  screen-space error in pixels past which a node refines
 * @param {string} [options.up]  the up axis where the root node does not store one
 * @param {number} [options.concurrency]
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(arrival: import('../src/tilestream.js').TileArrival) => void} [options.onArrival]
 * @param {(shown: Set<import('../src/tileset.js').Tile>, covers: boolean) => void} [options.onShown]
 * @param {(error: unknown, tile: import('../src/tileset.js').Tile) => void} [options.onError]
 * @param {(tileset: import('../src/tileset.js').Tileset, rotation: number[], indexBytes: number) => void} [options.onOpen]
 *   once the index is read, before the first selection: where a page places its camera
 * @returns {Promise<{group: InstanceType<T['Group']>, stream: import('../src/tilestream.js').TilesetStream<M>,
 *   tileset: import('../src/tileset.js').Tileset, update(): void, close(): void}>}
 */
export async function loadTileset(url, { THREE, spark, camera, height, parent = null, budget, threshold,
  up = null, concurrency, fetchImpl, onArrival, onShown, onError, onOpen } = /** @type {any} */ ({})) {
  if (!THREE || !spark?.SplatMesh || !spark.PackedSplats || !spark.utils || !camera) {
    throw new Error('loadTileset needs { THREE, spark, camera, height }: three.js, Spark as a module, '
      + 'the camera the selection follows and the viewport height');
  }
  const encoding = { ...spark.defines.DEFAULT_SPLAT_ENCODING };
  const group = /** @type {InstanceType<T['Group']> & {remove(o: unknown): unknown}} */ (new THREE.Group());
  group.name = `tileset ${url}`;
  parent?.add(group);
  /** @type {import('../src/tilestream.js').TileRenderer<M>} */
  const renderer = {
    add: (tile, cloud) => {
      const packedSplats = new spark.PackedSplats(packCloud(cloud, spark.utils, encoding));
      const mesh = new spark.SplatMesh({ packedSplats, splatEncoding: encoding });
      mesh.name = tile.id;
      mesh.visible = false;
      group.add(mesh);
      return mesh;
    },
    show: (mesh, visible) => { mesh.visible = visible; },
    remove: (mesh) => {
      group.remove(mesh);
      mesh.dispose?.();
    },
  };
  const stream = new TilesetStream(url, renderer, { budget, threshold, up, concurrency, fetchImpl,
    onArrival, onShown, onError });
  const { tileset, rotation } = await stream.open();
  group.quaternion.set(...rotation);
  onOpen?.(tileset, rotation, stream.indexBytes);
  const position = new THREE.Vector3(), direction = new THREE.Vector3();
  let last = '';
  const update = (force = false) => {
    const p = camera.getWorldPosition(position), f = camera.getWorldDirection(direction);
    const pixels = typeof height === 'function' ? height() : height;
    const view = { position: [p.x, p.y, p.z], forward: [f.x, f.y, f.z], fov: camera.fov,
      height: pixels || 1, aspect: camera.aspect || 1 };
    const key = JSON.stringify(view, (_k, v) => (typeof v === 'number' ? Number(v.toPrecision(5)) : v));
    if (!force && key === last) return;
    last = key;
    stream.update(view);
  };
  update(true);
  return { group, stream, tileset, update: () => update(), close: () => stream.close() };
}
