#!/usr/bin/env node
// Validate a .glb with the Khronos glTF-Validator and print its report as JSON on stdout.
//   node test/validate-gltf.mjs FILE.glb
// (The released validator predates KHR_gaussian_splatting: it reports the extension as unsupported
// and its attribute names as invalid; tests/test_viewer.py accepts exactly those and nothing else.)

import fs from 'node:fs';
import validator from 'gltf-validator';

const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])),
  { maxIssues: 1000 });
process.stdout.write(`${JSON.stringify(report)}\n`);
