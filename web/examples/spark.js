// An .spc in a three.js app rendered by Spark: `loadSpc` streams its layers into SplatMeshes,
// and `loadTileset` streams a tileset (src ending in .json, `python -m spcodec.tiling`) by view.
//
// URL parameters: src (an .spc, a .glb written by `spcodec embed`, or a tileset.json), width/height,
// cam/target/fov (camera, in the upright +Y world), up (the scene's up axis where the file does
// not say), ply=1 (load `src` as a PLY with Spark's own loader instead, for comparison),
// budget/sse (a tileset's splat budget and screen-space error in px), capture=1.
// `window.spcViewer` holds the progress the browser tests read.

import * as spark from '@sparkjsdev/spark';
import { boxCorners, configureDraco, rotatePositions, upRotation } from 'spcodec';
import { browserDraco } from 'spcodec/draco-browser';
import { loadSpc, loadTileset } from 'spcodec/spark';
import * as THREE from 'three';

const params = new URLSearchParams(location.search);
const state = { status: 'loading', layersShown: 0, gaussians: 0, tFirstPicture: null, camera: null,
  error: null, tilesShown: null, covers: null };
window.spcViewer = state;
const canvas = document.getElementById('scene');
const say = (text) => { document.getElementById('status').textContent = text; };

function frame(positions, fov) {
  const cam = params.get('cam')?.split(',').map(Number);
  const target = params.get('target')?.split(',').map(Number);
  if (cam && target) return { position: cam, target };
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < positions.length; i += 3) for (let a = 0; a < 3; a++) {
    lo[a] = Math.min(lo[a], positions[i + a]);
    hi[a] = Math.max(hi[a], positions[i + a]);
  }
  const centre = lo.map((v, a) => (v + hi[a]) / 2);
  const distance = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2 / Math.sin((fov * Math.PI) / 360);
  const e = (20 * Math.PI) / 180;
  return { position: [centre[0], centre[1] + Math.sin(e) * distance, centre[2] - Math.cos(e) * distance],
    target: centre };
}

async function main() {
  const src = params.get('src');
  const width = Number(params.get('width')) || innerWidth, height = Number(params.get('height')) || innerHeight;
  const fov = Number(params.get('fov')) || 50;
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(width, height);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(fov, width / height, 0.01, 1000);
  scene.add(new spark.SparkRenderer({ renderer }));
  configureDraco(browserDraco());
  const start = performance.now();
  let placed = false;
  const place = (positions) => {
    if (placed) return;
    const view = frame(positions, fov);
    camera.position.set(...view.position);
    camera.up.set(0, 1, 0);
    camera.lookAt(...view.target);
    const d = Math.hypot(...view.position.map((p, i) => p - view.target[i]));
    camera.near = d * 1e-3;
    camera.far = d * 1e3;
    camera.updateProjectionMatrix();
    state.camera = { position: view.position, target: view.target, fov };
    placed = true;
  };
  renderer.setAnimationLoop(() => renderer.render(scene, camera));
  if (src.endsWith('.json')) {
    await showTileset(src, { scene, camera, renderer, place, start });
  } else if (params.has('ply')) {  // Spark's own PLY loader, for comparison
    const rotation = upRotation(params.get('up'));
    const group = new THREE.Group();
    group.quaternion.set(...rotation);
    const mesh = new spark.SplatMesh({ url: src });
    group.add(mesh);
    scene.add(group);
    await mesh.initialized;
    const centres = [];
    mesh.packedSplats.forEachSplat((i, center) => centres.push(center.x, center.y, center.z));
    place(rotatePositions(Float32Array.from(centres), rotation));
    state.gaussians = mesh.packedSplats.numSplats;
    state.layersShown = 1;
  } else {
    await loadSpc(src, {
      THREE, spark, parent: scene, up: params.get('up'),
      onLayer: (layer) => {
        if (layer.cloud.count) place(rotatePositions(layer.cloud.positions, layer.rotation));
        state.gaussians += layer.cloud.count;
        state.layersShown = layer.index + 1;
        state.tFirstPicture ??= performance.now() - start;
        say(`layers: ${layer.index + 1}, Gaussians: ${state.gaussians}`);
      },
    });
  }
  // a few frames for Spark's sort of the final set of splats to come back and be drawn
  for (let i = 0; i < 10; i++) await new Promise((resolve) => requestAnimationFrame(resolve));
  await new Promise((resolve) => setTimeout(resolve, 500));
  for (let i = 0; i < 5; i++) await new Promise((resolve) => requestAnimationFrame(resolve));
  state.status = 'complete';
  say(`${src}: ${state.gaussians} Gaussians`);
}

/** Stream a tileset by view: the camera frames the root's box (or stands where the URL says),
 * the render loop asks for a new selection when the camera moved, and the page is complete once
 * every node of the selection is in and drawn. */
async function showTileset(src, { scene, camera, renderer, place, start }) {
  const positive = (name) => (Number(params.get(name)) > 0 ? Number(params.get(name)) : undefined);
  const errors = [];
  const tiles = await loadTileset(src, {
    THREE, spark, camera, parent: scene, height: () => renderer.domElement.height,
    budget: positive('budget'), threshold: positive('sse'), up: params.get('up'),
    onOpen: (tileset, rotation) => {  // the URL's camera, else the root's box, upright
      place(boxCorners(tileset.root, rotation));
      camera.updateMatrixWorld();
    },
    onShown: (shown, covers) => {
      state.tilesShown = [...shown].map((tile) => tile.id).sort();
      state.gaussians = [...shown].reduce((sum, tile) => sum + tile.gaussians, 0);
      state.covers = covers;
      state.tFirstPicture ??= performance.now() - start;
      say(`tiles: ${shown.size}, Gaussians: ${state.gaussians}`);
    },
    onError: (error, tile) => errors.push(`${tile.id}: ${error instanceof Error ? error.message : error}`),
  });
  renderer.setAnimationLoop(() => {  // replaces the page's loop: select where the camera is, then draw
    tiles.update();
    renderer.render(scene, camera);
  });
  await tiles.stream.whenIdle();
  if (errors.length) throw new Error(`${errors.length} node(s) did not load, first ${errors[0]}`);
}

main().catch((error) => {
  state.status = 'error';
  state.error = { code: error.code ?? null, message: error.message, line: error.message };
  say(`error: ${error.message}`);
});
