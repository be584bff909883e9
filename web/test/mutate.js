/**
 * Structure-aware mutations of valid files for the fuzz test, after tests/fuzzing/ (Python): every
 * byte of a valid file is under a CRC, so random flips die at the CRC checks; these mutators edit
 * fields, payloads and section lists and then *repair the checksums*, so that the parsers behind
 * the CRCs see the damage.
 */
import zlib from 'node:zlib';

import { crc32 } from '../src/checksums.js';
import { decompress } from '../src/codecs.js';
import { headerSize } from '../src/header.js';

/**
 * A file taken apart: the fixed header, layer entries and sections with their stored bytes.
 * @typedef {{fixed: Uint8Array, layers: {kind: number, count: number, end: number}[],
 *   sections: {type: number, codec: number, flags: number, layer: number, rawLength: number,
 *   stored: Uint8Array}[]}} Parts
 */

/**
 * @param {Uint8Array} bytes a valid, unwrapped file
 * @returns {Parts}
 */
export function takeApart(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const layerCount = view.getUint16(20, true);
  const sectionCount = view.getUint16(22, true);
  const layers = [];
  for (let i = 0; i < layerCount; i++) {
    const at = 48 + 16 * i;
    layers.push({ kind: bytes[at], count: view.getUint32(at + 4, true), end: Number(view.getBigUint64(at + 8, true)) });
  }
  const sections = [];
  for (let i = 0; i < sectionCount; i++) {
    const at = 48 + 16 * layerCount + 40 * i;
    const offset = Number(view.getBigUint64(at + 8, true));
    const stored = Number(view.getBigUint64(at + 16, true));
    sections.push({
      type: view.getUint16(at, true),
      codec: bytes[at + 2],
      flags: bytes[at + 3],
      layer: view.getUint16(at + 4, true),
      rawLength: Number(view.getBigUint64(at + 24, true)),
      stored: bytes.slice(offset, offset + stored),
    });
  }
  return { fixed: bytes.slice(0, 48), layers, sections };
}

/**
 * Lay the parts out again with derived offsets, lengths, layer ends, file size and CRCs.
 * @param {Parts} parts
 * @param {{gaussianCount?: boolean}} [options] recompute the header's Gaussian count too
 * @returns {Uint8Array}
 */
export function assemble(parts, options = {}) {
  const { fixed, layers, sections } = parts;
  const size = headerSize(layers.length, sections.length);
  let offset = size;
  const ends = layers.map(() => size);
  const toc = new Uint8Array(40 * sections.length);
  const tv = new DataView(toc.buffer);
  sections.forEach((s, i) => {
    const at = 40 * i;
    tv.setUint16(at, s.type, true);
    toc[at + 2] = s.codec;
    toc[at + 3] = s.flags;
    tv.setUint16(at + 4, s.layer, true);
    tv.setBigUint64(at + 8, BigInt(offset), true);
    tv.setBigUint64(at + 16, BigInt(s.stored.length), true);
    tv.setBigUint64(at + 24, BigInt(s.rawLength), true);
    tv.setUint32(at + 32, crc32(s.stored), true);
    offset += s.stored.length;
    if (s.layer < ends.length) ends[s.layer] = offset;
  });
  const table = new Uint8Array(16 * layers.length);
  const lv = new DataView(table.buffer);
  layers.forEach((l, i) => {
    table[16 * i] = l.kind;
    lv.setUint32(16 * i + 4, l.count, true);
    lv.setBigUint64(16 * i + 8, BigInt(ends[i]), true);
  });
  const head = fixed.slice();
  const hv = new DataView(head.buffer);
  hv.setUint32(16, size, true);
  hv.setUint16(20, layers.length, true);
  hv.setUint16(22, sections.length, true);
  if (options.gaussianCount) hv.setBigUint64(32, BigInt(layers.reduce((s, l) => s + l.count, 0)), true);
  hv.setBigUint64(40, BigInt(offset), true);
  const out = new Uint8Array(offset);
  out.set(head);
  out.set(table, 48);
  out.set(toc, 48 + table.length);
  new DataView(out.buffer).setUint32(size - 4, crc32(out.subarray(0, size - 4)), true);
  let at = size;
  for (const s of sections) {
    out.set(s.stored, at);
    at += s.stored.length;
  }
  return out;
}

/** Recompute the header CRC in place (for edits of header fields). */
export function repairHeaderCrc(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const size = headerSize(view.getUint16(20, true), view.getUint16(22, true));
  if (size <= bytes.length && size === view.getUint32(16, true)) {
    view.setUint32(size - 4, crc32(bytes.subarray(0, size - 4)), true);
  }
}

/** Values that tend to break parsers, for a field of `bytes` bytes holding `original`. */
function interesting(r, bytes, original) {
  const max = 2 ** (8 * Math.min(bytes, 6)) - 1;
  return r.pick([0, 1, 2, 3, original + 1, Math.max(0, original - 1), 255, 256, 65535, 65536,
    2 ** 31, 2 ** 32 - 1, max, r.int(0, 2 ** 16), original * 2]) % (max + 1);
}

/** Write an unsigned little-endian integer of `bytes` bytes (up to 8). */
function putUint(buf, at, bytes, value) {
  for (let i = 0; i < bytes; i++) buf[at + i] = Math.floor(value / 2 ** (8 * i)) & 255;
}

/** Byte-level havoc: set, flip, insert, delete, duplicate. */
function havoc(data, r) {
  let out = Array.from(data);
  for (let round = r.int(1, 5); round > 0; round--) {
    const at = out.length ? r.int(0, out.length) : 0;
    const op = r.int(0, 6);
    if (op === 0 && out.length) out[at] = r.int(0, 256);
    else if (op === 1 && out.length) out[at] ^= 1 << r.int(0, 8);
    else if (op === 2) out.splice(at, 0, ...Array.from({ length: r.int(1, 9) }, () => r.int(0, 256)));
    else if (op === 3) out.splice(at, r.int(1, 17));
    else if (op === 4) out.splice(at, 0, ...out.slice(at, at + r.int(1, 33)));
    else if (out.length) out[at] = r.pick([0, 0xFF, 0x7F, 0x80]);
  }
  return new Uint8Array(out);
}

/** Float32 values that break things. */
const BAD_FLOATS = [NaN, Infinity, -Infinity, 0, -1, 1e-45, 3.4e38, 1e30, -0];

/**
 * Edit a payload where its layout is known (counts, frames, degrees, modes, Draco headers), or
 * anywhere.
 */
function editPayload(type, raw, r) {
  const out = raw.slice();
  const view = new DataView(out.buffer);
  if (type === 0x10 && out.length >= 44 && r.chance(0.8)) {
    const rec = 4 + 40 * r.int(0, (out.length - 4) / 40);
    const field = r.int(0, 6);
    if (field === 0) putUint(out, 0, 4, interesting(r, 4, view.getUint32(0, true)));
    else if (field === 1) putUint(out, rec, 4, interesting(r, 4, view.getUint32(rec, true)));
    else if (field === 2) putUint(out, rec + 4, 4, interesting(r, 4, view.getUint32(rec + 4, true)));
    else if (field === 3) view.setFloat32(rec + 8 + 4 * r.int(0, 6), r.pick(BAD_FLOATS), true);
    else if (field === 4) out[rec + 32 + r.int(0, 5)] = r.pick([0, 1, 10, 11, 254, 255]);
    else out[rec + 37 + r.int(0, 3)] = 1;
    return out;
  }
  if (type === 0x20 && out.length > 5 && r.chance(0.8)) {
    const field = r.int(0, 4);
    if (field === 0) out[0] = r.pick([0, 3, 4, 5, 7, 255]);
    else if (field === 1) out[1 + r.int(0, 2)] = r.pick([0, 2, 5, 7, 9, 255]);
    else if (field === 2) putUint(out, 3, 2, r.pick([0, 1, 256, 257, 65535]));
    else view.setUint16(5 + 2 * r.int(0, (out.length - 5) >> 1), r.pick([0x7C00, 0xFC00, 0x7E00]), true);
    return out;
  }
  if (type === 0x21 && out.length >= 4 && r.chance(0.8)) {
    const field = r.int(0, 4);
    if (field === 0) out[0] = r.pick([0, 1, 2, 3, 4, 255]);
    else if (field === 1) out[1 + r.int(0, 3)] = 1;
    else if (field === 2 && out[0] === 1 && out.length >= 28) view.setFloat32(4 + 4 * r.int(0, 6), r.pick(BAD_FLOATS), true);
    else if (out[0] === 3 && out.length >= 19) out[4 + r.int(5, 15)] = r.int(0, 256);
    else return havoc(out, r);
    return out;
  }
  if (type === 0x11 && out.length >= 15 && r.chance(0.6)) {
    out[r.int(5, 15)] = r.int(0, 256);
    return out;
  }
  if (type === 0x22 && out.length && r.chance(0.5)) {
    out[r.int(0, out.length)] = 255;
    return out;
  }
  if (type === 0x01 && r.chance(0.7)) {
    return new TextEncoder().encode(r.pick(['[1,2]', '{"a":', '\uFEFF{}', 'null', '{"x":NaN}', '"s"', '{}']));
  }
  return havoc(out, r);
}

/** Store a new raw payload in a section with its codec (zstd becomes codec none here). */
function restore(section, raw) {
  if (section.codec === 1) section.stored = new Uint8Array(zlib.deflateSync(raw));
  else {
    section.codec = 0;
    section.stored = raw;
  }
  section.rawLength = raw.length;
}

/** The mutators: each takes a valid unwrapped file and returns a mutant. */
export const MUTATORS = {
  flip(bytes, r) {
    const out = bytes.slice();
    for (let n = r.int(1, 5); n > 0; n--) out[r.int(0, out.length)] ^= 1 << r.int(0, 8);
    return out;
  },
  truncate(bytes, r) {
    return bytes.slice(0, r.int(0, bytes.length));
  },
  append(bytes, r) {
    return new Uint8Array([...bytes, ...Array.from({ length: r.int(1, 17) }, () => r.int(0, 256))]);
  },
  header(bytes, r) {
    const out = bytes.slice();
    const view = new DataView(out.buffer);
    const layers = view.getUint16(20, true);
    const sections = view.getUint16(22, true);
    const fields = [[8, 2], [10, 2], [12, 4], [16, 4], [20, 2], [22, 2], [24, 1], [25 + r.int(0, 7), 1], [32, 8], [40, 8]];
    for (let i = 0; i < layers; i++) fields.push([48 + 16 * i, 1], [49 + 16 * i, 1], [52 + 16 * i, 4], [56 + 16 * i, 8]);
    for (let i = 0; i < sections; i++) {
      const at = 48 + 16 * layers + 40 * i;
      fields.push([at, 2], [at + 2, 1], [at + 3, 1], [at + 4, 2], [at + 6, 2], [at + 8, 8], [at + 16, 8], [at + 24, 8], [at + 32, 4], [at + 36, 4]);
    }
    const [at, size] = r.pick(fields);
    let original = 0;
    for (let i = 0; i < size; i++) original += out[at + i] * 2 ** (8 * i);
    putUint(out, at, size, interesting(r, size, original));
    repairHeaderCrc(out);
    return out;
  },
  stored(bytes, r) {
    const parts = takeApart(bytes);
    const s = r.pick(parts.sections);
    s.stored = havoc(s.stored, r);
    if (s.codec === 0 && r.chance(0.5)) s.rawLength = s.stored.length;
    return assemble(parts);
  },
  payload(bytes, r) {
    const parts = takeApart(bytes);
    const s = r.pick(parts.sections);
    const raw = decompress(s.codec, s.stored, s.rawLength).slice();
    restore(s, editPayload(s.type, raw, r));
    return assemble(parts);
  },
  sections(bytes, r) {
    const parts = takeApart(bytes);
    const list = parts.sections;
    const i = r.int(0, list.length);
    const op = r.int(0, 8);
    if (op === 0) list.splice(i, 1);
    else if (op === 1) list.splice(i, 0, { ...list[i] });
    else if (op === 2) {
      const j = r.int(0, list.length);
      [list[i], list[j]] = [list[j], list[i]];
    } else if (op === 3) list[i].type = r.pick([0x01, 0x10, 0x11, 0x12, 0x20, 0x21, 0x22, 0x7F00, 0x1234]);
    else if (op === 4) list[i].layer = r.int(0, parts.layers.length + 1);
    else if (op === 5) list[i].codec = r.pick([0, 1, 2, 3, 255]);
    else if (op === 6) list[i].flags ^= r.pick([1, 2, 128]);
    else {
      const layer = r.int(0, parts.layers.length);
      const at = list.findIndex((s) => s.layer > layer);
      const extra = { type: 0x7F00 + r.int(0, 255), codec: 0, flags: r.int(0, 2), layer, rawLength: 3, stored: new Uint8Array([1, 2, 3]) };
      list.splice(at < 0 ? list.length : at, 0, extra);
    }
    if (r.chance(0.3)) {
      const l = r.pick(parts.layers);
      if (r.chance(0.5)) l.count = interesting(r, 4, l.count);
      else l.kind ^= 1;
    }
    return assemble(parts, { gaussianCount: r.chance(0.7) });
  },
  claim(bytes, r) {
    const parts = takeApart(bytes);
    const s = r.pick(parts.sections);
    if (r.chance(0.5)) {
      s.rawLength = r.pick([2 ** 31, 2 ** 32, 2 ** 40, s.rawLength * 1000]);
      return assemble(parts);
    }
    const l = r.pick(parts.layers);
    l.count = r.pick([2 ** 31, 2 ** 32 - 1, 64_000_001, l.count * 1000]);
    return assemble(parts, { gaussianCount: true });
  },
};

/**
 * Wrap a (possibly mutated) inner file in gzip, and sometimes damage the wrapper.
 * @param {Uint8Array} inner
 */
export function gzipMutant(inner, r) {
  const gz = new Uint8Array(zlib.gzipSync(inner));
  const op = r.int(0, 5);
  if (op === 0) return gz;
  if (op === 1) return gz.slice(0, r.int(0, gz.length));
  if (op === 2) return new Uint8Array([...gz, ...gz.slice(0, r.int(1, 20))]);
  const out = gz.slice();
  const at = op === 3 ? r.int(0, Math.min(12, out.length)) : r.int(0, out.length);
  out[at] ^= 1 << r.int(0, 8);
  return out;
}
