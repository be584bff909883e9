// Draco in the browser for the decoder (web/src/draco.js takes a factory via configureDraco).

/** The draco3d package ships only its node build, an Emscripten script that also runs in a
 * browser as a classic script (it defines `DracoDecoderModule`); the decoder creates the module
 * through this factory the first time a layer holds a Draco blob. */
export function browserDraco() {
  const base = new URL('../../node_modules/draco3d/', import.meta.url);
  return async () => {
    if (!window.DracoDecoderModule) {
      await new Promise((resolve, reject) => {
        const script = document.createElement('script');
        script.src = new URL('draco_decoder_nodejs.js', base).href;
        script.onload = resolve;
        script.onerror = () => reject(new Error('cannot load the Draco decoder script'));
        document.head.appendChild(script);
      });
    }
    const wasm = await fetch(new URL('draco_decoder.wasm', base));
    if (!wasm.ok) throw new Error(`cannot load the Draco decoder (HTTP ${wasm.status})`);
    return window.DracoDecoderModule({ wasmBinary: await wasm.arrayBuffer() });
  };
}
