#!/usr/bin/env node
// Drive the viewer page in headless Chromium and report what it showed.
//
//   node test/drive.mjs JOB.json      (or the job as JSON on stdin)
//
// A job is {"visits": [visit, ...]}; a visit is
//   {"url": "...", "width": 400, "height": 300, "timeoutMs": 120000,
//    "captures": [{"when": "firstPicture" | "complete" | "layers:K", "path": "shot.png"}, ...],
//    "waitFor": "optional JS expression: wait until it is true before anything else",
//    "evaluate": "optional JS expression whose value is reported once the last capture is taken"}
// Each capture waits until the page's `window.spcViewer` reaches the condition, saves the canvas
// as a PNG and keeps a copy of the page state at that moment. The report, one JSON object on
// stdout, has per visit: {captures: [{when, path, state}], state, value, console, error,
// failedRequests: [{url, status, error}]} (responses of status 400 or more, and requests that got
// no response: status null, and Chromium's reason, e.g. net::ERR_ABORTED for a cancelled body).
// The Python browser tests and bench/bench_viewer.py call this script; assertions live there.

import fs from 'node:fs';
import { launchChromium } from './browser.mjs';

const CONDITIONS = {
  firstPicture: (s) => s.tFirstPicture != null,
  complete: (s) => s.status === 'complete',
};

function condition(when) {
  if (CONDITIONS[when]) return CONDITIONS[when];
  const layers = /^layers:(\d+)$/.exec(when);
  if (layers) return (s) => s.layersShown >= Number(layers[1]);
  throw new Error(`unknown capture condition ${when}`);
}

async function visit(browser, spec) {
  const page = await browser.newPage({ viewport: { width: spec.width ?? 400, height: spec.height ?? 300 },
    deviceScaleFactor: 1 });
  const consoleLines = [];
  page.on('console', (m) => consoleLines.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => consoleLines.push(`pageerror: ${e.message}`));
  const failedRequests = [];
  page.on('response', (r) => {
    if (r.status() >= 400) failedRequests.push({ url: r.url(), status: r.status() });
  });
  page.on('requestfailed', (r) => failedRequests.push({ url: r.url(), status: null,
    error: r.failure()?.errorText ?? null }));
  const report = { url: spec.url, captures: [], console: consoleLines, error: null, failedRequests };
  const deadline = Date.now() + (spec.timeoutMs ?? 120000);
  try {
    await page.goto(spec.url);
    if (spec.waitFor) {
      await page.waitForFunction(spec.waitFor, null, { timeout: Math.max(1, deadline - Date.now()) });
    }
    for (const capture of spec.captures ?? []) {
      const test = condition(capture.when);
      let state;
      for (;;) {
        state = await page.evaluate(() => JSON.parse(JSON.stringify(window.spcViewer ?? null)));
        if (state && (state.status === 'error' || test(state))) break;
        if (Date.now() > deadline) throw new Error(`timed out waiting for ${capture.when}`);
        await page.waitForTimeout(20);
      }
      if (state.status === 'error') throw new Error(`page error: ${JSON.stringify(state.error)}`);
      if (capture.path) {
        // the canvas's own pixels (the page keeps its drawing buffer): exact, and much faster
        // than a screenshot through the compositor while the page renders continuously; for the
        // first picture, the copy the page took in the frame that showed it (capture=1)
        const url = await page.evaluate((when) => (when === 'firstPicture' && window.spcViewerFirstPicture) ||
          document.getElementById('scene').toDataURL('image/png'), capture.when);
        fs.writeFileSync(capture.path, Buffer.from(url.slice(url.indexOf(',') + 1), 'base64'));
      }
      report.captures.push({ when: capture.when, path: capture.path ?? null, state });
    }
    if (spec.evaluate) report.value = await page.evaluate(spec.evaluate);
  } catch (error) {
    report.error = error.message;
  }
  report.state = await page.evaluate(() => JSON.parse(JSON.stringify(window.spcViewer ?? null)))
    .catch(() => null);
  await page.close();
  return report;
}

const text = process.argv[2] ? fs.readFileSync(process.argv[2], 'utf8') : fs.readFileSync(0, 'utf8');
const job = JSON.parse(text);
const browser = await launchChromium();
try {
  const visits = [];
  for (const spec of job.visits) visits.push(await visit(browser, spec));
  process.stdout.write(`${JSON.stringify({ visits })}\n`);
} finally {
  await browser.close();
}
