// The streaming viewer: an .spc shown layer by layer as its bytes arrive, on PlayCanvas's GSplat
// component. It also opens a 3DGS PLY (PlayCanvas's PLY loader) or a KHR_gaussian_splatting GLB
// (PlayCanvas's glTF loader), so the same page and camera compare our decoder with those files.
//
// URL parameters:
//   src=URL            the scene (.spc streams; .ply and .glb load whole; a tileset.json of .spc
//                      nodes streams by view: see tileset.js for its budget= and sse=)
//   maxLayer=K         fetch and show layers 0..K only (.spc)
//   width=W&height=H   fixed canvas resolution (default: fill the window)
//   cam=x,y,z&target=x,y,z&fov=DEG   camera, in the upright world (+Y up; default: framed on
//                      the whole scene's box from the file's metadata (`bounds`) as soon as the
//                      preview or layer 0 is in, and left there; for a file without one, framed on
//                      what has arrived and again as layers reach out of the view; either way
//                      never again once the user moves the camera)
//   up=AXIS            the scene's up axis where the file does not store one (a PLY, an older
//                      .spc): -y (default, COLMAP-derived scenes), +z, or a vector such as 0,0,1.
//                      Every scene is stood upright in a +Y-up world: an .spc by the axis its
//                      metadata stores, a .glb by its node's rotation (glTF is +Y up).
//   capture=1          no overlay, and keep the frame of the first picture (tests, benchmark)
//   layerPictures=1    also keep the frame that showed each non-empty layer (and the preview, as
//                      layer 'preview'), in `window.spcViewerLayerPictures` (benchmark: quality
//                      at every layer)
//   preview=0          ignore the file's preview (spec 7.4) and show its layers as they come
//
// A file with a preview shows it as soon as its bytes are in, and keeps it on screen instead of
// the layers before its takeover layer T; when layers 0..T are in (or the last layer asked for),
// the scene replaces it in one frame ([R-104]). A preview that does not decode is noted on the
// page, and the layers show as if the file had none.
//
// Progress is shown on the page and kept in `window.spcViewer` (see `state` below), which the
// browser tests and the benchmark read.

import * as pc from 'playcanvas';
import { browserDraco } from '../../src/draco-browser.js';
import { createApp, frameWatcher } from './engine.js';
import { rotatePositions, upRotation } from '../../src/orientation.js';
import { SceneFraming, frameBounds, metadataBounds, turnBounds } from './splats.js';
import { showTileset, tilesetLines } from './tileset.js';

const params = new URLSearchParams(location.search);
const src = params.get('src');

/** Everything the page knows about its progress. Times are ms from `tStart`, when loading the
 * scene begins (the engine is up; the decoder's code is fetched after it). */
const state = {
  status: 'starting',  // starting | loading | complete | error
  src,
  kind: src ? kindOf(src) : null,
  mode: null,  // for .spc: 'ranges' (one request per layer) or 'stream'
  totalBytes: null,
  bytesLoaded: 0,
  layerCount: null,
  layersDecoded: 0,
  layersShown: 0,
  gaussians: 0,
  events: [],  // one per layer: {index, kind, gaussians, bytesLoaded, tDecoded, tShown}
  requests: [],
  error: null,
  tStart: null,
  tFirstPicture: null,  // the first non-empty layer on screen
  tComplete: null,
  bytesAtFirstPicture: null,  // bytes that layer needed (received when it was decoded)
  layersInFirstPicture: null,
  bytesWhenFirstPictureShown: null,
  renderer: null,
  camera: null,  // {position, target, fov} once placed: pass it back in the URL to reproduce a view
  cameraFramings: 0,  // times the default framing placed the camera (1 on a file's bounds; else per layer)
  framedOn: null,  // what the default framing used: 'bounds' (the file's metadata) or 'centres'
  sceneUp: null,  // the scene's up axis as used (stored in the file, from the URL, or the default)
  prefixPsnr: null,  // what the encoder measured per layer prefix (metadata stats.prefix_psnr)
  prefixLine: null,  // the on-screen line made from it for the prefix shown, or null
  showing: null,  // what is on screen (.spc): 'preview' (the file's preview) or 'scene' (its layers)
  // the file's preview (spec 7.4) once decoded: {bytes (its section), gaussians, takeoverLayer,
  // showFrom (the layer that replaces it), bytesLoaded, tDecoded, tShown, tDropped, droppedAtLayer}
  preview: null,
  previewError: null,  // why the file's preview is not shown ({code, name, message, line}), or null
  tileset: null,  // a tileset's progress (tileset.js), or null
};
window.spcViewer = state;

const hud = document.getElementById('hud');
const canvas = document.getElementById('scene');

function kindOf(url) {
  const path = new URL(url, location.href).pathname.toLowerCase();
  if (path.endsWith('.ply')) return 'ply';
  if (path.endsWith('.glb')) return 'glb';
  if (path.endsWith('.json')) return 'tileset';
  return 'spc';
}

function now() {
  return performance.now() - state.tStart;
}

function formatBytes(n) {
  if (n == null) return '?';
  if (n < 1e3) return `${n} B`;
  if (n < 1e6) return `${(n / 1e3).toFixed(1)} kB`;
  return `${(n / 1e6).toFixed(2)} MB`;
}

/**
 * One line on what the prefix on screen scored when it was encoded, from the metadata's
 * `stats.prefix_psnr` (`[{layer, psnr}]`, written by retrained encodes; untrusted like the rest of
 * the file, so anything malformed gives no line), or null.
 */
function prefixLine(table, layersShown) {
  if (!Array.isArray(table) || layersShown < 1) return null;
  const valid = table.filter((e) => Number.isInteger(e?.layer) && Number.isFinite(e?.psnr));
  const reached = valid.filter((e) => e.layer <= layersShown - 1).pop();
  const full = valid[valid.length - 1];
  if (!reached || !full) return null;
  return `this prefix: ${reached.psnr.toFixed(1)} dB of the file's ${full.psnr.toFixed(1)} dB ` +
    '(encoder, training views)';
}

function showProgress() {
  const share = state.totalBytes ? ` (${(100 * state.bytesLoaded / state.totalBytes).toFixed(0)}%)` : '';
  const lines = [
    `${state.src ?? 'no scene: add ?src=URL'}`,
    `bytes loaded: ${formatBytes(state.bytesLoaded)} of ${formatBytes(state.totalBytes)}${share}`,
  ];
  if (state.kind === 'spc') {
    if (state.showing === 'preview') lines.push(previewLine(state.preview));
    else lines.push(`layers shown: ${state.layersShown} of ${state.layerCount ?? '?'}`);
    state.prefixLine = prefixLine(state.prefixPsnr, state.layersShown);
    if (state.prefixLine) lines.push(state.prefixLine);
    if (state.preview?.droppedAtLayer != null) {
      lines.push(`preview (${formatBytes(state.preview.bytes)}) replaced by the scene at layer ` +
        `${state.preview.droppedAtLayer}`);
    }
    if (state.previewError) lines.push(`preview not shown: ${state.previewError.line}`);
  }
  if (state.kind === 'tileset') lines.push(...tilesetLines(state.tileset));
  const onScreen = state.showing === 'preview' ? `${state.preview.gaussians.toLocaleString('en')} (preview)`
    : state.gaussians.toLocaleString('en');
  lines.push(`Gaussians: ${onScreen}`);
  if (state.tFirstPicture != null) lines.push(`first picture: ${(state.tFirstPicture / 1000).toFixed(2)} s`);
  if (state.tComplete != null) lines.push(`complete: ${(state.tComplete / 1000).toFixed(2)} s`);
  if (state.error) lines.push(`error: ${errorLine(state.error)}`);
  hud.textContent = lines.join('\n');
  hud.dataset.status = state.status;
}

/** What the page says while the preview stands in for the scene: its size, and how far the
 * scene's layers have come. */
function previewLine(preview) {
  return `showing: preview (${formatBytes(preview.bytes)}); scene: ${state.layersDecoded} of ` +
    `${state.layerCount ?? '?'} layers in, shown once ${preview.showFrom + 1} are`;
}

/** One line for an error: the decoder's messages already end with their [code]; others get it
 * once, in front. */
export function errorLine(error) {
  const tagged = error.code && !error.message.endsWith(`[${error.code}]`);
  return `${tagged ? `[${error.code}] ` : ''}${error.message}`;
}

function numbers(name, count) {
  const text = params.get(name);
  if (!text) return null;
  const values = text.split(',').map(Number);
  if (values.length !== count || !values.every(Number.isFinite)) {
    throw new Error(`URL parameter ${name} needs ${count} comma-separated numbers, got "${text}"`);
  }
  return values;
}

// ------------------------------------------------------------------------------- the renderer
function createCamera(app) {
  const camera = new pc.Entity('camera');
  camera.addComponent('camera', { clearColor: new pc.Color(0, 0, 0, 1), fov: 50 });
  app.root.addChild(camera);
  return camera;
}

const UP = [0, 1, 0];

/**
 * Where the camera looks: as the URL says (`cam`, `target`, `fov`); or framed on the whole scene's
 * box when the file's metadata gives one, once, as the first part (the preview or layer 0) comes
 * in; or else framed on the scene seen so far, again each time a part of it (the preview, a layer)
 * reaches out of the view. Never once the user turns or zooms. The world is +Y up: scenes are
 * stood upright before they are shown.
 */
class CameraRig {
  constructor(camera) {
    this.camera = camera;
    this.fov = Number(params.get('fov')) || 50;
    this.framing = new SceneFraming();
    /** @type {{centre: number[], radius: number}|null} the whole scene's bounds, from the file */
    this.sceneBounds = null;
    /** the orbit's centre, moved with each framing */
    this.target = new pc.Vec3();
    /** the user has moved the camera: framing stops */
    this.moved = false;
    const position = numbers('cam', 3);
    const target = numbers('target', 3);
    this.fixed = Boolean(position && target);
    if (this.fixed) this.aim({ position, target, up: UP, fov: this.fov });
    orbit(this);
  }

  /**
   * A part of the scene is in: frame the scene again if it reaches out of the view.
   * @param {Float32Array} positions  xyz, as the file stores them
   * @param {number[]} [rotation]  the quaternion that stands them upright (default: none)
   */
  see(positions, rotation = null) {
    if (this.fixed || this.moved) return;
    if (this.sceneBounds) {  // the file said where all of it lies: framed once, on that
      if (state.framedOn === 'bounds') return;
      this.aim(frameBounds(turnBounds(this.sceneBounds, rotation), UP, this.fov));
      state.framedOn = 'bounds';
      state.cameraFramings++;
      return;
    }
    if (positions.length < 3) return;
    const toWorld = rotation ? (sampled) => rotatePositions(sampled, rotation) : undefined;
    const bounds = this.framing.add(positions, toWorld);
    if (!bounds) return;
    this.aim(frameBounds(bounds, UP, this.fov));
    state.framedOn = 'centres';
    state.cameraFramings++;
  }

  /**
   * The whole scene's bounds as the file's metadata gives them (see metadataBounds), in the file's
   * coordinates: the first part to arrive is framed on them (turned upright by its rotation)
   * rather than on its own centres, and no later part moves the camera. Null: framing follows the
   * centres. Only before the first part: the file's header comes first.
   * @param {{centre: number[], radius: number}|null} bounds
   */
  expect(bounds) {
    if (state.framedOn == null) this.sceneBounds = bounds;
  }

  /** @param {{position: number[], target: number[], up: number[], fov: number}} view */
  aim(view) {
    const camera = this.camera;
    state.camera = { position: view.position, target: view.target, fov: view.fov };
    const distance = Math.hypot(...view.position.map((p, i) => p - view.target[i]));
    camera.camera.fov = view.fov;
    camera.camera.nearClip = Math.max(distance * 1e-3, 1e-4);
    camera.camera.farClip = distance * 1e3;
    camera.setPosition(...view.position);
    this.target.set(...view.target);
    camera.lookAt(this.target, new pc.Vec3(...view.up));
  }
}

/** Drag to turn around the rig's target, wheel to come closer: about the world's up axis. Either
 * marks the rig moved, so the framing leaves the camera to the user. */
function orbit(rig) {
  const camera = rig.camera;
  const target = rig.target;  // the rig moves it in place when it frames the scene again
  const up = new pc.Vec3(...UP);
  let dragging = null;
  canvas.addEventListener('pointerdown', (e) => { dragging = { x: e.clientX, y: e.clientY }; });
  window.addEventListener('pointerup', () => { dragging = null; });
  window.addEventListener('pointermove', (e) => {
    if (!dragging) return;
    const dx = e.clientX - dragging.x, dy = e.clientY - dragging.y;
    if (!dx && !dy) return;
    dragging = { x: e.clientX, y: e.clientY };
    rig.moved = true;
    const offset = camera.getPosition().clone().sub(target);
    const yaw = new pc.Quat().setFromAxisAngle(up, -dx * 0.3);
    const side = new pc.Vec3().cross(up, offset).normalize();
    const pitch = new pc.Quat().setFromAxisAngle(side, -dy * 0.3);
    pitch.mul(yaw).transformVector(offset, offset);
    camera.setPosition(target.clone().add(offset));
    camera.lookAt(target, up);
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    rig.moved = true;
    const offset = camera.getPosition().clone().sub(target).mulScalar(Math.exp(e.deltaY * 0.001));
    camera.setPosition(target.clone().add(offset));
  }, { passive: false });
}

// ------------------------------------------------------------------------------- the scenes
async function showSpc(app, rig, whenShown) {
  const spc = await import('../../src/index.js');
  const { loadSpc } = await import('../../loaders/playcanvas.js');
  spc.configureDraco(browserDraco());
  const maxLayer = params.has('maxLayer') ? Number(params.get('maxLayer')) : Infinity;
  if (!(Number.isInteger(maxLayer) && maxLayer >= 0) && maxLayer !== Infinity) {
    throw new Error(`URL parameter maxLayer must be a layer number (0, 1, ...), got "${params.get('maxLayer')}"`);
  }
  const shown = [];
  /** @type {object[]} events of the layers held back behind the preview, until it is dropped */
  let held = [];
  /** @type {object[] | null} set when the preview was just dropped: the layers it held back */
  let released = null;

  const addPreview = (p) => {  // its entity is in the scene already (the loader added it)
    const preview = { bytes: p.bytes, gaussians: p.cloud.count, takeoverLayer: p.takeoverLayer,
      showFrom: p.showFrom, bytesLoaded: p.bytesLoaded, tDecoded: now(), tShown: null,
      tDropped: null, droppedAtLayer: null };
    state.preview = preview;
    state.showing = 'preview';
    state.layerCount ??= p.layerCount;  // a file read as one stream gives no info document
    rig.see(p.cloud.positions, p.rotation);  // a small copy of the whole scene
    if (p.cloud.count > 0) {
      shown.push(whenShown().then(() => {
        if (preview.tDropped != null) return;  // replaced before any frame showed it
        preview.tShown = now();
        firstPicture(preview.tShown, preview.bytesLoaded, 0);
        if (params.has('layerPictures')) keepLayerPicture({ index: 'preview', tShown: preview.tShown }, 0);
        showProgress();
      }));
    }
    showProgress();
  };

  const dropPreview = (drop) => {  // before the layer that drops it is told to addLayer
    state.preview.tDropped = now();
    state.preview.droppedAtLayer = drop.layer;
    state.showing = 'scene';
    released = held;
    held = [];
  };

  const addLayer = (layer) => {  // its entity is in the scene already (the loader added it)
    const cloud = layer.cloud;
    const event = { index: layer.index, kind: layer.kind, gaussians: cloud.count,
      bytesLoaded: layer.bytesLoaded, tDecoded: now(), tShown: null };
    state.events.push(event);
    state.layersDecoded = layer.index + 1;
    state.gaussians += cloud.count;
    if (state.showing == null) state.showing = 'scene';
    rig.see(cloud.positions, layer.rotation);  // held back or not: it is part of the scene
    if (!layer.shown) {  // held back behind the preview
      held.push(event);
      showProgress();
      return;
    }
    const waited = released ?? [];
    released = null;
    const inPicture = cloud.count + waited.reduce((n, e) => n + e.gaussians, 0);
    const ready = inPicture > 0 ? whenShown() : Promise.resolve();
    shown.push(ready.then(() => {
      event.tShown = now();
      for (const e of waited) e.tShown = event.tShown;
      state.layersShown = Math.max(state.layersShown, layer.index + 1);
      if (inPicture > 0) firstPicture(event.tShown, event.bytesLoaded, state.layersDecoded);
      if (cloud.count > 0 && params.has('layerPictures')) keepLayerPicture(event, state.layersDecoded);
      showProgress();
    }));
    showProgress();
  };

  const result = await streamLayersInto(loadSpc, app, maxLayer,
    { addLayer, addPreview, dropPreview, expectBounds: (bounds) => rig.expect(bounds) });
  state.mode = result.mode;
  state.totalBytes = state.totalBytes ?? result.fileSize;
  if (Number.isFinite(maxLayer)) {
    state.layerCount = Math.min(state.layerCount ?? Infinity, maxLayer + 1);
  }
  await Promise.all(shown);
}

/** Note the first picture on screen, once: when, the bytes it needed, and the scene layers in it
 * (0 for the preview). */
function firstPicture(t, bytesNeeded, layers) {
  if (state.tFirstPicture != null) return;
  state.tFirstPicture = t;
  state.bytesAtFirstPicture = bytesNeeded;
  // a slow renderer may show later layers in the same frame when bytes come in fast
  state.layersInFirstPicture = layers;
  state.bytesWhenFirstPictureShown = state.bytesLoaded;
  // Still the frame that showed it (promises resolve after the frame, before the next): kept for
  // tests, which may look later, when more layers are on screen.
  if (params.has('capture')) window.spcViewerFirstPicture = canvas.toDataURL('image/png');
}

/** The frame that showed the layer of `event` (or the preview: layer 'preview'), with what it
 * holds: layers decoded after this one but before its frame are in it too (`layersInPicture`), as
 * when bytes come faster than frames; 0 for the preview, which stands in for the layers. */
function keepLayerPicture(event, layersInPicture) {
  window.spcViewerLayerPictures ??= [];
  window.spcViewerLayerPictures.push({ layer: event.index, layersInPicture,
    bytesLoaded: state.bytesLoaded, tShown: event.tShown, png: canvas.toDataURL('image/png') });
}

/** The package's PlayCanvas loader, with the page's bookkeeping of requests and bytes; the file's
 * box of the scene, if its metadata has one, goes to `expectBounds` before any layer. */
async function streamLayersInto(loadSpc, app, maxLayer, { addLayer, addPreview, dropPreview,
  expectBounds }) {
  return loadSpc(app, pc, src, {
    maxLayer, up: params.get('up'),
    preview: params.get('preview') !== '0',
    onPreview: addPreview,
    onPreviewDropped: dropPreview,
    onPreviewError: (error) => {
      state.previewError = { code: error.code ?? null, name: error.name, message: error.message };
      state.previewError.line = errorLine(state.previewError);
      console.warn('the preview is not shown:', error);
      showProgress();
    },
    onRequest: (r) => {
      state.requests.push({ first: r.first, last: r.last, status: r.status, t: now() });
      state.totalBytes = state.totalBytes ?? r.contentRange?.size ?? null;
    },
    onInfo: (info) => {
      state.layerCount = info.layers.length;
      state.sceneUp = info.metadata?.up ?? params.get('up') ?? '-y';
      state.prefixPsnr = info.metadata?.stats?.prefix_psnr ?? null;
      expectBounds(metadataBounds(info.metadata));
    },
    onProgress: (bytes) => {
      state.bytesLoaded = bytes;
      showProgress();
    },
    onLayer: addLayer,
  });
}

async function showAsset(app, rig, whenShown) {
  const type = state.kind === 'ply' ? 'gsplat' : 'container';
  const asset = new pc.Asset('scene', type, { url: src });
  asset.on('progress', (received, total) => {
    state.bytesLoaded = received;
    state.totalBytes = total || state.totalBytes;
    showProgress();
  });
  app.assets.add(asset);
  await new Promise((resolve, reject) => {
    asset.once('load', resolve);
    asset.once('error', (message) => reject(new Error(String(message))));
    app.assets.load(asset);
  });
  let entity, resources, upright;
  if (type === 'gsplat') {  // a PLY stores no up axis: the URL's, else -y
    state.sceneUp = params.get('up') ?? '-y';
    upright = upRotation(state.sceneUp);
    entity = new pc.Entity('scene');
    entity.addComponent('gsplat', { asset });
    entity.setLocalRotation(new pc.Quat(...upright));
    resources = [asset.resource];
  } else {  // glTF is +Y up: its node's rotation stands the scene upright
    state.sceneUp = 'glTF node';
    entity = asset.resource.instantiateRenderEntity();
    resources = (asset.resource.gsplats ?? []).map((a) => a.resource);
  }
  if (!resources.length) throw new Error(`${src} holds no Gaussian splats PlayCanvas can show`);
  state.gaussians = resources.reduce((sum, r) => sum + r.gsplatData.numSplats, 0);
  app.root.addChild(entity);
  const centres = resources[0].centers ?? resources[0].gsplatData.getCenters();
  rig.see(worldPositions(centres, upright ?? nodeRotation(entity)));
  await whenShown();
  state.tFirstPicture = now();
  state.bytesAtFirstPicture = state.bytesLoaded;
}

/** The rotation of the first entity under `root` that draws splats (a glTF's node). */
function nodeRotation(root) {
  const node = root.findComponents('gsplat')[0]?.entity ?? root;
  const q = node.getRotation();
  return [q.x, q.y, q.z, q.w];
}

function worldPositions(centres, rotation) {
  return rotatePositions(centres instanceof Float32Array ? centres : Float32Array.from(centres),
    rotation);
}

/** Whether the .glb at `url` carries an .spc (`spcodec embed`) rather than glTF accessors: read
 * from its header and JSON chunk (two small range requests). */
async function embedsSpc(url) {
  const { GLB_PREAMBLE_BYTES, jsonEnd, locateSpc } = await import('../../src/glb.js');
  const bytes = async (last) => new Uint8Array(await (await fetch(url, {
    headers: { Range: `bytes=0-${last}` } })).arrayBuffer());
  try {
    locateSpc((await bytes(jsonEnd(await bytes(GLB_PREAMBLE_BYTES - 1)) - 1)));
    return true;
  } catch (error) {
    if (error.code === 'bad-glb' && /holds no SPCODEC/.test(error.message)) return false;
    throw error;
  }
}

// ------------------------------------------------------------------------------- main
async function main() {
  showProgress();
  if (!src) return;
  const app = await createApp(canvas, Number(params.get('width')) || 0, Number(params.get('height')) || 0);
  const gl = app.graphicsDevice.gl;
  state.renderer = gl ? gl.getParameter(gl.RENDERER) : app.graphicsDevice.deviceType;
  const rig = new CameraRig(createCamera(app));
  const whenShown = frameWatcher(app);
  state.status = 'loading';
  state.tStart = performance.now();
  if (state.kind === 'glb' && await embedsSpc(src)) state.kind = 'spc';  // `spcodec embed`
  if (state.kind === 'spc') await showSpc(app, rig, whenShown);
  else if (state.kind === 'tileset') {
    await showTileset({ app, pc, rig, whenShown, state, params, now, showProgress,
      firstPicture: (t, bytes) => firstPicture(t, bytes, 0) });
  } else await showAsset(app, rig, whenShown);
  state.tComplete = now();
  state.status = 'complete';
  showProgress();
}

main().catch((error) => {
  state.status = 'error';
  state.error = { code: error.code ?? null, name: error.name, message: error.message };
  state.error.line = errorLine(state.error);  // what the page shows
  showProgress();
  console.error(error);
});
