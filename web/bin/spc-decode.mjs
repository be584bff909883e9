#!/usr/bin/env node
/**
 * Decode an .spc file into an INRIA 3DGS PLY (the format `spcodec decode` writes).
 *
 *   node web/bin/spc-decode.mjs IN.spc OUT.ply [--max-layer K | --preview]
 *
 * `--preview` writes the file's preview instead (spec 7.4: the small file a viewer shows first),
 * in the same format; a file without one is an error.
 *
 * Exits 0 on success; on any error prints one line on stderr, exits non-zero and leaves no output
 * file (the PLY is written to a temporary name in the same folder, then renamed).
 */
import { randomBytes } from 'node:crypto';
import { closeSync, fsyncSync, openSync, readFileSync, renameSync, rmSync, writeSync } from 'node:fs';
import { basename, dirname, join } from 'node:path';

import { SpcError, decode, decodePreview } from '../src/index.js';
import { plyBytes } from '../src/ply.js';

const USAGE = 'usage: spc-decode IN.spc OUT.ply [--max-layer K | --preview]';

/** @param {string[]} argv */
function parseArgs(argv) {
  const positional = [];
  let maxLayer;
  let preview = false;
  for (let i = 0; i < argv.length; i++) {
    const arg = argv[i];
    if (arg === '--max-layer' || arg.startsWith('--max-layer=')) {
      const value = arg.includes('=') ? arg.slice(arg.indexOf('=') + 1) : argv[++i];
      if (value === undefined || !/^\d+$/.test(value)) throw new UsageError(`--max-layer needs an integer >= 0, got ${value ?? 'nothing'}`);
      maxLayer = Number(value);
    } else if (arg === '--preview') {
      preview = true;
    } else if (arg === '-h' || arg === '--help') {
      process.stdout.write(`${USAGE}\n`);
      process.exit(0);
    } else if (arg.startsWith('-') && arg !== '-') {
      throw new UsageError(`unknown option ${arg}`);
    } else {
      positional.push(arg);
    }
  }
  if (positional.length !== 2) throw new UsageError(USAGE);
  // the preview is a whole file of its own: the scene's layers do not apply to it
  if (preview && maxLayer !== undefined) throw new UsageError('--preview and --max-layer do not go together');
  return { input: positional[0], output: positional[1], maxLayer, preview };
}

class UsageError extends Error {}

/** A file asked for its preview that has none: bad input for this run, but no fault of the file. */
class NoPreviewError extends Error {}

/**
 * Write `data` to `path` through a temporary file in the same folder, then rename.
 * @param {string} path
 * @param {Uint8Array} data
 */
function atomicWrite(path, data) {
  const tmp = join(dirname(path), `.${basename(path)}.${randomBytes(6).toString('hex')}.part`);
  let fd = -1;
  try {
    fd = openSync(tmp, 'wx', 0o666);
    for (let at = 0; at < data.length;) at += writeSync(fd, data, at, data.length - at);
    fsyncSync(fd);
    closeSync(fd);
    fd = -1;
    renameSync(tmp, path);
  } catch (err) {
    if (fd >= 0) closeSync(fd);
    rmSync(tmp, { force: true });
    throw err;
  }
}

async function main() {
  const { input, output, maxLayer, preview } = parseArgs(process.argv.slice(2));
  const bytes = readFileSync(input);
  const scene = preview ? await decodePreview(bytes) : await decode(bytes, { maxLayer });
  if (!scene) throw new NoPreviewError(`${input} has no preview (no PREVIEW section in layer 0)`);
  atomicWrite(output, plyBytes(scene));
}

main().catch((err) => {
  let line;
  if (err instanceof SpcError) line = `spc-decode: ${err.message}`;
  else if (err instanceof UsageError || err instanceof NoPreviewError) line = `spc-decode: ${err.message}`;
  else if (err && typeof err === 'object' && 'code' in err && 'path' in err) {
    line = `spc-decode: cannot access ${err.path}: ${err.code}`;
  } else line = `spc-decode: internal error: ${err instanceof Error ? err.message : String(err)}`;
  process.stderr.write(`${line.split('\n')[0]}\n`);
  process.exitCode = err instanceof UsageError ? 2 : 1;
});
