// What the real-browser tests share: a `pofvr serve` per test, one headless chromium,
// and helpers that read the frame on screen.
//
// Environment:
//   POFVR_BIN          the pofvr binary (run.sh sets it)
//   CHROMIUM           browser binary, default /usr/bin/chromium
//   POFVR_ARTIFACTS    where the screenshot and the benchmark JSON go,
//                      default <repo>/target/browser-artifacts
import { before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { mkdtempSync, mkdirSync, rmSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { inflateSync } from 'node:zlib';
import { chromium } from 'playwright-core';

export const here = path.dirname(fileURLToPath(import.meta.url));
export const repo = path.resolve(here, '../../../..');
export const artifacts = process.env.POFVR_ARTIFACTS || path.join(repo, 'target/browser-artifacts');
export const bin = process.env.POFVR_BIN || path.join(process.env.CARGO_TARGET_DIR || path.join(repo, 'target'), 'release/pofvr');
export const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
export const FRAME_TIMEOUT = 60_000;

const servers = [];
let context;
let userDataDir;

/** Starts `pofvr serve VOLUME --port 0 ...` and resolves with the address it prints. */
export function startServer(volume, extra = []) {
  return new Promise((resolve, reject) => {
    const child = spawn(bin, ['serve', volume, '--port', '0', '--quiet', ...extra], {
      stdio: ['ignore', 'pipe', 'pipe'],
    });
    servers.push(child);
    let out = '';
    let err = '';
    const timer = setTimeout(() => reject(new Error(`no address from ${bin} within 120 s\n${err}`)), 120_000);
    child.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/listening on (http:\/\/\S+)/);
      if (m) {
        clearTimeout(timer);
        resolve(m[1]);
      }
    });
    child.stderr.on('data', (d) => {
      err += d;
    });
    child.on('exit', (code) => {
      clearTimeout(timer);
      reject(new Error(`${bin} exited with ${code}\n${err}`));
    });
  });
}

/** Registers the browser's start and the servers' and browser's end around the tests. */
export function setup() {
  before(async () => {
    assert.ok(existsSync(bin), `pofvr binary not found at ${bin} (set POFVR_BIN)`);
    mkdirSync(artifacts, { recursive: true });
    userDataDir = mkdtempSync(path.join(tmpdir(), 'pofvr-chromium-'));
    context = await chromium.launchPersistentContext(userDataDir, {
      executablePath: chromiumPath,
      headless: true,
      viewport: { width: 1280, height: 800 },
      args: [
        '--no-sandbox',
        '--disable-gpu',
        '--disable-background-networking',
        '--disable-component-update',
        '--no-first-run',
        '--disable-sync',
        // This machine's network is closed; QUIC probes would only log refusals.
        '--disable-quic',
      ],
    });
  });

  after(async () => {
    if (context) await context.close();
    for (const s of servers) s.kill();
    if (userDataDir) rmSync(userDataDir, { recursive: true, force: true });
  });
}

/** Opens the viewer and waits for its first full-resolution frame; `prepare(page)`, when
 * given, runs before the page loads (to route its requests). */
export async function openViewer(url, prepare) {
  const page = await context.newPage();
  if (prepare) await prepare(page);
  const problems = [];
  page.on('pageerror', (e) => problems.push(String(e)));
  page.on('console', (m) => {
    if (m.type() === 'error') problems.push(m.text());
  });
  await page.goto(url);
  await page.waitForFunction(() => window.pofvr && window.pofvr.frames >= 1, null, { timeout: FRAME_TIMEOUT });
  return { page, problems };
}

/** The frame on screen: its sequence number, figures, size and a hash of its pixels. */
export function frameNow(page) {
  return page.evaluate(() => {
    const img = document.getElementById('frame');
    const c = document.createElement('canvas');
    c.width = img.naturalWidth;
    c.height = img.naturalHeight;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const px = g.getImageData(0, 0, c.width, c.height).data;
    let h = 0x811c9dc5;
    let lit = 0;
    for (let i = 0; i < px.length; i++) {
      h = Math.imul(h ^ px[i], 0x01000193) >>> 0;
      if ((i & 3) === 3 && px[i] > 0) lit++;
    }
    return {
      seq: window.pofvr.shown,
      low: window.pofvr.last.low,
      stats: window.pofvr.last.stats,
      width: img.naturalWidth,
      height: img.naturalHeight,
      hash: h,
      lit,
      culledText: document.getElementById('fig-culled').textContent,
    };
  });
}

/** Waits for a full-resolution frame newer than every request made so far. */
export async function nextFullFrame(page, after) {
  await page.waitForFunction(
    (a) => window.pofvr.shown > a && !window.pofvr.last.low && window.pofvr.shown >= window.pofvr.requested,
    after,
    { timeout: FRAME_TIMEOUT },
  );
  return frameNow(page);
}

/** Moves a range input to `value` the way a user's drag ends: one `input` event. */
export async function setSlider(page, id, value) {
  await page.evaluate(
    ({ id, value }) => {
      const el = document.getElementById(id);
      el.value = String(value);
      el.dispatchEvent(new Event('input', { bubbles: true }));
    },
    { id, value },
  );
}


/**
 * Decodes an 8-bit RGBA, non-interlaced PNG (what pofvr writes) to its bytes, so that
 * images are compared as written, not as a canvas re-quantises them.
 */
export function decodePng(buf) {
  assert.equal(buf.subarray(1, 4).toString('latin1'), 'PNG', 'a PNG file');
  let at = 8;
  let width = 0;
  let height = 0;
  const idat = [];
  while (at < buf.length) {
    const len = buf.readUInt32BE(at);
    const type = buf.subarray(at + 4, at + 8).toString('latin1');
    const data = buf.subarray(at + 8, at + 8 + len);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      assert.deepEqual([data[8], data[9], data[12]], [8, 6, 0], '8-bit RGBA, not interlaced');
    } else if (type === 'IDAT') {
      idat.push(data);
    }
    at += 12 + len;
  }
  const raw = inflateSync(Buffer.concat(idat));
  const stride = width * 4;
  const rgba = Buffer.alloc(stride * height);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let x = 0; x < stride; x++) {
      const a = x >= 4 ? rgba[y * stride + x - 4] : 0;
      const b = y > 0 ? rgba[(y - 1) * stride + x] : 0;
      const c = x >= 4 && y > 0 ? rgba[(y - 1) * stride + x - 4] : 0;
      let v = line[x];
      if (filter === 1) v += a;
      else if (filter === 2) v += b;
      else if (filter === 3) v += (a + b) >> 1;
      else if (filter === 4) {
        const p = a + b - c;
        const pa = Math.abs(p - a);
        const pb = Math.abs(p - b);
        const pc = Math.abs(p - c);
        v += pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      }
      rgba[y * stride + x] = v & 0xff;
    }
  }
  return { width, height, rgba };
}
