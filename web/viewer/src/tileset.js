// The viewer's tileset mode: `src=.../tileset.json` (a scene tiled by `python -m spcodec.tiling`)
// streams its nodes by view through the package's PlayCanvas loader (loadTileset): the root node
// first, the whole scene coarse, then what the camera looks at down to full detail within the
// splat budget, then the rest; dragging or zooming selects again.
//
// URL parameters (besides the viewer's camera and size ones):
//   budget=N   Gaussians drawn at most (default 1,500,000: web splat renderers draw 0.5-2.5 M a
//              frame)
//   sse=PX     screen-space error, in pixels, past which a node is replaced by its children
//              (default 16)
//
// Progress is kept in `window.spcViewer.tileset` (see `progress` below), which the browser test
// reads: when the whole scene was first on screen and after how many bytes, and the order in
// which the nodes arrived.

import { rotate } from '../../src/tileset.js';
import { frameBounds } from './splats.js';

const UP = [0, 1, 0];

/**
 * Stream the tileset at `src` into `app`, the camera following `rig`; resolves once the nodes of
 * the first selection are in and on screen.
 * @param {object} page  the viewer's page: {app, pc, rig, whenShown, state, params, now,
 *   showProgress, firstPicture(t, bytesNeeded)}: the page's own bookkeeping
 */
export async function showTileset({ app, pc, rig, whenShown, state, params, now, showProgress, firstPicture }) {
  const spc = await import('../../src/index.js');
  const { browserDraco } = await import('../../src/draco-browser.js');
  const { loadTileset } = await import('../../loaders/playcanvas.js');
  spc.configureDraco(browserDraco());
  const budget = positiveParam(params, 'budget', 1_500_000);
  const threshold = positiveParam(params, 'sse', 16);
  /** Everything the page knows of the tileset's progress. */
  const progress = {
    tiles: null, gaussians: null, bytes: null,  // the whole tileset, as its index states
    budget, threshold,
    indexBytes: null,  // of tileset.json
    subtreeBytes: 0,  // of the external tilesets read so far (subtrees/*.json)
    arrivals: [],  // {id, level, view, leaf, gaussians, bytes, bytesLoaded, t}, in arrival order
    shown: [],  // the ids of the nodes on screen
    gaussiansShown: 0,
    bytesAtFullPicture: null,  // bytes received when the whole scene was first drawn (index too)
    nodeBytesAtFullPicture: null,  // of which node files
    shownAtFullPicture: null,  // the nodes on screen then (ids)
    tFullPicture: null,  // when a frame first held it
    idle: false,  // every node of the current selection is in
    errors: [],  // {id, message} of nodes that failed
  };
  state.tileset = progress;
  let nodeBytes = 0;
  const tiles = await loadTileset(app, pc, state.src, {
    camera: rig.camera, budget, threshold, up: params.get('up'),
    onOpen: (tileset, rotation, indexBytes) => {
      Object.assign(progress, { tiles: tileset.tileCount, gaussians: tileset.gaussians,
        bytes: tileset.bytes, indexBytes });
      state.totalBytes = tileset.bytes == null ? null : tileset.bytes + indexBytes;  // as bytesLoaded
      const root = tileset.root;
      if (!rig.fixed && !rig.moved) {  // framed on the root's box, turned upright
        rig.aim(frameBounds({ centre: rotate(root.centre, rotation), radius: root.radius }, UP, rig.fov));
        state.cameraFramings++;
      }
    },
    onProgress: (bytes) => {
      state.bytesLoaded = bytes;
      showProgress();
    },
    onArrival: (arrival) => {
      nodeBytes += arrival.bytes;
      progress.arrivals.push({ ...arrival, t: now() });
      state.layersDecoded = progress.arrivals.length;
    },
    onShown: (shown, covers) => {
      progress.shown = [...shown].map((t) => t.id);
      progress.gaussiansShown = [...shown].reduce((n, t) => n + t.gaussians, 0);
      state.gaussians = progress.gaussiansShown;
      if (covers && progress.bytesAtFullPicture == null) {
        progress.bytesAtFullPicture = state.bytesLoaded;
        progress.nodeBytesAtFullPicture = nodeBytes;
        progress.shownAtFullPicture = progress.shown;
        whenShown().then(() => {
          progress.tFullPicture = now();
          firstPicture(progress.tFullPicture, progress.bytesAtFullPicture);
          showProgress();
        });
      }
      showProgress();
    },
    onError: (error, tile) => {
      progress.errors.push({ id: tile.id, message: error instanceof Error ? error.message : String(error) });
      console.error(`node ${tile.id}:`, error);
      showProgress();
    },
  });
  app.on('update', () => {
    progress.idle = tiles.stream.idle;
    progress.subtreeBytes = tiles.stream.subtreeBytes;
  });
  await tiles.stream.whenIdle();
  await whenShown();
  progress.idle = true;
  progress.subtreeBytes = tiles.stream.subtreeBytes;
  if (progress.errors.length) {  // the scene stays on screen, coarser there; the page says why
    const first = progress.errors[0];
    throw new Error(`${progress.errors.length} node(s) did not load, first ${first.id}: ${first.message}`);
  }
  return tiles;
}

/** Lines for the page's overlay. */
export function tilesetLines(progress) {
  if (!progress) return [];
  const lines = [`nodes: ${progress.arrivals.length} in, ${progress.shown.length} shown of ` +
    `${progress.tiles ?? '?'}; budget ${progress.budget.toLocaleString('en')} Gaussians`];
  if (progress.nodeBytesAtFullPicture != null && progress.bytes) {
    const share = (100 * progress.nodeBytesAtFullPicture / progress.bytes).toFixed(1);
    lines.push(`whole scene on screen after ${share}% of the tileset's nodes`);
  }
  if (progress.errors.length) {
    lines.push(`nodes failed: ${progress.errors.length} (first: ${progress.errors[0].id})`);
  }
  return lines;
}

/** A positive number from the URL, or `fallback`. */
function positiveParam(params, name, fallback) {
  if (!params.has(name)) return fallback;
  const value = Number(params.get(name));
  if (!(value > 0)) throw new Error(`URL parameter ${name} must be a positive number, got "${params.get(name)}"`);
  return value;
}
