// The viewer and a file with a preview (spec 7.4, [R-104]), in headless Chromium: the preview is on
// screen, and said so, while the scene's first layers are held back; when the takeover layer is in,
// the scene replaces it with no blank frame between. A preview that does not decode is noted and
// the layers show as without one. Skips, saying why, where Chromium or the npm packages are missing.

import assert from 'node:assert/strict';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import { PreviewStand } from '../../loaders/playcanvas.js';
import { inspect } from '../../src/index.js';
import { assemble, takeApart } from '../../test/mutate.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const WEB = path.resolve(here, '..', '..');
const CHROMIUM = process.env.SPCODEC_CHROMIUM ?? '/usr/bin/chromium';

/** Why the browser cannot run here, or null. */
function missing() {
  if (!fs.existsSync(CHROMIUM)) return `no Chromium at ${CHROMIUM} (apt-get install chromium, or set SPCODEC_CHROMIUM)`;
  for (const dir of ['viewer/node_modules/playwright-core', 'viewer/node_modules/playcanvas', 'node_modules/draco3d']) {
    if (!fs.existsSync(path.join(WEB, dir))) return `${dir} is missing: run npm ci in web/ and web/viewer/`;
  }
  return null;
}

/**
 * The preview fixture (three layers, preview shown until layer 1) with layer 0 padded by an
 * unknown optional section, so that it ends past the viewer's first 4 KB request: the preview
 * comes with that request, layer 1 with a request of its own, which the server can hold back.
 * @param {(parts: ReturnType<typeof takeApart>) => void} [edit]
 */
function sceneFile(edit = () => {}) {
  const parts = takeApart(new Uint8Array(fs.readFileSync(path.join(WEB, 'test', 'fixtures', 'sh1-preview.spc'))));
  const at = parts.sections.findIndex((s) => s.layer === 1);
  parts.sections.splice(at, 0, { type: 0x7F01, codec: 0, flags: 0, layer: 0, rawLength: 6000,
    stored: new Uint8Array(6000) });
  edit(parts);
  return assemble(parts);
}

test('PreviewStand holds the layers before the takeover and swaps them in with one step', () => {
  const entity = (name) => ({ name, enabled: true });
  const stand = new PreviewStand();
  const preview = entity('preview');
  assert.equal(stand.open(preview, 2, 5), 2);
  const layers = [entity('0'), null, entity('2'), entity('3')];  // layer 1 is empty
  assert.equal(stand.place(layers[0], 0), false);
  assert.equal(stand.place(layers[1], 1), false);
  assert.equal(layers[0].enabled, false);
  assert.equal(preview.enabled, true);
  assert.equal(stand.place(layers[2], 2), true);
  assert.deepEqual([layers[0].enabled, layers[2].enabled, preview.enabled], [true, true, false]);
  assert.deepEqual([stand.dropped, stand.heldIndices, stand.retired], [2, [0, 1], preview]);
  assert.equal(stand.place(layers[3], 3), true);
  assert.equal(layers[3].enabled, true);
  // the last layer asked for drops it when it comes before the takeover layer
  const short = new PreviewStand();
  assert.equal(short.open(entity('p'), 4, 1), 1);
  assert.equal(short.place(entity('0'), 0), false);
  assert.equal(short.place(entity('1'), 1), true);
  // no preview: every layer is shown as it comes
  assert.equal(new PreviewStand().place(entity('0'), 0), true);
});

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript',
  '.json': 'application/json', '.wasm': 'application/wasm' };

/**
 * Serve web/ and `scenes` (at /scenes/NAME, with byte ranges). Bytes of a scene from `holdFrom` on
 * wait until `release()`.
 * @param {Record<string, Uint8Array>} scenes
 */
async function serve(scenes, holdFrom = Infinity) {
  let release;
  const released = new Promise((resolve) => { release = resolve; });
  const server = http.createServer(async (req, res) => {
    const url = new URL(req.url, 'http://x');
    const scene = url.pathname.startsWith('/scenes/') ? scenes[url.pathname.slice(8)] : null;
    if (scene) {
      const match = /^bytes=(\d+)-(\d+)$/.exec(req.headers.range ?? '');
      const first = match ? Number(match[1]) : 0;
      const last = match ? Math.min(Number(match[2]), scene.length - 1) : scene.length - 1;
      res.writeHead(match ? 206 : 200, { 'Content-Length': last + 1 - first,
        ...(match ? { 'Content-Range': `bytes ${first}-${last}/${scene.length}` } : {}) });
      if (first >= holdFrom) await released;
      res.end(scene.subarray(first, last + 1));
      return;
    }
    const file = path.join(WEB, decodeURIComponent(url.pathname));
    if (!file.startsWith(WEB + path.sep) || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
      res.writeHead(404).end();
      return;
    }
    res.writeHead(200, { 'Content-Type': TYPES[path.extname(file)] ?? 'application/octet-stream' });
    res.end(req.method === 'HEAD' ? undefined : fs.readFileSync(file));
  });
  await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve));
  return { base: `http://127.0.0.1:${server.address().port}`, release, close: () => server.close() };
}

/** Open the viewer on `name` and return the page (the caller closes it). */
async function open(browser, base, name, extra = '') {
  const page = await browser.newPage({ viewport: { width: 320, height: 240 } });
  page.on('pageerror', (e) => console.error(`pageerror: ${e.message}`));
  await page.goto(`${base}/viewer/index.html?src=/scenes/${name}&width=160&height=120${extra}`);
  return page;
}

/** Share of the canvas's pixels that are not the black background, sampled in the page. */
const LIT_SHARE = `(() => {
  const probe = window.__probe ??= Object.assign(document.createElement('canvas'), { width: 40, height: 30 });
  const ctx = probe.getContext('2d', { willReadFrequently: true });
  ctx.drawImage(document.getElementById('scene'), 0, 0, 40, 30);
  const px = ctx.getImageData(0, 0, 40, 30).data;
  let lit = 0;
  for (let i = 0; i < px.length; i += 4) if (Math.max(px[i], px[i + 1], px[i + 2]) > 5) lit++;
  return lit / (px.length / 4);
})()`;

const hud = (page) => page.evaluate(() => document.getElementById('hud').textContent);
const viewerState = (page) => page.evaluate(() => JSON.parse(JSON.stringify(window.spcViewer)));

test('the preview is shown first, then the scene replaces it with no blank frame', { skip: missing() ?? false, timeout: 180000 }, async () => {
  const { launchChromium } = await import('./browser.mjs');
  const file = sceneFile();
  const layers = inspect(file).layers;
  assert.ok(layers[0].end_offset > 4096, 'layer 0 ends past the first request');
  const server = await serve({ 'preview.spc': file }, layers[0].end_offset);
  const browser = await launchChromium();
  try {
    const page = await open(browser, server.base, 'preview.spc', '&layerPictures=1');
    await page.waitForFunction(() => {
      const s = window.spcViewer;
      return s.status === 'error' || (s.preview?.tShown != null && s.layersDecoded === 1);
    }, null, { timeout: 120000 });
    const early = await viewerState(page);
    assert.equal(early.error, null);
    assert.equal(early.showing, 'preview');
    assert.equal(early.layersShown, 0, 'layer 0 is in but held back');
    assert.equal(early.preview.takeoverLayer, 1);
    assert.equal(early.preview.showFrom, 1);
    assert.equal(early.layersInFirstPicture, 0, 'the first picture is the preview');
    assert.ok(early.bytesAtFirstPicture < layers[0].end_offset);
    const text = await hud(page);
    assert.match(text, /showing: preview \([\d.]+ (B|kB)\); scene: 1 of 3 layers in, shown once 2 are/);
    assert.match(text, /Gaussians: \d+ \(preview\)/);
    assert.ok(await page.evaluate(LIT_SHARE) > 0, 'the preview is drawn');
    // sample every frame from here on, to 30 frames after the end (the preview is destroyed once
    // a frame without it is drawn), then let the rest of the file come
    await page.evaluate(`(() => {
      window.__lit = [];
      let after = 30;
      const sample = () => {
        window.__lit.push(${LIT_SHARE});
        if (window.spcViewer.status === 'loading' || --after > 0) requestAnimationFrame(sample);
        else window.__sampled = true;
      };
      requestAnimationFrame(sample);
    })()`);
    server.release();
    await page.waitForFunction(() => window.__sampled === true, null, { timeout: 120000 });
    const end = await viewerState(page);
    assert.equal(end.status, 'complete', JSON.stringify(end.error));
    assert.equal(end.showing, 'scene');
    assert.equal(end.layersShown, 3);
    assert.equal(end.preview.droppedAtLayer, 1);
    assert.ok(end.events.every((e) => e.tShown != null && e.tShown >= end.preview.tDropped), 'held layers shown at the swap');
    const after = await hud(page);
    assert.doesNotMatch(after, /showing: preview/);
    assert.match(after, /layers shown: 3 of 3/);
    assert.match(after, /replaced by the scene at layer 1/);
    const lit = await page.evaluate(() => window.__lit);
    assert.ok(lit.length > 0);
    assert.deepEqual(lit.filter((share) => share === 0), [], `a blank frame among ${lit.length}: ${lit}`);
    assert.ok(await page.evaluate(LIT_SHARE) > 0, 'the scene is drawn');
    // the benchmark's frame per step: the preview, then the layer that replaced it, then the rest
    const pictures = await page.evaluate(() => window.spcViewerLayerPictures.map((p) =>
      ({ layer: p.layer, layersInPicture: p.layersInPicture })));
    assert.deepEqual(pictures.map((p) => p.layer), ['preview', 1, 2]);
    assert.equal(pictures[0].layersInPicture, 0);
    assert.ok(pictures[1].layersInPicture >= 2);
    await page.close();
  } finally {
    await browser.close();
    server.close();
  }
});

test('a preview that does not decode is noted, and preview=0 ignores one; the layers show', { skip: missing() ?? false, timeout: 180000 }, async () => {
  const { launchChromium } = await import('./browser.mjs');
  const broken = sceneFile((parts) => {
    const section = parts.sections.find((s) => s.type === 0x0002);
    section.stored = section.stored.slice();
    section.stored[2] = 1;  // its reserved field (the CRC is recomputed)
  });
  const server = await serve({ 'broken.spc': broken, 'good.spc': sceneFile() });
  const browser = await launchChromium();
  try {
    for (const [name, extra] of [['broken.spc', ''], ['good.spc', '&preview=0']]) {
      const page = await open(browser, server.base, name, extra);
      await page.waitForFunction(() => window.spcViewer.status !== 'loading' && window.spcViewer.status !== 'starting',
        null, { timeout: 120000 });
      const s = await viewerState(page);
      assert.equal(s.status, 'complete', `${name}: ${JSON.stringify(s.error)}`);
      assert.equal(s.showing, 'scene');
      assert.equal(s.preview, null);
      assert.equal(s.layersShown, 3);
      assert.equal(s.layersInFirstPicture >= 1, true);
      if (name === 'broken.spc') {
        assert.equal(s.previewError.code, 'reserved-nonzero');
        assert.match(await hud(page), /preview not shown: .*\[reserved-nonzero\]/);
      } else {
        assert.equal(s.previewError, null);
      }
      await page.close();
    }
  } finally {
    await browser.close();
    server.close();
  }
});
