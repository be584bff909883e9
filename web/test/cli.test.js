/**
 * bin/spc-decode.mjs: writes the PLY atomically, exits 0; on any error exits non-zero with one
 * stderr line (carrying the spec's [code] for bad bytes) and leaves no file behind.
 */
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { mkdtempSync, readFileSync, readdirSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join } from 'node:path';
import { test } from 'node:test';
import { fileURLToPath } from 'node:url';

import { decode, decodePreview } from '../src/index.js';
import { plyBytes } from '../src/ply.js';
import { FIXTURES, fixture } from './helpers.js';

const CLI = join(dirname(fileURLToPath(import.meta.url)), '..', 'bin', 'spc-decode.mjs');

function run(...args) {
  return spawnSync(process.execPath, [CLI, ...args], { encoding: 'utf8' });
}

function scratch() {
  return mkdtempSync(join(tmpdir(), 'spc-decode-'));
}

test('decodes a file to the PLY of decode(), and --max-layer K to layers 0..K', async () => {
  const dir = scratch();
  const input = join(FIXTURES, 'sh3-zlib-quant16.spc');
  const out = join(dir, 'out.ply');
  const result = run(input, out);
  assert.equal(result.status, 0, result.stderr);
  assert.deepEqual(new Uint8Array(readFileSync(out)), plyBytes(await decode(fixture('sh3-zlib-quant16'))));
  const limited = run(input, out, '--max-layer', '1');
  assert.equal(limited.status, 0, limited.stderr);
  const scene = await decode(fixture('sh3-zlib-quant16'), { maxLayer: 1 });
  assert.deepEqual(new Uint8Array(readFileSync(out)), plyBytes(scene));
  assert.deepEqual(readdirSync(dir), ['out.ply'], 'no temporary file left');
});

test('bad bytes: non-zero exit, one line naming the code, no output file', () => {
  const dir = scratch();
  const bytes = fixture('sh0-none-float16');
  const cases = {
    'bad-magic': new Uint8Array([1, 2, 3, 4, 5, 6, 7, 8, 9]),
    truncated: bytes.subarray(0, bytes.length - 5),
    'header-crc': (() => { const b = bytes.slice(); b[33] ^= 1; return b; })(),
    'trailing-data': new Uint8Array([...bytes, 0]),
  };
  for (const [code, data] of Object.entries(cases)) {
    const input = join(dir, `${code}.spc`);
    writeFileSync(input, data);
    const result = run(input, join(dir, `${code}.ply`));
    assert.equal(result.status, 1, code);
    const lines = result.stderr.trim().split('\n');
    assert.equal(lines.length, 1, result.stderr);
    assert.match(lines[0], new RegExp(`\\[${code}\\]$`));
  }
  assert.deepEqual(readdirSync(dir).filter((f) => !f.endsWith('.spc')), []);
});

test('usage and file-system errors: one line, no output', () => {
  const dir = scratch();
  const input = join(FIXTURES, 'sh0-none-float16.spc');
  for (const args of [[], [input], [input, join(dir, 'a.ply'), '--max-layer', 'x'], [input, join(dir, 'a.ply'), '--bogus']]) {
    const result = run(...args);
    assert.equal(result.status, 2, `${args}: ${result.stderr}`);
    assert.equal(result.stderr.trim().split('\n').length, 1);
  }
  const missing = run(join(dir, 'nope.spc'), join(dir, 'a.ply'));
  assert.equal(missing.status, 1);
  assert.match(missing.stderr, /nope\.spc/);
  const noFolder = run(input, join(dir, 'no', 'such', 'a.ply'));
  assert.equal(noFolder.status, 1);
  assert.equal(noFolder.stderr.trim().split('\n').length, 1);
  assert.deepEqual(readdirSync(dir), []);
});

test('--preview writes the preview\'s PLY, or says the file has none', async () => {
  const dir = scratch();
  const out = join(dir, 'preview.ply');
  const result = run(join(FIXTURES, 'sh1-preview.spc'), out, '--preview');
  assert.equal(result.status, 0, result.stderr);
  assert.deepEqual(new Uint8Array(readFileSync(out)), plyBytes(await decodePreview(fixture('sh1-preview'))));
  const none = run(join(FIXTURES, 'sh3-zlib-quant16.spc'), join(dir, 'none.ply'), '--preview');
  assert.equal(none.status, 1);
  assert.equal(none.stderr.trim().split('\n').length, 1);
  assert.match(none.stderr, /has no preview/);
  const both = run(join(FIXTURES, 'sh1-preview.spc'), join(dir, 'both.ply'), '--preview', '--max-layer', '0');
  assert.equal(both.status, 2);
  assert.deepEqual(readdirSync(dir), ['preview.ply']);
});
