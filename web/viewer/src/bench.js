// Measurements in the browser for bench/bench_viewer.py: the JavaScript decoder's throughput, and
// an .spc against a PLY from request to a PlayCanvas resource that can be drawn.

import * as pc from 'playcanvas';
import { configureDraco, decode } from '../../src/index.js';
import { browserDraco } from '../../src/draco-browser.js';
import { createApp } from './engine.js';
import { toGSplatData } from '../../loaders/playcanvas.js';

configureDraco(browserDraco());
const app = await createApp(document.getElementById('scene'), 64, 64);

async function fetchBytes(url) {
  const response = await fetch(url, { cache: 'no-store' });
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return new Uint8Array(await response.arrayBuffer());
}

window.spcBench = {
  renderer: app.graphicsDevice.gl?.getParameter(app.graphicsDevice.gl.RENDERER) ?? null,

  /** Decode the whole file `repeat` times (after one warm-up); times in ms. */
  async decodeTimes(url, repeat) {
    const bytes = await fetchBytes(url);
    const warm = await decode(bytes);
    const times = [];
    for (let i = 0; i < repeat; i++) {
      const start = performance.now();
      await decode(bytes);
      times.push(performance.now() - start);
    }
    return { bytes: bytes.length, gaussians: warm.count, times };
  },

  /** Request, decode and hand an .spc to PlayCanvas (GSplatData, then a GPU resource); ms. */
  async spcToResource(url) {
    const start = performance.now();
    const bytes = await fetchBytes(url);
    const fetched = performance.now();
    const cloud = await decode(bytes);
    const decoded = performance.now();
    const data = toGSplatData(pc, cloud);
    const converted = performance.now();
    const resource = new pc.GSplatResource(app.graphicsDevice, data);
    const end = performance.now();
    resource.destroy();
    return { ms: end - start, fetchMs: fetched - start, decodeMs: decoded - fetched,
      convertMs: converted - decoded, resourceMs: end - converted, gaussians: cloud.count };
  },

  /** The same for a PLY through PlayCanvas's own PLY loader (it builds the same resource); ms. */
  async plyToResource(url) {
    const start = performance.now();
    const asset = new pc.Asset(`ply ${start}`, 'gsplat', { url });
    app.assets.add(asset);
    await new Promise((resolve, reject) => {
      asset.once('load', resolve);
      asset.once('error', (message) => reject(new Error(String(message))));
      app.assets.load(asset);
    });
    const ms = performance.now() - start;
    const gaussians = asset.resource.gsplatData.numSplats;
    app.assets.remove(asset);
    asset.unload();
    return { ms, gaussians };
  },
};
window.spcBenchReady = true;
