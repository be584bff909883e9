// The pages' import maps: the same on every page, and every target present once `npm ci` has run
// in web/ and web/viewer/ (a package update that moves its files shows up here, not in a browser).

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const viewer = path.resolve(here, '..');

function importMap(page) {
  const html = fs.readFileSync(path.join(viewer, page), 'utf8');
  const match = /<script type="importmap">([\s\S]*?)<\/script>/.exec(html);
  assert.ok(match, `${page} has an import map`);
  return JSON.parse(match[1]).imports;
}

test('every page has the same import map', () => {
  assert.deepEqual(importMap('bench.html'), importMap('index.html'));
});

test('import map targets exist after npm ci', (t) => {
  const imports = importMap('index.html');
  const installed = fs.existsSync(path.join(viewer, 'node_modules', 'playcanvas')) &&
    fs.existsSync(path.join(viewer, '..', 'node_modules', 'fflate'));
  if (!installed) {
    t.skip('npm ci has not run in web/ and web/viewer/');
    return;
  }
  for (const [name, target] of Object.entries(imports)) {
    assert.ok(fs.existsSync(path.resolve(viewer, target)), `${name} -> ${target}`);
  }
  for (const file of ['draco_decoder_nodejs.js', 'draco_decoder.wasm']) {  // src/draco-browser.js
    assert.ok(fs.existsSync(path.join(viewer, '..', 'node_modules', 'draco3d', file)), file);
  }
});
