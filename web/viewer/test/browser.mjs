// Launching the headless Chromium the browser tests use: Debian's `chromium` package (playwright's
// own browser download is not used), no network services of its own, and WebGL 2 through
// SwiftShader (a CPU implementation), which needs no GPU. Playwright gives every launch a fresh
// temporary profile folder (it refuses a --user-data-dir argument to launch()).

import { chromium } from 'playwright-core';

export const CHROMIUM = process.env.SPCODEC_CHROMIUM ?? '/usr/bin/chromium';

export const CHROMIUM_ARGS = [
  '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
];

/** A headless Chromium with a fresh profile. */
export async function launchChromium(extraArgs = []) {
  return chromium.launch({ executablePath: CHROMIUM, args: [...CHROMIUM_ARGS, ...extraArgs] });
}
