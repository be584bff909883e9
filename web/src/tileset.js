// A tiled scene's index (a 3D Tiles 1.1 `tileset.json` whose tile contents are .spc files, as
// `python -m spcodec.tiling` writes it) and which of its tiles to draw and fetch for a camera.
//
// Selection is pure (no fetching, no renderer): the streamer (tilestream.js) and the loaders call
// it again whenever the camera moves. Refinement is REPLACE, as 3D Tiles viewers do it: a tile is
// replaced by its children when its screen-space error exceeds a threshold in pixels and the
// splat budget allows the children; tiles in view and nearest the view's centre are refined and
// fetched first; tiles wholly behind the camera are culled, neither fetched nor counted, and
// tiles beside the view get only what the view leaves of the budget, so it goes to what can be
// seen.

/** A tileset.json that cannot be used; the message is one line naming the problem. */
export class TilesetError extends Error {
  /** @param {string} message */
  constructor(message) {
    super(message);
    this.name = 'TilesetError';
  }
}

/** Most tiles and the deepest nesting a tileset may have: bounds against hostile documents. */
export const TILESET_LIMITS = Object.freeze({ maxTiles: 1_000_000, maxDepth: 64 });

/**
 * Where a tile lies relative to the view: in the cone that holds the view frustum, beside it, or
 * wholly behind the camera's plane. A tile's class is never lower than its parent's.
 */
export const VIEW = Object.freeze({ IN: 0, SIDE: 1, BEHIND: 2 });

/**
 * @typedef {object} Tile
 * @property {string} id        the content URI, unique in the tileset (e.g. `nodes/n03.spc`)
 * @property {string} uri       the same: the node's file, relative to the root tileset.json
 * @property {string|null} subtree  for a tile that points to an external tileset not yet read
 *   (`graftSubtree`), that file relative to the root tileset.json, and `id` and `uri` are it
 *   too; the tile stands for the external tileset's root (its box, error and Gaussians, as the
 *   link states them) and has no children until the file is grafted. null otherwise
 * @property {number[]} box     the 3D Tiles box: centre, then three half-axis vectors
 * @property {number[]} centre  the box's centre
 * @property {number} radius    the radius of the sphere around the box
 * @property {number} geometricError  the error, in scene units, of drawing this tile and none of
 *   its descendants
 * @property {number} gaussians  Gaussians in the tile's own .spc (extras.spcodec.gaussians)
 * @property {number|null} bytes  the .spc's size as the index states it, or null
 * @property {number} level     depth in the tree (0: the root)
 * @property {Tile|null} parent
 * @property {Tile[]} children
 */

/**
 * @typedef {object} Tileset
 * @property {Tile} root
 * @property {Tile[]} tiles   every tile read so far, parents before their children
 * @property {Map<string, Tile>} byId
 * @property {number} geometricError  the tileset's own (drawing nothing)
 * @property {number} tileCount  tiles in the whole tileset, external files included: as the
 *   index states it (extras.spcodec.tiles), else those read so far
 * @property {number} gaussians  Gaussians in all tiles together (stated, else of those read)
 * @property {number|null} bytes  bytes of all tiles together: as stated, else when every tile
 *   read states its own and no external tileset is left unread
 * @property {boolean} stated  whether the three totals are the index's own
 */

/**
 * A camera in the tileset's coordinates.
 * @typedef {object} Camera
 * @property {number[]} position
 * @property {number[]} forward  where it looks (any length)
 * @property {number} fov        vertical field of view, degrees
 * @property {number} height     viewport height, pixels
 * @property {number} [aspect]   width / height (default 16/9; widens the view cone only)
 */

/**
 * Read and check a tileset.json document (text or parsed JSON). Tiles that point to an external
 * tileset (a `.json` content) are read as links (`Tile.subtree`), to be grafted when needed.
 * @param {string|unknown} document
 * @returns {Tileset}
 */
export function parseTileset(document) {
  const doc = readDocument(document, 'tileset.json');
  const root = readTile(doc.root, 'root', null, 0, '');
  if (root.subtree) throw new TilesetError('root.content.uri: the root tile must hold a node, not an external tileset');
  const extras = isObject(doc.extras) && isObject(doc.extras.spcodec) ? doc.extras.spcodec : {};
  const stated = [extras.tiles, extras.gaussians, extras.bytes].every((x) => Number.isSafeInteger(x) && x >= 0);
  /** @type {Tileset} */
  const tileset = { root, tiles: [root], byId: new Map([[root.id, root]]), geometricError: doc.geometricError,
    tileCount: stated ? extras.tiles : 0, gaussians: stated ? extras.gaussians : 0, bytes: stated ? extras.bytes : null,
    stated };
  readChildren(tileset, doc.root, 'root', root, '');
  if (!stated) total(tileset);
  return tileset;
}

/**
 * Put the external tileset `document` (text or parsed JSON) in place of `tile`, a link
 * (`Tile.subtree`) of `tileset`: the tile becomes the external root's node, with its subtree
 * below it, its own links left to graft in turn. Its URIs are read relative to the file's.
 * @param {Tileset} tileset
 * @param {Tile} tile
 * @param {string|unknown} document
 */
export function graftSubtree(tileset, tile, document) {
  const name = tile.subtree;
  if (!name) throw new TilesetError(`${tile.uri} is not an external tileset waiting to be read`);
  const doc = readDocument(document, name);
  const base = name.slice(0, name.lastIndexOf('/') + 1);
  const where = `${name} root`;
  const root = readTile(doc.root, where, tile.parent, tile.level, base);
  if (root.subtree) throw new TilesetError(`${where}.content.uri: an external tileset's root must hold a node`);
  if (root.gaussians !== tile.gaussians) {
    throw new TilesetError(`${where} holds ${root.gaussians} Gaussians, the tile pointing to it says ${tile.gaussians}`);
  }
  if (tileset.byId.has(root.id)) throw new TilesetError(`${where}.content.uri "${root.uri}" names a second tile`);
  tileset.byId.delete(tile.id);
  const { id, uri, box, centre, radius, geometricError, bytes } = root;
  Object.assign(tile, { id, uri, box, centre, radius, geometricError, bytes, subtree: null });
  tileset.byId.set(tile.id, tile);
  readChildren(tileset, doc.root, where, tile, base);
  if (!tileset.stated) total(tileset);
}

/**
 * The checked top level of a tileset document.
 * @param {string|unknown} document
 * @param {string} name  the file, for messages
 * @returns {{root: Record<string, unknown>, geometricError: number, extras?: unknown}}
 */
function readDocument(document, name) {
  let doc = document;
  if (typeof doc === 'string') {
    try {
      doc = JSON.parse(doc);
    } catch (error) {
      throw new TilesetError(`${name} is not JSON: ${error.message}`);
    }
  }
  if (!isObject(doc)) throw new TilesetError(`${name} must be a JSON object`);
  const asset = doc.asset;
  if (!isObject(asset) || typeof asset.version !== 'string') {
    throw new TilesetError(`${name} has no asset.version`);
  }
  if (!/^1\.[01]$/.test(asset.version)) {
    throw new TilesetError(`${name} asset.version "${asset.version}" is not 3D Tiles 1.0 or 1.1`);
  }
  const geometricError = nonNegative(doc.geometricError, `${name} geometricError`);
  if (!isObject(doc.root)) throw new TilesetError(`${name} has no root tile`);
  return { root: doc.root, geometricError, extras: doc.extras };
}

/**
 * Read the children of `raw` (the document's tile that `tile` was read from) and all below
 * them into `tileset`, breadth first, iteratively: a deep document cannot overflow the stack.
 * @param {Tileset} tileset
 * @param {Record<string, unknown>} raw
 * @param {string} where
 * @param {Tile} tile
 * @param {string} base  the folder of the document's file, relative to the root tileset.json
 */
function readChildren(tileset, raw, where, tile, base) {
  /** @type {[unknown, string, Tile][]} */
  let pending = childrenOf(raw, where, tile);
  while (pending.length) {
    /** @type {[unknown, string, Tile][]} */
    const next = [];
    for (const [child, at, parent] of pending) {
      if (parent.level + 1 > TILESET_LIMITS.maxDepth) {
        throw new TilesetError(`${at}: tiles nest deeper than ${TILESET_LIMITS.maxDepth} levels`);
      }
      if (tileset.tiles.length >= TILESET_LIMITS.maxTiles) {
        throw new TilesetError(`the tileset has more than ${TILESET_LIMITS.maxTiles} tiles`);
      }
      const read = readTile(child, at, parent, parent.level + 1, base);
      if (tileset.byId.has(read.id)) throw new TilesetError(`${at}.content.uri "${read.uri}" names a second tile`);
      if (read.subtree && /** @type {Record<string, unknown>} */ (child).children != null
        && /** @type {unknown[]} */ (/** @type {Record<string, unknown>} */ (child).children).length) {
        throw new TilesetError(`${at} points to an external tileset and has children`);
      }
      parent.children.push(read);
      tileset.tiles.push(read);
      tileset.byId.set(read.id, read);
      next.push(...childrenOf(/** @type {Record<string, unknown>} */ (child), at, read));
    }
    pending = next;
  }
}

/** The totals of the tiles read so far, where the index states none. @param {Tileset} tileset */
function total(tileset) {
  const tiles = tileset.tiles;
  tileset.tileCount = tiles.length;
  tileset.gaussians = tiles.reduce((n, t) => n + t.gaussians, 0);
  tileset.bytes = tiles.every((t) => t.bytes != null && !t.subtree)
    ? tiles.reduce((n, t) => n + /** @type {number} */ (t.bytes), 0) : null;
}

/**
 * `uri`, written in a file in folder `base` (relative to the root tileset.json, '' or ending in
 * '/'), relative to the root tileset.json; an absolute URI unchanged.
 * @param {string} base
 * @param {string} uri
 */
function resolveUri(base, uri) {
  if (!base || /^[a-z][a-z0-9+.-]*:|^\//i.test(uri)) return uri;
  const url = new URL(uri, `http://tileset.invalid/${base}`);
  if (url.host !== 'tileset.invalid') return uri;
  return decodeURIComponent(url.pathname.slice(1)) + url.search + url.hash;
}

/** Whether a content URI names an external tileset (a JSON file), not a node. @param {string} uri */
export function isSubtree(uri) {
  return /\.json$/i.test(uri.split(/[?#]/)[0]);
}

/**
 * @param {unknown} raw
 * @param {string} where
 * @param {Tile|null} parent
 * @param {number} level
 * @param {string} base  the folder of the file `raw` is in, relative to the root tileset.json
 * @returns {Tile}
 */
function readTile(raw, where, parent, level, base) {
  if (!isObject(raw)) throw new TilesetError(`${where} must be an object`);
  const volume = raw.boundingVolume;
  const box = isObject(volume) ? volume.box : undefined;
  if (!Array.isArray(box) || box.length !== 12 || !box.every(Number.isFinite)) {
    throw new TilesetError(`${where}.boundingVolume.box must be 12 finite numbers (other volumes are not read)`);
  }
  // a child without `refine` inherits its parent's, which is REPLACE (checked there); so does
  // the root of an external tileset, whose parent is the tile that pointed to it
  const refine = raw.refine ?? (parent ? 'REPLACE' : null);
  if (refine !== 'REPLACE') {
    throw new TilesetError(`${where}.refine is ${JSON.stringify(refine)}: only "REPLACE" is supported`);
  }
  const written = isObject(raw.content) ? raw.content.uri : undefined;
  if (typeof written !== 'string' || !written) throw new TilesetError(`${where}.content.uri must name the tile's .spc`);
  const uri = resolveUri(base, written);
  const extras = isObject(raw.extras) && isObject(raw.extras.spcodec) ? raw.extras.spcodec : null;
  if (!extras) throw new TilesetError(`${where}.extras.spcodec is missing: not an spcodec tileset`);
  const gaussians = extras.gaussians;
  if (!Number.isSafeInteger(gaussians) || gaussians < 0) {
    throw new TilesetError(`${where}.extras.spcodec.gaussians must be a count, got ${JSON.stringify(gaussians)}`);
  }
  const bytes = extras.bytes;
  if (bytes != null && !(Number.isSafeInteger(bytes) && bytes >= 0)) {
    throw new TilesetError(`${where}.extras.spcodec.bytes must be a byte count, got ${JSON.stringify(bytes)}`);
  }
  const centre = box.slice(0, 3);
  const [u, v, w] = [box.slice(3, 6), box.slice(6, 9), box.slice(9, 12)];
  // the farthest corner from the centre, for any three half-axes
  let radius = 0;
  for (const [a, b] of [[1, 1], [1, -1], [-1, 1], [-1, -1]]) {
    radius = Math.max(radius, Math.hypot(...u.map((x, i) => x + a * v[i] + b * w[i])));
  }
  return { id: uri, uri, subtree: isSubtree(uri) ? uri : null, box: box.slice(), centre, radius,
    geometricError: nonNegative(raw.geometricError, `${where}.geometricError`), gaussians,
    bytes: bytes ?? null, level, parent, children: [] };
}

/**
 * @param {Record<string, unknown>} raw
 * @param {string} where
 * @param {Tile} tile
 * @returns {[unknown, string, Tile][]}
 */
function childrenOf(raw, where, tile) {
  if (raw.children == null || tile.subtree) return [];
  if (!Array.isArray(raw.children)) throw new TilesetError(`${where}.children must be an array`);
  return raw.children.map((child, i) => [child, `${where}.children[${i}]`, tile]);
}

/**
 * @param {unknown} x
 * @returns {x is Record<string, any>}
 */
function isObject(x) {
  return typeof x === 'object' && x !== null && !Array.isArray(x);
}

/** @param {unknown} x @param {string} what */
function nonNegative(x, what) {
  if (typeof x !== 'number' || !Number.isFinite(x) || x < 0) {
    throw new TilesetError(`${what} must be a non-negative number, got ${JSON.stringify(x)}`);
  }
  return x;
}

// ----------------------------------------------------------------------------- geometry
/**
 * Distance from `point` to the tile's box (0 inside), measured along each half-axis: exact for
 * boxes whose axes are perpendicular, as spcodec's tiler writes them (axis-aligned); for a skewed
 * box an estimate, which only moves the moment a tile refines.
 * @param {Tile} tile
 * @param {number[]} point
 */
export function boxDistance(tile, point) {
  const d = point.map((p, i) => p - tile.centre[i]);
  let sum = 0;
  for (let axis = 0; axis < 3; axis++) {
    const h = tile.box.slice(3 + 3 * axis, 6 + 3 * axis);
    const length = Math.hypot(...h);
    if (length === 0) continue;
    const along = Math.abs(d[0] * h[0] + d[1] * h[1] + d[2] * h[2]) / length;
    const out = Math.max(0, along - length);
    sum += out * out;
  }
  return Math.sqrt(sum);
}

/**
 * The tile's screen-space error in pixels, as 3D Tiles viewers compute it: its geometric error
 * seen from the camera's distance to its box (a camera inside the box sees it as infinite).
 * @param {Tile} tile
 * @param {Camera} camera
 */
export function screenSpaceError(tile, camera) {
  const distance = boxDistance(tile, camera.position);
  if (tile.geometricError === 0) return 0;
  if (distance === 0) return Infinity;
  return tile.geometricError * camera.height / (2 * distance * Math.tan(camera.fov * Math.PI / 360));
}

/**
 * Where the tile lies for the camera: its class (behind: the whole box is behind the camera's
 * plane; in view: its sphere meets the view's cone, the cone around `forward` that holds the
 * frustum's corners at `aspect`); how far (radians) its sphere is from the view's centre
 * (`offset`, 0 when the sphere holds the camera or the view's axis); and the angle between that
 * axis and the direction to the box's centre (`angle`, which orders tiles of equal offset: of the
 * tiles around the camera, those ahead first).
 * @param {Tile} tile
 * @param {Camera} camera
 * @returns {{view: number, offset: number, angle: number}}
 */
export function viewOf(tile, camera) {
  const forward = unit(camera.forward);
  const d = tile.centre.map((c, i) => c - camera.position[i]);
  const distance = Math.hypot(...d);
  const cos = distance > 0 ? (d[0] * forward[0] + d[1] * forward[1] + d[2] * forward[2]) / distance : 1;
  const angle = Math.acos(Math.min(1, Math.max(-1, cos)));
  // how far the box reaches along `forward`: behind the camera's plane when even its farthest
  // corner is (exact for the box, where the sphere would reach past the plane)
  const reach = [3, 6, 9].reduce((n, k) => n + Math.abs(tile.box[k] * forward[0] + tile.box[k + 1] * forward[1]
    + tile.box[k + 2] * forward[2]), 0);
  // (tiles behind are ordered by their error alone: the largest, the nearest, first)
  if (distance * cos + reach <= 0) return { view: VIEW.BEHIND, offset: Math.PI, angle: Math.PI };
  if (distance <= tile.radius) return { view: VIEW.IN, offset: 0, angle };
  const spread = Math.asin(tile.radius / distance);
  const offset = Math.max(0, angle - spread);
  const tanHalf = Math.tan(camera.fov * Math.PI / 360);
  const halfCone = Math.atan(tanHalf * Math.hypot(1, camera.aspect ?? 16 / 9));
  if (offset <= halfCone) return { view: VIEW.IN, offset, angle };
  return { view: offset >= Math.PI / 2 ? VIEW.BEHIND : VIEW.SIDE, offset, angle };
}

/** @param {number[]} v */
function unit(v) {
  const length = Math.hypot(...v);
  if (!(length > 0) || !Number.isFinite(length)) {
    throw new TilesetError('the camera\'s forward vector has no direction');
  }
  return v.map((x) => x / length);
}

/**
 * A camera given in the world the tileset is drawn in, in the tileset's own coordinates: the
 * tileset's entity is turned by `rotation` (x, y, z, w) and sits at the origin.
 * @param {Camera} camera
 * @param {number[]} rotation
 * @returns {Camera}
 */
export function cameraInTileset(camera, rotation) {
  const inverse = [-rotation[0], -rotation[1], -rotation[2], rotation[3]];
  return { ...camera, position: rotate(camera.position, inverse), forward: rotate(camera.forward, inverse) };
}

/**
 * `v` turned by the unit quaternion `q` (x, y, z, w).
 * @param {number[]} v
 * @param {number[]} q
 */
export function rotate(v, q) {
  const [x, y, z, w] = q;
  const cx = y * v[2] - z * v[1], cy = z * v[0] - x * v[2], cz = x * v[1] - y * v[0];
  return [v[0] + 2 * (w * cx + y * cz - z * cy), v[1] + 2 * (w * cy + z * cx - x * cz),
    v[2] + 2 * (w * cz + x * cy - y * cx)];
}

/**
 * The eight corners of a tile's box, turned by `rotation` (the tileset's, as the loaders report
 * it), flat x, y, z: what a page frames its camera on before any node has arrived.
 * @param {Tile} tile
 * @param {number[]} [rotation]  a unit quaternion (x, y, z, w); none turns nothing
 * @returns {Float32Array}
 */
export function boxCorners(tile, rotation = [0, 0, 0, 1]) {
  const b = tile.box, out = new Float32Array(24);
  let k = 0;
  for (const a of [1, -1]) for (const c of [1, -1]) for (const d of [1, -1]) {
    const corner = [0, 1, 2].map((i) => b[i] + a * b[3 + i] + c * b[6 + i] + d * b[9 + i]);
    out.set(rotate(corner, rotation), 3 * k++);
  }
  return out;
}

// ----------------------------------------------------------------------------- selection
/** What the selection computed of a tile: its view class (never lower than its parent's), its
 * offset from and angle to the view's centre (radians), and its screen-space error (pixels).
 * @typedef {{view: number, offset: number, angle: number, sse: number}} TileView */

/**
 * @typedef {object} Selection
 * @property {Tile[]} draw    the tiles to draw once loaded (the cut through the tree)
 * @property {Tile[]} fetch   every tile needed, in the order to fetch it: the draw tiles and the
 *   refined tiles above them (shown until their children are in), in view first (nearest the
 *   view's centre first, parents before children), then beside the view, then behind the camera
 *   (only the root can be: the whole scene behind it)
 * @property {Set<Tile>} refined  tiles replaced by their children (only tiles in view are)
 * @property {Set<Tile>} culled   children of refined tiles left out: wholly behind the camera, or
 *   beside the view where the budget the view left does not hold them. They cannot be seen, so
 *   they are neither drawn, fetched nor counted against the budget (as 3D Tiles viewers cull
 *   tiles outside the view); a new camera selects them again
 * @property {Map<Tile, TileView>} seen  what was computed for each tile of `fetch`
 * @property {number} gaussians  Gaussians of the draw tiles together
 */

/**
 * The tiles to draw and fetch for `camera` within `budget` Gaussians.
 *
 * The root is always drawn (the whole scene, coarse), even past the budget. Then, best first
 * (nearer the view's centre first; then the larger error first, so the tile around the camera
 * before a far one on the view's axis; then ahead before around the camera), a tile in view whose
 * screen-space error exceeds `threshold` pixels is replaced by its children in view if they fit in
 * what the budget has left; one that does not fit stays, and others are tried. Only tiles in view
 * are refined, and only their children in view count while the view refines: nothing else can be
 * seen, so the budget goes to what can. Then the children beside the view (outside the cone that
 * holds the frustum), nearest it first, are drawn as they are while the rest of the budget holds
 * them, ready for a turn; the others, and children wholly behind the camera, are culled
 * (`Selection.culled`).
 * @param {Tileset} tileset
 * @param {Camera} camera
 * @param {{budget?: number, threshold?: number}} [options]  budget in Gaussians (default
 *   1,500,000, within the 0.5-2.5 M a frame that web splat renderers draw), threshold in pixels
 *   (default 16)
 * @returns {Selection}
 */
export function selectTiles(tileset, camera, { budget = 1_500_000, threshold = 16 } = {}) {
  if (!(budget >= 0)) throw new TilesetError(`the splat budget must be a count of Gaussians, got ${budget}`);
  if (!(threshold > 0)) {
    throw new TilesetError(`the screen-space error threshold must be positive, got ${threshold}`);
  }
  /** @type {Map<Tile, TileView>} */
  const seen = new Map();
  /** @returns {TileView} */
  const viewFor = (/** @type {Tile} */ tile, /** @type {number} */ parentView) => {
    const where = viewOf(tile, camera);
    return { ...where, view: Math.max(where.view, parentView), sse: screenSpaceError(tile, camera) };
  };
  const order = (/** @type {Tile} */ a, /** @type {Tile} */ b) => compare(
    /** @type {any} */ (seen.get(a)), /** @type {any} */ (seen.get(b)));
  seen.set(tileset.root, viewFor(tileset.root, VIEW.IN));
  /** @type {Tile[]} */
  const fetch = [tileset.root];
  /** @type {Set<Tile>} */
  const refined = new Set();
  /** @type {Set<Tile>} */
  const culled = new Set();
  /** @type {Tile[]} children beside the view of refined tiles: drawn with what the view leaves */
  const beside = [];
  let gaussians = tileset.root.gaussians;
  const queue = new Heap(order);
  queue.push(tileset.root);
  while (queue.size) {
    const tile = /** @type {Tile} */ (queue.pop());
    const own = /** @type {TileView} */ (seen.get(tile));
    if (!tile.children.length || own.sse <= threshold || own.view !== VIEW.IN) continue;
    const views = tile.children.map((c) => viewFor(c, own.view));
    const kept = tile.children.filter((_, i) => views[i].view === VIEW.IN);
    const cost = kept.reduce((n, c) => n + c.gaussians, 0) - tile.gaussians;
    if (gaussians + cost > budget) continue;
    gaussians += cost;
    refined.add(tile);
    tile.children.forEach((c, i) => {
      seen.set(c, views[i]);
      if (views[i].view === VIEW.BEHIND) culled.add(c);
      else if (views[i].view === VIEW.SIDE) beside.push(c);
    });
    const children = kept.sort(order);
    fetch.push(...children);
    children.forEach((c) => queue.push(c));
  }
  // then, nearest the view first, the tiles beside it that the rest of the budget holds (what a
  // turn shows at once); those it does not hold are culled, since they cannot be seen either
  for (const tile of beside.sort(order)) {
    if (gaussians + tile.gaussians <= budget) {
      gaussians += tile.gaussians;
      fetch.push(tile);
    } else {
      culled.add(tile);
    }
  }
  // stable: within a class, the order refinement reached the tiles (parents before children)
  const classOf = (/** @type {Tile} */ tile) => /** @type {TileView} */ (seen.get(tile)).view;
  const byView = fetch.map((tile, i) => ({ tile, i }))
    .sort((a, b) => classOf(a.tile) - classOf(b.tile) || a.i - b.i)
    .map((x) => x.tile);
  return { draw: fetch.filter((t) => !refined.has(t)), fetch: byView, refined, culled, seen, gaussians };
}

/**
 * @param {TileView} a
 * @param {TileView} b
 */
function compare(a, b) {
  // Infinity - Infinity is NaN: equal errors compare as 0
  const sse = a.sse === b.sse ? 0 : (a.sse > b.sse ? -1 : 1);
  return a.view - b.view || a.offset - b.offset || sse || a.angle - b.angle;
}

/**
 * The tiles to show now, given which are loaded: REPLACE refinement as it streams. A refined
 * tile gives way to its children once they are ready (loaded, or refined with their own children
 * ready); until then it stays on screen. A tile in view waits only for its children in view (those
 * beside or behind cannot be seen, and are shown when they are in), so the view refines without
 * waiting for what lies behind; a tile out of view waits for all its children, keeping the
 * scene whole for when the camera turns.
 * @param {Selection} selection
 * @param {(tile: Tile) => boolean} loaded
 * @returns {Tile[]}
 */
export function visibleTiles(selection, loaded) {
  /** @type {Map<Tile, boolean>} */
  const readyMemo = new Map();
  const view = (/** @type {Tile} */ t) => /** @type {any} */ (selection.seen.get(t)).view;
  // children of a later class than their parent's (beside or behind a tile in view) cannot be
  // seen where the parent can: they are not waited for
  const childrenReady = (/** @type {Tile} */ t) => t.children.every((c) => view(c) > view(t) || ready(c));
  /** @param {Tile} t @returns {boolean} */
  function ready(t) {
    if (!readyMemo.has(t)) {
      readyMemo.set(t, loaded(t) || (selection.refined.has(t) && childrenReady(t)));
    }
    return /** @type {boolean} */ (readyMemo.get(t));
  }
  /** @type {Tile[]} */
  const shown = [];
  const root = selection.fetch.find((t) => t.parent === null);
  /** @type {Tile[]} */
  const stack = root ? [root] : [];
  while (stack.length) {
    const tile = /** @type {Tile} */ (stack.pop());
    const replaced = selection.refined.has(tile) && (childrenReady(tile) || !loaded(tile));
    if (replaced) stack.push(...tile.children);
    else if (loaded(tile)) shown.push(tile);
  }
  return shown;
}

/**
 * Whether the drawn tiles cover the whole scene that can be seen: every part of the root's box
 * lies in a drawn tile, in a culled one (out of the view: `Selection.culled`), or in a tile all
 * of whose children are covered.
 * @param {Tile} root
 * @param {Set<Tile>} drawn
 * @param {Set<Tile>} [culled]
 */
export function coversRoot(root, drawn, culled = new Set()) {
  /** @type {Tile[]} */
  const order = [];
  /** @type {Tile[]} */
  const stack = [root];
  while (stack.length) {  // parents before children; decided children first, below
    const tile = /** @type {Tile} */ (stack.pop());
    order.push(tile);
    if (!drawn.has(tile) && !culled.has(tile)) stack.push(...tile.children);
  }
  /** @type {Map<Tile, boolean>} */
  const covered = new Map();
  for (const tile of order.reverse()) {
    covered.set(tile, drawn.has(tile) || culled.has(tile)
      || (tile.children.length > 0 && tile.children.every((c) => covered.get(c))));
  }
  return /** @type {boolean} */ (covered.get(root));
}

/** A binary min-heap of tiles under `compareFn`'s order (negative: a before b). */
class Heap {
  /** @param {(a: Tile, b: Tile) => number} compareFn */
  constructor(compareFn) {
    this.compare = compareFn;
    /** @type {Tile[]} */
    this.items = [];
  }

  get size() {
    return this.items.length;
  }

  /** @param {Tile} item */
  push(item) {
    const items = this.items;
    items.push(item);
    let i = items.length - 1;
    while (i > 0) {
      const up = (i - 1) >> 1;
      if (this.compare(items[i], items[up]) >= 0) break;
      [items[i], items[up]] = [items[up], items[i]];
      i = up;
    }
  }

  pop() {
    const items = this.items;
    const top = items[0];
    const last = /** @type {Tile} */ (items.pop());
    if (items.length) {
      items[0] = last;
      let i = 0;
      for (;;) {
        const l = 2 * i + 1, r = l + 1;
        let m = i;
        if (l < items.length && this.compare(items[l], items[m]) < 0) m = l;
        if (r < items.length && this.compare(items[r], items[m]) < 0) m = r;
        if (m === i) break;
        [items[i], items[m]] = [items[m], items[i]];
        i = m;
      }
    }
    return top;
  }
}
