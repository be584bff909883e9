// An .spc in a PlayCanvas app, the way an app adds it: `loadSpc` streams the layers into
// entities (the default), or `registerSpc` lets the app load it as a gsplat asset (?mode=asset);
// `loadTileset` streams a tileset (src ending in .json, `python -m spcodec.tiling`) by view.
//
// URL parameters: src (an .spc, a .glb written by `spcodec embed`, or a tileset.json),
// mode=stream|asset, width/height, cam/target/fov (camera, in the upright +Y world), up (the
// scene's up axis where the file does not say), budget/sse (a tileset's splat budget and
// screen-space error in px), capture=1 (tests). `window.spcViewer` holds the page's progress in the
// form the browser tests read (status, layersShown, tFirstPicture, camera, error).

import * as pc from 'playcanvas';
import { boxCorners, configureDraco, rotatePositions } from 'spcodec';
import { browserDraco } from 'spcodec/draco-browser';
import { loadSpc, loadTileset, registerSpc } from 'spcodec/playcanvas';

const params = new URLSearchParams(location.search);
const state = { status: 'loading', layersShown: 0, gaussians: 0, tFirstPicture: null, camera: null,
  error: null, tilesShown: null, covers: null };
window.spcViewer = state;
const canvas = document.getElementById('scene');
const say = (text) => { document.getElementById('status').textContent = text; };

async function createApp() {
  const width = Number(params.get('width')) || 0, height = Number(params.get('height')) || 0;
  const device = await pc.createGraphicsDevice(canvas, {
    deviceTypes: [pc.DEVICETYPE_WEBGL2], antialias: false, preserveDrawingBuffer: true });
  const options = new pc.AppOptions();
  options.graphicsDevice = device;
  options.componentSystems = [pc.CameraComponentSystem, pc.GSplatComponentSystem];
  options.resourceHandlers = [pc.GSplatHandler];
  const app = new pc.AppBase(canvas);
  app.init(options);
  if (width && height) {
    app.setCanvasFillMode(pc.FILLMODE_NONE, width, height);
    app.setCanvasResolution(pc.RESOLUTION_FIXED, width, height);
  } else {
    app.setCanvasFillMode(pc.FILLMODE_FILL_WINDOW);
    app.setCanvasResolution(pc.RESOLUTION_AUTO);
  }
  app.start();
  return app;
}

/** Look at the scene from 20 degrees above its horizon (or from where the URL says). */
function placeCamera(camera, positions) {
  const cam = params.get('cam')?.split(',').map(Number);
  const target = params.get('target')?.split(',').map(Number);
  const fov = Number(params.get('fov')) || 50;
  let view = cam && target ? { position: cam, target } : null;
  if (!view) {
    const n = positions.length / 3, lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < n; i++) for (let a = 0; a < 3; a++) {
      lo[a] = Math.min(lo[a], positions[3 * i + a]);
      hi[a] = Math.max(hi[a], positions[3 * i + a]);
    }
    const centre = lo.map((v, a) => (v + hi[a]) / 2);
    const radius = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2;
    const distance = radius / Math.sin((fov * Math.PI) / 360);
    const e = (20 * Math.PI) / 180;
    view = { position: [centre[0], centre[1] + Math.sin(e) * distance, centre[2] - Math.cos(e) * distance],
      target: centre };
  }
  camera.camera.fov = fov;
  camera.setPosition(...view.position);
  camera.lookAt(new pc.Vec3(...view.target), pc.Vec3.UP);
  state.camera = { position: view.position, target: view.target, fov };
}

/** A function whose promise resolves once a frame with every change made before the call is on
 * screen, sorted: PlayCanvas's gsplat frame:ready with nothing left loading, a frame later. */
function whenDrawn(app) {
  let frame = 0;
  const waiting = [];
  app.on('frameend', () => { frame++; });
  app.systems.gsplat.on('frame:ready', (cam, layer, ready, loading) => {
    if (!ready || loading) return;
    for (const w of waiting.filter((x) => frame > x.frame)) w.resolve();
    waiting.splice(0, waiting.length, ...waiting.filter((x) => frame <= x.frame));
  });
  return () => new Promise((resolve) => waiting.push({ frame, resolve }));
}

async function main() {
  const src = params.get('src');
  const app = await createApp();
  configureDraco(browserDraco());
  const camera = new pc.Entity('camera');
  camera.addComponent('camera', { clearColor: new pc.Color(0, 0, 0, 1), fov: 50 });
  app.root.addChild(camera);
  const start = performance.now();
  const shown = whenDrawn(app);
  if (src.endsWith('.json')) {
    await showTileset(app, camera, src);
  } else if (params.get('mode') === 'asset') {
    registerSpc(app, pc, { up: params.get('up') });
    const asset = new pc.Asset('scene', 'gsplat', { url: src });
    app.assets.add(asset);
    await new Promise((resolve, reject) => {
      asset.once('load', resolve);
      asset.once('error', (error) => reject(error instanceof Error ? error : new Error(String(error))));
      app.assets.load(asset);
    });
    const entity = new pc.Entity('scene');
    entity.addComponent('gsplat', { asset });
    entity.setLocalRotation(new pc.Quat(...asset.resource.spcRotation));
    app.root.addChild(entity);
    placeCamera(camera, rotatePositions(asset.resource.centers ?? asset.resource.gsplatData.getCenters(),
      asset.resource.spcRotation));
    state.gaussians = asset.resource.gsplatData.numSplats;
    state.layersShown = 1;
  } else {
    let placed = false;
    await loadSpc(app, pc, src, {
      up: params.get('up'),
      onLayer: (layer) => {
        if (!placed && layer.cloud.count) {
          placeCamera(camera, rotatePositions(layer.cloud.positions, layer.rotation));
          placed = true;
        }
        state.gaussians += layer.cloud.count;
        shown().then(() => {
          state.layersShown = Math.max(state.layersShown, layer.index + 1);
          state.tFirstPicture ??= performance.now() - start;
        });
        say(`layers: ${layer.index + 1}, Gaussians: ${state.gaussians}`);
      },
    });
  }
  await shown();
  state.tFirstPicture ??= performance.now() - start;
  state.status = 'complete';
  say(`${src}: ${state.gaussians} Gaussians`);
}

/** Stream a tileset by view: the camera frames the root's box (or stands where the URL says),
 * the loader selects again whenever it moved, and the page waits until every node of the
 * selection is in. */
async function showTileset(app, camera, src) {
  const positive = (name) => (Number(params.get(name)) > 0 ? Number(params.get(name)) : undefined);
  const errors = [];
  const tiles = await loadTileset(app, pc, src, {
    camera, budget: positive('budget'), threshold: positive('sse'), up: params.get('up'),
    onOpen: (tileset, rotation) => placeCamera(camera, boxCorners(tileset.root, rotation)),
    onShown: (shown, covers) => {
      state.tilesShown = [...shown].map((tile) => tile.id).sort();
      state.gaussians = [...shown].reduce((sum, tile) => sum + tile.gaussians, 0);
      state.covers = covers;
      say(`tiles: ${shown.size}, Gaussians: ${state.gaussians}`);
    },
    onError: (error, tile) => errors.push(`${tile.id}: ${error instanceof Error ? error.message : error}`),
  });
  await tiles.stream.whenIdle();
  if (errors.length) throw new Error(`${errors.length} node(s) did not load, first ${errors[0]}`);
}

main().catch((error) => {
  state.status = 'error';
  state.error = { code: error.code ?? null, message: error.message, line: error.message };
  say(`error: ${error.message}`);
});
