#!/usr/bin/env node
/**
 * Decode many files in one process (for the Python cross-check of tests/test_web_decoder.py,
 * where starting node per file would cost more than the decoding):
 *
 *   node web/test/decode-batch.mjs FILE[:MAX_LAYER]...
 *
 * prints one JSON line per argument: {"input", "code" ("ok" or the SpcError code), "count"}.
 * Anything but an SpcError is reported with code "crash" and the exception.
 */
import { readFileSync } from 'node:fs';

import { SpcError, decode } from '../src/index.js';

for (const arg of process.argv.slice(2)) {
  const match = /^(.*):(\d+)$/.exec(arg);
  const input = match ? match[1] : arg;
  const maxLayer = match ? Number(match[2]) : undefined;
  let line;
  try {
    const scene = await decode(new Uint8Array(readFileSync(input)), { maxLayer });
    line = { input: arg, code: 'ok', count: scene.count };
  } catch (err) {
    line = err instanceof SpcError ? { input: arg, code: err.code, message: err.message }
      : { input: arg, code: 'crash', message: String(err?.stack ?? err) };
  }
  process.stdout.write(`${JSON.stringify(line)}\n`);
}
