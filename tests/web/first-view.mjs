// Times the site's first view with each of eframe's renderers: for each run, a fresh page
// of one headless Chromium with WebGPU (SwiftShader's adapter here) loads the site with
// `?render=glow` and then `?render=wgpu`, and the page's own "bundle ready after N ms" (from
// the start of the download to the bundle shown) and the wall clock from navigation are
// recorded. Prints each run and the median, min and max per renderer.
//
//   node tests/web/first-view.mjs URL [--runs N]
//
// A measurement, not a test: it fails only if a page never gets ready.
import { createRequire } from 'node:module';

const require = createRequire(new URL('../../web/', import.meta.url));
const { chromium } = require('playwright-core');

const [url, ...rest] = process.argv.slice(2);
const runsAt = rest.indexOf('--runs');
const runs = runsAt >= 0 ? Number(rest[runsAt + 1]) : 5;
if (!url || !(runs > 0)) {
  console.error('usage: node tests/web/first-view.mjs URL [--runs N]');
  process.exit(2);
}

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--enable-unsafe-webgpu', '--enable-unsafe-swiftshader', '--disable-quic',
         '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
const times = { glow: [], wgpu: [] };
let failed = false;
try {
  for (let run = 0; run < runs; run++) {
    for (const render of ['glow', 'wgpu']) {
      const page = await browser.newPage({ viewport: { width: 1440, height: 920 } });
      const logs = [];
      page.on('console', (m) => logs.push(m.text()));
      const base = url.split('#')[0];
      const started = Date.now();
      await page.goto(`${base}${base.includes('?') ? '&' : '?'}render=${render}`);
      let ready;
      while (!(ready = logs.find((l) => l.includes('bundle ready'))) && Date.now() - started < 60_000) {
        await page.waitForTimeout(20);
      }
      const wall = Date.now() - started;
      const drawing = logs.find((l) => l.includes('page: drawing:')) ?? 'renderer not reported';
      if (!ready) {
        console.log(`run ${run} ${render}: never ready (${drawing})`);
        failed = true;
      } else {
        const ms = Number(/after (\d+) ms/.exec(ready)[1]);
        times[render].push({ ms, wall });
        console.log(`run ${run} ${render}: bundle ready after ${ms} ms, ${wall} ms after navigation (${drawing})`);
      }
      await page.close();
    }
  }
} finally {
  await browser.close();
}
const median = (v) => { const s = [...v].sort((a, b) => a - b); return s[Math.floor((s.length - 1) / 2)]; };
for (const [render, t] of Object.entries(times)) {
  if (t.length === 0) continue;
  const walls = t.map((x) => x.wall);
  console.log(`${render}: ${t.length} runs, after navigation median ${median(walls)} ms (min ${Math.min(...walls)}, max ${Math.max(...walls)}); page's own: median ${median(t.map((x) => x.ms))} ms`);
}
process.exit(failed ? 1 : 0);
