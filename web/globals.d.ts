// Globals that browser-only modules read, declared for the type check (`npm run typecheck`,
// tsconfig.json) alone: nothing here is emitted or shipped.

/** draco3d's Emscripten build, which src/draco-browser.js runs as a classic script: it defines
 * this factory on the window. */
declare var DracoDecoderModule:
  ((options?: { wasmBinary?: ArrayBuffer }) => Promise<unknown>) | undefined;
