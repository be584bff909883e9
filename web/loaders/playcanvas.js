// .spc in PlayCanvas apps: stream a scene into entities layer by layer, or load it as a gsplat
// asset like a PLY.
//
//   import * as pc from 'playcanvas';
//   import { loadSpc, loadTileset, registerSpc } from 'spcodec/playcanvas';
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
//   // a tileset (`python -m spcodec.tiling`): nodes fetched by view within a splat budget
//   const tiles = await loadTileset(app, pc, 'out/tileset.json', { camera, budget: 1_500_000 });
//
// Both .spc loaders read an .spc or a .glb written by `spcodec embed` (the .spc inside it), fetch it with HTTP
// range requests (one per layer after the header block), and take PlayCanvas as an argument
// (`pc`), so the app's own copy of the engine makes the resources. PlayCanvas describes splats the
// way a 3DGS PLY does, one float array per PLY property; handing it each decoded layer under those
// names renders it as PlayCanvas renders the PLY `spcodec decode` writes, which the browser tests
// check pixel by pixel.

import { streamLayers } from '../src/stream.js';
import { TilesetStream } from '../src/tilestream.js';

// PlayCanvas comes in as an argument (`pc`), not as an import: the types below say what these
// loaders use of its objects, so that they check without PlayCanvas installed and any PlayCanvas 2
// app fits them.

/**
 * What the loaders use of a PlayCanvas `GraphNode`.
 * @typedef {{enabled: boolean, destroy(): void}} PcNode
 */

/**
 * What the loaders use of a PlayCanvas `Entity`.
 * @typedef {PcNode & {
 *   addChild(node: PcNode): void,
 *   setLocalRotation(rotation: unknown): void,
 *   addComponent(type: string, data?: object): unknown,
 *   gsplat?: {resource?: {destroy(): void} | null},
 * }} PcEntity
 */

/**
 * What the loaders use of PlayCanvas's event handlers (an `AppBase`, a component system).
 * @typedef {{
 *   on(name: string, callback: (...args: any[]) => void): unknown,
 *   off(name: string, callback?: (...args: any[]) => void): unknown,
 * }} PcEvents
 */

/**
 * What the loaders use of a PlayCanvas application (`pc.AppBase`).
 * @typedef {PcEvents & {
 *   root: PcEntity,
 *   graphicsDevice: unknown,
 *   systems?: {gsplat?: PcEvents},
 *   loader: {getHandler(type: string): {addParser(parser: SpcParser): void} | undefined},
 * }} PcApp
 */

/**
 * A GSplatResource as the loaders make it; SpcParser adds `spcRotation`.
 * @typedef {{destroy(): void, spcRotation?: number[]}} PcGSplatResource
 */

/**
 * What the loaders use of the PlayCanvas module (`import * as pc from 'playcanvas'`).
 * GSplatResource's arguments are PlayCanvas's own: `app.graphicsDevice` and a `pc.GSplatData`.
 * @typedef {{
 *   Entity: new (name?: string) => PcEntity,
 *   Quat: new (...xyzw: number[]) => unknown,
 *   GSplatData: new (elements: {name: string, count: number, properties: {type: string,
 *     name: string, storage: Float32Array, byteSize: number}[]}[]) => unknown,
 *   GSplatResource: new (device: any, data: any) => PcGSplatResource,
 * }} PcModule
 */

/** The `spcodec info --json` document of a file (the decoder's `inspect`).
 * @typedef {ReturnType<typeof import('../src/decoder.js').inspect>} SpcInfo */

/** A range request and its answer (offsets in the file, `contentRange` as the server said).
 * @typedef {{first: number, last: number, status: number,
 *   contentRange: {first: number, last: number, size: number}|null}} SpcRequest */

/** A streamed layer and its entity (an `E`, the app's `pc.Entity`; null for an empty layer);
 * `shown`: false while it waits behind the preview.
 * @template E
 * @typedef {import('../src/stream.js').StreamedLayer & {entity: E|null, shown: boolean}}
 *   SpcLayerEntity */

/** The file's preview and its entity (an `E`; null for an empty preview); `showFrom`: the layer
 * whose arrival drops it.
 * @template E
 * @typedef {import('../src/stream.js').StreamedPreview & {entity: E|null, showFrom: number}}
 *   SpcPreviewEntity */

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
 * @template {PcModule} M
 * @param {M} pc
 * @param {import('../src/decoder.js').Cloud} cloud
 * @returns {InstanceType<M['GSplatData']>}
 */
export function toGSplatData(pc, cloud) {
  const properties = [...plyProperties(cloud)].map(([name, storage]) =>
    ({ type: 'float', name, storage, byteSize: 4 }));
  return /** @type {InstanceType<M['GSplatData']>} */ (
    new pc.GSplatData([{ name: 'vertex', count: cloud.count, properties }]));
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
 * A file with a preview (spec 7.4) shows it first, in a child of its own, as soon as its bytes are
 * in; the layers that arrive meanwhile are added disabled, and when the preview's takeover layer
 * (or the last layer asked for, if that comes first) arrives they are enabled and the preview is
 * destroyed in the same step, so the next frame drawn holds the scene ([R-104]). A preview that
 * does not decode is reported to `onPreviewError` and the layers show as without one.
 *
 * @template {PcModule} M
 * @param {PcApp} app  the PlayCanvas application
 * @param {M} pc   the PlayCanvas module the app runs on (its `Entity` class makes the entities)
 * @param {string} url  an .spc, or a .glb written by `spcodec embed`
 * @param {object} [options]
 * @param {PcEntity} [options.parent]  where the scene's entity goes (default: app.root)
 * @param {number} [options.maxLayer]  stop after this layer
 * @param {string} [options.up]  the up axis where the file does not store one (default -y)
 * @param {(layer: SpcLayerEntity<InstanceType<M['Entity']>>) => void} [options.onLayer]  after
 *   each layer's entity is added; `shown` is false for a layer held back behind the preview
 * @param {(loaded: number, total: number|null) => void} [options.onProgress]
 * @param {(info: SpcInfo) => void} [options.onInfo]  the `spcodec info --json` document, first
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(event: SpcRequest) => void} [options.onRequest]  each range request and its answer
 * @param {boolean} [options.preview]  show the file's preview (default true)
 * @param {(preview: SpcPreviewEntity<InstanceType<M['Entity']>>) => void} [options.onPreview]
 *   after the preview's entity is added, with `showFrom`: the layer whose arrival drops it
 * @param {(drop: {layer: number, held: number[]}) => void} [options.onPreviewDropped]  the
 *   preview is gone and layers 0..layer are enabled (`held`: those that waited), before that
 *   layer's onLayer
 * @param {(error: unknown) => void} [options.onPreviewError]
 * @returns {Promise<{entity: InstanceType<M['Entity']>, info: SpcInfo|null, layers: number,
 *   bytes: number, mode: string, fileSize: number|null, previewError: unknown}>}
 */
export async function loadSpc(app, pc, url, { parent = app.root, maxLayer = Infinity, up = null,
  onLayer = () => {}, onProgress = () => {}, onInfo = () => {}, fetchImpl = fetch,
  onRequest = () => {}, preview = true, onPreview = () => {}, onPreviewDropped = () => {},
  onPreviewError = () => {} } = {}) {
  const entity = /** @type {InstanceType<M['Entity']>} */ (new pc.Entity(`spc ${url}`));
  parent.addChild(entity);
  const stand = new PreviewStand();
  const result = await streamLayers(url, {
    maxLayer, up, onProgress, onInfo, fetchImpl, onRequest, preview, onPreviewError,
    onPreview: (p) => {
      entity.setLocalRotation(new pc.Quat(...p.rotation));
      const child = p.cloud.count > 0 ? gsplatEntity(app, pc, 'preview', p.cloud) : null;
      if (child) entity.addChild(child);
      const showFrom = stand.open(child, p.takeoverLayer, Math.min(maxLayer, p.layerCount - 1));
      onPreview({ ...p, entity: child, showFrom });
    },
    onLayer: (layer) => {
      entity.setLocalRotation(new pc.Quat(...layer.rotation));
      const child = layer.cloud.count > 0 ? gsplatEntity(app, pc, `layer ${layer.index}`, layer.cloud) : null;
      if (child) entity.addChild(child);
      const shown = stand.place(child, layer.index);
      if (shown && stand.dropped === layer.index) {
        destroyOnceReplaced(app, stand.retired);
        onPreviewDropped({ layer: layer.index, held: stand.heldIndices });
      }
      onLayer({ ...layer, entity: child, shown });
    },
  });
  return { entity, info: result.info, layers: result.layers, bytes: result.bytes,
    mode: result.mode, fileSize: result.fileSize, previewError: result.previewError };
}

/**
 * An entity drawing `cloud` with a GSplat component of its own.
 * @template {PcModule} M
 * @param {PcApp} app
 * @param {M} pc
 * @param {string} name
 * @param {import('../src/decoder.js').Cloud} cloud
 * @returns {InstanceType<M['Entity']>}
 */
function gsplatEntity(app, pc, name, cloud) {
  const child = /** @type {InstanceType<M['Entity']>} */ (new pc.Entity(name));
  child.addComponent('gsplat', {
    resource: new pc.GSplatResource(app.graphicsDevice, toGSplatData(pc, cloud)) });
  return child;
}

/**
 * Destroy a disabled GSplat entity, and the resource it drew, once PlayCanvas has drawn a frame
 * without it. Destroying it in the step that disables it frees its placement while the sorted
 * state still drawn (until the new one is sorted) holds it: a blank frame (PlayCanvas 2.23; the
 * viewer's browser test sees it). The resource is not the component's to free: it is freed here
 * (PlayCanvas defers that while a state still counts it).
 * @param {PcApp} app
 * @param {PcEntity|null} entity  null: nothing to do
 */
function destroyOnceReplaced(app, entity) {
  const system = app.systems?.gsplat;
  const destroy = () => {
    const resource = entity.gsplat?.resource;
    entity.destroy();
    resource?.destroy();
  };
  if (!entity) return;
  if (!system) {
    destroy();
    return;
  }
  let frames = 0;
  const counted = () => { frames++; };
  const ready = (_camera, _layer, sorted, loading) => {
    if (!sorted || loading || frames < 1) return;
    app.off('frameend', counted);
    system.off('frame:ready', ready);
    destroy();
  };
  app.on('frameend', counted);
  system.on('frame:ready', ready);
}

/**
 * What is on screen while a preview stands in for the scene ([R-104]): the preview's entity until
 * layer `showFrom` arrives; the layers before it wait, disabled. The swap is one step (enable the
 * layers, disable the preview, no frame between), so no frame is without a picture; the preview's
 * entity is then `retired`, for the caller to destroy once a frame without it is drawn.
 */
export class PreviewStand {
  constructor() {
    /** @type {PcEntity|null} the preview's entity (null for an empty preview) */
    this.entity = null;
    /** the layer whose arrival drops the preview; -1: no preview (any more) */
    this.showFrom = -1;
    /** @type {{index: number, entity: PcEntity|null}[]} layers waiting behind the preview */
    this.held = [];
    /** @type {number[]} the layers that waited, once the preview is dropped */
    this.heldIndices = [];
    /** the layer at which the preview was dropped, or -1 */
    this.dropped = -1;
    /** @type {PcEntity|null} the preview's entity once dropped (disabled), until the caller
     * destroys it */
    this.retired = null;
  }

  /**
   * Show the preview until layer `takeover`, or `last` (the last layer that will come) if sooner.
   * @param {PcEntity|null} entity
   * @param {number} takeover
   * @param {number} last
   * @returns {number} the layer that will drop it
   */
  open(entity, takeover, last) {
    this.entity = entity;
    this.showFrom = Math.min(takeover, last);
    return this.showFrom;
  }

  /**
   * A layer's entity has arrived (null for an empty layer): hold it back behind the preview, or
   * swap the preview for it and the layers held. Returns whether the layer is on screen now.
   * @param {PcEntity|null} entity
   * @param {number} index
   */
  place(entity, index) {
    if (this.showFrom < 0) return true;
    if (index < this.showFrom) {
      if (entity) entity.enabled = false;
      this.held.push({ index, entity });
      return false;
    }
    for (const layer of this.held) if (layer.entity) layer.entity.enabled = true;
    if (this.entity) this.entity.enabled = false;
    this.retired = this.entity;
    this.heldIndices = this.held.map((layer) => layer.index);
    this.held = [];
    this.entity = null;
    this.showFrom = -1;
    this.dropped = index;
    return true;
  }
}

/**
 * A parser for PlayCanvas's gsplat resource handler: `.spc` URLs (and `.glb` ones written by
 * `spcodec embed`) load as one GSplatResource of every layer. The asset fires `progress`
 * (bytes, total) and `spc:layer` (index, count) as layers arrive; the resource carries
 * `spcRotation` (x, y, z, w), the rotation that stands the scene upright, for the entity.
 */
export class SpcParser {
  /**
   * @param {PcApp} app
   * @param {PcModule} pc
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
   * @param {(error: any, resource?: PcGSplatResource) => void} callback  PlayCanvas's
   *   ResourceHandlerCallback; the error is the decoder's or the transfer's
   * @param {{fire(name: string, ...args: unknown[]): unknown}} [asset]  the asset loading it
   */
  async load(url, callback, asset) {
    const clouds = [];
    try {
      const result = await streamLayers(typeof url === 'string' ? url : url.load, {
        up: this.up, fetchImpl: this.fetchImpl ?? fetch,
        preview: false,  // one resource of every layer: nothing is shown before it, no preview
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
 * @param {PcApp} app
 * @param {PcModule} pc
 * @param {{up?: string, fetchImpl?: typeof fetch}} [options]
 * @returns {SpcParser}
 */
export function registerSpc(app, pc, options = {}) {
  const parser = new SpcParser(app, pc, options);
  app.loader.getHandler('gsplat').addParser(parser);
  return parser;
}

/**
 * What the tileset loader reads of the camera entity (a PlayCanvas `Entity` with a camera
 * component): where it is, where it looks, and its vertical field of view in degrees.
 * @typedef {{getPosition(): {x: number, y: number, z: number},
 *   forward: {x: number, y: number, z: number}, camera: {fov: number}}} PcCameraEntity
 */

/**
 * Stream a tileset (`python -m spcodec.tiling`'s tileset.json of .spc nodes) into the scene by
 * view: an entity under `parent` (untransformed: its world is the tileset's), turned upright by
 * the root node's up axis, gets one GSplat child per node as it arrives. The root (the whole
 * scene, coarse) comes first; then, while the camera moves, the nodes the selection by
 * screen-space error needs within `budget` Gaussians (src/tileset.js), in view first; a parent is
 * hidden in the step its children in view are shown. The camera is read every frame and the
 * selection made again when it moved.
 *
 * @template {PcModule} M
 * @param {PcApp} app
 * @param {M} pc
 * @param {string} url  the tileset.json
 * @param {object} options
 * @param {PcCameraEntity} options.camera  the camera entity the selection follows
 * @param {PcEntity} [options.parent]  default app.root
 * @param {number} [options.budget]  Gaussians drawn at most (default 1,500,000)
 * @param {number} [options.threshold]  screen-space error in pixels past which a node refines
 *   (default 16)
 * @param {string} [options.up]  the up axis where the root node does not store one
 * @param {number} [options.concurrency]  node requests at a time (default 4)
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(arrival: import('../src/tilestream.js').TileArrival) => void} [options.onArrival]
 * @param {(shown: Set<import('../src/tileset.js').Tile>, covers: boolean) => void} [options.onShown]
 * @param {(loaded: number) => void} [options.onProgress]
 * @param {(error: unknown, tile: import('../src/tileset.js').Tile) => void} [options.onError]
 * @param {(tileset: import('../src/tileset.js').Tileset, rotation: number[], indexBytes: number) => void}
 *   [options.onOpen]  once the index and the root are in, before the first selection: the moment
 *   to place the camera on the scene (the root's box, turned by `rotation`)
 * @returns {Promise<{entity: InstanceType<M['Entity']>,
 *   stream: import('../src/tilestream.js').TilesetStream<InstanceType<M['Entity']>>,
 *   tileset: import('../src/tileset.js').Tileset, rotation: number[], update(): void, destroy(): void}>}
 */
export async function loadTileset(app, pc, url, { camera, parent = app.root, budget, threshold, up = null,
  concurrency, fetchImpl, onArrival, onShown, onProgress, onError, onOpen } = /** @type {any} */ ({})) {
  if (!camera?.camera) throw new Error('loadTileset needs { camera }: the camera entity the selection follows');
  const entity = /** @type {InstanceType<M['Entity']>} */ (new pc.Entity(`tileset ${url}`));
  parent.addChild(entity);
  /** @type {import('../src/tilestream.js').TileRenderer<InstanceType<M['Entity']>>} */
  const renderer = {
    add: (tile, cloud) => {
      const child = gsplatEntity(app, pc, tile.id, cloud);
      child.enabled = false;
      entity.addChild(child);
      return child;
    },
    show: (child, visible) => { child.enabled = visible; },
    remove: (child) => {
      child.enabled = false;
      destroyOnceReplaced(app, child);
    },
  };
  const stream = new TilesetStream(url, renderer, { budget, threshold, up, concurrency, fetchImpl,
    onArrival, onShown, onProgress, onError });
  const { tileset, rotation } = await stream.open();
  entity.setLocalRotation(new pc.Quat(...rotation));
  onOpen?.(tileset, rotation, stream.indexBytes);
  let last = '';
  const update = (force = false) => {
    const device = /** @type {{width: number, height: number}} */ (app.graphicsDevice);
    const p = camera.getPosition(), f = camera.forward;
    const view = { position: [p.x, p.y, p.z], forward: [f.x, f.y, f.z], fov: camera.camera.fov,
      height: device.height || 1, aspect: (device.width || 1) / (device.height || 1) };
    const key = JSON.stringify(view, (_k, v) => (typeof v === 'number' ? Number(v.toPrecision(5)) : v));
    if (!force && key === last) return;
    last = key;
    stream.update(view);
  };
  const onUpdate = () => update();
  app.on('update', onUpdate);
  update(true);
  return { entity, stream, tileset, rotation, update: () => update(true),
    destroy: () => {
      app.off('update', onUpdate);
      stream.close();
      entity.destroy();
    } };
}
