// The PlayCanvas application the viewer (and its benchmark page) render with: WebGL 2, the camera,
// render and GSplat components, and the loaders for PLY (gsplat) and glTF (container) assets.

import * as pc from 'playcanvas';

/**
 * Start an application on `canvas`, at a fixed resolution when `width` and `height` are given,
 * else filling the window. The drawing buffer is kept so the canvas can be read back (tests).
 * @param {HTMLCanvasElement} canvas
 */
export async function createApp(canvas, width = 0, height = 0) {
  if (width && height) {
    canvas.style.width = `${width}px`;
    canvas.style.height = `${height}px`;
  }
  const device = await pc.createGraphicsDevice(canvas, {
    deviceTypes: [pc.DEVICETYPE_WEBGL2], antialias: false, preserveDrawingBuffer: true,
  });
  const options = new pc.AppOptions();
  options.graphicsDevice = device;
  options.componentSystems = [pc.CameraComponentSystem, pc.RenderComponentSystem, pc.GSplatComponentSystem];
  options.resourceHandlers = [pc.ContainerHandler, pc.GSplatHandler, pc.TextureHandler];
  const app = new pc.AppBase(canvas);
  app.init(options);
  if (width && height) {
    app.setCanvasFillMode(pc.FILLMODE_NONE, width, height);
    app.setCanvasResolution(pc.RESOLUTION_FIXED, width, height);
  } else {
    app.setCanvasFillMode(pc.FILLMODE_FILL_WINDOW);
    app.setCanvasResolution(pc.RESOLUTION_AUTO);
    window.addEventListener('resize', () => app.resizeCanvas());
  }
  app.start();
  return app;
}

/**
 * A function returning a promise that resolves once a frame including every change made before
 * the call is on screen: PlayCanvas's frame:ready with up-to-date sorting, at least one frame
 * later. Promises resolve in the order they were asked for.
 */
export function frameWatcher(app) {
  let frame = 0;
  const waiting = [];
  app.on('frameend', () => { frame++; });
  app.systems.gsplat.on('frame:ready', (camera, layer, ready, loadingCount) => {
    if (!ready || loadingCount) return;
    const due = waiting.filter((w) => frame > w.frame);
    due.forEach((w) => w.resolve());
    waiting.splice(0, waiting.length, ...waiting.filter((w) => frame <= w.frame));
  });
  return () => new Promise((resolve) => waiting.push({ frame, resolve }));
}
