/**
 * The loaders' loadTileset (loaders/playcanvas.js, loaders/spark.js) with fake engines: the
 * tileset's parent turned upright, one object per node, REPLACE on screen (leaves shown, the root
 * hidden once they are in), a new selection only when the camera moved, and removal when a turn
 * of the camera drops tiles.
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import { loadTileset as loadPlayCanvas } from '../loaders/playcanvas.js';
import { loadTileset as loadSpark } from '../loaders/spark.js';
import { decode } from '../src/index.js';
import { fakeThree, fixture } from './helpers.js';
import { quadtree } from './tileset-docs.js';

const NODE = fixture('sh0-none-float16');
const URL_ = 'http://tiles.test/t/tileset.json';

async function served() {
  const doc = quadtree({ depth: 2, gaussians: (await decode(NODE)).count });
  const fetchImpl = async (url) => {
    const body = String(url).endsWith('tileset.json') ? new TextEncoder().encode(JSON.stringify(doc)) : NODE;
    return /** @type {Response} */ (/** @type {unknown} */ ({ ok: true, status: 200,
      text: async () => new TextDecoder().decode(body), arrayBuffer: async () => body.slice().buffer }));
  };
  return { doc, fetchImpl };
}

/** A fake PlayCanvas: entities with children, an enabled flag and a rotation. */
function fakePlayCanvas() {
  class Entity {
    constructor(name) {
      this.name = name;
      this.children = [];
      this.enabled = true;
      this.destroyed = false;
      this.rotation = null;
    }
    addChild(child) { this.children.push(child); }
    setLocalRotation(q) { this.rotation = q; }
    addComponent(type, data) { this[type] = data; }
    destroy() { this.destroyed = true; }
  }
  const pc = {
    Entity,
    Quat: class { constructor(...xyzw) { this.xyzw = xyzw; } },
    GSplatData: class { constructor(elements) { this.elements = elements; } },
    GSplatResource: class {
      constructor(device, data) { this.data = data; }
      destroy() {}
    },
  };
  const handlers = new Map();
  const app = {
    root: new Entity('root'),
    graphicsDevice: { width: 640, height: 480 },
    on: (name, fn) => handlers.set(name, fn),
    off: (name) => handlers.delete(name),
    loader: { getHandler: () => undefined },
    frame: () => handlers.get('update')?.(),
  };
  return { pc, app };
}

test('PlayCanvas: upright, one entity per node, the root off once its children are on', async () => {
  const { doc, fetchImpl } = await served();
  const { pc, app } = fakePlayCanvas();
  // outside the scene, looking across it: every tile in front of the camera
  const camera = { position: { x: -30, y: 0, z: 0 }, forward: { x: 1, y: 0, z: 0 }, camera: { fov: 50 },
    getPosition() { return this.position; } };
  const tiles = await loadPlayCanvas(app, /** @type {any} */ (pc), URL_, { camera: /** @type {any} */ (camera),
    fetchImpl, up: '+z', threshold: 1e-9, budget: Infinity });
  assert.deepEqual(/** @type {any} */ (tiles.entity).rotation.xyzw, [-Math.SQRT1_2, 0, 0, Math.SQRT1_2]);
  await tiles.stream.whenIdle();
  const nodes = /** @type {any[]} */ (/** @type {any} */ (tiles.entity).children);
  assert.equal(nodes.length, 21);
  const on = nodes.filter((e) => e.enabled).map((e) => e.name).sort();
  const leaves = doc.root.children.flatMap((c) => c.children.map((g) => g.content.uri)).sort();
  assert.deepEqual(on, leaves);
  assert.ok(nodes.every((e) => e.gsplat?.resource instanceof pc.GSplatResource));
  // no movement, no new selection; a move selects again
  const selection = tiles.stream.selection;
  app.frame();
  assert.equal(tiles.stream.selection, selection);
  camera.forward = { x: -1, y: 0, z: 0 };
  app.frame();
  assert.notEqual(tiles.stream.selection, selection);
  tiles.destroy();
  assert.ok(nodes.every((e) => e.destroyed));
});

test('PlayCanvas: a camera is required', async () => {
  const { pc, app } = fakePlayCanvas();
  await assert.rejects(loadPlayCanvas(app, /** @type {any} */ (pc), URL_, /** @type {any} */ ({})),
    /needs \{ camera \}/);
});

function fakeSpark() {
  return {
    defines: { DEFAULT_SPLAT_ENCODING: { rgbMin: 0, rgbMax: 1 } },
    utils: { setPackedSplat() {}, encodeSh1Rgb() {}, encodeSh2Rgb() {}, encodeSh3Rgb() {},
      getTextureSize: (n) => ({ maxSplats: n }) },
    PackedSplats: class { constructor(options) { this.options = options; } },
    SplatMesh: class {
      name = '';
      visible = true;
      disposed = false;
      constructor(options) { this.options = options; this.initialized = Promise.resolve(this); }
      dispose() { this.disposed = true; }
    },
  };
}

test('Spark: upright group, one mesh per node, update() follows the camera and drops tiles', async () => {
  const served_ = await served();
  /** @type {string[]} */
  const nodeFetches = [];
  const fetchImpl = async (url) => {
    if (!String(url).endsWith('tileset.json')) nodeFetches.push(String(url));
    return served_.fetchImpl(url);
  };
  const view = { position: [-30, 0, -4], forward: [1, 0, 0] };
  const camera = { fov: 50, aspect: 4 / 3,
    getWorldPosition: (v) => Object.assign(v, { x: view.position[0], y: view.position[1], z: view.position[2] }),
    getWorldDirection: (v) => Object.assign(v, { x: view.forward[0], y: view.forward[1], z: view.forward[2] }) };
  const count = (await decode(NODE)).count;
  /** @type {any[]} */
  const opened = [];
  const tiles = await loadSpark(URL_, { THREE: fakeThree, spark: /** @type {any} */ (fakeSpark()),
    camera, height: () => 480, fetchImpl, up: '+y', threshold: 1e-9, budget: 8 * count,
    onOpen: (tileset, rotation) => opened.push({ tileset, rotation, fetched: nodeFetches.slice() }) });
  assert.deepEqual(/** @type {any} */ (tiles.group).quaternion.xyzw, [0, 0, 0, 1]);
  assert.equal(opened.length, 1, 'onOpen once, with the index');
  assert.equal(opened[0].tileset, tiles.tileset);
  assert.deepEqual(opened[0].rotation, [0, 0, 0, 1]);
  // before the first selection: at most the root (which every view needs) has been asked for
  assert.ok(opened[0].fetched.every((url) => url.endsWith(`/t/${served_.doc.root.content.uri}`)),
    opened[0].fetched.join());
  assert.ok(nodeFetches.length > opened[0].fetched.length + 1, 'the selection fetched more afterwards');
  await tiles.stream.whenIdle();
  const group = /** @type {any} */ (tiles.group);
  const before = group.children.slice();
  assert.ok(before.some((m) => m.visible) && before.some((m) => !m.visible), 'the root hidden, children shown');
  assert.ok(!before.find((m) => m.name === 'nodes/n.spc').visible);
  view.position = [30, 0, 4];
  view.forward = [-1, 0, 0];
  tiles.update();
  await tiles.stream.whenIdle();
  const dropped = before.filter((m) => !group.children.includes(m));
  assert.ok(dropped.length > 0 && dropped.every((m) => m.disposed));
  assert.ok(tiles.stream.selection && tiles.stream.selection.gaussians <= 8 * count);
});
