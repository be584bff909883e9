/**
 * The preview of a 1.1 file (spec 7.4): a small whole file in an optional section of layer 0,
 * for a viewer to show until the file's own layers overtake it ([R-104]).
 *
 * Decoding the scene never looks inside it ([R-102]): this module is the one place that does, and
 * what it finds wrong concerns the preview only. Its checks, their order and their codes are those
 * of and of the reference decoder (decoder/preview.py). Everything it needs it borrows
 * from the scene decoder: the header block, the section CRC and codecs, and `decode` for the
 * embedded file, which is decoded as any whole file is.
 */
import { decompress } from './codecs.js';
import { asBytes, decode, storedBytes, unwrap } from './decoder.js';
import { fail } from './errors.js';
import { isGzip } from './gzip.js';
import { SectionType, readHeader } from './header.js';
import { resolveLimits } from './limits.js';

/** Bytes of the payload before the embedded file: u16 takeover_layer, u16 reserved. */
export const PREVIEW_PREFIX_SIZE = 4;

/**
 * A file's preview: the embedded file's Gaussians, as `decode` returns a scene, and what a viewer
 * needs to show it.
 * @typedef {import('./decoder.js').Scene & {
 *   takeoverLayer: number,
 *   section: {offset: number, end: number},
 * }} Preview
 * `takeoverLayer` (T): show the preview until layers 0..T of the file have arrived ([R-104]).
 * `section`: where the PREVIEW section lies in the inner file; the preview needs the bytes up to
 * `section.end` and nothing of the layers.
 */

/**
 * The PREVIEW section of layer 0, or null ([R-103]: PREVIEW sections of other layers are not
 * previews). Two in layer 0 are `duplicate-section`; the scene decode allows that, the preview
 * cannot choose between them.
 * @param {import('./header.js').Header} header
 * @returns {import('./header.js').Section | null}
 */
export function findPreview(header) {
  const found = header.layers[0].sections.filter((s) => s.type === SectionType.PREVIEW);
  if (found.length > 1) fail('duplicate-section', 'layer 0 holds PREVIEW twice');
  return found[0] ?? null;
}

/**
 * Decode the preview of a file (plain or gzip-wrapped), or of a prefix that holds the preview's
 * section; null when the file has none. A failure is an SpcError about the preview: the scene may
 * still decode ([R-102]).
 * @param {Uint8Array | ArrayBuffer | ArrayBufferView} bytes
 * @param {{limits?: Partial<import('./limits.js').Limits>}} [options]
 * @returns {Promise<Preview | null>}
 */
export async function decodePreview(bytes, options = {}) {
  const limits = resolveLimits(options.limits);
  const inner = unwrap(asBytes(bytes), limits);
  const header = readHeader(inner, limits);
  const section = findPreview(header);
  if (!section) return null;
  return previewFromSection(inner, header, section, limits);
}

/**
 * The preview from inner bytes that may stop anywhere after the header block: the section's
 * bytes must be in (`truncated` otherwise), then its CRC and codec ([R-7], [R-22]..[R-24]) and
 * the checks of {@link parsePreview}. The stream decoder calls this as soon as they are in.
 * @param {Uint8Array} inner
 * @param {import('./header.js').Header} header
 * @param {import('./header.js').Section} section the one {@link findPreview} gave
 * @param {import('./limits.js').Limits} limits
 * @returns {Promise<Preview>}
 */
export async function previewFromSection(inner, header, section, limits) {
  if (inner.length < section.end) {
    fail('truncated', `the data ends at byte ${inner.length}, inside the PREVIEW section ` +
      `(bytes ${section.offset}..${section.end})`);
  }
  const raw = decompress(section.codec, storedBytes(inner, section), section.rawLength);
  return parsePreview(raw, header, section, limits);
}

/**
 * The checks of on an inflated PREVIEW payload, in the reference's order, then the
 * embedded file's decode (section 11 for a whole file, without a last layer).
 * @param {Uint8Array} raw
 * @param {import('./header.js').Header} header the outer file's
 * @param {import('./header.js').Section} section
 * @param {import('./limits.js').Limits} limits
 * @returns {Promise<Preview>}
 */
export async function parsePreview(raw, header, section, limits) {
  if (raw.length < PREVIEW_PREFIX_SIZE) {
    fail('bad-section', `the PREVIEW payload has ${raw.length} bytes, fewer than its ` +
      `${PREVIEW_PREFIX_SIZE}-byte prefix`);
  }
  const view = new DataView(raw.buffer, raw.byteOffset, PREVIEW_PREFIX_SIZE);
  const takeoverLayer = view.getUint16(0, true);
  if (view.getUint16(2, true)) fail('reserved-nonzero', "the PREVIEW payload's reserved field is not zero");
  if (takeoverLayer >= header.layers.length) {
    fail('bad-value', `the preview's takeover layer ${takeoverLayer} is not a layer of the file ` +
      `(it has ${header.layers.length})`);
  }
  const file = raw.subarray(PREVIEW_PREFIX_SIZE);
  checkEmbedded(file, limits);
  const scene = await decode(file, { limits });
  return { ...scene, takeoverLayer, section: { offset: section.offset, end: section.end } };
}

/**
 * The embedded file must be a whole plain file without a preview of its own ([R-103]): a gzip
 * wrapper, a prefix or bytes past its `file_size`, or nesting are `bad-section`, while its header
 * block's own faults keep their codes (steps 2-5, as for any file).
 * @param {Uint8Array} file
 * @param {import('./limits.js').Limits} limits
 */
function checkEmbedded(file, limits) {
  if (isGzip(file)) fail('bad-section', "the preview's embedded file is gzip-wrapped");
  const embedded = readHeader(file, limits);
  if (file.length !== embedded.fileSize) {
    fail('bad-section', `the preview's embedded file holds ${file.length} bytes, its header says ` +
      `${embedded.fileSize}`);
  }
  if (embedded.sections.some((s) => s.type === SectionType.PREVIEW)) {
    fail('bad-section', "the preview's embedded file has a preview of its own");
  }
}
