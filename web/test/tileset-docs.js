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
