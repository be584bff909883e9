// .spc in PlayCanvas apps: stream a scene into entities layer by layer, or load it as a gsplat
// asset like a PLY.
//
//   import * as pc from 'playcanvas';
//   import { loadSpc, registerSpc } from 'spcodec/playcanvas';
//
//   // streaming: an upright entity under app.root, one GSplat child per layer as it arrives
//   const { entity } = await loadSpc(app, pc, 'scene.spc', { onLayer: (l) => console.log(l.index) });
//
//   // or as an asset (all layers, one resource), beside PlayCanvas's own PLY and SOG parsers
//   registerSpc(app, pc);
//   const asset = new pc.Asset('scene', 'gsplat', { url: 'scene.spc' });
//   asset.ready(() => {
//     const e = new pc.Entity();
//     e.addComponent('gsplat', { asset });
//     e.setLocalRotation(new pc.Quat(...asset.resource.spcRotation));  // upright in +Y
//     app.root.addChild(e);
//   });
//   app.assets.add(asset);
//   app.assets.load(asset);
//
// Both read an .spc or a .glb written by `spcodec embed` (the .spc inside it), fetch it with HTTP
// range requests (one per layer after the header block), and take PlayCanvas as an argument
// (`pc`), so the app's own copy of the engine makes the resources. PlayCanvas describes splats the
// way a 3DGS PLY does, one float array per PLY property; handing it each decoded layer under those
// names renders it as PlayCanvas renders the PLY `spcodec decode` writes, which the browser tests
// check pixel by pixel.

import { streamLayers } from '../src/stream.js';

/**
 * The PLY-named property arrays of a decoded cloud (the decoder API's layout: positions xyz,
 * log-scales, rotations wxyz, opacity logits, SH DC, SH rest per Gaussian coefficient-major then
 * channel). f_rest is channel-major, as in the PLY.
 * @param {{count: number, shDegree: number, positions: Float32Array, scales: Float32Array,
 *   rotations: Float32Array, opacities: Float32Array, shDC: Float32Array, shRest: Float32Array}} cloud
 * @returns {Map<string, Float32Array>}
 */
export function plyProperties(cloud) {
  const n = cloud.count;
  const props = new Map();
  const columns = (names) => names.map((name) => {
    const column = new Float32Array(n);
    props.set(name, column);
    return column;
  });
  deinterleave(cloud.positions, n, columns(['x', 'y', 'z']));
  deinterleave(cloud.shDC, n, columns(['f_dc_0', 'f_dc_1', 'f_dc_2']));
  props.set('opacity', Float32Array.from(cloud.opacities));
  deinterleave(cloud.scales, n, columns(['scale_0', 'scale_1', 'scale_2']));
  deinterleave(cloud.rotations, n, columns(['rot_0', 'rot_1', 'rot_2', 'rot_3']));
  const k = (cloud.shDegree + 1) ** 2 - 1;
  const rest = columns(Array.from({ length: 3 * k }, (_, j) => `f_rest_${j}`));
  // source value j = coefficient * 3 + channel goes to PLY column channel * K + coefficient
  const targets = Array.from({ length: 3 * k }, (_, j) => rest[(j % 3) * k + Math.floor(j / 3)]);
  deinterleave(cloud.shRest, n, targets);
  return props;
}

/** Copy `n` records of `targets.length` interleaved values into one column each. Row by row:
 * reading the source in order is several times faster than a strided pass per column. */
function deinterleave(source, n, targets) {
  const width = targets.length;
  for (let i = 0, base = 0; i < n; i++, base += width) {
    for (let j = 0; j < width; j++) targets[j][i] = source[base + j];
  }
}

/**
 * A PlayCanvas GSplatData holding `cloud`. PlayCanvas's PLY loader sorts a PLY's splats along a
 * Morton curve for memory locality; our layers need no such pass: the encoder stores each patch
 * layer in Morton order (its positions are delta-coded along that curve) and the sketch cluster
 * by cluster. Drawing order is the renderer's depth sort either way.
 * @param {typeof import('playcanvas')} pc
 */
export function toGSplatData(pc, cloud) {
  const properties = [...plyProperties(cloud)].map(([name, storage]) =>
    ({ type: 'float', name, storage, byteSize: 4 }));
  return new pc.GSplatData([{ name: 'vertex', count: cloud.count, properties }]);
}

/**
 * One cloud holding the Gaussians of `clouds` in order (the layers of a file, merged).
 * @param {import('../src/decoder.js').Cloud[]} clouds
 * @returns {import('../src/decoder.js').Cloud}
 */
export function concatClouds(clouds) {
  const shDegree = clouds.length ? clouds[0].shDegree : 0;
  const join = (name) => {
    const out = new Float32Array(clouds.reduce((n, c) => n + c[name].length, 0));
    let at = 0;
    for (const c of clouds) {
      out.set(c[name], at);
      at += c[name].length;
    }
    return out;
  };
  return { count: clouds.reduce((n, c) => n + c.count, 0), shDegree, positions: join('positions'),
    scales: join('scales'), rotations: join('rotations'), opacities: join('opacities'),
    shDC: join('shDC'), shRest: join('shRest') };
}

/**
 * Stream `url` into the scene: an entity under `parent`, turned upright (+Y up, from the file's
 * up axis or a .glb's node), gets one child with a GSplat component per layer as the layer
 * arrives, so the first picture comes after a few percent of the bytes. PlayCanvas sorts the
 * layers' splats together.
 *
 * @param {any} app  the PlayCanvas application
 * @param {any} pc   the PlayCanvas module the app runs on
 * @param {string} url  an .spc, or a .glb written by `spcodec embed`
 * @param {object} [options]
 * @param {any} [options.parent]  where the scene's entity goes (default: app.root)
 * @param {number} [options.maxLayer]  stop after this layer
 * @param {string} [options.up]  the up axis where the file does not store one (default -y)
 * @param {(layer: object) => void} [options.onLayer]  after each layer's entity is added
 * @param {(loaded: number, total: number|null) => void} [options.onProgress]
 * @param {(info: object) => void} [options.onInfo]  the `spcodec info --json` document, first
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(event: object) => void} [options.onRequest]
 * @returns {Promise<{entity: any, info: object|null, layers: number, bytes: number,
 *   mode: string, fileSize: number|null}>}
 */
export async function loadSpc(app, pc, url, { parent = app.root, maxLayer = Infinity, up = null,
  onLayer = () => {}, onProgress = () => {}, onInfo = () => {}, fetchImpl = fetch,
  onRequest = () => {} } = {}) {
  const entity = new pc.Entity(`spc ${url}`);
  parent.addChild(entity);
  const result = await streamLayers(url, {
    maxLayer, up, onProgress, onInfo, fetchImpl, onRequest,
    onLayer: (layer) => {
      entity.setLocalRotation(new pc.Quat(...layer.rotation));
      let child = null;
      if (layer.cloud.count > 0) {
        child = new pc.Entity(`layer ${layer.index}`);
        child.addComponent('gsplat', {
          resource: new pc.GSplatResource(app.graphicsDevice, toGSplatData(pc, layer.cloud)) });
        entity.addChild(child);
      }
      onLayer({ ...layer, entity: child });
    },
  });
  return { entity, info: result.info, layers: result.layers, bytes: result.bytes,
    mode: result.mode, fileSize: result.fileSize };
}

/**
 * A parser for PlayCanvas's gsplat resource handler: `.spc` URLs (and `.glb` ones written by
 * `spcodec embed`) load as one GSplatResource of every layer. The asset fires `progress`
 * (bytes, total) and `spc:layer` (index, count) as layers arrive; the resource carries
 * `spcRotation` (x, y, z, w), the rotation that stands the scene upright, for the entity.
 */
export class SpcParser {
  /**
   * @param {any} app
   * @param {any} pc
   * @param {{up?: string, fetchImpl?: typeof fetch}} [options]
   */
  constructor(app, pc, { up = null, fetchImpl = null } = {}) {
    this.app = app;
    this.pc = pc;
    this.up = up;
    this.fetchImpl = fetchImpl;
  }

  /** @param {{ext: string}} context */
  canParse(context) {
    return context.ext === 'spc' || context.ext === 'glb';
  }

  /**
   * @param {string|{load: string}} url
   * @param {(error: any, resource?: any) => void} callback
   * @param {any} asset
   */
  async load(url, callback, asset) {
    const clouds = [];
    try {
      const result = await streamLayers(typeof url === 'string' ? url : url.load, {
        up: this.up, fetchImpl: this.fetchImpl ?? fetch,
        onProgress: (loaded, total) => asset?.fire('progress', loaded, total ?? 0),
        onLayer: (layer) => {
          clouds.push(layer.cloud);
          asset?.fire('spc:layer', layer.index, layer.cloud.count);
        },
      });
      const resource = new this.pc.GSplatResource(this.app.graphicsDevice,
        toGSplatData(this.pc, concatClouds(clouds)));
      resource.spcRotation = result.rotation;
      callback(null, resource);
    } catch (error) {
      callback(error);
    }
  }

  open(url, data) {
    return data;
  }
}

/**
 * Let `app` load .spc files as gsplat assets (adds an {@link SpcParser} to its gsplat handler).
 * @param {any} app
 * @param {any} pc
 * @param {{up?: string, fetchImpl?: typeof fetch}} [options]
 * @returns {SpcParser}
 */
export function registerSpc(app, pc, options = {}) {
  const parser = new SpcParser(app, pc, options);
  app.loader.getHandler('gsplat').addParser(parser);
  return parser;
}
