/**
 * The tileset index and the selection by view (src/tileset.js), on synthetic tileset documents:
 * one-line errors for bad documents, the budget held, the root always first, the view refined
 * and fetched before what lies behind, refinement ending at leaves, REPLACE as tiles arrive.
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';

import {
  TilesetError, VIEW, boxCorners, cameraInTileset, coversRoot, graftSubtree, parseTileset, rotate,
  screenSpaceError, selectTiles, visibleTiles,
} from '../src/tileset.js';
import { rng } from './helpers.js';
import { quadtree, splitIndex } from './tileset-docs.js';

/** A camera at `position` looking along `forward`, 50 degrees, 600 px high. */
const camera = (position, forward, extra = {}) => ({ position, forward, fov: 50, height: 600, ...extra });

test('a tileset document parses: tiles, parents, counts and spheres', () => {
  const set = parseTileset(JSON.stringify(quadtree({ depth: 2 })));
  assert.equal(set.tiles.length, 1 + 4 + 16);
  assert.equal(set.root.id, 'nodes/n.spc');
  assert.equal(set.root.children.length, 4);
  assert.equal(set.byId.get('nodes/n03.spc')?.parent?.id, 'nodes/n0.spc');
  assert.equal(set.gaussians, 21 * 1000);
  assert.equal(set.bytes, 21 * 20000);
  assert.ok(Math.abs(set.root.radius - Math.hypot(8, 1, 8)) < 1e-9);
  assert.ok(set.tiles.every((t) => t.parent === null || set.tiles.indexOf(t.parent) < set.tiles.indexOf(t)));
});

/** @param {(doc: any) => void} change @param {RegExp} message */
function rejects(change, message) {
  const doc = quadtree({ depth: 1 });
  change(doc);
  assert.throws(() => parseTileset(doc), (error) => {
    assert.ok(error instanceof TilesetError, String(error));
    assert.match(error.message, message);
    assert.ok(!error.message.includes('\n'), 'one line');
    return true;
  });
}

test('a bad document gets one line naming the problem', () => {
  assert.throws(() => parseTileset('{"asset":'), /tileset\.json is not JSON/);
  assert.throws(() => parseTileset('[]'), /must be a JSON object/);
  rejects((d) => { delete d.asset; }, /no asset\.version/);
  rejects((d) => { d.asset.version = '2.0'; }, /asset\.version "2\.0"/);
  rejects((d) => { d.geometricError = -1; }, /^tileset\.json geometricError must be a non-negative number/);
  rejects((d) => { delete d.root; }, /no root tile/);
  rejects((d) => { d.root.children[1].boundingVolume.box.pop(); }, /root\.children\[1\]\.boundingVolume\.box must be 12/);
  rejects((d) => { d.root.children[0].boundingVolume = { sphere: [0, 0, 0, 1] }; }, /children\[0\]\.boundingVolume\.box/);
  rejects((d) => { d.root.children[2].boundingVolume.box[4] = NaN; }, /children\[2\]\.boundingVolume\.box/);
  rejects((d) => { d.root.refine = 'ADD'; }, /root\.refine is "ADD": only "REPLACE"/);
  rejects((d) => { delete d.root.refine; }, /root\.refine is null/);
  rejects((d) => { d.root.children[3].content.uri = d.root.children[0].content.uri; },
    /children\[3\]\.content\.uri "nodes\/n0\.spc" names a second tile/);
  rejects((d) => { delete d.root.children[0].content; }, /children\[0\]\.content\.uri must name/);
  rejects((d) => { delete d.root.extras; }, /root\.extras\.spcodec is missing/);
  rejects((d) => { d.root.extras.spcodec.gaussians = -3; }, /root\.extras\.spcodec\.gaussians must be a count, got -3/);
  rejects((d) => { d.root.extras.spcodec.bytes = 1.5; }, /bytes must be a byte count/);
  rejects((d) => { d.root.children = {}; }, /root\.children must be an array/);
  rejects((d) => { d.root.children[0].geometricError = 'x'; }, /children\[0\]\.geometricError must be/);
});

/** Every external tileset of `files` grafted, shallowest first, as a viewer would reach them. */
function graftAll(/** @type {Record<string, any>} */ files) {
  const set = parseTileset(files['tileset.json']);
  for (let link = set.tiles.find((t) => t.subtree); link; link = set.tiles.find((t) => t.subtree)) {
    graftSubtree(set, link, JSON.stringify(files[/** @type {string} */ (link.subtree)]));
  }
  return set;
}

/** The shape of a parsed tileset: each tile's id, parent, box, error, counts and level. */
const shape = (/** @type {import('../src/tileset.js').Tileset} */ set) => set.tiles
  .map((t) => [t.id, t.parent?.id ?? null, t.box, t.geometricError, t.gaussians, t.bytes, t.level,
    t.children.map((c) => c.id)])
  .sort((a, b) => String(a[0]).localeCompare(String(b[0])));

test('an index split into external tilesets reads, once grafted, as the one file it was split from', () => {
  for (const levels of [1, 2, 3]) {
    const doc = quadtree({ depth: 4 });
    const files = splitIndex(doc, levels);
    assert.ok(Object.keys(files).length > 1);
    const top = parseTileset(files['tileset.json']);
    // the top file alone: its levels, links for the inner tiles below them, the totals stated
    assert.ok(top.tiles.every((t) => t.level <= levels && (t.subtree === null) === (t.level < levels)));
    assert.equal(top.tileCount, 341);
    assert.equal(top.gaussians, 341 * 1000);
    assert.equal(top.bytes, 341 * 20000);
    const link = /** @type {import('../src/tileset.js').Tile} */ (top.tiles.find((t) => t.subtree));
    assert.match(link.id, /^subtrees\/n\d+\.json$/);
    assert.equal(link.children.length, 0);
    assert.ok(selectTiles(top, camera([-30, 0, 0], [1, 0, 0]), { threshold: 1e-9, budget: Infinity })
      .draw.includes(link), 'a link is drawn (and so fetched) as the node it stands for');
    const grafted = graftAll(files);
    assert.deepEqual(shape(grafted), shape(parseTileset(doc)));
    assert.equal(grafted.tileCount, 341);
  }
});

test('a bad external tileset gets one line naming it and the problem', () => {
  const files = splitIndex(quadtree({ depth: 2 }), 1);
  /** @param {(doc: any) => void} change @param {RegExp} message */
  const graftRejects = (change, message) => {
    const set = parseTileset(files['tileset.json']);
    const link = /** @type {import('../src/tileset.js').Tile} */ (set.byId.get('subtrees/n2.json'));
    const doc = JSON.parse(JSON.stringify(files['subtrees/n2.json']));
    change(doc);
    assert.throws(() => graftSubtree(set, link, doc), (error) => {
      assert.ok(error instanceof TilesetError, String(error));
      assert.match(error.message, message);
      assert.ok(!error.message.includes('\n'));
      return true;
    });
  };
  graftRejects((d) => { d.root.extras.spcodec.gaussians = 7; }, /subtrees\/n2\.json root holds 7 Gaussians, the tile pointing to it says 1000/);
  graftRejects((d) => { d.root.content.uri = '../nodes/n.spc'; }, /"nodes\/n\.spc" names a second tile/);
  graftRejects((d) => { d.root.content.uri = 'n3.json'; }, /an external tileset's root must hold a node/);
  graftRejects((d) => { delete d.root; }, /subtrees\/n2\.json has no root tile/);
  graftRejects((d) => { d.root.children[1].boundingVolume.box.pop(); }, /subtrees\/n2\.json root\.children\[1\]\.boundingVolume/);
  const set = parseTileset(files['tileset.json']);
  assert.throws(() => graftSubtree(set, set.root, files['subtrees/n2.json']), /not an external tileset waiting/);
  const withChildren = JSON.parse(JSON.stringify(files['tileset.json']));
  withChildren.root.children[0].children = [withChildren.root.children[1]];
  assert.throws(() => parseTileset(withChildren), /root\.children\[0\] points to an external tileset and has children/);
  const rootLink = JSON.parse(JSON.stringify(files['tileset.json']));
  rootLink.root.content.uri = 'subtrees/n.json';
  assert.throws(() => parseTileset(rootLink), /the root tile must hold a node/);
});

test('a child without refine inherits REPLACE; a very deep document is refused, not a stack overflow', () => {
  const doc = quadtree({ depth: 1 });
  delete doc.root.children[0].refine;
  assert.equal(parseTileset(doc).tiles.length, 5);
  const deep = quadtree({ depth: 0 });
  let tip = deep.root;
  for (let i = 0; i < 100; i++) {
    tip.children = [{ ...quadtree({ depth: 0 }).root, content: { uri: `nodes/${i}.spc` } }];
    tip = tip.children[0];
  }
  assert.throws(() => parseTileset(deep), /nest deeper than 64 levels/);
});

test('the screen-space error follows the 3D Tiles formula and is 0 at leaves', () => {
  const set = parseTileset(quadtree({ depth: 1 }));
  const cam = camera([0, 0, 18], [0, 0, -1]);  // 10 units from the root's box (z reaches 8)
  const expected = 2 * 600 / (2 * 10 * Math.tan(25 * Math.PI / 180));
  assert.ok(Math.abs(screenSpaceError(set.root, cam) - expected) < 1e-9);
  assert.equal(screenSpaceError(set.root.children[0], cam), 0);
  assert.equal(screenSpaceError(set.root, camera([1, 0, 1], [0, 0, -1])), Infinity);  // inside
});

test('the budget is respected for any camera, and the root is always drawn and fetched first', () => {
  const set = parseTileset(quadtree({ depth: 4 }));
  const random = rng(7).next;
  for (let trial = 0; trial < 300; trial++) {
    const position = [0, 1, 2].map(() => (random() - 0.5) * 40);
    const forward = [0, 1, 2].map(() => random() - 0.5);
    const budget = Math.floor(random() * 40000);
    const threshold = 1 + random() * 40;
    const s = selectTiles(set, camera(position, forward), { budget, threshold });
    assert.equal(s.fetch[0], set.root);
    const drawn = s.draw.reduce((n, t) => n + t.gaussians, 0);
    assert.equal(drawn, s.gaussians);
    if (budget >= set.root.gaussians) assert.ok(drawn <= budget, `${drawn} > ${budget}`);
    else assert.deepEqual(s.draw, [set.root]);
    // the draw tiles cover what can be seen (REPLACE never leaves a hole; culled tiles lie
    // wholly behind the camera or beside the view), and none is refined
    assert.ok(coversRoot(set.root, new Set(s.draw), s.culled));
    assert.ok(s.draw.every((t) => !s.refined.has(t)));
    assert.ok([...s.culled].every((t) => s.seen.get(t)?.view !== VIEW.IN && !s.fetch.includes(t)));
    // the tiles beside the view come after every tile in view
    const classes = s.fetch.slice(1).map((t) => s.seen.get(t)?.view ?? NaN);
    assert.deepEqual(classes, [...classes].sort((a, b) => a - b));
    // parents come before their children in the fetch order
    const at = new Map(s.fetch.map((t, i) => [t, i]));
    for (const t of s.fetch) if (t.parent) assert.ok(at.get(t.parent) < at.get(t), t.id);
    // a tile refines only past the threshold and in view, into every child it does not cull
    for (const t of s.refined) {
      assert.ok(screenSpaceError(t, camera(position, forward)) > threshold);
      assert.ok(t.children.every((c) => at.has(c) !== s.culled.has(c)));
      assert.equal(s.seen.get(t)?.view, VIEW.IN);
    }
  }
});

test('tiles in view are fetched before tiles beside; tiles behind the camera are culled, not fetched', () => {
  const set = parseTileset(quadtree({ depth: 4 }));
  const cam = camera([0, 0, 0], [1, 0, 0]);  // in the middle, looking along +x
  const s = selectTiles(set, cam, { budget: Infinity });
  const views = s.fetch.map((t) => s.seen.get(t)?.view);
  assert.deepEqual(views, [...views].sort((a, b) => a - b));
  const inView = s.fetch.filter((t) => s.seen.get(t)?.view === VIEW.IN);
  assert.ok(inView.length > 10 && s.culled.size >= 2);
  assert.ok(s.fetch.every((t) => s.seen.get(t)?.view !== VIEW.BEHIND), 'nothing behind is fetched');
  // a tile is culled exactly when its box lies wholly behind the camera's plane
  for (const t of [...s.fetch, ...s.culled]) {
    const back = t.centre[0] + Math.abs(t.box[3]) <= 0;
    assert.equal(s.culled.has(t), back, t.id);
  }
  assert.ok(coversRoot(set.root, new Set(s.draw), s.culled) && !coversRoot(set.root, new Set(s.draw)));
  // a tile in view reaches in front of the camera (its sphere, which holds the box)
  assert.ok(inView.every((t) => t.centre[0] + t.radius > 0));
  // from outside the scene, the first leaf fetched is the one nearest the view's centre
  const outside = camera([-20, 0, 3], [1, 0, 0]);
  const far = selectTiles(set, outside, { budget: Infinity, threshold: 1e-9 });
  const leaves = far.fetch.filter((t) => !t.children.length);
  const offsets = leaves.map((t) => far.seen.get(t)?.offset ?? NaN);
  assert.equal(offsets[0], Math.min(...offsets));
});

test('the place the camera looks at reaches its leaves first; refinement stops at leaves', () => {
  const set = parseTileset(quadtree({ depth: 3 }));
  const cam = camera([-7, 0, 0], [1, 0, 0]);
  const s = selectTiles(set, cam, { budget: Infinity, threshold: 1e-9 });
  // with no budget and any error too large, every tile in view is refined to its leaves; the
  // tiles beside the view (at the camera's sides: two of level 2, four leaves of refined tiles)
  // are drawn as they are: they cannot be seen, and are there for a turn
  const inView = s.draw.filter((t) => s.seen.get(t)?.view === VIEW.IN);
  const beside = s.draw.filter((t) => s.seen.get(t)?.view === VIEW.SIDE);
  assert.ok(inView.length === 52 && inView.every((t) => t.children.length === 0));
  assert.deepEqual(beside.map((t) => t.level).sort(), [2, 2, 3, 3, 3, 3]);
  assert.equal(inView.length + beside.length, s.draw.length);
  assert.equal(s.refined.size, 1 + 4 + 14);
  // a small budget refines the tiles in a narrow view, leaves the rest of it coarse, and spends
  // nothing beside it
  const narrow = camera([-12, 0, -4], [1, 0, 0], { fov: 20, aspect: 1 });
  const tight = selectTiles(set, narrow, { budget: 14000 });
  assert.ok(tight.gaussians <= 14000);
  const deepest = Math.max(...tight.draw.map((t) => t.level));
  assert.equal(deepest, 3, 'the budget reaches leaves');
  assert.ok([...tight.refined].every((t) => tight.seen.get(t)?.view === VIEW.IN), 'refined where the camera looks');
  assert.ok(tight.draw.some((t) => t.level < deepest), 'coarse where the budget ran out');
  assert.ok(tight.draw.every((t) => tight.seen.get(t)?.view === VIEW.IN), 'the budget went to the view');
  assert.ok([...tight.culled].some((t) => tight.seen.get(t)?.view === VIEW.SIDE));
});

test('where the view\'s centre leaves a choice, the larger error refines first: the tile around the camera', () => {
  const set = parseTileset(quadtree({ depth: 2 }));
  // inside n0 (the -x, -z quarter), looking down +x: n1 lies straight ahead, n0 around the camera
  const cam = camera([-6, 0, -6], [1, 0, 0]);
  const n0 = /** @type {import('../src/tileset.js').Tile} */ (set.byId.get('nodes/n0.spc'));
  const n1 = /** @type {import('../src/tileset.js').Tile} */ (set.byId.get('nodes/n1.spc'));
  const s = selectTiles(set, cam, { budget: 7000, threshold: 1e-9 });  // the root and one more
  assert.equal(s.seen.get(n0)?.offset, 0);
  assert.equal(s.seen.get(n1)?.offset, 0);
  assert.ok((s.seen.get(n1)?.angle ?? 0) < (s.seen.get(n0)?.angle ?? 0), 'n1 is more nearly ahead');
  assert.deepEqual([...s.refined].map((t) => t.id).sort(), ['nodes/n.spc', 'nodes/n0.spc']);
  assert.equal(s.gaussians, 7000);
});

test('children behind the camera are culled, those beside the view get what it leaves; neither is refined', () => {
  const set = parseTileset(quadtree({ depth: 2 }));
  const cam = camera([0.5, 0, -4], [1, 0, 0]);  // just past the middle, looking along +x
  const s = selectTiles(set, cam, { budget: 5000, threshold: 1e-9 });
  // the root's two children at x < 0 lie wholly behind: culled, so the root (1000) gave way to
  // its two children in front (2000); n1 refines into its four children in view (+3000), n3
  // into its one (n31, +0), and its three beside the view find no budget left: culled too.
  // Counting every child would have refined the root alone
  assert.deepEqual([...s.culled].map((t) => t.id).sort(),
    ['nodes/n0.spc', 'nodes/n2.spc', 'nodes/n30.spc', 'nodes/n32.spc', 'nodes/n33.spc']);
  assert.equal(s.refined.size, 3);
  assert.equal(s.gaussians, 5000);
  // with room, the tiles beside come in after the view, unrefined
  const roomy = selectTiles(set, cam, { budget: 8000, threshold: 1e-9 });
  assert.deepEqual(roomy.fetch.slice(-3).map((t) => t.id).sort(),
    ['nodes/n30.spc', 'nodes/n32.spc', 'nodes/n33.spc']);
  assert.deepEqual([...roomy.culled].map((t) => t.id).sort(), ['nodes/n0.spc', 'nodes/n2.spc']);
  assert.ok(s.fetch.every((t) => !s.culled.has(t)));
  // the whole scene behind the camera: the root is drawn, never refined
  const away = selectTiles(set, camera([12, 0, 0], [1, 0, 0]), { budget: Infinity, threshold: 1e-9 });
  assert.deepEqual(away.draw, [set.root]);
  assert.equal(away.refined.size, 0);
});

test('REPLACE as tiles arrive: a parent stays until its children in view are in', () => {
  const set = parseTileset(quadtree({ depth: 2 }));
  // a narrow view from beyond one edge: two of the root's children in it, two beside it
  const cam = camera([-4, 0, 9], [0, 0, -1], { fov: 10, aspect: 1 });
  const s = selectTiles(set, cam, { budget: Infinity, threshold: 1e-9 });
  const loaded = new Set([set.root]);
  const show = () => visibleTiles(s, (t) => loaded.has(t));
  assert.deepEqual(show(), [set.root]);
  const first = set.root.children.filter((c) => s.seen.get(c)?.view === VIEW.IN);
  const rest = set.root.children.filter((c) => s.seen.get(c)?.view !== VIEW.IN);
  assert.deepEqual([first.length, rest.length], [2, 2]);
  loaded.add(first[0]);
  assert.deepEqual(show(), [set.root], 'one child of two in view is not enough');
  first.forEach((c) => loaded.add(c));
  const shown = new Set(show());
  assert.ok(!shown.has(set.root) && first.every((c) => shown.has(c)), 'children in view replace the root');
  assert.ok(rest.every((c) => !shown.has(c)));
  rest.forEach((c) => loaded.add(c));
  assert.ok(coversRoot(set.root, new Set(show())));
  // nothing loaded at all: nothing shown, no error
  assert.deepEqual(visibleTiles(s, () => false), []);
});

test('a camera in the drawn world is turned back into the tileset frame', () => {
  const q = [1, 0, 0, 0];  // 180 degrees about x: the -y up rotation
  const world = camera([1, 2, 3], [0, 0, -1]);
  const local = cameraInTileset(world, q);
  assert.deepEqual(local.position.map((v) => Math.round(v * 1e9) / 1e9), [1, -2, -3]);
  assert.deepEqual(local.forward.map((v) => Math.round(v * 1e9) / 1e9), [0, 0, 1]);
  assert.throws(() => selectTiles(parseTileset(quadtree({ depth: 1 })), camera([0, 0, 0], [0, 0, 0])),
    /forward vector has no direction/);
  assert.throws(() => selectTiles(parseTileset(quadtree({ depth: 1 })), world, { budget: -1 }), /budget/);
});

test('a box has eight corners, each the centre plus or minus every half-axis, turned as asked', () => {
  const tile = /** @type {any} */ ({ box: [1, 2, 3, 2, 0, 0, 0, 0.5, 0.5, 0, -0.5, 0.5] });
  const corners = boxCorners(tile);
  const points = [];
  for (let k = 0; k < 8; k++) points.push(Array.from(corners.subarray(3 * k, 3 * k + 3)));
  assert.equal(new Set(points.map((p) => p.map((x) => x.toFixed(6)).join())).size, 8);
  const mean = [0, 1, 2].map((a) => points.reduce((sum, p) => sum + p[a], 0) / 8);
  assert.deepEqual(mean.map((x) => +x.toFixed(6)), [1, 2, 3]);
  const axes = [tile.box.slice(3, 6), tile.box.slice(6, 9), tile.box.slice(9, 12)];  // orthogonal here
  const dot = (x, y) => x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
  for (const p of points) {  // a corner: the offset from the centre is +-u +-v +-w
    const d = p.map((x, a) => x - tile.box[a]);
    for (const axis of axes) assert.ok(Math.abs(Math.abs(dot(d, axis) / dot(axis, axis)) - 1) < 1e-6);
  }
  const q = [Math.SQRT1_2, 0, 0, Math.SQRT1_2];  // 90 degrees about x
  const turned = boxCorners(tile, q);
  for (let k = 0; k < 8; k++) {
    const expected = rotate(points[k], q);
    for (let a = 0; a < 3; a++) assert.ok(Math.abs(turned[3 * k + a] - expected[a]) < 1e-5);
  }
});
