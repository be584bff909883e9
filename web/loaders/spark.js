// .spc in three.js apps with Spark (@sparkjsdev/spark), the most used three.js splat renderer.
//
//   import * as THREE from 'three';
//   import { SparkRenderer, SplatMesh } from '@sparkjsdev/spark';
//   import { loadSpc } from 'spcodec/spark';
//
//   scene.add(new SparkRenderer({ renderer }));
//   const { group } = await loadSpc('scene.spc', { THREE, SplatMesh, parent: scene,
//                                                  onLayer: (l) => console.log(l.index) });
//
// Each layer becomes a SplatMesh of its own, added (under one group turned upright, +Y up) as soon
// as its bytes are in: Spark sorts the splats of every mesh together, so later layers refine the
// picture the first ones started. A layer reaches Spark as the INRIA PLY `spcodec decode` writes
// (Spark's own PLY reader), so every attribute, SH included, takes the path Spark's users rely on.
// Reads an .spc or a .glb written by `spcodec embed`, by HTTP range requests. three.js and Spark
// are passed in, so the app's own copies make the objects.

import { plyBytes } from '../src/ply.js';
import { streamLayers } from '../src/stream.js';

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
 * What the loader uses of Spark's SplatMesh class (`fileType` is 'ply', Spark's
 * SplatFileType.PLY).
 * @typedef {new (options: {fileBytes: Uint8Array, fileType: any, fileName: string}) =>
 *   {name?: string, initialized: Promise<unknown>}} SplatMeshClass
 */

/**
 * Stream `url` into a THREE.Group of SplatMeshes, one per layer as it arrives.
 *
 * @template {ThreeModule} T
 * @template {SplatMeshClass} S
 * @param {string} url  an .spc, or a .glb written by `spcodec embed`
 * @param {object} options
 * @param {T} options.THREE  the three.js module
 * @param {S} options.SplatMesh  Spark's SplatMesh class
 * @param {ThreeParent|null} [options.parent]  an Object3D the group is added to at once (default:
 *   none)
 * @param {number} [options.maxLayer]  stop after this layer
 * @param {string} [options.up]  the up axis where the file does not store one (default -y)
 * @param {(layer: import('../src/stream.js').StreamedLayer & {mesh: InstanceType<S>|null}) => void}
 *   [options.onLayer]  once each layer's mesh is ready (`mesh`: null for an empty layer)
 * @param {(loaded: number, total: number|null) => void} [options.onProgress]
 * @param {typeof fetch} [options.fetchImpl]
 * @returns {Promise<{group: InstanceType<T['Group']>, meshes: InstanceType<S>[],
 *   info: ReturnType<typeof import('../src/decoder.js').inspect>|null, layers: number,
 *   bytes: number}>}
 */
export async function loadSpc(url, { THREE, SplatMesh, parent = null, maxLayer = Infinity,
  up = null, onLayer = () => {}, onProgress = () => {}, fetchImpl = fetch,
} = /** @type {any} */ ({})) {  // {}: THREE and SplatMesh are required, the check below says so
  if (!THREE || !SplatMesh) throw new Error('loadSpc needs { THREE, SplatMesh } (three and @sparkjsdev/spark)');
  const group = /** @type {InstanceType<T['Group']>} */ (new THREE.Group());
  group.name = `spc ${url}`;
  parent?.add(group);
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
      const mesh = /** @type {InstanceType<S>} */ (new SplatMesh({ fileBytes: plyBytes(layer.cloud),
        fileType: 'ply', fileName: `layer-${layer.index}.ply` }));
      mesh.name = `layer ${layer.index}`;
      meshes.push(mesh);
      group.add(mesh);
      ready.push(mesh.initialized.then(() => onLayer({ ...layer, mesh })));
    },
  });
  await Promise.all(ready);
  return { group, meshes, info: result.info, layers: result.layers, bytes: result.bytes };
}
