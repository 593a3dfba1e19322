// Takes a picture of the explorer at a given view (used for the README's screenshot):
//   node tests/web/shot.mjs 'URL#seq=...&t=120' OUT.png [SECONDS]
import { createRequire } from 'node:module';

const require = createRequire(new URL('../../web/', import.meta.url));
const { chromium } = require('playwright-core');
const [url, out, seconds = '20'] = process.argv.slice(2);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--disable-gpu', '--enable-unsafe-swiftshader'],
});
const page = await browser.newPage({ viewport: { width: 1440, height: 920 } });
page.on('console', (m) => console.log(m.text()));
await page.goto(url);
await page.waitForTimeout(Number(seconds) * 1000);
await page.screenshot({ path: out });
await browser.close();
