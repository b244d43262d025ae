// Real-browser test of `pofvr serve`: headless Debian chromium driven by playwright-core.
//
// Environment: as harness.mjs, and
//   POFVR_BENCH_VOLUME volume for the slider benchmark, default phantom:head:64
//   POFVR_BENCH_TF     its family JSON (phantoms have a built-in one)
//   POFVR_BENCH_ARGS   more `pofvr serve` flags, space-separated (e.g. raw --dims/--dtype)
//   POFVR_BENCH_REPS   slider moves per cull mode, default 3
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { writeFileSync } from 'node:fs';
import path from 'node:path';
import {
  artifacts, chromiumPath, FRAME_TIMEOUT, setup, startServer, openViewer, frameNow, nextFullFrame, setSlider,
} from './harness.mjs';

setup();

test('the viewer shows frames and reacts to sliders, culling and dragging', async () => {
  const url = await startServer('phantom:head:64');
  const { page, problems } = await openViewer(url);

  const first = await frameNow(page);
  assert.equal(first.width, 512, 'default frame is 512 wide');
  assert.equal(first.height, 512);
  assert.ok(first.lit > 1000, `the phantom is visible (${first.lit} lit pixels)`);
  const sliders = await page.locator('input.weight').count();
  assert.equal(sliders, 2, 'one slider per basis');
  assert.match(await page.locator('label:has(#weight-0)').innerText(), /skin/);
  assert.match(await page.locator('label:has(#weight-1)').innerText(), /bone/);
  assert.ok(await page.locator('#fig-culled').isVisible(), 'the culled count is shown');

  // The exact oracle needs no POF file, so the culled count can move with the weights.
  let seq = (await frameNow(page)).seq;
  await page.selectOption('#cull', 'exact');
  const exact = await nextFullFrame(page, seq);
  assert.equal(exact.stats.cull, 'exact');
  assert.equal(exact.culledText, String(exact.stats.bricks.culled));

  await setSlider(page, 'weight-0', 4);
  const heavy = await nextFullFrame(page, exact.seq);
  assert.notEqual(heavy.hash, exact.hash, 'moving the skin weight changes the frame');
  assert.notEqual(heavy.stats.bricks.culled, exact.stats.bricks.culled, 'and the culled count');
  assert.equal(heavy.culledText, String(heavy.stats.bricks.culled), 'the page shows the new count');

  // The overlay tints what was culled.
  await page.check('#overlay');
  const tinted = await nextFullFrame(page, heavy.seq);
  if (tinted.stats.bricks.culled > 0) assert.notEqual(tinted.hash, heavy.hash, 'the overlay changes the frame');

  // Dragging shows low-resolution frames, then a full one when the pointer is released.
  const box = await page.locator('#frame').boundingBox();
  const lowBefore = await page.evaluate(() => window.pofvr.lowFrames);
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  for (let i = 1; i <= 12; i++) {
    await page.mouse.move(box.x + box.width / 2 + i * 8, box.y + box.height / 2 + i * 2);
    await page.waitForTimeout(40);
  }
  await page.waitForFunction((n) => window.pofvr.lowFrames > n, lowBefore, { timeout: FRAME_TIMEOUT });
  const low = await page.evaluate(() => window.pofvr.lastLow);
  assert.equal(low.stats.width, 128, 'a dragging frame is a quarter of the side');
  await page.mouse.up();
  const settled = await nextFullFrame(page, tinted.seq);
  assert.equal(settled.width, 512);
  assert.notEqual(settled.hash, tinted.hash, 'orbiting changed the view');

  await page.screenshot({ path: path.join(artifacts, 'viewer.png') });
  assert.deepEqual(problems, [], 'no errors in the page');
  await page.close();
});

test('benchmark: slider change to new frame at 512², with and without culling', async () => {
  const volume = process.env.POFVR_BENCH_VOLUME || 'phantom:head:64';
  const extra = process.env.POFVR_BENCH_TF ? ['--tf', process.env.POFVR_BENCH_TF] : [];
  extra.push(...(process.env.POFVR_BENCH_ARGS || '').split(' ').filter((a) => a));
  const reps = Number(process.env.POFVR_BENCH_REPS || 3);
  const url = await startServer(volume, extra);
  const { page } = await openViewer(url);
  const report = { volume, args: extra, size: 512, reps, browser: chromiumPath, modes: {} };
  // With a POF file among the serve flags, POF culling is timed too.
  const modes = extra.includes('--pof') ? ['none', 'pof', 'exact'] : ['none', 'exact'];
  for (const mode of modes) {
    let seq = (await frameNow(page)).seq;
    await page.selectOption('#cull', mode);
    await nextFullFrame(page, seq);
    const runs = [];
    for (let i = 0; i < reps; i++) {
      // Alternate between two weights so every move asks for a different frame.
      const value = i % 2 === 0 ? 1.5 : 1.0;
      const r = await page.evaluate(
        async ({ value }) => {
          const el = document.getElementById('weight-0');
          const before = window.pofvr.requested;
          const shown = new Promise((resolve) => {
            window.addEventListener('pofvr:frame', function onFrame(e) {
              if (e.detail.seq > before && !e.detail.low) {
                window.removeEventListener('pofvr:frame', onFrame);
                // The next animation frame is when the new image is painted.
                requestAnimationFrame(() => resolve({ detail: e.detail, painted: performance.now() }));
              }
            });
          });
          const t0 = performance.now();
          el.value = String(value);
          el.dispatchEvent(new Event('input', { bubbles: true }));
          const { detail, painted } = await shown;
          const s = detail.stats;
          return {
            slider_to_load_ms: detail.shownAt - t0,
            slider_to_paint_ms: painted - t0,
            frame_ms: s.frame_ms,
            cull_ms: s.times.cull_ms,
            raycast_ms: s.times.raycast_ms,
            composite_ms: s.times.composite_ms,
            encode_ms: s.times.encode_ms,
            server_ms: s.times.server_ms,
            bricks: s.bricks,
          };
        },
        { value },
      );
      assert.equal(r.bricks.total > 0, true);
      runs.push(r);
    }
    const median = (k) => {
      const v = runs.map((r) => r[k]).sort((a, b) => a - b);
      return v[Math.floor(v.length / 2)];
    };
    report.modes[mode] = {
      median_slider_to_load_ms: median('slider_to_load_ms'),
      median_slider_to_paint_ms: median('slider_to_paint_ms'),
      median_frame_ms: median('frame_ms'),
      runs,
    };
  }
  const out = path.join(artifacts, 'bench-slider.json');
  writeFileSync(out, JSON.stringify(report, null, 2) + '\n');
  console.log(`slider benchmark (${volume}, 512²): ` +
    Object.entries(report.modes).map(([m, r]) => `${m} ${r.median_slider_to_paint_ms.toFixed(1)} ms`).join(', ') +
    ` → ${out}`);
  await page.close();
});
