// Times one live run of the explorer in headless Chromium with WebGPU (SwiftShader's
// adapter here), for comparing where the worker computes:
//   node tests/web/live-run.mjs URL 'compute=webgpu' SECONDS SCREENSHOT.png
// It opens the page with that query, starts the smoke test's live condition (16x16 vision
// and proprioception, 50 updates per step) and waits up to SECONDS. It prints the run's
// "computed live" line if it finished; otherwise the screenshot's status bar shows the
// step it reached ("inference: step N/289").
import { createRequire } from 'node:module';
import { writeFileSync } from 'node:fs';

const require = createRequire(new URL('../../web/', import.meta.url));
const { chromium } = require('playwright-core');

const [url, query, seconds, shot] = process.argv.slice(2);
if (!url || query === undefined || !seconds || !shot) {
  console.error("usage: node tests/web/live-run.mjs URL 'QUERY' SECONDS SCREENSHOT.png");
  process.exit(2);
}
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--enable-unsafe-webgpu', '--disable-quic', '--no-first-run',
         '--enable-unsafe-swiftshader'],
});
let failed = false;
try {
  const page = await browser.newPage({ viewport: { width: 1440, height: 920 } });
  const logs = [];
  page.on('console', (m) => logs.push(m.text()));
  page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
  await page.goto(`${url.split('#')[0]}?${query}`);
  let until = Date.now() + 60_000;
  while (!logs.some((l) => l.includes('bundle ready')) && Date.now() < until) await page.waitForTimeout(200);
  await page.evaluate(() => { location.hash = 'vision=1&proprio=1&ablate=1000&maps=0&t=0'; });
  const started = Date.now();
  until = started + Number(seconds) * 1000;
  let live;
  while (!(live = logs.find((l) => l.includes('computed live'))) && Date.now() < until) await page.waitForTimeout(500);
  writeFileSync(shot, await page.screenshot());
  for (const l of logs) if (/live runs compute on/.test(l)) console.log(l);
  console.log(live ?? `not finished after ${((Date.now() - started) / 1000).toFixed(0)} s: the step reached is in ${shot}`);
  for (const l of logs) {
    if (/panicked|pageerror|validation error|uncaptured/i.test(l)) { console.error(`console: ${l}`); failed = true; }
  }
} finally {
  await browser.close();
}
process.exit(failed ? 1 : 0);
