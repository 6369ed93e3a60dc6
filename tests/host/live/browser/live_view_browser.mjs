// Drives Debian's Chromium (playwright-core, no browser download) against a running
// storetrack-host --live page: waits until every camera of the scene has drawn a snapshot, then
// reads what the page DISPLAYS (per camera: marks drawn, the exposure's sequence; the latest
// sample's cells) several times while the host runs, and keeps a screenshot per camera.
// Usage: node live_view_browser.mjs URL OUT_DIR READS [CHROMIUM]
// Writes OUT_DIR/page_reads.json; check_live_view.py compares it with the host's outputs.
import { chromium } from 'playwright-core';
import fs from 'node:fs';
import path from 'node:path';

const [url, outDir, readsArg, executable = '/usr/bin/chromium'] = process.argv.slice(2);
const reads = Number(readsArg || 10);
fs.mkdirSync(outDir, { recursive: true });

const browser = await chromium.launch({
  executablePath: executable,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
const result = { url, scene: null, reads: [], console_errors: [], events: 0 };
try {
  const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
  page.on('console', (m) => { if (m.type() === 'error') result.console_errors.push(m.text()); });
  page.on('pageerror', (e) => result.console_errors.push(String(e)));
  await page.goto(url, { waitUntil: 'load', timeout: 15000 });
  result.scene = await page.evaluate(() => fetch('/api/scene').then((r) => r.json()));
  const cameraIds = result.scene.cameras.map((c) => c.camera_id);
  // Every camera canvas exists and has drawn an exposure it was in.
  await page.waitForFunction((ids) => ids.every((id) => {
    const c = document.getElementById('camera-' + id);
    return c && c.dataset.triggerSeq;
  }), cameraIds, { timeout: 30000 });

  // One read is one synchronous evaluation: all its values come from the same rendered snapshot.
  const readPage = () => page.evaluate(() => {
    const text = (id) => { const e = document.getElementById(id); return e ? e.textContent : null; };
    const cameras = [...document.querySelectorAll('canvas[data-camera-id]')].map((c) => ({
      camera_id: Number(c.dataset.cameraId), marks_drawn: Number(c.dataset.marksDrawn),
      mark_count: Number(c.dataset.markCount), trigger_seq: c.dataset.triggerSeq,
      coverage_outlines: Number(c.dataset.coverageOutlines || 0) }));
    const sample = {};
    for (const k of ['trigger_seq', 'x', 'y', 'z', 'yaw', 'pitch', 'roll',
                     'U_x', 'U_y', 'U_z', 'U_yaw', 'U_pitch', 'U_roll'])
      sample[k] = text('sample-' + k);
    return { t_ms: performance.now(), publication: Number(document.body.dataset.publication), cameras, sample,
             events: window.storetrackLive.events, connection: text('connection') };
  });
  for (let i = 0; i < reads; ++i) {
    result.reads.push(await readPage());
    if (i === Math.floor(reads / 2)) {
      for (const id of cameraIds) {
        await page.locator('#camera-box-' + id).screenshot({ path: path.join(outDir, `camera-${id}.png`) });
      }
      await page.screenshot({ path: path.join(outDir, 'page.png'), fullPage: true });
    }
    await page.waitForTimeout(250);
  }
  result.events = result.reads[result.reads.length - 1].events;
} finally {
  await browser.close();
  fs.writeFileSync(path.join(outDir, 'page_reads.json'), JSON.stringify(result, null, 1));
}
