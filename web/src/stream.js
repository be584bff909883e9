// The layers of an .spc as they arrive, for any renderer: fetched by HTTP ranges (one request
// per layer after the header block), decoded, and handed over one by one with the rotation that
// stands the scene upright. The PlayCanvas and three.js loaders and the viewer are built on it.

import { StreamDecoder, inspect } from './decoder.js';
import { upRotation } from './orientation.js';
import { streamScene } from './ranges.js';

/**
 * @typedef {object} StreamedLayer
 * @property {number} index    the layer's index (0: the sketch)
 * @property {string} kind     'sketch' or 'patch'
 * @property {import('./decoder.js').Cloud} cloud  the Gaussians this layer adds (never changes
 *   earlier layers')
 * @property {number[]} rotation  (x, y, z, w) that stands the scene upright in a +Y-up world
 * @property {number} bytesLoaded  bytes received when it completed
 */

/**
 * Stream `url` (an .spc, or a .glb written by `spcodec embed`), calling `onLayer` for each
 * decoded layer in order; resolves once every asked-for layer is in (or rejects with the
 * decoder's SpcError, a GlbError or a TransferError: the layers before the fault were delivered).
 *
 * The up axis comes from the .spc's metadata (`spcodec encode --up`) or the .glb's node; `up`
 * is used when the file says nothing (default -y, COLMAP-derived scenes).
 *
 * @param {string} url
 * @param {object} [options]
 * @param {(layer: StreamedLayer) => (void|Promise<void>)} [options.onLayer]
 * @param {(loaded: number, total: number|null) => void} [options.onProgress]  bytes so far
 * @param {(info: object) => void} [options.onInfo]  the `spcodec info --json` document, first
 * @param {number} [options.maxLayer]  stop after this layer (default: every layer)
 * @param {string|number[]} [options.up]  the up axis where the file does not store one
 * @param {typeof fetch} [options.fetchImpl]
 * @param {(event: object) => void} [options.onRequest]  each range request and its answer
 * @returns {Promise<{info: object|null, rotation: number[], mode: string, bytes: number,
 *   fileSize: number|null, layers: number}>}
 */
export async function streamLayers(url, { onLayer = () => {}, onProgress = () => {},
  onInfo = () => {}, maxLayer = Infinity, up = null, fetchImpl = fetch,
  onRequest = () => {} } = {}) {
  const decoder = new StreamDecoder();
  let info = null;
  let rotation = upRotation(up);
  let loaded = 0;
  let total = null;
  let delivered = 0;
  let fromGlb = false;
  const result = await streamScene(url, {
    maxLayer, fetchImpl,
    onGlb: (where) => {  // glTF is +Y up: the node's rotation stands the scene upright
      fromGlb = where.rotation != null;
      if (fromGlb) rotation = where.rotation;
    },
    onRequest: (r) => {
      total = total ?? r.contentRange?.size ?? null;
      onRequest(r);
    },
    planLayers: (head) => {
      info = inspect(head);
      if (info.metadata?.up && !fromGlb) rotation = upRotation(info.metadata.up);
      onInfo(info);
      // end_offset: in the stored file (for a gzip wrapper, null unless it records them)
      return { layers: info.layers.map((l) => ({ index: l.index, endOffset: l.end_offset })) };
    },
    sink: async (chunk) => {
      loaded += chunk.length;
      onProgress(loaded, total);
      for (const layer of await decoder.push(chunk)) {
        if (layer.index > maxLayer) continue;
        delivered++;
        await onLayer({ index: layer.index, kind: layer.kind, cloud: layer.cloud, rotation,
          bytesLoaded: loaded });
      }
    },
  });
  if (!Number.isFinite(maxLayer)) await decoder.close();  // data stopping inside a layer fails
  return { info, rotation, mode: result.mode, bytes: loaded, fileSize: result.fileSize,
    layers: delivered };
}
