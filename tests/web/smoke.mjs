// Opens the built site in headless Chromium, waits for the explorer to load its bundle,
// takes a screenshot, and fails on a panic, a page error, or a blank canvas.
//
//   node tests/web/smoke.mjs URL SCREENSHOT.png [--live-seconds N] [--webgpu]
//
// With --live-seconds N it also opens a condition that is not precomputed (16x16 vision
// plus proprioception with the executive module ablated) and waits up to N seconds for the live run's speed in the console,
// then branches that run at step 20 without vision and waits as long for the branch's speed.
// It also checks that the first view came before the whole bundle (progressive load) and
// that the findings' figures are served.
// It also drives the robot from the address (`drive=`) in the worker and waits for the
// episode's outcome and the worker's speed.
// With --webgpu it also opens the site in a browser with WebGPU and checks that the worker
// takes it when asked (`?compute=webgpu`), and that eframe's wgpu renderer draws the page
// when asked (`?render=wgpu`).
import { createRequire } from 'node:module';
import { inflateSync } from 'node:zlib';
import { readFileSync, writeFileSync } from 'node:fs';

// playwright-core is installed with the web tools (web/package.json).
const require = createRequire(new URL('../../web/', import.meta.url));
const { chromium } = require('playwright-core');

const [url, out, ...rest] = process.argv.slice(2);
const liveAt = rest.indexOf('--live-seconds');
const liveSeconds = liveAt >= 0 ? Number(rest[liveAt + 1]) : 0;
const webgpu = rest.includes('--webgpu');
if (!url || !out) {
  console.error('usage: node tests/web/smoke.mjs URL SCREENSHOT.png [--live-seconds N] [--webgpu]');
  process.exit(2);
}

/** Decodes an 8-bit RGB(A) PNG into {width, height, channels, pixels}. */
function decodePng(buf) {
  let pos = 8, width = 0, height = 0, channels = 0;
  const idat = [];
  while (pos < buf.length) {
    const len = buf.readUInt32BE(pos);
    const type = buf.toString('ascii', pos + 4, pos + 8);
    const data = buf.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      channels = { 2: 3, 6: 4 }[data[9]];
      if (data[8] !== 8 || !channels) throw new Error('unsupported PNG');
    } else if (type === 'IDAT') idat.push(data);
    pos += 12 + len;
  }
  const raw = inflateSync(Buffer.concat(idat));
  const stride = width * channels;
  const pixels = Buffer.alloc(height * stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    for (let x = 0; x < stride; x++) {
      const v = raw[y * (stride + 1) + 1 + x];
      const a = x >= channels ? pixels[y * stride + x - channels] : 0;
      const b = y > 0 ? pixels[(y - 1) * stride + x] : 0;
      const c = x >= channels && y > 0 ? pixels[(y - 1) * stride + x - channels] : 0;
      let p;
      switch (filter) {
        case 0: p = v; break;
        case 1: p = v + a; break;
        case 2: p = v + b; break;
        case 3: p = v + ((a + b) >> 1); break;
        case 4: {
          const pa = Math.abs(b - c), pb = Math.abs(a - c), pc = Math.abs(a + b - 2 * c);
          p = v + (pa <= pb && pa <= pc ? a : pb <= pc ? b : c);
          break;
        }
        default: throw new Error('bad PNG filter');
      }
      pixels[y * stride + x] = p & 255;
    }
  }
  return { width, height, channels, pixels };
}

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
         '--disable-component-update', '--disable-sync', '--enable-unsafe-swiftshader'],
});
let failed = false;
const fail = (msg) => { console.error(`FAIL: ${msg}`); failed = true; };

// A new page of `b` that records its console, at the site's URL with `query` added and
// its `#` dropped (no query: the URL as given).
async function openPage(b, query) {
  const page = await b.newPage({ viewport: { width: 1440, height: 920 } });
  const logs = [];
  page.on('console', (m) => logs.push(m.text()));
  page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
  const base = url.split('#')[0];
  const started = Date.now();
  await page.goto(query ? `${base}${base.includes('?') ? '&' : '?'}${query}` : url);
  return { page, logs, started };
}

// The first console line containing `needle` within `ms` (undefined if none, or at once
// after a panic or page error).
async function waitForLog(page, logs, needle, ms = 60_000) {
  const until = Date.now() + ms;
  let line;
  while (!(line = logs.find((l) => l.includes(needle))) && Date.now() < until) {
    if (logs.some((l) => /panicked|pageerror/.test(l))) break;
    await page.waitForTimeout(100);
  }
  return line;
}
try {
  const { page, logs, started } = await openPage(browser);
  const ready = await waitForLog(page, logs, 'bundle ready');
  if (ready) console.log(`ready: ${ready} (${Date.now() - started} ms after navigation, wall clock)`);
  else fail('the bundle never finished loading');
  // Progressive: the first view's files (model, one sequence, the standard runs) are in,
  // and shown, before the rest.
  const first = logs.findIndex((l) => l.includes("first view's files in"));
  if (first < 0) fail('the first view did not come before the whole bundle');
  else if (first > logs.findIndex((l) => l.includes('bundle ready'))) fail('the first view came after the whole bundle');
  else console.log(`first view: ${logs[first]}`);
  // The findings panel's figures are served beside the site.
  for (const figure of ['findings/converged/robustness/report/robustness.png', 'findings/interference/report/interference_wiping.png']) {
    const response = await page.request.get(new URL(figure, url).href);
    if (!response.ok()) fail(`${figure}: HTTP ${response.status()}`);
  }
  await page.waitForTimeout(2500);
  const shot = await page.screenshot();
  writeFileSync(out, shot);
  const png = decodePng(shot);
  const colours = new Set();
  let sum = 0, sum2 = 0;
  for (let i = 0; i < png.pixels.length; i += png.channels) {
    const l = 0.299 * png.pixels[i] + 0.587 * png.pixels[i + 1] + 0.114 * png.pixels[i + 2];
    sum += l; sum2 += l * l;
    if (colours.size < 5000) colours.add((png.pixels[i] << 16) | (png.pixels[i + 1] << 8) | png.pixels[i + 2]);
  }
  const n = png.pixels.length / png.channels;
  const std = Math.sqrt(sum2 / n - (sum / n) ** 2);
  console.log(`screenshot ${out}: ${png.width}x${png.height}, ${colours.size}${colours.size >= 5000 ? '+' : ''} colours, brightness std ${std.toFixed(1)}`);
  if (colours.size < 50 || std < 5) fail('the canvas is blank');
  // By default the page draws with WebGL (glow).
  const drawing = logs.find((l) => l.includes('page: drawing:'));
  console.log(`renderer: ${drawing ?? 'the page never said what draws it'}`);
  if (!drawing?.includes('glow')) fail(`by default the page should draw with glow: ${drawing}`);

  if (liveSeconds > 0) {
    await page.evaluate(() => { location.hash = 'vision=1&proprio=1&ablate=1000&maps=0&t=0'; });
    const until = Date.now() + liveSeconds * 1000;
    let live;
    while (!(live = logs.find((l) => l.includes('computed live'))) && Date.now() < until) await page.waitForTimeout(500);
    const liveShot = out.replace(/\.png$/, '') + '-live.png';
    writeFileSync(liveShot, await page.screenshot());
    if (live) console.log(`live: ${live} (screenshot ${liveShot})`);
    else fail(`no live run finished within ${liveSeconds} s (screenshot ${liveShot})`);
    // Chromium runs module workers: live runs must be computed beside the page, not in it.
    const inPage = logs.find((l) => l.includes('computing in the page'));
    if (inPage) fail(`the inference worker did not work: ${inPage}`);
    // Branch the live run at step 20 without vision: the worker knows the run's states, so
    // only the steps from 20 on are computed; its speed is the branch's live speed.
    await page.evaluate(() => { location.hash = 'vision=1&proprio=1&ablate=1000&maps=0&t=20&branch=20&b.vision=0&b.proprio=1&b.ablate=1000'; });
    const branchUntil = Date.now() + liveSeconds * 1000;
    let branch;
    while (!(branch = logs.find((l) => l.includes('branch of run'))) && Date.now() < branchUntil) await page.waitForTimeout(500);
    if (branch) console.log(`branch: ${branch}`);
    else fail(`no branch finished within ${liveSeconds} s`);
  }
  // Every finding's link (crates/pvrnn-explorer/src/findings.rs) lands on a view the page
  // shows as it is: the status line corrects nothing and reports no error.
  const findings = readFileSync(new URL('../../crates/pvrnn-explorer/src/findings.rs', import.meta.url), 'utf8');
  const views = [...findings.matchAll(/view: Some\("([^"]+)"\)/g)].map((m) => m[1]);
  if (views.length < 5) fail(`only ${views.length} findings' views found in findings.rs`);
  for (const view of views) {
    const before = logs.length;
    await page.evaluate((h) => { location.hash = h; }, view);
    await page.waitForTimeout(1500);
    const said = logs.slice(before).filter((l) => l.startsWith('status'));
    const wrong = said.find((l) => /ignored|no sequence|past the sequence|status \(error\)/.test(l));
    if (wrong) fail(`finding link #${view}: ${wrong}`);
  }
  console.log(`findings' links: ${views.length} views opened without a correction`);
  // A second network from the address: `second=` names a bundle relative to the site (the
  // shipped one again here); it downloads and opens beside the first.
  {
    const before = logs.length;
    await page.evaluate(() => { location.hash = 'second=models%2Fdefault%2F'; });
    const until = Date.now() + 90_000;
    let opened;
    while (!(opened = logs.slice(before).find((l) => l.startsWith('status: second network:'))) && Date.now() < until) {
      const error = logs.slice(before).find((l) => l.startsWith('status (error)'));
      if (error) { fail(`second=models/default/: ${error}`); break; }
      await page.waitForTimeout(250);
    }
    if (opened) console.log(`second network from the address: ${opened}`);
    else fail('second=models/default/: the second network did not open within 90 s');
  }
  for (const l of logs) if (/panicked|pageerror/.test(l)) fail(`console: ${l}`);
  await page.close();
  // A drive from the address, on a page of its own (nothing else computing): the shipped
  // network drives caresim's robot in the worker (16x16 + proprioception observed, an arm
  // pushed, the vision dropped) and the episode opens as a sequence.
  {
    const { page: drivePage, logs: driveLogs } = await openPage(browser);
    await waitForLog(drivePage, driveLogs, 'bundle ready');
    const started = Date.now();
    await drivePage.evaluate(() => {
      // Pushed at step 40 and blind from step 100: the worker replays both from the address.
      location.hash = 'drive=repositioning%3A650%3A0%3A1%3Anetwork%3Bpush%3D40%3Aleft%3A0.2%3Bvision%3D100%3A0&vision=1&proprio=1&maps=0';
    });
    const done = await waitForLog(drivePage, driveLogs, 'status: repositioning: ', 400_000);
    const driveShot = out.replace(/\.png$/, '') + '-drive.png';
    writeFileSync(driveShot, await drivePage.screenshot());
    const error = driveLogs.find((l) => l.startsWith('status (error)'));
    if (error) fail(`drive from the address: ${error}`);
    else if (done) console.log(`drive from the address in ${((Date.now() - started) / 1000).toFixed(0)} s: ${done} (screenshot ${driveShot})`);
    else fail(`drive from the address: no episode finished within 400 s (screenshot ${driveShot})`);
    // Stepped in the worker, not the page: the page says how fast the worker drove.
    const inWorker = driveLogs.find((l) => l.includes('drive: the worker drove'));
    if (inWorker) console.log(inWorker);
    else if (done) fail('the episode was not driven in the worker');
    // The main panels followed the episode while it ran (the worker sent it so far).
    const followed = Number(/the episode so far arrived (\d+) times/.exec(inWorker ?? '')?.[1] ?? 0);
    if (inWorker && followed < 2) fail(`the driven episode so far arrived ${followed} times for the main panels: not live`);
    // Once: the finished episode is open, so the address does not start it again.
    await drivePage.waitForTimeout(3000);
    const sent = driveLogs.filter((l) => l.includes('sent to the worker')).length;
    if (done && sent !== 1) fail(`the address's episode was sent to the worker ${sent} times, not once`);
    for (const l of driveLogs) if (/panicked|pageerror/.test(l)) fail(`console (drive): ${l}`);
    await drivePage.close();
  }

  // `?render=wgpu` in a browser without WebGPU (this one) falls back to WebGL.
  const { page: fallback, logs: fallbackLogs } = await openPage(browser, 'render=wgpu');
  await waitForLog(fallback, fallbackLogs, 'bundle ready');
  const fellBack = fallbackLogs.find((l) => l.includes('page: drawing:'));
  console.log(`?render=wgpu without WebGPU: ${fellBack ?? 'the page never said what draws it'}`);
  if (!fellBack?.includes('glow')) fail(`?render=wgpu without WebGPU should fall back to glow: ${fellBack}`);
  if (!fallbackLogs.some((l) => l.includes('bundle ready'))) fail('?render=wgpu without WebGPU: the bundle never finished loading');
  for (const l of fallbackLogs) if (/panicked|pageerror/.test(l)) fail(`console (?render=wgpu without WebGPU): ${l}`);
} finally {
  await browser.close();
}

// WebGPU in the worker: a browser with WebGPU (headless Chromium: SwiftShader's adapter,
// with --enable-unsafe-webgpu) and `?compute=webgpu` must take it; `auto` (the default) says
// what it chose. Agreement with the CPU is crates/pvrnn-wgpu/tests/webgpu.rs.
if (webgpu) {
  const gpuBrowser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--enable-unsafe-webgpu', '--disable-quic', '--no-first-run',
           '--disable-background-networking', '--disable-component-update', '--disable-sync',
           '--enable-unsafe-swiftshader'],
  });
  try {
    for (const preference of ['webgpu', 'auto']) {
      const { page, logs } = await openPage(gpuBrowser, `compute=${preference}`);
      const chosen = await waitForLog(page, logs, 'live runs compute on');
      console.log(`?compute=${preference}: ${chosen ?? 'the worker never said where it computes'}`);
      if (!chosen) fail(`?compute=${preference}: the worker never said where it computes`);
      else if (preference === 'webgpu' && !chosen.includes('WebGPU')) fail(`?compute=${preference} did not take WebGPU: ${chosen}`);
      for (const l of logs) if (/panicked|pageerror|validation error|uncaptured|wgpu error/i.test(l)) fail(`console (?compute=${preference}): ${l}`);
      await page.close();
    }
    // eframe's wgpu renderer on WebGPU (`?render=wgpu`): the page must draw with it and load
    // the bundle without an error. Headless Chromium leaves a WebGPU canvas out of its
    // screenshots (and `drawImage` reads it as transparent), so the wgpu renderer's pixels
    // are checked natively instead (scripts/test.sh: the desktop app with --renderer wgpu).
    {
      const { page, logs, started } = await openPage(gpuBrowser, 'render=wgpu');
      const ready = await waitForLog(page, logs, 'bundle ready');
      const drawing = logs.find((l) => l.includes('page: drawing:'));
      console.log(`?render=wgpu: ${drawing ?? 'the page never said what draws it'}; ${ready ?? 'the bundle never finished loading'} (${Date.now() - started} ms after navigation, wall clock)`);
      if (!ready) fail('?render=wgpu: the bundle never finished loading');
      if (!drawing?.includes('wgpu')) fail(`?render=wgpu should draw with wgpu: ${drawing}`);
      // A few seconds of frames (the view's plots and images) for wgpu to report errors in.
      await page.waitForTimeout(2500);
      for (const l of logs) {
        if (/panicked|pageerror|validation error|uncaptured|wgpu error/i.test(l)) fail(`console (?render=wgpu): ${l}`);
      }
      await page.close();
    }
  } finally {
    await gpuBrowser.close();
  }
}
process.exit(failed ? 1 : 0);
