/**
 * The decoding process of spec section 11: whole files and prefixes ({@link decode}), files that
 * arrive in chunks ({@link StreamDecoder}), and header descriptions ({@link inspect}).
 *
 * Each layer is *loaded* (CRC-checked and inflated, step 7), then *prepared* (parsed, validated,
 * Draco-decoded, steps 8-9 short of output), and only then given output memory, so the output is
 * sized by data that exists rather than by a count that a header claims ([R-60], [R-62]).
 * `decode` loads every layer before preparing any, and prepares every layer before filling any:
 * the order in which the reference decoder reports errors.
 */
import { crc32 } from './checksums.js';
import { CODEC_NAMES, decompress } from './codecs.js';
import { loadDraco } from './draco.js';
import { SpcError, allocate, fail } from './errors.js';
import { GzipReader, gzipLayerEnds, isGzip } from './gzip.js';
import {
  SectionType, checkFixedHeader, headerBytesNeeded, isMagicPrefix, layerSection, readHeader,
} from './header.js';
import { OutputLimitError } from './inflate.js';
import { checkLimit, resolveLimits } from './limits.js';
import { parseContexts } from './contexts.js';
import { fillPatch, parseCodebooks, parsePositions, readIndices } from './patch.js';
import { fillSketch, prepareSketch } from './sketch.js';

/** A gzip header's fixed part, XLEN and the largest FEXTRA field: where `SP` offsets can be. */
const WRAPPER_HEAD_BYTES = 12 + 65535;

const SKETCH_TYPES = {
  clusters: SectionType.SKETCH_CLUSTERS,
  positions: SectionType.SKETCH_POSITIONS,
  coefficients: SectionType.SKETCH_COEFFICIENTS,
};

/**
 * Gaussians in the INRIA parametrization, as flat typed arrays a renderer takes directly.
 * @typedef {object} Cloud
 * @property {number} count
 * @property {number} shDegree
 * @property {Float32Array} positions 3 per Gaussian: x, y, z
 * @property {Float32Array} scales 3 per Gaussian: log standard deviations
 * @property {Float32Array} rotations 4 per Gaussian: unit quaternion w, x, y, z
 * @property {Float32Array} opacities 1 per Gaussian: logit
 * @property {Float32Array} shDC 3 per Gaussian: f_dc_0..2
 * @property {Float32Array} shRest K x 3 per Gaussian, K = (shDegree + 1)^2 - 1: coefficient-major,
 *   then channel (c1 R, c1 G, c1 B, c2 R, ...)
 */

/**
 * One layer of a decoded scene.
 * @typedef {object} LayerInfo
 * @property {number} index
 * @property {'sketch'|'patch'} kind
 * @property {number} start first Gaussian of the layer in the scene's arrays
 * @property {number} count Gaussians in the layer
 * @property {number | null} byteEnd where the layer ends in the input: the inner file's
 *   `end_offset`, or for a gzip-wrapped input the wrapper's recorded offset ([R-83]; null if absent)
 * @property {number} innerByteEnd the layer's `end_offset` in the inner file
 */

/**
 * @typedef {Cloud & {
 *   layers: LayerInfo[],
 *   complete: boolean,
 *   metadata: object | null,
 *   metadataError: string | null,
 * }} Scene
 */

/**
 * @typedef {object} DecodeOptions
 * @property {number} [maxLayer] decode layers 0..maxLayer only (needs only their bytes)
 * @property {Partial<import('./limits.js').Limits>} [limits]
 */

// ------------------------------------------------------------------------------ output arrays
/**
 * @param {number} n
 * @param {number} sh
 * @returns {Cloud}
 */
function allocateCloud(n, sh) {
  const k = (sh + 1) ** 2 - 1;
  return {
    count: n,
    shDegree: sh,
    positions: allocate(Float32Array, 3 * n),
    scales: allocate(Float32Array, 3 * n),
    rotations: allocate(Float32Array, 4 * n),
    opacities: allocate(Float32Array, n),
    shDC: allocate(Float32Array, 3 * n),
    shRest: allocate(Float32Array, 3 * k * n),
  };
}

/**
 * Views of Gaussians [start, start + count) of a cloud.
 * @param {Cloud} cloud
 * @param {number} start
 * @param {number} count
 * @returns {Cloud}
 */
function viewCloud(cloud, start, count) {
  const k3 = cloud.shRest.length / Math.max(cloud.count, 1);
  return {
    count,
    shDegree: cloud.shDegree,
    positions: cloud.positions.subarray(3 * start, 3 * (start + count)),
    scales: cloud.scales.subarray(3 * start, 3 * (start + count)),
    rotations: cloud.rotations.subarray(4 * start, 4 * (start + count)),
    opacities: cloud.opacities.subarray(start, start + count),
    shDC: cloud.shDC.subarray(3 * start, 3 * (start + count)),
    shRest: cloud.shRest.subarray(k3 * start, k3 * (start + count)),
  };
}

// ------------------------------------------------------------------------------ layer decoding
/**
 * Decodes the layers of one file in order, keeping the codebooks and index contexts that layer 1
 * carries.
 */
class LayerDecoder {
  /**
   * @param {import('./header.js').Header} header
   * @param {import('./limits.js').Limits} limits
   */
  constructor(header, limits) {
    this.header = header;
    this.limits = limits;
    /** @type {import('./draco.js').DracoModule | null} set by {@link withDraco} when needed */
    this.draco = null;
    /** @type {import('./patch.js').Codebook[] | null} */
    this.codebooks = null;
    /** @type {import('./contexts.js').IndexContext[]} */
    this.contexts = [];
    /** @type {Uint8Array | null} */
    this.metadata = null;
  }

  /**
   * Decoding step 7 for one layer, in the spec's order: reject unknown required sections, verify
   * the CRC of every section (unknown optional ones included), then inflate the known ones.
   * @param {Uint8Array} data the inner file (or a prefix holding the layer)
   * @param {number} index
   * @returns {Map<number, Uint8Array>} the known sections' payloads by type
   */
  load(data, index) {
    const layer = this.header.layers[index];
    for (const sec of layer.sections) {
      if (!sec.known && sec.required) {
        fail('unknown-required-section', `layer ${index} holds required section type 0x` +
          `${sec.type.toString(16).padStart(4, '0')}, unknown to this decoder`);
      }
    }
    const meta = layerSection(layer, SectionType.METADATA);
    if (meta) checkLimit('metadata length', meta.rawLength, this.limits.maxMetadataBytes);
    const stored = layer.sections.map((sec) => storedBytes(data, sec));
    const payloads = new Map();
    layer.sections.forEach((sec, i) => {
      if (sec.known) payloads.set(sec.type, decompress(sec.codec, stored[i], sec.rawLength));
    });
    if (index === 0) this.metadata = payloads.get(SectionType.METADATA) ?? null;
    return payloads;
  }

  /**
   * Make sure the Draco module is loaded if a loaded layer has Draco data: instantiating it costs
   * more than decoding a small file, and files without Draco data (or that fail earlier) need none.
   * @param {Map<number, Uint8Array>} payloads
   */
  async withDraco(payloads) {
    const sketch = payloads.get(SectionType.SKETCH_POSITIONS);
    const patch = payloads.get(SectionType.PATCH_POSITIONS);
    if (!this.draco && ((sketch && sketch.length) || (patch && patch.length > 4 && patch[0] === 3))) {
      this.draco = await loadDraco();
    }
  }

  /**
   * Steps 8-9 for a loaded layer, short of allocating its output.
   * @param {Map<number, Uint8Array>} payloads
   * @param {number} index
   */
  prepare(payloads, index) {
    if (index === 0) {
      return prepareSketch(payloads, this.header, this.limits, this.draco, SKETCH_TYPES);
    }
    if (!this.codebooks) {
      this.codebooks = parseCodebooks(/** @type {Uint8Array} */ (payloads.get(SectionType.PATCH_CODEBOOKS)),
        this.header.shDegree);
      const contexts = payloads.get(SectionType.PATCH_INDEX_CONTEXTS);
      this.contexts = contexts ? parseContexts(contexts, this.codebooks) : [];
    }
    const n = this.header.layers[index].gaussianCount;
    const { mode, positions } = parsePositions(/** @type {Uint8Array} */ (payloads.get(SectionType.PATCH_POSITIONS)),
      n, this.draco, index);
    const stored = /** @type {Uint8Array} */ (payloads.get(SectionType.PATCH_ATTRIBUTES));
    const indices = readIndices(stored, n, this.codebooks, this.contexts);
    return { gaussianCount: n, mode, positions, indices };
  }

  /**
   * Decode a prepared layer into `out`.
   * @param {any} plan
   * @param {number} index
   * @param {Cloud} out
   */
  fill(plan, index, out) {
    if (index === 0) fillSketch(plan, out);
    else fillPatch(plan, /** @type {import('./patch.js').Codebook[]} */ (this.codebooks), out, this.header.shDegree);
  }

  /**
   * Load, prepare and decode one layer into a new cloud.
   * @param {Uint8Array} data
   * @param {number} index
   * @returns {Promise<Cloud>}
   */
  async decode(data, index) {
    const payloads = this.load(data, index);
    await this.withDraco(payloads);
    const plan = this.prepare(payloads, index);
    const out = allocateCloud(plan.gaussianCount, this.header.shDegree);
    this.fill(plan, index, out);
    return out;
  }
}

/**
 * A section's stored bytes, CRC-checked ([R-7]).
 * @param {Uint8Array} data
 * @param {import('./header.js').Section} sec
 */
export function storedBytes(data, sec) {
  if (sec.end > data.length) fail('truncated', `section ${sec.index} (${sec.typeName}) is cut short`);
  const stored = data.subarray(sec.offset, sec.end);
  if (crc32(stored) !== sec.crc32) fail('section-crc', `section ${sec.index} (${sec.typeName}) CRC-32 mismatch`);
  return stored;
}

/**
 * Index of the last layer to decode from `available` inner bytes (decoding step 6, [R-11], [R-12]).
 * @param {import('./header.js').Header} header
 * @param {number} available
 * @param {number | undefined} maxLayer
 */
function lastDecodableLayer(header, available, maxLayer) {
  if (available > header.fileSize) {
    fail('trailing-data', `${available - header.fileSize} bytes follow the last section`);
  }
  const last = header.layers.length - 1;
  const target = maxLayer === undefined ? last : Math.min(maxLayer, last);
  if (available >= header.layers[target].endOffset) return target;
  if (maxLayer === undefined) {
    for (let k = last - 1; k >= 0; k--) if (header.layers[k].endOffset === available) return k;
  }
  const inside = header.layers.find((l) => available < l.endOffset) ?? header.layers[last];
  return fail('truncated', `the data ends at byte ${available}, inside layer ${inside.index} (layer ` +
    `boundaries: ${header.layers.map((l) => l.endOffset).join(', ')})`);
}

/**
 * @param {number | undefined} maxLayer
 */
function checkMaxLayer(maxLayer) {
  if (maxLayer !== undefined && maxLayer !== null && !(Number.isInteger(maxLayer) && maxLayer >= 0)) {
    throw new RangeError(`maxLayer must be an integer >= 0, got ${maxLayer}`);
  }
}

/**
 * @param {ArrayBuffer | ArrayBufferView} bytes
 * @returns {Uint8Array}
 */
export function asBytes(bytes) {
  if (bytes instanceof Uint8Array) return bytes;
  if (ArrayBuffer.isView(bytes)) return new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes instanceof ArrayBuffer) return new Uint8Array(bytes);
  throw new TypeError('decode needs a Uint8Array, an ArrayBuffer or another ArrayBuffer view');
}

// ------------------------------------------------------------------------------ gzip wrapper
/**
 * Read the inner header as soon as it is whole (refusing a bad fixed header before that).
 * @param {Uint8Array} buffer inner bytes so far
 * @param {import('./limits.js').Limits} limits
 * @returns {import('./header.js').Header | null}
 */
function headerIfReady(buffer, limits) {
  const need = headerBytesNeeded(buffer);
  if (need < 0) {
    if (!isMagicPrefix(buffer)) fail('bad-magic', 'not an spcodec file (bad magic)');
    return null;
  }
  if (buffer.length < need) {
    checkFixedHeader(buffer, limits);
    return null;
  }
  return readHeader(buffer, limits);
}

/**
 * Where the gzip reader should pause next while the inner header is unknown: at the fixed header,
 * then at the end of the header block, so that the header is checked before the wrapper's later
 * bytes are inflated (the reference decoder's order).
 * @param {Uint8Array} inner
 */
function headerWatermark(inner) {
  const need = headerBytesNeeded(inner);
  return need < 0 ? 48 : need;
}

/**
 * The cap on a wrapper's output was passed: past the inner `file_size` that is trailing data,
 * past the size limit it is a limit ([R-84]).
 * @param {number} cap
 * @param {import('./limits.js').Limits} limits
 * @returns {never}
 */
function wrapperOverflow(cap, limits) {
  if (cap < limits.maxFileBytes) {
    fail('trailing-data', `the gzip wrapper inflates past the inner file's file_size of ${cap} bytes`);
  }
  return fail('limit-exceeded', `the gzip wrapper inflates past the limit of ${limits.maxFileBytes} bytes`);
}

/**
 * The inner file of a whole input (or prefix): the input itself, or its gzip wrapper inflated
 * within the limits ([R-80]..[R-84]).
 * @param {Uint8Array} data
 * @param {import('./limits.js').Limits} limits
 * @returns {Uint8Array}
 */
export function unwrap(data, limits) {
  if (!isGzip(data)) {
    if (data.length === 1 && data[0] === 0x1F) fail('truncated', 'the data ends inside the gzip header');
    return data;
  }
  let header = null;
  const reader = new GzipReader(limits.maxFileBytes, (r) => {
    if (header) return;
    header = headerIfReady(r.inner, limits);
    if (header) r.setCap(header.fileSize);
    r.watermark = header ? Infinity : headerWatermark(r.inner);
  });
  reader.watermark = 48;
  try {
    reader.push(data);
  } catch (err) {
    if (err instanceof OutputLimitError) wrapperOverflow(reader.cap, limits);
    throw err;
  }
  return reader.inner;
}

// ------------------------------------------------------------------------------ metadata
/**
 * The metadata section's JSON object ([R-70]), or the reason it is not one.
 * @param {Uint8Array | null} raw
 * @returns {{metadata: object | null, error: string | null}}
 */
export function parseMetadata(raw) {
  if (!raw) return { metadata: null, error: null };
  try {
    const text = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true }).decode(raw);
    const value = JSON.parse(text);
    if (value === null || typeof value !== 'object' || Array.isArray(value)) {
      return { metadata: null, error: 'metadata is not a JSON object [bad-metadata]' };
    }
    return { metadata: value, error: null };
  } catch (err) {
    return { metadata: null, error: `metadata is not UTF-8 JSON (${err instanceof Error ? err.name : 'error'}) [bad-metadata]` };
  }
}

// ------------------------------------------------------------------------------ decode
/**
 * Decode a file, or a prefix of one ending at a layer boundary, into Gaussians.
 *
 * With `maxLayer: k` layers 0..k are decoded and only their bytes are needed. Without it every
 * layer is decoded; data that ends exactly at a layer boundary decodes to the layers before it
 * ([R-11]), data that ends anywhere else is `truncated`.
 * @param {Uint8Array | ArrayBuffer | ArrayBufferView} bytes
 * @param {DecodeOptions} [options]
 * @returns {Promise<Scene>}
 */
export async function decode(bytes, options = {}) {
  checkMaxLayer(options.maxLayer);
  const limits = resolveLimits(options.limits);
  const data = asBytes(bytes);
  const inner = unwrap(data, limits);
  const header = readHeader(inner, limits);
  const last = lastDecodableLayer(header, inner.length, options.maxLayer ?? undefined);
  const decoder = new LayerDecoder(header, limits);
  const payloads = [];
  for (let k = 0; k <= last; k++) payloads.push(decoder.load(inner, k));
  for (const p of payloads) await decoder.withDraco(p);
  const plans = payloads.map((p, k) => decoder.prepare(p, k));
  payloads.length = 0;
  const total = plans.reduce((sum, plan) => sum + plan.gaussianCount, 0);
  const cloud = allocateCloud(total, header.shDegree);
  const wrapperEnds = isGzip(data) ? validGzipEnds(data, header) : null;
  /** @type {LayerInfo[]} */
  const layers = [];
  let start = 0;
  plans.forEach((plan, k) => {
    decoder.fill(plan, k, viewCloud(cloud, start, plan.gaussianCount));
    const layer = header.layers[k];
    layers.push({
      index: k,
      kind: layer.kind,
      start,
      count: plan.gaussianCount,
      byteEnd: isGzip(data) ? (wrapperEnds ? wrapperEnds[k] : null) : layer.endOffset,
      innerByteEnd: layer.endOffset,
    });
    start += plan.gaussianCount;
  });
  const { metadata, error } = parseMetadata(decoder.metadata);
  return { ...cloud, layers, complete: last === header.layers.length - 1, metadata, metadataError: error };
}

/**
 * The wrapper's `SP` layer offsets when they can describe this file ([R-83]): as many as the
 * layers, strictly increasing; else null.
 * @param {Uint8Array} data
 * @param {import('./header.js').Header} header
 * @returns {number[] | null}
 */
function validGzipEnds(data, header) {
  const ends = gzipLayerEnds(data);
  if (!ends || ends.length !== header.layers.length) return null;
  for (let i = 1; i < ends.length; i++) if (!(ends[i - 1] < ends[i])) return null;
  return ends;
}

// ------------------------------------------------------------------------------ inspect
/**
 * Describe a file (or a prefix holding its header block) from its header: the document of
 * `spcodec info --json` (spec annex A), with the same keys.
 * @param {Uint8Array | ArrayBuffer | ArrayBufferView} bytes
 * @param {{limits?: Partial<import('./limits.js').Limits>}} [options]
 */
export function inspect(bytes, options = {}) {
  const limits = resolveLimits(options.limits);
  const data = asBytes(bytes);
  const wrapped = isGzip(data);
  const inner = unwrap(data, limits);
  const header = readHeader(inner, limits);
  const gzipEnds = wrapped ? validGzipEnds(data, header) : null;
  /** @type {object | null} */
  let metadata = null;
  /** @type {string | null} */
  let metadataError = null;
  const meta = layerSection(header.layers[0], SectionType.METADATA);
  if (meta && inner.length >= meta.end) {
    try {
      checkLimit('metadata length', meta.rawLength, limits.maxMetadataBytes);
      const parsed = parseMetadata(decompress(meta.codec, storedBytes(inner, meta), meta.rawLength));
      metadata = parsed.metadata;
      metadataError = parsed.error;
    } catch (err) {
      if (!(err instanceof SpcError)) throw err;
      metadataError = err.message;
    }
  }
  return {
    version: `${header.version[0]}.${header.version[1]}`,
    gaussians: header.gaussianCount,
    sh_degree: header.shDegree,
    file_size: header.fileSize,
    header_size: header.headerSize,
    gzip: wrapped,
    stored_size: data.length,
    sections: header.sections.map((s) => ({
      index: s.index,
      type: s.typeName,
      type_id: s.type,
      codec: CODEC_NAMES[s.codec] ?? `unknown-${s.codec}`,
      layer: s.layer,
      offset: s.offset,
      length: s.storedLength,
      raw_length: s.rawLength,
      crc32: s.crc32.toString(16).padStart(8, '0'),
      required: s.required,
    })),
    layers: header.layers.map((l) => ({
      index: l.index,
      kind: l.kind,
      gaussians: l.gaussianCount,
      end_offset: wrapped ? (gzipEnds ? gzipEnds[l.index] : null) : l.endOffset,
      ...(wrapped ? { inner_end_offset: l.endOffset } : {}),
    })),
    metadata,
    metadata_error: metadataError,
  };
}

// ------------------------------------------------------------------------------ streaming
/**
 * One layer handed out by the {@link StreamDecoder}.
 * @typedef {object} StreamLayer
 * @property {number} index
 * @property {'sketch'|'patch'} kind
 * @property {number | null} byteEnd where the layer ends in the input (see {@link LayerInfo})
 * @property {number} innerByteEnd
 * @property {Cloud} cloud this layer's Gaussians only
 */

/**
 * Incremental decoder: push bytes as they arrive, get each layer as soon as its last byte is in.
 * gzip-wrapped input is inflated on the fly. After a failure every further call throws the same
 * error.
 */
export class StreamDecoder {
  /**
   * @param {{limits?: Partial<import('./limits.js').Limits>, maxLayer?: number}} [options]
   */
  constructor(options = {}) {
    checkMaxLayer(options.maxLayer);
    this.limits = resolveLimits(options.limits);
    /** @type {number | undefined} */
    this.maxLayer = options.maxLayer ?? undefined;
    /** @type {import('./header.js').Header | null} */
    this.header = null;
    /** bytes of the inner file received so far (plain input) */
    this.buffer = new Uint8Array(1 << 16);
    this.length = 0;
    /** @type {Uint8Array} first bytes, until the wrapper question is settled */
    this.pending = new Uint8Array(0);
    this.started = false;
    /** @type {GzipReader | null} */
    this.gzip = null;
    /** @type {Uint8Array} the start of a gzip wrapper, where its `SP` layer offsets are */
    this.wrapperHead = new Uint8Array(0);
    /** @type {number[] | null} */
    this.gzipEnds = null;
    this.nextLayer = 0;
    /** @type {LayerDecoder | null} */
    this.decoder = null;
    /** @type {unknown} */
    this.failure = null;
    /** @type {object | null} */
    this.metadata = null;
    /** @type {string | null} */
    this.metadataError = null;
  }

  /** The inner bytes received so far. */
  get inner() {
    return this.gzip ? this.gzip.inner : this.buffer.subarray(0, this.length);
  }

  /**
   * Add bytes; returns the layers they complete (possibly none).
   * @param {Uint8Array} chunk
   * @returns {Promise<StreamLayer[]>}
   */
  async push(chunk) {
    if (this.failure) throw this.failure;
    try {
      return await this.accept(asBytes(chunk));
    } catch (err) {
      this.failure = err;
      throw err;
    }
  }

  /**
   * @param {Uint8Array} chunk
   * @returns {Promise<StreamLayer[]>}
   */
  async accept(chunk) {
    if (!this.started) {
      const pending = new Uint8Array(this.pending.length + chunk.length);
      pending.set(this.pending);
      pending.set(chunk, this.pending.length);
      if (pending.length > 0 && pending[0] !== 0x89 && pending[0] !== 0x1F) {
        fail('bad-magic', 'not an spcodec file (bad magic)');
      }
      if (pending.length < 2) {
        this.pending = pending;
        return [];
      }
      this.started = true;
      this.pending = new Uint8Array(0);
      if (isGzip(pending)) this.startGzip();
      chunk = pending;
    }
    if (this.gzip) this.inflate(chunk);
    else this.append(chunk);
    return this.drain();
  }

  startGzip() {
    const limits = this.limits;
    this.gzip = new GzipReader(limits.maxFileBytes, (r) => {
      if (!this.header) this.readHeaderIfReady(r.inner);
      if (this.header) r.setCap(this.header.fileSize);
      r.watermark = this.header ? Infinity : headerWatermark(r.inner);
    });
    this.gzip.watermark = 48;
  }

  /** @param {Uint8Array} chunk */
  inflate(chunk) {
    const reader = /** @type {GzipReader} */ (this.gzip);
    const room = WRAPPER_HEAD_BYTES - this.wrapperHead.length;
    if (room > 0 && chunk.length) {
      const head = new Uint8Array(this.wrapperHead.length + Math.min(room, chunk.length));
      head.set(this.wrapperHead);
      head.set(chunk.subarray(0, head.length - this.wrapperHead.length), this.wrapperHead.length);
      this.wrapperHead = head;
    }
    try {
      reader.push(chunk);
    } catch (err) {
      if (err instanceof OutputLimitError) wrapperOverflow(reader.cap, this.limits);
      throw err;
    }
  }

  /** @param {Uint8Array} chunk */
  append(chunk) {
    const need = this.length + chunk.length;
    checkLimit('input size', need, this.limits.maxFileBytes);
    if (need > this.buffer.length) {
      const bigger = allocate(Uint8Array, Math.max(need, 2 * this.buffer.length));
      bigger.set(this.buffer.subarray(0, this.length));
      this.buffer = bigger;
    }
    this.buffer.set(chunk, this.length);
    this.length = need;
  }

  /** @param {Uint8Array} inner */
  readHeaderIfReady(inner) {
    if (this.header) return;
    this.header = headerIfReady(inner, this.limits);
  }

  /**
   * Decode every requested layer whose bytes are all in.
   * @returns {Promise<StreamLayer[]>}
   */
  async drain() {
    const inner = this.inner;
    this.readHeaderIfReady(inner);
    const header = this.header;
    if (!header) return [];
    if (inner.length > header.fileSize) fail('trailing-data', 'bytes follow the last section');
    const last = this.lastWanted();
    /** @type {StreamLayer[]} */
    const done = [];
    while (this.nextLayer <= last && inner.length >= header.layers[this.nextLayer].endOffset) {
      if (!this.decoder) this.decoder = new LayerDecoder(header, this.limits);
      const k = this.nextLayer;
      const cloud = await this.decoder.decode(inner, k);
      if (k === 0) {
        const parsed = parseMetadata(this.decoder.metadata);
        this.metadata = parsed.metadata;
        this.metadataError = parsed.error;
      }
      const layer = header.layers[k];
      done.push({ index: k, kind: layer.kind, byteEnd: this.byteEnd(k), innerByteEnd: layer.endOffset, cloud });
      this.nextLayer++;
    }
    return done;
  }

  /** @param {number} k */
  byteEnd(k) {
    const header = /** @type {import('./header.js').Header} */ (this.header);
    if (!this.gzip) return header.layers[k].endOffset;
    if (this.gzipEnds === null) this.gzipEnds = validGzipEnds(this.wrapperHead, header);
    return this.gzipEnds ? this.gzipEnds[k] : null;
  }

  lastWanted() {
    const header = /** @type {import('./header.js').Header} */ (this.header);
    const last = header.layers.length - 1;
    return this.maxLayer === undefined ? last : Math.min(this.maxLayer, last);
  }

  /** True when every requested layer has been returned. */
  get complete() {
    return this.header !== null && this.nextLayer > this.lastWanted();
  }

  /**
   * Declare the end of the data: throws `truncated` if it stopped inside the header or inside a
   * layer (stopping at a layer boundary is a valid prefix, unless `maxLayer` asked for more).
   * @returns {Promise<void>}
   */
  async close() {
    if (this.failure) throw this.failure;
    if (!this.header) fail('truncated', 'the data ends before the header block is complete');
    if (this.complete) return;
    const length = this.inner.length;
    const boundary = this.header.layers.some((l) => l.endOffset === length);
    if (this.maxLayer !== undefined || !boundary) {
      fail('truncated', `the data ends at byte ${length}, inside layer ${this.nextLayer}`);
    }
  }
}
