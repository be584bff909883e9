/**
 * The tileset streamer (src/tilestream.js) with a recording renderer: the index, then the root,
 * then the nodes in the selection's order, real .spc files decoded; a parent hidden in the same
 * step its children in view are shown; nothing behind the camera before the view is complete;
 * tiles no longer needed dropped when the camera turns; a bad node reported, not fatal.
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import { decode } from '../src/index.js';
import { TilesetStream } from '../src/tilestream.js';
import { VIEW } from '../src/tileset.js';
import { fixture } from './helpers.js';
import { quadtree, splitIndex } from './tileset-docs.js';

const NODE = fixture('sh0-none-float16');
const BASE = 'http://tiles.test/scene/';

/**
 * A fetch serving `doc` as tileset.json (or `files`, index files by name) and NODE for every
 * node, recording the URLs asked.
 */
function server(doc, { broken = new Set(), files = { 'tileset.json': doc } } = {}) {
  const asked = [];
  const fetchImpl = async (url) => {
    asked.push(String(url));
    const name = String(url).slice(BASE.length);
    const body = name in files ? new TextEncoder().encode(JSON.stringify(files[name]))
      : broken.has(name) ? NODE.subarray(0, 100) : NODE;
    return /** @type {Response} */ (/** @type {unknown} */ ({ ok: true, status: 200,
      text: async () => new TextDecoder().decode(body), arrayBuffer: async () => body.slice().buffer }));
  };
  return { asked, fetchImpl };
}

/** A renderer that records what is on screen after each step. */
function recorder() {
  const visible = new Set();
  const log = [];
  let next = 0;
  return {
    visible, log,
    renderer: {
      add: (tile, cloud) => ({ id: tile.id, count: cloud.count, serial: next++ }),
      show: (handle, on) => {
        if (on) visible.add(handle.id);
        else visible.delete(handle.id);
        log.push([on ? 'show' : 'hide', handle.id]);
      },
      remove: (handle) => {
        visible.delete(handle.id);
        log.push(['remove', handle.id]);
      },
    },
  };
}

const camera = (position, forward) => ({ position, forward, fov: 50, height: 600 });
const IDENTITY_UP = '+y';  // the fixture stores no up axis: +y leaves the tileset frame as the world

test('the root first, then the view to its leaves; nothing behind the camera is fetched', async () => {
  const count = (await decode(NODE)).count;
  const doc = quadtree({ depth: 2, gaussians: count, bytes: NODE.length });
  const { asked, fetchImpl } = server(doc);
  const screen = recorder();
  const covered = [];
  const stream = new TilesetStream(`${BASE}tileset.json`, screen.renderer, {
    fetchImpl, up: IDENTITY_UP, threshold: 1e-9, budget: Infinity, concurrency: 3,
    onShown: (_shown, covers) => covered.push(covers) });
  await stream.open();
  assert.deepEqual(asked, [`${BASE}tileset.json`, `${BASE}nodes/n.spc`]);
  assert.deepEqual([...screen.visible], ['nodes/n.spc']);
  assert.equal(covered[0], true, 'the root alone covers the scene');
  stream.update(camera([0, 0, 0], [1, 0, 0]));  // in the middle, looking along +x
  await stream.whenIdle();
  const arrivals = stream.arrivals;
  // the root, its two children in front (x > 0) and their eight leaves; the two behind culled
  assert.equal(arrivals.length, 11);
  assert.equal(new Set(arrivals.map((a) => a.id)).size, 11);
  assert.ok(arrivals.every((a) => a.view !== VIEW.BEHIND));
  const front = doc.root.children.filter((c) => c.boundingVolume.box[0] > 0);
  assert.equal(front.length, 2);
  assert.deepEqual([...screen.visible].sort(), front.flatMap((c) => c.children.map((g) => g.content.uri)).sort());
  assert.equal(stream.bytesLoaded, JSON.stringify(doc).length + 11 * NODE.length);
  // the root went off screen in the same step its children in view came on
  const rootOff = screen.log.findIndex(([what, id]) => what === 'hide' && id === 'nodes/n.spc');
  assert.ok(rootOff > 0);
  assert.equal(covered.at(-1), true, 'what can be seen is covered');
});

test('turning the camera drops the tiles no longer needed and fetches the new view', async () => {
  const count = (await decode(NODE)).count;
  const doc = quadtree({ depth: 2, gaussians: count });
  const { fetchImpl } = server(doc);
  const screen = recorder();
  // a budget for the root, its children and one grandchild group: the view refines, nothing else
  const stream = new TilesetStream(`${BASE}tileset.json`, screen.renderer, {
    fetchImpl, up: IDENTITY_UP, threshold: 1e-9, budget: 8 * count });
  await stream.open();
  stream.update(camera([-30, 0, -4], [1, 0, 0]));
  await stream.whenIdle();
  const before = new Set(stream.loaded.keys());
  stream.update(camera([30, 0, 4], [-1, 0, 0]));
  await stream.whenIdle();
  const after = new Set(stream.loaded.keys());
  const removed = screen.log.filter(([what]) => what === 'remove').map(([, id]) => id);
  assert.ok(removed.length > 0);
  for (const id of removed) assert.ok([...before].some((t) => t.id === id) && ![...after].some((t) => t.id === id));
  assert.ok([...after].some((t) => !before.has(t)), 'the new view fetched tiles of its own');
  assert.ok(stream.selection && stream.selection.gaussians <= 8 * count);
  assert.ok([...screen.visible].length > 0);
});

test('external tilesets: fetched as the view reaches them, each before its node, the same picture', async () => {
  const count = (await decode(NODE)).count;
  const doc = quadtree({ depth: 3, gaussians: count, bytes: NODE.length });
  const files = splitIndex(doc, 2);
  const finals = [];
  for (const [index, budget] of [[{ 'tileset.json': doc }, Infinity], [files, Infinity], [files, 8 * count]]) {
    const { asked, fetchImpl } = server(doc, { files: index });
    const screen = recorder();
    const stream = new TilesetStream(`${BASE}tileset.json`, screen.renderer, {
      fetchImpl, up: IDENTITY_UP, threshold: 1e-9, budget });
    await stream.open();
    stream.update(camera([-30, 0, -4], [1, 0, 0]));
    await stream.whenIdle();
    const names = asked.map((u) => u.slice(BASE.length));
    for (const [i, name] of names.entries()) {  // every node after the file that names it
      const id = name.match(/^nodes\/(n\d*)\.spc$/)?.[1];
      if (id && id.length > 3) assert.ok(names.indexOf(`subtrees/${id.slice(0, 3)}.json`) < i, name);
    }
    const subtrees = names.filter((n) => n.startsWith('subtrees/'));
    if (subtrees.length) {  // the selection's links are read at once, not in their turn after the nodes above
      assert.ok(names.indexOf(subtrees[0]) < names.findIndex((n) => /^nodes\/n\d\.spc$/.test(n)), names.join(' '));
    }
    const sizes = subtrees.reduce((n, name) => n + JSON.stringify(index[name]).length, 0);
    assert.equal(stream.subtreeBytes, sizes);
    assert.equal(stream.bytesLoaded, JSON.stringify(index['tileset.json']).length + sizes
      + stream.arrivals.length * NODE.length);
    assert.equal(stream.tileset?.tileCount, 85);
    finals.push({ visible: [...screen.visible].sort(), subtrees });
  }
  const [whole, split, small] = finals;
  assert.equal(whole.subtrees.length, 0);
  assert.deepEqual(split.visible, whole.visible, 'the same tiles on screen from one file or many');
  assert.equal(split.subtrees.length, 16, 'every subtree, once, when the budget refines everything');
  // within a small budget only the subtrees the view reaches are read
  assert.ok(small.subtrees.length > 0 && small.subtrees.length <= 4, JSON.stringify(small.subtrees));
  assert.ok(small.visible.some((id) => id.length > 'nodes/n0.spc'.length), 'refined into a subtree');
});

test('a node that does not decode is reported and the tiles above it stay', async () => {
  const count = (await decode(NODE)).count;
  const doc = quadtree({ depth: 1, gaussians: count });
  const { fetchImpl } = server(doc, { broken: new Set(['nodes/n2.spc']) });
  const screen = recorder();
  const errors = [];
  const stream = new TilesetStream(`${BASE}tileset.json`, screen.renderer, {
    fetchImpl, up: IDENTITY_UP, threshold: 1e-9, budget: Infinity,
    onError: (error, tile) => errors.push([tile.id, error.code ?? error.name]) });
  await stream.open();
  stream.update(camera([0, 0, 30], [0, 0, -1]));
  await stream.whenIdle();
  assert.deepEqual(errors, [['nodes/n2.spc', 'truncated']]);
  assert.ok(screen.visible.has('nodes/n.spc'), 'the root stays: one child in view is missing');
});

test('an external tileset that does not read is reported and the tile above it stays', async () => {
  const count = (await decode(NODE)).count;
  const files = splitIndex(quadtree({ depth: 2, gaussians: count }), 1);
  files['subtrees/n2.json'] = { asset: { version: '1.1' }, geometricError: 1 };
  const { fetchImpl } = server(null, { files });
  const errors = [];
  const stream = new TilesetStream(`${BASE}tileset.json`, recorder().renderer, {
    fetchImpl, up: IDENTITY_UP, threshold: 1e-9, budget: Infinity,
    onError: (error, tile) => errors.push([tile.id, error.message]) });
  await stream.open();
  stream.update(camera([0, 0, 30], [0, 0, -1]));
  await stream.whenIdle();
  assert.deepEqual(errors, [['subtrees/n2.json', 'subtrees/n2.json has no root tile']]);
  assert.ok(stream.shown.has(stream.tileset.root), 'the root stays: one child in view is missing');
});

test('an index that is not a tileset fails open() with one line', async () => {
  const { fetchImpl } = server({ asset: { version: '1.1' }, geometricError: 1 });
  const stream = new TilesetStream(`${BASE}tileset.json`, recorder().renderer, { fetchImpl });
  await assert.rejects(stream.open(), /tileset\.json has no root tile/);
});
