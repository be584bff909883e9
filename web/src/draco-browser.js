// Draco in a browser, for the decoder (src/draco.js takes a factory via configureDraco).

const NODE_MODULES = '/node_modules/';

/**
 * Where the draco3d package's files are served, worked out from the URL of this module alone (no
 * request: probing with fetch logged a 404 on every page for the layout that was not the one).
 * Installed from npm (`.../node_modules/spcodec/src/draco-browser.js`, pnpm's
 * `.../node_modules/.pnpm/spcodec@x/node_modules/spcodec/src/...` too), draco3d is a sibling
 * package in the same node_modules folder; in this repository (`web/src/`), it is in
 * `web/node_modules/`.
 * @param {string|URL} [moduleUrl]  the URL of this module (default: its own)
 * @returns {URL} the draco3d package's folder, ending in a slash
 */
export function dracoFolder(moduleUrl = import.meta.url) {
  const url = new URL(moduleUrl);
  const at = url.pathname.lastIndexOf(NODE_MODULES);
  if (at >= 0) return new URL(`${url.pathname.slice(0, at + NODE_MODULES.length)}draco3d/`, url);
  return new URL('../node_modules/draco3d/', url);
}

/**
 * A factory for `configureDraco` that works in a browser. The draco3d package ships only its node
 * build, an Emscripten script that also runs in a browser as a classic script (it defines
 * `DracoDecoderModule`); the module is created the first time a layer holds a Draco blob.
 * @param {string|URL} [base]  the URL of the draco3d package's folder (default: beside this
 *   package, see {@link dracoFolder}; pass it where a bundler or server puts draco3d elsewhere)
 * @returns {() => Promise<any>}
 */
export function browserDraco(base) {
  return async () => {
    const folder = base ? new URL(base, location.href) : dracoFolder();
    if (!window.DracoDecoderModule) await loadScript(new URL('draco_decoder_nodejs.js', folder));
    const wasm = await fetch(new URL('draco_decoder.wasm', folder));
    if (!wasm.ok) {
      throw new Error(`cannot load the Draco decoder from ${folder.href} (HTTP ${wasm.status}): ` +
        'pass the draco3d package\'s URL to browserDraco(url)');
    }
    return window.DracoDecoderModule({ wasmBinary: await wasm.arrayBuffer() });
  };
}

/** Run a classic script (the Emscripten build defines a global, it is not a module). */
function loadScript(url) {
  return new Promise((resolve, reject) => {
    const script = document.createElement('script');
    script.src = url.href;
    script.onload = resolve;
    script.onerror = () => reject(new Error(`cannot load the Draco decoder script ${url.href}: ` +
      'pass the draco3d package\'s URL to browserDraco(url)'));
    document.head.appendChild(script);
  });
}
