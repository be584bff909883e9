// A tiled scene streamed by view, for any renderer: the index first, then the root node (the whole
// scene, coarse), then the nodes the camera's selection needs (tileset.js), fetched in its order
// and decoded whole with the decoder; each node is shown, and its parent hidden, as REPLACE
// refinement allows. A tile of the selection that points to an external tileset has that file
// read at once, grafted into the tree, and the camera's selection made again, which then asks
// for the tile's node and, as the view needs, the subtree below it. The PlayCanvas and three.js
// loaders and the viewer are built on it: they give it a renderer (three functions) and call
// `update` when the camera moves.

import { decode } from './decoder.js';
import { upRotation } from './orientation.js';
import {
  TilesetError, cameraInTileset, coversRoot, graftSubtree, parseTileset, selectTiles,
  visibleTiles,
} from './tileset.js';

/**
 * What a renderer does with the tiles' Gaussians; `H` is its object for one tile.
 * @template H
 * @typedef {object} TileRenderer
 * @property {(tile: import('./tileset.js').Tile, cloud: import('./decoder.js').Cloud) => H} add
 *   make the tile's object, hidden, under the tileset's (upright) parent
 * @property {(handle: H, visible: boolean) => void} show
 * @property {(handle: H) => void} remove  free it: the tile is no longer needed
 */

/**
 * One node's arrival.
 * @typedef {object} TileArrival
 * @property {string} id      the tile's content URI
 * @property {number} level
 * @property {number} view    its class for the camera when it arrived (tileset.js VIEW)
 * @property {boolean} leaf
 * @property {number} gaussians
 * @property {number} bytes   its file's size
 * @property {number} bytesLoaded  bytes of the index and all nodes received so far
 */

/**
 * @template H
 * @typedef {object} StreamOptions
 * @property {number} [budget]     Gaussians drawn at most (default: selectTiles')
 * @property {number} [threshold]  screen-space error, pixels, past which a tile refines
 * @property {string|null} [up]    the up axis where the root node does not store one
 * @property {number} [concurrency]  node requests at a time (default 4)
 * @property {typeof fetch} [fetchImpl]
 * @property {(arrival: TileArrival) => void} [onArrival]  after a node's object is added, before
 *   it is shown
 * @property {(shown: Set<import('./tileset.js').Tile>, covers: boolean) => void} [onShown]
 *   after the tiles shown changed; `covers`: they cover the whole scene
 * @property {(loaded: number) => void} [onProgress]  bytes received so far
 * @property {(error: unknown, tile: import('./tileset.js').Tile) => void} [onError]  a node
 *   failed (it is not fetched again; the tiles above it stay on screen)
 */

/**
 * A tileset streamed into a renderer.
 * @template H
 */
export class TilesetStream {
  /**
   * @param {string} url  the tileset.json
   * @param {TileRenderer<H>} renderer
   * @param {StreamOptions<H>} [options]
   */
  constructor(url, renderer, options = {}) {
    this.url = url;
    this.renderer = renderer;
    this.options = options;
    /** @type {typeof fetch} called unbound: a browser's `fetch` refuses any other `this` */
    this.fetchImpl = options.fetchImpl ?? ((input, init) => fetch(input, init));
    /** @type {import('./tileset.js').Tileset|null} */
    this.tileset = null;
    /** the rotation (x, y, z, w) that stands the scene upright, from the root node */
    this.rotation = upRotation(options.up);
    /** @type {import('./tileset.js').Selection|null} */
    this.selection = null;
    /** @type {Map<import('./tileset.js').Tile, H>} */
    this.loaded = new Map();
    /** @type {Map<import('./tileset.js').Tile, Promise<void>>} nodes on their way */
    this.inFlight = new Map();
    /** @type {Map<import('./tileset.js').Tile, Promise<void>>} external tilesets on their way,
     * by the link tile they replace */
    this.subtrees = new Map();
    /** @type {Set<import('./tileset.js').Tile>} */
    this.failed = new Set();
    /** @type {Set<import('./tileset.js').Tile>} */
    this.shown = new Set();
    this.bytesLoaded = 0;
    this.indexBytes = 0;
    /** bytes of the external tilesets read so far (in `bytesLoaded` too) */
    this.subtreeBytes = 0;
    /** @type {import('./tileset.js').Camera|null} the last camera, selected for again when a
     * subtree arrives */
    this.camera = null;
    /** @type {TileArrival[]} */
    this.arrivals = [];
    /** @type {Array<() => void>} */
    this.idleWaiters = [];
  }

  /**
   * Fetch the index and the root node, and show the root: the whole scene, coarse. Returns the
   * tileset and the rotation the caller turns its parent by.
   */
  async open() {
    const response = await this.fetchImpl(this.url);
    if (!response.ok) throw new TilesetError(`${this.url}: HTTP ${response.status}`);
    const text = await response.text();
    /** the index's size in bytes */
    this.indexBytes = new TextEncoder().encode(text).length;
    this.bytesLoaded += this.indexBytes;
    this.tileset = parseTileset(text);
    const root = this.tileset.root;
    const scene = await this.fetchNode(root);
    this.rotation = upRotation(scene.metadata?.up ?? this.options.up);
    this.selection = { draw: [root], fetch: [root], refined: new Set(), culled: new Set(), gaussians: root.gaussians,
      seen: new Map([[root, { view: 0, offset: 0, angle: 0, sse: Infinity }]]) };
    this.arrive(root, scene);
    return { tileset: this.tileset, rotation: this.rotation };
  }

  /**
   * Select for a camera in the world the tileset is drawn in (its parent turned by `rotation`,
   * at the origin), start the fetches the selection needs, and drop the tiles it no longer does.
   * @param {import('./tileset.js').Camera} camera
   */
  update(camera) {
    if (!this.tileset) throw new Error('TilesetStream.update before open()');
    this.camera = camera;
    const { budget, threshold } = this.options;
    this.selection = selectTiles(this.tileset, cameraInTileset(camera, this.rotation), { budget, threshold });
    const needed = new Set(this.selection.fetch);
    for (const [tile, handle] of this.loaded) {
      if (needed.has(tile)) continue;
      this.loaded.delete(tile);
      this.shown.delete(tile);
      this.renderer.remove(handle);
    }
    this.refresh();
    this.pump();
  }

  /** Whether every tile the current selection needs is in (or failed). */
  get idle() {
    return this.inFlight.size === 0 && this.subtrees.size === 0 && this.next() === null;
  }

  /** A promise resolving once the stream is idle. */
  whenIdle() {
    if (this.idle) return Promise.resolve();
    return new Promise((resolve) => this.idleWaiters.push(() => resolve(undefined)));
  }

  /** Remove every tile's object. */
  close() {
    for (const handle of this.loaded.values()) this.renderer.remove(handle);
    this.loaded.clear();
    this.shown.clear();
    this.selection = null;
  }

  /**
   * The next node to fetch: the first in the selection's order neither in nor on its way. Tiles
   * of a later view class (beside, behind) wait until those before them are in, so nothing
   * behind the camera arrives before the view is complete. A link is not a node yet: its file
   * is `prefetchSubtrees`' to read, and until it is grafted it holds back later classes as a
   * node on its way does.
   */
  next() {
    const selection = this.selection;
    if (!selection) return null;
    const unread = selection.fetch.filter((t) => t.subtree && !this.failed.has(t));
    const pendingView = Math.min(Infinity, ...[...this.inFlight.keys(), ...unread].map((t) => this.viewOf(t)));
    for (const tile of selection.fetch) {
      if (tile.subtree || this.loaded.has(tile) || this.inFlight.has(tile) || this.failed.has(tile)) continue;
      return this.viewOf(tile) > pendingView ? null : tile;
    }
    return null;
  }

  /** @param {import('./tileset.js').Tile} tile */
  viewOf(tile) {
    return this.selection?.seen.get(tile)?.view ?? 0;
  }

  /**
   * Start fetches up to the concurrency: nodes in the selection's order, and (`prefetchSubtrees`)
   * the external tilesets of its links.
   */
  pump() {
    const limit = this.options.concurrency ?? 4;
    this.prefetchSubtrees(limit);
    for (let tile = this.next(); tile && this.inFlight.size < limit; tile = this.next()) {
      const node = tile;
      this.inFlight.set(node, this.settle(this.inFlight, node, this.fetchNode(node).then((scene) => {
        if (this.selection?.fetch.includes(node)) this.arrive(node, scene);
      })));
    }
  }

  /**
   * Read the external tilesets of the selection's links now, in its order, `limit` at a time,
   * rather than in their turn among the nodes: a link's node cannot be asked for until its file
   * is in, and a file asked for only in its turn waited behind the decoding of the nodes before
   * it, on the path to full detail, at every subtree. The files are small (a few kilobytes),
   * so reading those of tiles behind the camera early costs the view little.
   * @param {number} limit
   */
  prefetchSubtrees(limit) {
    const selection = this.selection;
    if (!selection) return;
    for (const tile of selection.fetch) {
      if (this.subtrees.size >= limit) return;
      if (tile.subtree && !this.subtrees.has(tile) && !this.failed.has(tile)) {
        this.readSubtree(tile);
      }
    }
  }

  /** Fetch and graft `tile`'s external tileset (once). @param {import('./tileset.js').Tile} tile */
  readSubtree(tile) {
    this.subtrees.set(tile, this.settle(this.subtrees, tile, this.fetchSubtree(tile)));
  }

  /**
   * `job` for `tile`, ending in `jobs`' bookkeeping: a failure is reported and not retried,
   * and the end starts the next fetches and wakes the callers waiting for idle.
   * @param {Map<import('./tileset.js').Tile, Promise<void>>} jobs
   * @param {import('./tileset.js').Tile} tile
   * @param {Promise<void>} job
   */
  settle(jobs, tile, job) {
    return job
      .catch((error) => {
        this.failed.add(tile);
        (this.options.onError ?? ((e) => console.error(e)))(error, tile);
      })
      .finally(() => {
        jobs.delete(tile);
        this.pump();
        if (this.idle) this.idleWaiters.splice(0).forEach((wake) => wake());
      });
  }

  /**
   * Fetch an external tileset, graft it in place of `tile`, and select again for the camera: the
   * tile now names its node, and its subtree is there to refine into.
   * @param {import('./tileset.js').Tile} tile
   */
  async fetchSubtree(tile) {
    const tileset = /** @type {import('./tileset.js').Tileset} */ (this.tileset);
    const response = await this.fetchImpl(this.urlOf(/** @type {string} */ (tile.subtree)));
    if (!response.ok) throw new TilesetError(`${tile.subtree}: HTTP ${response.status}`);
    const text = await response.text();
    const size = new TextEncoder().encode(text).length;
    this.subtreeBytes += size;
    this.bytesLoaded += size;
    this.options.onProgress?.(this.bytesLoaded);
    graftSubtree(tileset, tile, text);
    if (this.camera) this.update(this.camera);
  }

  /** `uri`, relative to the index, as a URL. @param {string} uri */
  urlOf(uri) {
    return new URL(uri, new URL(this.url, globalThis.location?.href ?? 'file:///')).href;
  }

  /**
   * Fetch and decode one node.
   * @param {import('./tileset.js').Tile} tile
   */
  async fetchNode(tile) {
    const response = await this.fetchImpl(this.urlOf(tile.uri));
    if (!response.ok) throw new TilesetError(`${tile.uri}: HTTP ${response.status}`);
    const bytes = new Uint8Array(await response.arrayBuffer());
    this.bytesLoaded += bytes.length;
    this.options.onProgress?.(this.bytesLoaded);
    const scene = await decode(bytes);
    if (scene.count !== tile.gaussians) {
      throw new TilesetError(`${tile.uri} holds ${scene.count} Gaussians, the index says ${tile.gaussians}`);
    }
    return Object.assign(scene, { fileBytes: bytes.length });
  }

  /**
   * A node is in: add its object, tell the caller (before what it changes on screen), and show
   * what REPLACE refinement allows now.
   * @param {import('./tileset.js').Tile} tile
   * @param {import('./decoder.js').Cloud & {fileBytes: number}} cloud
   */
  arrive(tile, cloud) {
    this.loaded.set(tile, this.renderer.add(tile, cloud));
    const arrival = { id: tile.id, level: tile.level, view: this.viewOf(tile), leaf: !tile.children.length,
      gaussians: tile.gaussians, bytes: cloud.fileBytes, bytesLoaded: this.bytesLoaded };
    this.arrivals.push(arrival);
    this.options.onArrival?.(arrival);
    this.refresh();
  }

  /** Show and hide tiles as the selection and the tiles in allow. */
  refresh() {
    if (!this.selection) return;
    const visible = new Set(visibleTiles(this.selection, (t) => this.loaded.has(t)));
    let changed = false;
    for (const [tile, handle] of this.loaded) {
      const on = visible.has(tile);
      if (on === this.shown.has(tile)) continue;
      changed = true;
      if (on) this.shown.add(tile);
      else this.shown.delete(tile);
      this.renderer.show(handle, on);
    }
    if (changed && this.tileset) {
      this.options.onShown?.(new Set(this.shown), coversRoot(this.tileset.root, this.shown, this.selection.culled));
    }
  }
}
