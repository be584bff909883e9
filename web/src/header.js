/**
 * The header block (spec section 3; decoding steps 2-5): fixed header, layer table, table of
 * contents and header CRC. Everything here reads the header alone, so a client that fetched only
 * the first `header_size` bytes knows every byte range of the file.
 */
import { crc32 } from './checksums.js';
import { fail } from './errors.js';
import { checkExpansion, checkGaussianDensity, checkLimit } from './limits.js';

export const MAGIC = new Uint8Array([0x89, 0x53, 0x50, 0x43, 0x0D, 0x0A, 0x1A, 0x0A]);
export const FIXED_HEADER_SIZE = 48;
export const LAYER_ENTRY_SIZE = 16;
export const SECTION_ENTRY_SIZE = 40;
export const VERSION_MAJOR = 1;
const SECTION_FLAG_REQUIRED = 1;

/**
 * Section type ids (section 4.1). `PREVIEW` (1.1) is named here, for inspect and messages, but it
 * is not in {@link KNOWN_SECTIONS}: decoding the scene treats it as an optional section of unknown
 * type ([R-102]); only src/preview.js reads it.
 */
export const SectionType = Object.freeze({
  METADATA: 0x0001,
  PREVIEW: 0x0002,
  SKETCH_CLUSTERS: 0x0010,
  SKETCH_POSITIONS: 0x0011,
  SKETCH_COEFFICIENTS: 0x0012,
  PATCH_CODEBOOKS: 0x0020,
  PATCH_POSITIONS: 0x0021,
  PATCH_ATTRIBUTES: 0x0022,
  PATCH_INDEX_CONTEXTS: 0x0023,
});

/** @type {Record<number, string>} */
const SECTION_NAMES = Object.fromEntries(Object.entries(SectionType).map(([k, v]) => [v, k]));

/**
 * Where each known type may appear ('sketch' = layer 0, 'first' = layer 1, 'patch' = every patch
 * layer) and whether it must be flagged required ([R-13], [R-14]).
 * @type {Record<number, [string, boolean]>}
 */
const KNOWN_SECTIONS = {
  [SectionType.METADATA]: ['sketch', false],
  [SectionType.SKETCH_CLUSTERS]: ['sketch', true],
  [SectionType.SKETCH_POSITIONS]: ['sketch', true],
  [SectionType.SKETCH_COEFFICIENTS]: ['sketch', true],
  [SectionType.PATCH_CODEBOOKS]: ['first', true],
  [SectionType.PATCH_POSITIONS]: ['patch', true],
  [SectionType.PATCH_ATTRIBUTES]: ['patch', true],
  [SectionType.PATCH_INDEX_CONTEXTS]: ['first', true],
};

/** @type {Record<string, number[]>} */
const MANDATORY = {
  sketch: [SectionType.SKETCH_CLUSTERS, SectionType.SKETCH_POSITIONS, SectionType.SKETCH_COEFFICIENTS],
  first: [SectionType.PATCH_CODEBOOKS, SectionType.PATCH_POSITIONS, SectionType.PATCH_ATTRIBUTES],
  patch: [SectionType.PATCH_POSITIONS, SectionType.PATCH_ATTRIBUTES],
};

/**
 * One table-of-contents entry.
 * @typedef {object} Section
 * @property {number} index
 * @property {number} type
 * @property {string} typeName
 * @property {number} codec
 * @property {boolean} required
 * @property {boolean} known
 * @property {number} layer
 * @property {number} offset
 * @property {number} storedLength
 * @property {number} rawLength
 * @property {number} crc32
 * @property {number} end offset + storedLength
 */

/**
 * One layer-table entry with its sections.
 * @typedef {object} Layer
 * @property {number} index
 * @property {'sketch'|'patch'} kind
 * @property {number} gaussianCount
 * @property {number} endOffset
 * @property {Section[]} sections
 */

/**
 * The parsed and validated header block.
 * @typedef {object} Header
 * @property {[number, number]} version
 * @property {number} headerSize
 * @property {number} shDegree
 * @property {number} gaussianCount
 * @property {number} fileSize
 * @property {Layer[]} layers
 * @property {Section[]} sections
 */

/**
 * Size of the header block for the given table sizes ([R-6]).
 * @param {number} layers
 * @param {number} sections
 */
export function headerSize(layers, sections) {
  return FIXED_HEADER_SIZE + LAYER_ENTRY_SIZE * layers + SECTION_ENTRY_SIZE * sections + 4;
}

/**
 * A u64 as a Number: exact below 2^53; larger values (which no limit admits) become Infinity, so
 * every comparison with a real size or offset fails as it should.
 * @param {DataView} view
 * @param {number} at
 */
function u64(view, at) {
  const hi = view.getUint32(at + 4, true);
  return hi >= 2 ** 21 ? Infinity : hi * 2 ** 32 + view.getUint32(at, true);
}

/**
 * @param {Uint8Array} data
 * @returns {boolean} whether data (shorter than the magic) could still become the magic
 */
export function isMagicPrefix(data) {
  for (let i = 0; i < Math.min(data.length, MAGIC.length); i++) if (data[i] !== MAGIC[i]) return false;
  return true;
}

/**
 * Check the magic, or report why `data` cannot start a file ([R-3]).
 * @param {Uint8Array} data
 */
export function checkMagic(data) {
  if (!isMagicPrefix(data)) fail('bad-magic', 'not an spcodec file (bad magic)');
  if (data.length < MAGIC.length) fail('truncated', 'the data ends inside the file header');
}

/**
 * How many bytes the header block needs, once the fixed header is present (else -1).
 * @param {Uint8Array} data
 */
export function headerBytesNeeded(data) {
  if (data.length < FIXED_HEADER_SIZE) return -1;
  return new DataView(data.buffer, data.byteOffset, 48).getUint32(16, true);
}

/**
 * Validate the fixed header's first checks (version, table sizes, header_size) on the first 48
 * bytes, before waiting for the rest of the header block (decoding step 3).
 * @param {Uint8Array} data at least 48 bytes
 * @param {import('./limits.js').Limits} limits
 * @returns {number} the header block's size
 */
export function checkFixedHeader(data, limits) {
  checkMagic(data);
  if (data.length < FIXED_HEADER_SIZE) fail('truncated', 'the data ends inside the file header');
  const view = new DataView(data.buffer, data.byteOffset, FIXED_HEADER_SIZE);
  const major = view.getUint16(8, true);
  if (major !== VERSION_MAJOR) {
    fail('unsupported-version', `bitstream major version ${major} is not supported (this decoder ` +
      `reads ${VERSION_MAJOR}.x)`);
  }
  const layerCount = view.getUint16(20, true);
  const sectionCount = view.getUint16(22, true);
  checkLimit('layer count', layerCount, limits.maxLayers);
  checkLimit('section count', sectionCount, limits.maxSections);
  const size = headerSize(layerCount, sectionCount);
  const declared = view.getUint32(16, true);
  if (declared !== size) fail('bad-layout', `header_size is ${declared}, but the tables need ${size}`);
  return size;
}

/**
 * Parse and validate the header block at the start of `data` (decoding steps 2-5).
 * @param {Uint8Array} data
 * @param {import('./limits.js').Limits} limits
 * @returns {Header}
 */
export function readHeader(data, limits) {
  const size = checkFixedHeader(data, limits);
  if (data.length < size) fail('truncated', 'the data ends inside the header block');
  const view = new DataView(data.buffer, data.byteOffset, size);
  if (crc32(data.subarray(0, size - 4)) !== view.getUint32(size - 4, true)) {
    fail('header-crc', 'header CRC-32 mismatch');
  }
  // Semantic checks only after the CRC, so corruption is reported as corruption ([R-8]).
  let reserved = view.getUint32(12, true);
  for (let i = 25; i < 32; i++) reserved |= data[i];
  if (reserved) fail('reserved-nonzero', 'reserved header flags or bytes are not zero');
  const layerCount = view.getUint16(20, true);
  const sectionCount = view.getUint16(22, true);
  if (layerCount < 1 || sectionCount < 3) {
    fail('bad-layout', 'a file needs at least one layer and the three sketch sections');
  }
  const shDegree = data[24];
  if (shDegree > 3) fail('bad-value', `SH degree ${shDegree} is outside 0..3`);
  const gaussianCount = u64(view, 32);
  const fileSize = u64(view, 40);
  checkLimit('Gaussian count', gaussianCount, limits.maxGaussians);
  checkLimit('file size', fileSize, limits.maxFileBytes);
  checkGaussianDensity(limits, gaussianCount, fileSize);
  const sections = readSections(view, layerCount, sectionCount, size, fileSize, limits);
  const layers = readLayers(view, layerCount, sections, gaussianCount);
  return {
    version: [view.getUint16(8, true), view.getUint16(10, true)],
    headerSize: size,
    shDegree,
    gaussianCount,
    fileSize,
    layers,
    sections,
  };
}

/**
 * The table of contents ([R-4], [R-10], [R-15], [R-61]).
 * @param {DataView} view
 * @param {number} layerCount
 * @param {number} sectionCount
 * @param {number} start the header size, where section 0 starts
 * @param {number} fileSize
 * @param {import('./limits.js').Limits} limits
 * @returns {Section[]}
 */
function readSections(view, layerCount, sectionCount, start, fileSize, limits) {
  const sections = [];
  let offset = start;
  let previousLayer = 0;
  let rawTotal = 0;
  const base = FIXED_HEADER_SIZE + LAYER_ENTRY_SIZE * layerCount;
  for (let i = 0; i < sectionCount; i++) {
    const at = base + SECTION_ENTRY_SIZE * i;
    const type = view.getUint16(at, true);
    const flags = view.getUint8(at + 3);
    const layer = view.getUint16(at + 4, true);
    const sec = {
      index: i,
      type,
      typeName: SECTION_NAMES[type] ?? `UNKNOWN_0x${type.toString(16).toUpperCase().padStart(4, '0')}`,
      codec: view.getUint8(at + 2),
      required: (flags & SECTION_FLAG_REQUIRED) !== 0,
      known: type in KNOWN_SECTIONS,
      layer,
      offset: u64(view, at + 8),
      storedLength: u64(view, at + 16),
      rawLength: u64(view, at + 24),
      crc32: view.getUint32(at + 32, true),
      end: 0,
    };
    sec.end = sec.offset + sec.storedLength;
    if (view.getUint16(at + 6, true) || view.getUint32(at + 36, true) || (flags & ~SECTION_FLAG_REQUIRED)) {
      fail('reserved-nonzero', `section ${i} has reserved bits set`);
    }
    if (layer >= layerCount) fail('bad-layout', `section ${i} names layer ${layer} of ${layerCount}`);
    if (layer < previousLayer) fail('bad-layout', `section ${i} is out of layer order`);
    if (sec.offset !== offset) {
      fail('bad-layout', `section ${i} starts at ${sec.offset}, expected ${offset} (sections must be ` +
        'contiguous and in table order)');
    }
    checkLimit(`section ${i} raw length`, sec.rawLength, limits.maxSectionBytes);
    previousLayer = layer;
    offset = sec.end;
    rawTotal += sec.rawLength;
    sections.push(sec);
  }
  if (offset !== fileSize) fail('bad-layout', `sections end at ${offset}, file_size says ${fileSize}`);
  checkExpansion(limits, rawTotal, fileSize);
  return sections;
}

/**
 * The layer table ([R-9], [R-13], [R-14]).
 * @param {DataView} view
 * @param {number} layerCount
 * @param {Section[]} sections
 * @param {number} gaussianCount
 * @returns {Layer[]}
 */
function readLayers(view, layerCount, sections, gaussianCount) {
  const layers = [];
  let total = 0;
  for (let i = 0; i < layerCount; i++) {
    const at = FIXED_HEADER_SIZE + LAYER_ENTRY_SIZE * i;
    const kind = view.getUint8(at);
    if (kind !== (i === 0 ? 0 : 1)) {
      fail('bad-layout', `layer ${i} has kind ${kind}; layer 0 must be sketch (0) and later layers ` +
        'patch (1)');
    }
    if (view.getUint8(at + 1) | view.getUint8(at + 2) | view.getUint8(at + 3)) {
      fail('reserved-nonzero', `layer ${i} has reserved bytes set`);
    }
    const own = sections.filter((s) => s.layer === i);
    if (!own.length) fail('missing-section', `layer ${i} has no sections`);
    const endOffset = u64(view, at + 8);
    const lastEnd = own[own.length - 1].end;
    if (endOffset !== lastEnd) {
      fail('bad-layout', `layer ${i} end_offset ${endOffset} is not the end of its last section (${lastEnd})`);
    }
    if (layers.length && endOffset <= layers[layers.length - 1].endOffset) {
      // a layer of zero bytes would leave a prefix's last layer ambiguous ([R-9])
      fail('bad-layout', `layer ${i} ends where layer ${i - 1} does (${endOffset})`);
    }
    checkLayerSections(i, own);
    const count = view.getUint32(at + 4, true);
    total += count;
    layers.push({ index: i, kind: i === 0 ? 'sketch' : 'patch', gaussianCount: count, endOffset, sections: own });
  }
  if (total !== gaussianCount) {
    fail('bad-layout', `layer Gaussian counts add up to ${total}, the header says ${gaussianCount}`);
  }
  return /** @type {Layer[]} */ (layers);
}

/**
 * Which sections a layer may and must hold ([R-13], [R-14]).
 * @param {number} index
 * @param {Section[]} sections
 */
function checkLayerSections(index, sections) {
  const place = index === 0 ? 'sketch' : index === 1 ? 'first' : 'patch';
  const seen = new Set();
  for (const sec of sections) {
    if (!sec.known) continue;
    const [allowed, required] = KNOWN_SECTIONS[sec.type];
    if (allowed !== place && !(allowed === 'patch' && place === 'first')) {
      fail('bad-layout', `${sec.typeName} may not appear in layer ${index}`);
    }
    if (sec.required !== required) {
      fail('bad-layout', `${sec.typeName} must be flagged ${required ? 'required' : 'optional'}`);
    }
    if (seen.has(sec.type)) fail('duplicate-section', `layer ${index} holds ${sec.typeName} twice`);
    seen.add(sec.type);
  }
  const missing = MANDATORY[place].filter((t) => !seen.has(t));
  if (missing.length) {
    fail('missing-section', `layer ${index} lacks ${missing.map((t) => SECTION_NAMES[t]).sort().join(', ')}`);
  }
}

/**
 * A layer's section of the given type, or undefined.
 * @param {Layer} layer
 * @param {number} type
 */
export function layerSection(layer, type) {
  return layer.sections.find((s) => s.type === type);
}

