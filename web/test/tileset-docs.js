/**
 * Synthetic tileset.json documents for the tileset tests: a quadtree over a square in the x-z
 * plane (y up), shaped as `python -m spcodec.tiling` writes them.
 */

/**
 * A quadtree `depth` levels below the root over [-size, size] in x and z, every tile holding
 * `gaussians` Gaussians; geometric error halves per level and is 0 at the leaves.
 * @param {{depth?: number, size?: number, gaussians?: number, bytes?: number}} [options]
 */
export function quadtree({ depth = 3, size = 8, gaussians = 1000, bytes = 20000 } = {}) {
  /** @returns {any} */
  const tile = (/** @type {string} */ id, /** @type {number} */ cx, /** @type {number} */ cz,
    /** @type {number} */ half, /** @type {number} */ level) => {
    const out = {
      boundingVolume: { box: [cx, 0, cz, half, 0, 0, 0, 1, 0, 0, 0, half] },
      geometricError: level === depth ? 0 : half / 4,
      refine: 'REPLACE',
      content: { uri: `nodes/${id}.spc` },
      extras: { spcodec: { gaussians, bytes, inputGaussians: gaussians * 4 ** (depth - level), level } },
    };
    if (level < depth) {
      const h = half / 2;
      out.children = [[-1, -1], [1, -1], [-1, 1], [1, 1]].map(([sx, sz], i) =>
        tile(`${id}${i}`, cx + sx * h, cz + sz * h, h, level + 1));
    }
    return out;
  };
  return { asset: { version: '1.1', generator: 'test' }, geometricError: size * 3, root: tile('n', 0, 0, size, 0) };
}

/**
 * `doc` (one file, as `quadtree` makes it) split as `python -m spcodec.tiling` splits a deep
 * index: tileset.json holds the top `levels` levels and a link (`subtrees/<id>.json`, no
 * children) for every inner tile below them; each external tileset holds its node and the next
 * `levels` levels, its URIs relative to its own folder. Returns the files by name.
 * @param {any} doc
 * @param {number} levels
 * @returns {Record<string, any>}
 */
export function splitIndex(doc, levels) {
  /** @type {Record<string, any>} */
  const files = {};
  const clone = (/** @type {any} */ x) => JSON.parse(JSON.stringify(x));
  /** @returns {any} */
  const copy = (/** @type {any} */ tile, /** @type {number} */ depth, /** @type {string} */ prefix) => {
    const { children, ...own } = clone(tile);
    own.content = { uri: prefix + tile.content.uri };
    if (!tile.children) return own;
    own.children = tile.children.map((/** @type {any} */ child) => {
      if (depth + 1 < levels || !child.children) return copy(child, depth + 1, prefix);
      const id = child.content.uri.replace(/^nodes\/|\.spc$/g, '');
      files[`subtrees/${id}.json`] = { asset: doc.asset, geometricError: tile.geometricError,
        root: copy(child, 0, '../') };
      const { children: _, ...link } = clone(child);
      link.content = { uri: prefix ? `${id}.json` : `subtrees/${id}.json` };
      return link;
    });
    return own;
  };
  const tiles = [];
  for (const stack = [doc.root]; stack.length;) {
    const tile = stack.pop();
    tiles.push(tile);
    stack.push(...(tile.children ?? []));
  }
  files['tileset.json'] = { ...clone(doc), root: copy(doc.root, 0, ''),
    extras: { spcodec: { tiles: tiles.length, gaussians: tiles.reduce((n, t) => n + t.extras.spcodec.gaussians, 0),
      bytes: tiles.reduce((n, t) => n + t.extras.spcodec.bytes, 0) } } };
  return files;
}
