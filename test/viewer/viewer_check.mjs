// Opens the rigidwarp viewer in headless Debian chromium and checks that it
// really draws: the scene renders (canvas not blank), the overlay shows the
// body count, scrubbing changes the frame (and the picture), and for a live
// source that GVT moves. Saves a screenshot.
// usage: node test/viewer/viewer_check.mjs URL EXPECTED_BODIES SCREENSHOT.png [live]
import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';
import path from 'node:path';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, '../../apps/rigidwarp/priv/viewer/package.json'));
const { chromium } = require('playwright-core');

const [url, expectedBodies, shot, mode] = process.argv.slice(2);
const fail = (msg) => { console.error(`viewer check FAILED: ${msg}`); process.exit(1); };

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--headless=new', '--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-background-networking',
         '--disable-component-update', '--disable-sync', '--use-gl=angle', '--use-angle=swiftshader',
         '--enable-unsafe-swiftshader'],
});
try {
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error' && !/status of 404/.test(m.text())) errors.push(m.text()); });
  page.on('response', (r) => { if (r.status() >= 400 && !r.url().endsWith('/favicon.ico')) errors.push(`${r.status()} ${r.url()}`); });
  await page.goto(url);
  await page.waitForFunction(() => window.rwViewer && window.rwViewer.ready, null, { timeout: 30000 })
    .catch(() => fail(`viewer never became ready; page errors: ${errors.join(' | ')}`));
  await page.waitForTimeout(500);

  // pixels of the WebGL canvas: how many differ from the background, and a digest
  const pixels = () => page.evaluate(() => {
    const gl = document.querySelector('#view canvas');
    const c = document.createElement('canvas');
    c.width = gl.width; c.height = gl.height;
    const g = c.getContext('2d');
    g.drawImage(gl, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let lit = 0, hash = 0;
    for (let i = 0; i < d.length; i += 4) {
      const bg = Math.abs(d[i] - 0x1d) + Math.abs(d[i + 1] - 0x21) + Math.abs(d[i + 2] - 0x26) < 6;
      if (!bg) lit++;
      hash = (hash * 31 + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) >>> 0;
    }
    return { lit: lit / (d.length / 4), hash };
  });

  const before = await pixels();
  if (before.lit < 0.02) fail(`canvas is blank (${(before.lit * 100).toFixed(2)}% non-background pixels)`);
  const bodiesText = await page.textContent('#bodies');
  if (bodiesText.trim() !== `bodies ${expectedBodies}`) fail(`overlay says "${bodiesText}", expected "bodies ${expectedBodies}"`);

  if (mode === 'live') {
    const gvt1 = await page.textContent('#gvt');
    await page.waitForTimeout(2500);
    const gvt2 = await page.textContent('#gvt');
    if (gvt1 === gvt2) fail(`live GVT did not move: "${gvt1}"`);
    console.log(`live: ${gvt1} -> ${gvt2}`);
  } else {
    // pause, scrub to the first frame, then to the last
    await page.click('#play');
    await page.$eval('#scrub', (s) => { s.value = '0'; s.dispatchEvent(new Event('input')); });
    await page.waitForTimeout(300);
    const t0 = await page.evaluate(() => window.rwViewer.frameTime);
    const first = await pixels();
    await page.$eval('#scrub', (s) => { s.value = s.max; s.dispatchEvent(new Event('input')); });
    await page.waitForTimeout(300);
    const t1 = await page.evaluate(() => window.rwViewer.frameTime);
    const last = await pixels();
    if (t0 === t1) fail(`scrubbing did not change the frame time (${t0})`);
    if (first.hash === last.hash) fail('scrubbing did not change the picture');
    console.log(`scrub: t ${t0} -> ${t1} ms, picture changed`);
  }
  if (errors.length) fail(`page errors: ${errors.join(' | ')}`);
  await page.screenshot({ path: shot });
  console.log(`viewer check ok: ${(before.lit * 100).toFixed(1)}% of the canvas drawn, screenshot ${shot}`);
} finally {
  await browser.close();
}
