/**
 * The checksums the format and its wrappers use: CRC-32 (sections, header, gzip; ),
 * Adler-32 (zlib streams, RFC 1950) and the low 32 bits of XXH64 (zstd frame checksums, RFC 8878).
 */

// CRC-32/ISO-HDLC, slicing by 8: eight 256-entry tables, one per byte position of a 64-bit word.
const CRC_TABLES = (() => {
  const t = new Int32Array(256 * 8);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320 ^ (c >>> 1) : c >>> 1;
    t[n] = c;
  }
  for (let n = 0; n < 256; n++) {
    let c = t[n];
    for (let k = 1; k < 8; k++) {
      c = t[c & 0xFF] ^ (c >>> 8);
      t[k * 256 + n] = c;
    }
  }
  return t;
})();

/**
 * Continue a CRC-32 over `data` (start with `crc = 0`).
 * @param {Uint8Array} data
 * @param {number} [crc]
 * @returns {number} unsigned 32-bit CRC
 */
export function crc32(data, crc = 0) {
  const t = CRC_TABLES;
  let c = ~crc;
  let i = 0;
  const n = data.length;
  const end8 = n - (n & 7);
  for (; i < end8; i += 8) {
    const a = c ^ (data[i] | (data[i + 1] << 8) | (data[i + 2] << 16) | (data[i + 3] << 24));
    c = t[1792 + (a & 0xFF)] ^ t[1536 + ((a >>> 8) & 0xFF)] ^ t[1280 + ((a >>> 16) & 0xFF)] ^
      t[1024 + (a >>> 24)] ^ t[768 + data[i + 4]] ^ t[512 + data[i + 5]] ^ t[256 + data[i + 6]] ^
      t[data[i + 7]];
  }
  for (; i < n; i++) c = t[(c ^ data[i]) & 0xFF] ^ (c >>> 8);
  return ~c >>> 0;
}

/**
 * Adler-32 of `data` (RFC 1950).
 * @param {Uint8Array} data
 * @returns {number}
 */
export function adler32(data) {
  let a = 1;
  let b = 0;
  const n = data.length;
  for (let i = 0; i < n;) {
    const end = Math.min(i + 5552, n); // the longest run whose sums cannot overflow 2^53... or 2^32
    for (; i < end; i++) {
      a += data[i];
      b += a;
    }
    a %= 65521;
    b %= 65521;
  }
  return ((b << 16) | a) >>> 0;
}

// ------------------------------------------------------------------------------------ XXH64
// 64-bit words are kept as two unsigned 32-bit halves (hi, lo); the helpers return into `R`.
const R = new Uint32Array(2);

/** (ahi:alo) * (bhi:blo) mod 2^64 into R. */
function mul64(ahi, alo, bhi, blo) {
  const a0 = alo & 0xFFFF;
  const a1 = alo >>> 16;
  const b0 = blo & 0xFFFF;
  const b1 = blo >>> 16;
  const mid = a0 * b1 + a1 * b0;
  const low = a0 * b0 + (mid % 65536) * 65536;
  const lo = low % 4294967296;
  const hi = a1 * b1 + Math.floor(mid / 65536) + Math.floor(low / 4294967296);
  R[0] = hi + Math.imul(ahi, blo) + Math.imul(alo, bhi);
  R[1] = lo;
}

/** (ahi:alo) + (bhi:blo) mod 2^64 into R. */
function add64(ahi, alo, bhi, blo) {
  const lo = alo + blo;
  R[0] = ahi + bhi + (lo > 0xFFFFFFFF ? 1 : 0);
  R[1] = lo;
}

/** Rotate left by 0 < r < 32 into R. */
function rotl64(hi, lo, r) {
  R[0] = (hi << r) | (lo >>> (32 - r));
  R[1] = (lo << r) | (hi >>> (32 - r));
}

const P1H = 0x9E3779B1, P1L = 0x85EBCA87;
const P2H = 0xC2B2AE3D, P2L = 0x27D4EB4F;
const P3H = 0x165667B1, P3L = 0x9E3779F9;
const P4H = 0x85EBCA77, P4L = 0xC2B2AE63;
const P5H = 0x27D4EB2F, P5L = 0x165667C5;

/** round(acc, input) = rotl(acc + input * P2, 31) * P1, into R. */
function round64(acch, accl, inh, inl) {
  mul64(inh, inl, P2H, P2L);
  add64(acch, accl, R[0], R[1]);
  rotl64(R[0], R[1], 31);
  mul64(R[0], R[1], P1H, P1L);
}

/** h = (h ^ round(0, v)) * P1 + P4, into R. */
function mergeRound(hh, hl, vh, vl) {
  round64(0, 0, vh, vl);
  mul64((hh ^ R[0]) >>> 0, (hl ^ R[1]) >>> 0, P1H, P1L);
  add64(R[0], R[1], P4H, P4L);
}

/**
 * The low 32 bits of XXH64(data, seed 0): what a zstd frame's checksum stores.
 * @param {Uint8Array} data
 * @returns {number}
 */
export function xxh64Low32(data) {
  const n = data.length;
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
  let hh, hl;
  let i = 0;
  if (n >= 32) {
    add64(P1H, P1L, P2H, P2L);
    let v1h = R[0], v1l = R[1];
    let v2h = P2H, v2l = P2L;
    let v3h = 0, v3l = 0;
    add64(0, 0, ~P1H >>> 0, ~P1L >>> 0); // -P1 = ~P1 + 1
    add64(R[0], R[1], 0, 1);
    let v4h = R[0], v4l = R[1];
    for (; i + 32 <= n; i += 32) {
      round64(v1h, v1l, view.getUint32(i + 4, true), view.getUint32(i, true));
      v1h = R[0]; v1l = R[1];
      round64(v2h, v2l, view.getUint32(i + 12, true), view.getUint32(i + 8, true));
      v2h = R[0]; v2l = R[1];
      round64(v3h, v3l, view.getUint32(i + 20, true), view.getUint32(i + 16, true));
      v3h = R[0]; v3l = R[1];
      round64(v4h, v4l, view.getUint32(i + 28, true), view.getUint32(i + 24, true));
      v4h = R[0]; v4l = R[1];
    }
    rotl64(v1h, v1l, 1); hh = R[0]; hl = R[1];
    rotl64(v2h, v2l, 7); add64(hh, hl, R[0], R[1]); hh = R[0]; hl = R[1];
    rotl64(v3h, v3l, 12); add64(hh, hl, R[0], R[1]); hh = R[0]; hl = R[1];
    rotl64(v4h, v4l, 18); add64(hh, hl, R[0], R[1]); hh = R[0]; hl = R[1];
    mergeRound(hh, hl, v1h, v1l); hh = R[0]; hl = R[1];
    mergeRound(hh, hl, v2h, v2l); hh = R[0]; hl = R[1];
    mergeRound(hh, hl, v3h, v3l); hh = R[0]; hl = R[1];
    mergeRound(hh, hl, v4h, v4l); hh = R[0]; hl = R[1];
  } else {
    hh = P5H; hl = P5L;
  }
  add64(hh, hl, Math.floor(n / 4294967296), n >>> 0); hh = R[0]; hl = R[1];
  for (; i + 8 <= n; i += 8) {
    round64(0, 0, view.getUint32(i + 4, true), view.getUint32(i, true));
    rotl64((hh ^ R[0]) >>> 0, (hl ^ R[1]) >>> 0, 27);
    mul64(R[0], R[1], P1H, P1L);
    add64(R[0], R[1], P4H, P4L); hh = R[0]; hl = R[1];
  }
  if (i + 4 <= n) {
    mul64(0, view.getUint32(i, true), P1H, P1L);
    rotl64((hh ^ R[0]) >>> 0, (hl ^ R[1]) >>> 0, 23);
    mul64(R[0], R[1], P2H, P2L);
    add64(R[0], R[1], P3H, P3L); hh = R[0]; hl = R[1];
    i += 4;
  }
  for (; i < n; i++) {
    mul64(0, data[i], P5H, P5L);
    rotl64((hh ^ R[0]) >>> 0, (hl ^ R[1]) >>> 0, 11);
    mul64(R[0], R[1], P1H, P1L); hh = R[0]; hl = R[1];
  }
  // avalanche: h ^= h >> 33; h *= P2; h ^= h >> 29; h *= P3; h ^= h >> 32
  hl = (hl ^ (hh >>> 1)) >>> 0;
  mul64(hh, hl, P2H, P2L); hh = R[0]; hl = R[1];
  hl = (hl ^ ((hh << 3) | (hl >>> 29))) >>> 0;
  hh = (hh ^ (hh >>> 29)) >>> 0;
  mul64(hh, hl, P3H, P3L); hh = R[0]; hl = R[1];
  return (hl ^ hh) >>> 0;
}
