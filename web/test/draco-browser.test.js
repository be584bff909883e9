// Locating draco3d's files in a browser (src/draco-browser.js): from the module's own URL, without
// a request for a file that is not there (its probe of draco3d/package.json logged a 404 on every
// page of the viewer and the examples).

import assert from 'node:assert/strict';
import { existsSync, readFileSync } from 'node:fs';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

const MODULE = new URL('../src/draco-browser.js', import.meta.url);

test('dracoFolder finds draco3d beside an installed package and in this repository', async () => {
  const { dracoFolder } = await import(MODULE.href);
  const cases = {
    'https://example.org/node_modules/spcodec/src/draco-browser.js':
      'https://example.org/node_modules/draco3d/',
    'http://h/app/node_modules/.pnpm/spcodec@0.1.0/node_modules/spcodec/src/draco-browser.js':
      'http://h/app/node_modules/.pnpm/spcodec@0.1.0/node_modules/draco3d/',
    'http://h/src/draco-browser.js': 'http://h/node_modules/draco3d/',  // spcodec serve: web/
    'http://h/web/src/draco-browser.js?v=2': 'http://h/web/node_modules/draco3d/',
  };
  for (const [module, folder] of Object.entries(cases)) assert.equal(dracoFolder(module).href, folder, module);
  const own = fileURLToPath(dracoFolder());
  for (const file of ['draco_decoder_nodejs.js', 'draco_decoder.wasm']) {
    assert.ok(existsSync(own + file), `${own}${file} (npm ci in web/)`);
  }
});

/** A browser's globals, just enough for browserDraco: every URL asked for is noted, and a file
 * URL that is not on disk answers 404 as a static server would. */
function fakeBrowser() {
  const asked = [];
  const served = (url) => existsSync(fileURLToPath(url));
  const window = {};
  const fetch = async (url) => {
    asked.push(String(url));
    const ok = served(url);
    return { ok, status: ok ? 200 : 404, arrayBuffer: async () => readFileSync(fileURLToPath(url)) };
  };
  const head = { appendChild: (script) => {
    asked.push(script.src);
    if (!served(script.src)) return script.onerror();
    window.DracoDecoderModule = async (options) => ({ wasmBytes: options.wasmBinary.byteLength });
    return script.onload();
  } };
  const document = { head, createElement: () => ({}) };
  return { asked, globals: { window, document, fetch, location: { href: MODULE.href } } };
}

test('browserDraco loads the decoder without asking for a file that is not there', async (t) => {
  const { browserDraco } = await import(MODULE.href);
  const { asked, globals } = fakeBrowser();
  const saved = Object.fromEntries(Object.keys(globals).map((k) => [k, Object.getOwnPropertyDescriptor(globalThis, k)]));
  t.after(() => {
    for (const [k, descriptor] of Object.entries(saved)) {
      if (descriptor) Object.defineProperty(globalThis, k, descriptor);
      else delete globalThis[k];
    }
  });
  for (const [k, value] of Object.entries(globals)) {
    Object.defineProperty(globalThis, k, { value, configurable: true, writable: true });
  }
  const module = await browserDraco()();
  assert.ok(module.wasmBytes > 0);
  const missing = asked.filter((url) => !existsSync(fileURLToPath(url)));
  assert.deepEqual(missing, [], `requests for missing files: ${missing.join(', ')}`);
  assert.deepEqual(asked.map((url) => url.slice(url.lastIndexOf('/') + 1)),
    ['draco_decoder_nodejs.js', 'draco_decoder.wasm']);
});
