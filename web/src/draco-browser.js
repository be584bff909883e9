// Draco in a browser, for the decoder (src/draco.js takes a factory via configureDraco).

/** Where the draco3d package's files are served: beside this package in an app's node_modules
 * (node_modules/spcodec/src -> node_modules/draco3d), or in this repository's web/node_modules. */
function candidates() {
  return [new URL('../../draco3d/', import.meta.url), new URL('../node_modules/draco3d/', import.meta.url)];
}

/**
 * A factory for `configureDraco` that works in a browser. The draco3d package ships only its node
 * build, an Emscripten script that also runs in a browser as a classic script (it defines
 * `DracoDecoderModule`); the module is created the first time a layer holds a Draco blob.
 * @param {string|URL} [base]  the URL of the draco3d package's folder (default: found beside this
 *   package)
 * @returns {() => Promise<any>}
 */
export function browserDraco(base) {
  return async () => {
    const folder = base ? new URL(base, location.href) : await firstServed(candidates());
    if (!window.DracoDecoderModule) {
      await new Promise((resolve, reject) => {
        const script = document.createElement('script');
        script.src = new URL('draco_decoder_nodejs.js', folder).href;
        script.onload = resolve;
        script.onerror = () => reject(new Error('cannot load the Draco decoder script'));
        document.head.appendChild(script);
      });
    }
    const wasm = await fetch(new URL('draco_decoder.wasm', folder));
    if (!wasm.ok) throw new Error(`cannot load the Draco decoder (HTTP ${wasm.status})`);
    return window.DracoDecoderModule({ wasmBinary: await wasm.arrayBuffer() });
  };
}

async function firstServed(folders) {
  for (const folder of folders) {
    const probe = await fetch(new URL('package.json', folder), { method: 'HEAD' }).catch(() => null);
    if (probe?.ok) return folder;
  }
  throw new Error('cannot find the draco3d package: pass its URL to browserDraco(url)');
}
