// The layers of an .spc as they arrive, for any renderer: fetched by HTTP ranges (one request
// per layer after the header block), decoded, and handed over one by one with the rotation that
// stands the scene upright. The PlayCanvas and three.js loaders and the viewer are built on it.

import { StreamDecoder, inspect } from './decoder.js';
import { isGzip } from './gzip.js';
import { readHeader } from './header.js';
import { upRotation } from './orientation.js';
import { findPreview, previewFromSection } from './preview.js';
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
 * A file's preview (spec 7.4), handed out once its section is in, before layer 0 completes.
 * @typedef {object} StreamedPreview
 * @property {import('./decoder.js').Cloud} cloud  the preview's Gaussians (a small file of its own)
 * @property {number} takeoverLayer  show it until layers 0..takeoverLayer have arrived ([R-104])
 * @property {number} layerCount  layers in the file (the preview's own file has its own)
 * @property {number} bytes  the preview section's stored size
 * @property {number[]} rotation  as for the layers: the file's up axis, not the preview's
 * @property {number} bytesLoaded  bytes received when it was decoded
 */

/**
 * Watches a StreamDecoder's bytes for the file's preview and decodes it once its section is in.
 * Whatever goes wrong with the preview (a fault of, or no Draco) is kept as `error` and
 * never reaches the stream: the scene does not depend on it ([R-102]).
 */
class PreviewWatch {
  /** @param {StreamDecoder} decoder */
  constructor(decoder) {
    this.decoder = decoder;
    /** settled: delivered, failed, or the file has none */
    this.done = false;
    /** @type {unknown} */
    this.error = null;
  }

  /**
   * The preview, or why it failed, once: when the bytes so far complete its section (or show that
   * there is none); null before and after.
   * @returns {Promise<{preview: import('./preview.js').Preview, section: import('./header.js').Section}
   *   | {error: unknown} | null>}
   */
  async poll() {
    const { header, limits } = this.decoder;
    if (this.done || !header) return null;
    try {
      const section = findPreview(header);
      if (section && this.decoder.inner.length < section.end) return null;
      this.done = true;
      if (!section) return null;
      return { preview: await previewFromSection(this.decoder.inner, header, section, limits), section };
    } catch (error) {
      this.done = true;
      this.error = error;
      return { error };
    }
  }

  /**
   * How much of `chunk` to push first so that the preview is decoded before a layer that the same
   * chunk completes: up to the section's end when the chunk crosses it, else all of it. Only for
   * plain input, where the bytes pushed are the inner file's; the header block may come with the
   * same chunk (the first range request holds both), so it is read from the bytes to come.
   * @param {Uint8Array} chunk
   */
  firstPart(chunk) {
    const decoder = this.decoder;
    if (this.done || decoder.gzip) return chunk.length;
    const before = decoder.started ? decoder.inner : decoder.pending;
    if (!decoder.started && isGzip(concat(before, chunk.subarray(0, 2)))) return chunk.length;
    let section = null;
    try {
      section = findPreview(decoder.header ?? readHeader(concat(before, chunk), decoder.limits));
    } catch {
      return chunk.length;  // the decoder, or poll(), says why
    }
    const have = before.length;
    return section && section.end > have && section.end < have + chunk.length
      ? section.end - have : chunk.length;
  }
}

/**
 * @param {Uint8Array} a
 * @param {Uint8Array} b
 */
function concat(a, b) {
  const out = new Uint8Array(a.length + b.length);
  out.set(a);
  out.set(b, a.length);
  return out;
}

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
 * @param {(preview: StreamedPreview) => (void|Promise<void>)} [options.onPreview]  the file's
 *   preview (spec 7.4), once its section is in: before layer 0, and at most once
 * @param {(error: unknown) => void} [options.onPreviewError]  a preview that does not decode; the
 *   stream goes on as for a file without one ([R-102]), and the result's `previewError` says why
 * @param {boolean} [options.preview]  false: do not decode the preview (default true)
 * @returns {Promise<{info: object|null, rotation: number[], mode: string, bytes: number,
 *   fileSize: number|null, layers: number, preview: boolean, previewError: unknown}>}
 */
export async function streamLayers(url, { onLayer = () => {}, onProgress = () => {},
  onInfo = () => {}, maxLayer = Infinity, up = null, fetchImpl = fetch,
  onRequest = () => {}, onPreview = () => {}, onPreviewError = () => {}, preview = true } = {}) {
  const decoder = new StreamDecoder();
  const watch = new PreviewWatch(decoder);
  watch.done = !preview;
  let previewDelivered = false;
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
    sink: async (whole) => {
      let rest = whole;
      do {  // in two parts when it completes the preview's section and more (see firstPart)
        const chunk = rest.subarray(0, watch.firstPart(rest));
        rest = rest.subarray(chunk.length);
        loaded += chunk.length;
        onProgress(loaded, total);
        const layers = await decoder.push(chunk);
        const found = await watch.poll();
        if (found && 'error' in found) onPreviewError(found.error);
        if (found && 'preview' in found) {
          previewDelivered = true;
          await onPreview({ cloud: found.preview, takeoverLayer: found.preview.takeoverLayer,
            layerCount: /** @type {any} */ (decoder.header).layers.length,
            bytes: found.section.end - found.section.offset, rotation, bytesLoaded: loaded });
        }
        for (const layer of layers) {
          if (layer.index > maxLayer) continue;
          delivered++;
          await onLayer({ index: layer.index, kind: layer.kind, cloud: layer.cloud, rotation,
            bytesLoaded: loaded });
        }
      } while (rest.length);
    },
  });
  if (!Number.isFinite(maxLayer)) await decoder.close();  // data stopping inside a layer fails
  return { info, rotation, mode: result.mode, bytes: loaded, fileSize: result.fileSize,
    layers: delivered, preview: previewDelivered, previewError: watch.error };
}
