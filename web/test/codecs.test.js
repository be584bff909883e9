/**
 * Section codecs and the gzip wrapper ([R-22]..[R-25], [R-80]..[R-84]): round trips against
 * Node's zlib, and every way a stream can be wrong mapped to the spec's code.
 */
import assert from 'node:assert/strict';
import { randomBytes } from 'node:crypto';
import { test } from 'node:test';
import zlib from 'node:zlib';

import { adler32, crc32, xxh64Low32 } from '../src/checksums.js';
import { decompress } from '../src/codecs.js';
import { SpcError } from '../src/errors.js';
import { GzipReader } from '../src/gzip.js';
import { RawInflater } from '../src/inflate.js';
import { inflateZstd } from '../src/zstd.js';
import { rng } from './helpers.js';

const ZLIB = 1;
const ZSTD = 2;

function samples() {
  let text = '';
  for (let i = 0; i < 30000; i++) text += `w${(i * 7919) % 1000} `;
  const floats = new Float32Array(100000);
  for (let i = 0; i < floats.length; i++) floats[i] = Math.round(Math.sin(i / 50) * 100);
  return [new Uint8Array(0), new Uint8Array([7]), new Uint8Array(randomBytes(70000)),
    new Uint8Array(200000).fill(3), new TextEncoder().encode(text), new Uint8Array(floats.buffer)];
}

const u8 = (buf) => new Uint8Array(buf.buffer, buf.byteOffset, buf.length);

test('checksums: known values', () => {
  const abc = new TextEncoder().encode('abc');
  assert.equal(crc32(abc), 0x352441C2);
  assert.equal(crc32(new TextEncoder().encode('123456789')), 0xCBF43926);
  assert.equal(adler32(abc), 0x024D0127);
  assert.equal(xxh64Low32(new Uint8Array(0)), 0x51D8E999); // XXH64("") = EF46DB3751D8E999
  assert.equal(xxh64Low32(abc), 0xAD770999); // XXH64("abc") = 44BC2CF5AD770999
  const big = new Uint8Array(randomBytes(100003));
  assert.equal(crc32(big), zlib.crc32 ? zlib.crc32(big) : crc32(big));
  assert.equal(crc32(big.subarray(5000), crc32(big.subarray(0, 5000))), crc32(big), 'continuable');
});

test('zlib sections: every level and strategy of zlib inflates exactly', () => {
  for (const raw of samples()) {
    for (const level of [0, 1, 6, 9]) {
      for (const strategy of [0, 1, 2, 3, 4]) {
        const stored = u8(zlib.deflateSync(raw, { level, strategy }));
        assert.deepEqual(decompress(ZLIB, stored, raw.length), raw);
      }
    }
  }
});

test('zlib sections: wrong lengths, corruption, cuts and trailing bytes', () => {
  const raw = samples()[4];
  const stored = u8(zlib.deflateSync(raw));
  const code = (bytes, length = raw.length) => {
    try {
      decompress(ZLIB, bytes, length);
      return 'ok';
    } catch (err) {
      assert.ok(err instanceof SpcError, String(err));
      return err.code;
    }
  };
  assert.equal(code(stored), 'ok');
  assert.equal(code(stored, raw.length - 1), 'length-mismatch', 'inflates past the raw length');
  assert.equal(code(stored, raw.length + 1), 'length-mismatch', 'complete stream, fewer bytes');
  assert.equal(code(stored.subarray(0, stored.length - 2)), 'decompression-failed', 'cut in the Adler-32');
  assert.equal(code(stored.subarray(0, stored.length >> 1)), 'decompression-failed', 'cut in the data');
  const twice = new Uint8Array([...stored, ...stored]);
  assert.equal(code(twice), 'decompression-failed', 'a second stream after the first');
  assert.equal(code(new Uint8Array([...stored, 0])), 'decompression-failed', 'a byte after the stream');
  const badAdler = stored.slice();
  badAdler[badAdler.length - 1] ^= 1;
  assert.equal(code(badAdler), 'decompression-failed');
  const dict = u8(zlib.deflateSync(raw, { dictionary: Buffer.from('dictionary') }));
  assert.equal(code(dict), 'decompression-failed', 'FDICT');
  assert.equal(code(new Uint8Array([0x78, 0x9D, 0x03, 0x00])), 'decompression-failed', 'header check bits');
  assert.equal(code(new Uint8Array([0x78])), 'decompression-failed');
  // a bomb: 1 MB of zeros may not inflate past a 10-byte raw length
  const bomb = u8(zlib.deflateSync(new Uint8Array(1 << 20)));
  assert.equal(code(bomb, 10), 'length-mismatch');
  assert.equal(code(stored, raw.length), 'ok');
  assert.equal(decompress(0, stored, stored.length), stored);
  assert.throws(() => decompress(0, stored, stored.length + 1), { code: 'length-mismatch' });
  assert.throws(() => decompress(7, stored, raw.length), { code: 'unknown-codec' });
});

test('deflate: zlib\'s validity rules', () => {
  const raw = (bits) => {
    // pack a bit string (LSB first per byte) into bytes, then inflate with zlib framing removed
    const bytes = new Uint8Array(Math.ceil(bits.length / 8) + 4);
    for (let i = 0; i < bits.length; i++) if (bits[i] === '1') bytes[i >> 3] |= 1 << (i & 7);
    const inf = new RawInflater(1000);
    inf.setInput(new Uint8Array([...bytes, ...new Uint8Array(16)]), bytes.length, 0);
    inf.inputEnded = true;
    return () => inf.run();
  };
  // final stored block whose NLEN is not the complement of LEN
  const stored = new Uint8Array([0x01, 0x05, 0x00, 0x00, 0x00, 1, 2, 3, 4, 5]);
  const inf = new RawInflater(10);
  inf.setInput(new Uint8Array([...stored, ...new Uint8Array(16)]), stored.length, 0);
  assert.throws(() => inf.run(), /invalid stored block lengths/);
  // block type 3
  assert.throws(raw('111'), /invalid block type/);
  // fixed block: a match of distance 1 at the start of the output
  // BFINAL=1 BTYPE=01, length code 257 (0000001, 7 bits), distance code 0 (00000)
  assert.throws(raw('1' + '10' + '0000001' + '00000'), /too far back/);
  // fixed literal/length codes 286 and 287 are invalid: 286 = 11000110 (8 bits)
  assert.throws(raw('1' + '10' + '11000110'), /invalid literal\/length code/);
});

test('zstd sections: frames with and without checksums, and what a frame may not be', async () => {
  // frames made by the reference writer live in the fixtures; these are hand-built edge cases
  const code = (bytes, length) => {
    try {
      inflateZstd(bytes, length);
      return 'ok';
    } catch (err) {
      assert.ok(err instanceof SpcError, String(err));
      return err.code;
    }
  };
  // a raw block frame: magic, descriptor (single segment, FCS 1 byte, checksum flag c), size, block
  const frame = (content, checksum, extra = []) => {
    const desc = 0x20 | (checksum ? 4 : 0);
    const block = [(content.length << 3) | 1, content.length >> 5, content.length >> 13];
    const sum = checksum ? (() => { const v = xxh64Low32(new Uint8Array(content)); return [v & 255, (v >>> 8) & 255, (v >>> 16) & 255, v >>> 24]; })() : [];
    return new Uint8Array([0x28, 0xB5, 0x2F, 0xFD, desc, content.length, ...block, ...content, ...sum, ...extra]);
  };
  const content = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10];
  assert.equal(code(frame(content, false), 10), 'ok');
  assert.deepEqual(Array.from(inflateZstd(frame(content, true), 10)), content);
  const badSum = frame(content, true);
  badSum[badSum.length - 1] ^= 1;
  assert.equal(code(badSum, 10), 'decompression-failed', 'checksum mismatch');
  assert.equal(code(frame(content, false, [0]), 10), 'decompression-failed', 'byte after the frame');
  assert.equal(code(frame(content, false).subarray(0, 15), 10), 'decompression-failed', 'cut frame');
  assert.equal(code(frame(content, false), 11), 'length-mismatch', 'declared size differs');
  const skippable = new Uint8Array([0x50, 0x2A, 0x4D, 0x18, 0, 0, 0, 0, ...frame(content, false)]);
  assert.equal(code(skippable, 10), 'decompression-failed', 'skippable frame');
  const reserved = frame(content, false);
  reserved[4] |= 0x08;
  assert.equal(code(reserved, 10), 'decompression-failed', 'reserved bit');
  const bigWindow = new Uint8Array([0x28, 0xB5, 0x2F, 0xFD, 0x80, 0x88, 10, 0, 0, 0, 1, 0, 0]);
  assert.equal(code(bigWindow, 10), 'decompression-failed', 'window 2^28');
  const lies = frame(content, false);
  lies[6] = (11 << 3) | 1; // the block claims 11 bytes: the frame would end after the data
  assert.equal(code(lies, 10), 'decompression-failed');
  assert.equal(decompress(ZSTD, frame(content, false), 10).length, 10);
});

test('deflate: a code length code without symbols fails once its lengths are read (zlib)', () => {
  // BFINAL 0, BTYPE 2, HLIT 0, HDIST 0, HCLEN 0, four lengths 0: then one bit per code length
  const header = [0x04, 0x00, 0x00, 0x00]; // 29 header bits and 3 one-bit lengths
  const feed = (extra) => {
    const inf = new RawInflater(1000);
    inf.append(new Uint8Array([...header, ...new Array(extra).fill(0xFF)]));
    return inf.run();
  };
  assert.equal(feed(0), false, 'waits for more input: 3 of 258 lengths read');
  assert.equal(feed(31), false, '251 of 258 lengths read');
  assert.throws(() => feed(32), /missing end-of-block/);
});

test('zstd sections: the rules of [R-22] where libzstd and fzstd differed (spec 1.1.1)', () => {
  // each: a frame that must fail, the same frame made right, its content size (hand-made by the
  // conformance generator's zstd_bits.py)
  const pairs = [
    ['a Huffman stream with 8 bits left over', '28b52ffd20c8650500860c2aef00000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000001111111111111111a001b001a0007294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c3e5070100e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c3e501c3e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c301a1c3e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa10100', '28b52ffd20c85d050086cc29ef00000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000001111111111111111a001a001a0007294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c3e50701e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c3e501c3e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa1c301a1c3e507294b6d8fa1c3e507294b6d8fa1c3e507294b6d8fa10100', 200],
    ['a match before the start of the frame', '28b52ffd80000b0000007d0000406162636465666768015408040017', '28b52ffd80000b0000007d000040616263646566676801540803000b', 11],
    ['a literals length past the literals', '28b52ffd8000090000005d00002061626364015406020004', '28b52ffd8000090000006d000030616263646566015406020004', 9],
    ['sequence bits left over', '28b52ffd8000080000005d00002061626364015404020120', '28b52ffd8000080000005d00002061626364015404020104', 8],
    ['a repeated offset of 1 - 1 = 0', '28b52ffd800007000000200000616263643d000000015400010003', '28b52ffd800007000000200000616263643d000000015400000001', 7],
    ['a block decoding past the block maximum', '28b52ffd40001a034d00000861015401022e1610', '28b52ffd400000034d00000861015401022dfc09', 1024],
  ];
  const hex = (h) => new Uint8Array(Buffer.from(h, 'hex'));
  for (const [name, bad, good, size] of pairs) {
    const badSize = name.startsWith('a block') ? 1050 : size;
    assert.throws(() => inflateZstd(hex(bad), badSize), { code: 'decompression-failed' }, name);
    assert.equal(inflateZstd(hex(good), size).length, size, name);
  }
  // an FSE table description that libzstd's reader continues past the block (it goes on from
  // the block's last four bytes again): libzstd decodes this frame, the spec refuses it
  const wrapped = hex('28b52ffd800039000000dd0000806162636465666768696a6b6c6d6e6f7001800128868b2602953c');
  assert.throws(() => inflateZstd(wrapped, 57), { code: 'decompression-failed' });
  // window 1 KiB, two raw blocks of 1000 bytes, then a match 2000 bytes back: valid
  const first = new Uint8Array(1000).map((_, i) => i % 250);
  const raw = (data, last) => [(data.length << 3) | (last ? 1 : 0), data.length >> 5, data.length >> 13, ...data];
  const far = new Uint8Array([...hex('28b52ffd4000b80a'), ...raw(first, false),
    ...raw(new Uint8Array(1000).fill(121), false), ...hex('4d0000000154000a2de5a70f')]);
  const out = inflateZstd(far, 3000);
  assert.deepEqual(out.subarray(2000), first);
  // content size 0: an RLE block of 0 bytes (libzstd's streaming decoder takes its byte for a
  // block over the block maximum of 0)
  assert.equal(inflateZstd(hex('28b52ffd20000000000300006b'), 0).length, 0);
  // window 1 KiB, content 1025: a raw or an RLE block of 1025 bytes is over the block maximum
  const head1025 = hex('28b52ffd40000103');
  const rawBig = new Uint8Array([...head1025, 0x09, 0x20, 0x00, ...new Uint8Array(1025)]);
  assert.throws(() => inflateZstd(rawBig, 1025), { code: 'decompression-failed' });
  const rleBig = new Uint8Array([...head1025, 0x0B, 0x20, 0x00, 0x72]);
  assert.throws(() => inflateZstd(rleBig, 1025), { code: 'decompression-failed' });
  // ... and a compressed block needs at least 2 bytes
  const tiny = new Uint8Array([...hex('28b52ffd40000000'), 0x05, 0x00, 0x00]);
  assert.throws(() => inflateZstd(tiny, 256), { code: 'decompression-failed' });
});

test('gzip reader: prefixes at flush points inflate to exact inner prefixes', () => {
  const inner = samples()[4];
  const stops = [1000, 50000, 120000];
  const ends = [];
  // non-final stored blocks up to each stop (byte aligned, as after a full flush), then the rest
  const header = new Uint8Array([0x1F, 0x8B, 8, 0, 0, 0, 0, 0, 0, 255]);
  const body = [];
  let prev = 0;
  let length = header.length;
  for (const stop of stops) {
    const piece = inner.subarray(prev, stop);
    for (let i = 0; i < piece.length; i += 65535) {
      const n = Math.min(65535, piece.length - i);
      body.push(new Uint8Array([0, n & 255, n >> 8, ~n & 255, (~n >> 8) & 255]), piece.subarray(i, i + n));
      length += 5 + n;
    }
    ends.push(length);
    prev = stop;
  }
  const rest = u8(zlib.deflateRawSync(inner.subarray(prev)));
  body.push(rest);
  const trailer = new Uint8Array(8);
  new DataView(trailer.buffer).setUint32(0, crc32(inner), true);
  new DataView(trailer.buffer).setUint32(4, inner.length, true);
  const file = new Uint8Array([...header, ...body.flatMap((b) => Array.from(b)), ...trailer]);
  ends.forEach((end, i) => {
    const reader = new GzipReader(1 << 30);
    reader.push(file.subarray(0, end));
    assert.equal(reader.innerLength, stops[i], `prefix ${i}`);
    assert.equal(reader.complete, false);
  });
  const r = rng(3);
  const reader = new GzipReader(1 << 30);
  for (let at2 = 0; at2 < file.length;) {
    const n = r.pick([1, 3, 100, 4096]);
    reader.push(file.subarray(at2, at2 + n));
    at2 += n;
  }
  assert.equal(reader.complete, true);
  assert.deepEqual(reader.inner, inner);
});

test('gzip reader: CRC, ISIZE, header CRC, flags and trailing bytes', () => {
  const inner = samples()[5];
  const good = u8(zlib.gzipSync(inner));
  const run = (bytes) => {
    try {
      const reader = new GzipReader(1 << 30);
      reader.push(bytes);
      return reader.complete ? 'ok' : 'incomplete';
    } catch (err) {
      assert.ok(err instanceof SpcError, String(err));
      return err.code;
    }
  };
  assert.equal(run(good), 'ok');
  assert.equal(run(good.subarray(0, good.length - 3)), 'incomplete', 'cut inside the trailer: a prefix');
  const crc = good.slice();
  crc[crc.length - 8] ^= 1;
  assert.equal(run(crc), 'bad-gzip');
  const isize = good.slice();
  isize[isize.length - 1] ^= 1;
  assert.equal(run(isize), 'bad-gzip');
  assert.equal(run(new Uint8Array([...good, 0])), 'trailing-data');
  assert.equal(run(new Uint8Array([...good, ...good])), 'trailing-data', 'a second member');
  const method = good.slice();
  method[2] = 7;
  assert.equal(run(method), 'bad-gzip');
  const flags = good.slice();
  flags[3] = 0x20;
  assert.equal(run(flags), 'bad-gzip');
  // FHCRC: header CRC over the 10 fixed bytes
  const withHcrc = new Uint8Array(good.length + 2);
  withHcrc.set(good.subarray(0, 10));
  withHcrc[3] |= 2;
  const hcrc = crc32(withHcrc.subarray(0, 10)) & 0xFFFF;
  withHcrc[10] = hcrc & 255;
  withHcrc[11] = hcrc >> 8;
  withHcrc.set(good.subarray(10), 12);
  assert.equal(run(withHcrc), 'ok');
  withHcrc[10] ^= 1;
  assert.equal(run(withHcrc), 'bad-gzip');
  const corrupt = good.slice();
  corrupt[12] ^= 0xFF; // inside the deflate data: refused one way or another, never decoded
  assert.ok(['bad-gzip', 'trailing-data', 'incomplete'].includes(run(corrupt)));
});
