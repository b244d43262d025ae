// pofvr transfer-function panel: the volume's histogram with each basis's opacity curve
// over it, the colour map as a gradient bar, undo, load and save.
//
// Every edit posts the whole family to /api/tf (one post in flight; the newest edit
// waits for it), and asks for a frame once the server has swapped it in, so the frame
// on screen always shows a family the server has. While a point is dragged the frames
// come at reduced size, as while orbiting. Tests read `window.pofvr.tf`.
'use strict';

(() => {
  const COLOURS = ['#ff6b6b', '#4dabf7', '#69db7c', '#ffd43b', '#da77f2', '#ff922b', '#38d9a9', '#f783ac'];
  const Y_SCALES = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1];
  const PAD = 8;
  const HIT_PX = 8;
  const HISTORY = 100;
  const PRESETS = {
    grayscale: [[0, 0, 0], [1, 1, 1]],
    bone: [[0, 0, 0], [0.33, 0.33, 0.45], [0.66, 0.78, 0.78], [1, 1, 1]],
    hot: [[0, 0, 0], [0.9, 0.1, 0], [1, 0.85, 0], [1, 1, 1]],
    'cool-warm': [[0.23, 0.3, 0.75], [0.87, 0.87, 0.87], [0.71, 0.02, 0.15]],
    viridis: [[0.27, 0, 0.33], [0.23, 0.32, 0.55], [0.13, 0.57, 0.55], [0.37, 0.79, 0.38], [0.99, 0.91, 0.14]],
  };

  const $ = (id) => document.getElementById(id);
  const curves = $('tf-curves');
  const bar = $('tf-colorbar');
  const gc = curves.getContext('2d');
  const gb = bar.getContext('2d');

  let family = null; // {bases: [{name, opacity: [[v, a]]}], weights, color: [[v, r, g, b]]}
  let hist = null; // {lo, hi, counts}
  let yMax = 1;
  let selBasis = 0;
  let selPoint = null; // {basis, index}
  let selStop = 0;
  let drag = null; // {kind: 'point'|'stop', basis, index}
  const undo = [];

  // What tests read.
  const tfApi = {
    version: 0, // family version of the newest answered post
    posts: 0, // posts answered 200
    rejected: 0, // posts answered 400
    pofs: 'none',
    lastEditAt: 0, // performance.now() of the newest edit
    busy: false, // a post in flight or waiting
    get family() { return family; },
    pointOnPage: (b, i) => pageXY(curves, xOf(family.bases[b].opacity[i][0]), yOf(family.bases[b].opacity[i][1])),
    stopOnPage: (i) => pageXY(bar, xOf(family.color[i][0]), bar.height - 6),
    saved: () => JSON.stringify(savedFamily(), null, 2) + '\n',
  };

  function message(text, ok = false) {
    const m = $('tf-message');
    m.textContent = text;
    m.className = ok ? 'ok' : '';
  }

  // ---- coordinates ----
  const span = () => Math.max(hist.hi - hist.lo, 1e-12);
  const xOf = (v) => PAD + ((v - hist.lo) / span()) * (curves.width - 2 * PAD);
  const vOf = (x) => hist.lo + ((x - PAD) / (curves.width - 2 * PAD)) * span();
  const yOf = (a) => curves.height - PAD - (a / yMax) * (curves.height - 2 * PAD);
  const aOf = (y) => ((curves.height - PAD - y) / (curves.height - 2 * PAD)) * yMax;
  const clamp = (x, lo, hi) => Math.max(lo, Math.min(hi, x));

  // Canvas pixels of a pointer event (the canvas is scaled by CSS).
  function canvasXY(c, e) {
    const r = c.getBoundingClientRect();
    return { x: (e.clientX - r.left) * (c.width / r.width), y: (e.clientY - r.top) * (c.height / r.height) };
  }

  function pageXY(c, x, y) {
    const r = c.getBoundingClientRect();
    return { x: r.left + x * (r.width / c.width), y: r.top + y * (r.height / c.height) };
  }

  function fitYScale() {
    let m = 0;
    for (const b of family.bases) for (const [, a] of b.opacity) m = Math.max(m, a);
    yMax = Y_SCALES.find((s) => s >= m * 1.25) || 1;
  }

  // ---- drawing ----
  function draw() {
    if (!family || !hist) return;
    const W = curves.width;
    const H = curves.height;
    gc.clearRect(0, 0, W, H);
    // Histogram, log scale: empty space dwarfs everything else in most volumes.
    const peak = Math.log1p(Math.max(...hist.counts, 1));
    const n = hist.counts.length;
    const bw = (W - 2 * PAD) / n;
    gc.fillStyle = '#3a3f48';
    hist.counts.forEach((c, i) => {
      const h = (Math.log1p(c) / peak) * (H - 2 * PAD);
      gc.fillRect(PAD + i * bw, H - PAD - h, Math.max(bw - 0.5, 0.5), h);
    });
    gc.fillStyle = '#7d838e';
    gc.font = '10px system-ui, sans-serif';
    gc.fillText(`α ${yMax}`, PAD + 2, PAD + 8);
    gc.fillText(fmtValue(hist.lo), PAD + 2, H - 1);
    const hiText = fmtValue(hist.hi);
    gc.fillText(hiText, W - PAD - gc.measureText(hiText).width, H - 1);
    // The selected basis last, so that it is on top.
    const order = family.bases.map((_, i) => i).filter((i) => i !== selBasis).concat([selBasis]);
    for (const bi of order) {
      const b = family.bases[bi];
      const col = COLOURS[bi % COLOURS.length];
      gc.strokeStyle = col;
      gc.lineWidth = bi === selBasis ? 2 : 1.25;
      gc.beginPath();
      // Clamped outside its points, as the renderer reads it.
      gc.moveTo(PAD, yOf(b.opacity[0][1]));
      for (const [v, a] of b.opacity) gc.lineTo(xOf(v), yOf(a));
      gc.lineTo(W - PAD, yOf(b.opacity[b.opacity.length - 1][1]));
      gc.stroke();
      b.opacity.forEach(([v, a], i) => {
        const chosen = selPoint && selPoint.basis === bi && selPoint.index === i;
        gc.fillStyle = chosen ? '#fff' : col;
        gc.beginPath();
        gc.arc(xOf(v), yOf(a), chosen ? 5 : 3.5, 0, 2 * Math.PI);
        gc.fill();
      });
    }
    drawBar();
  }

  function colourAt(v) {
    const c = family.color;
    if (v <= c[0][0]) return c[0].slice(1);
    for (let i = 1; i < c.length; i++) {
      if (v <= c[i][0]) {
        const t = c[i][0] > c[i - 1][0] ? (v - c[i - 1][0]) / (c[i][0] - c[i - 1][0]) : 1;
        return [1, 2, 3].map((k) => c[i - 1][k] + t * (c[i][k] - c[i - 1][k]));
      }
    }
    return c[c.length - 1].slice(1);
  }

  const css = (rgb) => `rgb(${rgb.map((x) => Math.round(255 * x)).join(',')})`;
  const hex = (rgb) => '#' + rgb.map((x) => Math.round(255 * clamp(x, 0, 1)).toString(16).padStart(2, '0')).join('');

  function drawBar() {
    const W = bar.width;
    const barH = bar.height - 12;
    gb.clearRect(0, 0, W, bar.height);
    for (let x = PAD; x < W - PAD; x++) {
      gb.fillStyle = css(colourAt(vOf(x + 0.5)));
      gb.fillRect(x, 0, 1, barH);
    }
    family.color.forEach((p, i) => {
      const x = xOf(p[0]);
      gb.fillStyle = css(p.slice(1));
      gb.strokeStyle = i === selStop ? '#fff' : '#8b919c';
      gb.lineWidth = i === selStop ? 2 : 1;
      gb.beginPath();
      gb.moveTo(x, barH);
      gb.lineTo(x - 5, bar.height - 1);
      gb.lineTo(x + 5, bar.height - 1);
      gb.closePath();
      gb.fill();
      gb.stroke();
    });
  }

  function fmtValue(v) {
    return Math.abs(v) >= 100 ? v.toFixed(0) : Number(v.toPrecision(3)).toString();
  }

  function showBases() {
    const sel = $('tf-basis');
    sel.replaceChildren(...family.bases.map((b, i) => {
      const o = document.createElement('option');
      o.value = String(i);
      o.textContent = b.name;
      o.style.color = COLOURS[i % COLOURS.length];
      return o;
    }));
    selBasis = Math.min(selBasis, family.bases.length - 1);
    sel.value = String(selBasis);
  }

  function showStopColour() {
    selStop = clamp(selStop, 0, family.color.length - 1);
    $('tf-stop-color').value = hex(family.color[selStop].slice(1));
  }

  function showPofs(state, rendersAs) {
    tfApi.pofs = state;
    const el = $('tf-pofs');
    el.className = 'pofs-' + state;
    el.textContent = {
      match: 'POFs match the family',
      stale: `POFs are for other bases: pof and pof-set cull as ${rendersAs || 'exact'}`,
      none: 'no POFs: pof and pof-set need a build',
    }[state];
    if (state !== 'none') {
      window.pofvr.view.setCullAvailable(['none', 'pof', 'pof-set', 'exact']);
      const note = $('culling-note');
      if (note.dataset.fallback !== '1') note.hidden = true;
    }
  }

  // ---- the server ----
  let inFlight = false;
  let queued = null; // {body, then}

  // Posts `body` (a family JSON text); the newest one waiting replaces older waiting ones.
  function post(body, then) {
    queued = { body, then };
    tfApi.busy = true;
    if (!inFlight) pump();
  }

  async function pump() {
    const job = queued;
    queued = null;
    if (!job) {
      tfApi.busy = false;
      return;
    }
    inFlight = true;
    let ok = false;
    try {
      const res = await fetch('/api/tf', {
        method: 'POST',
        headers: { 'Content-Type': 'application/json' },
        body: job.body,
        cache: 'no-store',
      });
      const text = await res.text();
      if (res.ok) {
        const a = JSON.parse(text);
        tfApi.version = a.version;
        tfApi.posts++;
        showPofs(a.pofs, a.pof_renders_as);
        ok = true;
      } else {
        tfApi.rejected++;
        message(`family refused (HTTP ${res.status}): ${text.trim()}`);
      }
    } catch (e) {
      tfApi.rejected++;
      message('could not post the family: ' + e.message);
    }
    inFlight = false;
    if (job.then) job.then(ok);
    pump();
  }

  // Posts the family as edited; the frame after comes at reduced size while dragging.
  function commit() {
    tfApi.lastEditAt = performance.now();
    const low = drag !== null;
    draw();
    post(JSON.stringify(family), (ok) => {
      if (!ok) return;
      message('', true);
      window.pofvr.view.requestFrame(low);
      if (low) window.pofvr.view.settleLater();
    });
  }

  function remember() {
    undo.push(JSON.stringify(family));
    if (undo.length > HISTORY) undo.shift();
    $('tf-undo').disabled = false;
  }

  function undoLast() {
    if (!undo.length) return;
    family = JSON.parse(undo.pop());
    $('tf-undo').disabled = undo.length === 0;
    selPoint = null;
    afterReplace();
    commit();
  }

  // After the family was replaced wholesale (undo, load): the bases may have changed.
  function afterReplace() {
    const v = window.pofvr.view;
    if (family.weights.length !== v.state.weights.length) {
      v.setBases(family.bases.map((b, i) => ({ name: b.name, weight: family.weights[i] })));
    }
    showBases();
    showStopColour();
    fitYScale();
    draw();
  }

  // The family as `pofvr render --tf` should read it: with the weights on the sliders.
  function savedFamily() {
    const w = window.pofvr.view.state.weights;
    return { ...family, weights: w.length === family.bases.length ? w.slice() : family.weights };
  }

  // ---- opacity curves ----
  function hitPoint(x, y) {
    let best = null;
    const order = [selBasis].concat(family.bases.map((_, i) => i).filter((i) => i !== selBasis));
    for (const bi of order) {
      family.bases[bi].opacity.forEach(([v, a], i) => {
        const d = Math.hypot(xOf(v) - x, yOf(a) - y);
        if (d <= HIT_PX && (!best || d < best.d - 0.5)) best = { basis: bi, index: i, d };
      });
    }
    return best;
  }

  function removePoint(p) {
    const pts = family.bases[p.basis].opacity;
    if (pts.length <= 1) {
      message('a basis keeps at least one point');
      return;
    }
    remember();
    pts.splice(p.index, 1);
    selPoint = null;
    commit();
  }

  function bindCurves() {
    curves.addEventListener('pointerdown', (e) => {
      if (e.button !== 0) return;
      const { x, y } = canvasXY(curves, e);
      const hit = hitPoint(x, y);
      if (!hit) return;
      selBasis = hit.basis;
      $('tf-basis').value = String(selBasis);
      selPoint = { basis: hit.basis, index: hit.index };
      remember();
      drag = { kind: 'point', ...selPoint };
      curves.setPointerCapture(e.pointerId);
      curves.focus();
      e.preventDefault();
      draw();
    });
    curves.addEventListener('pointermove', (e) => {
      if (!drag || drag.kind !== 'point') return;
      const { x, y } = canvasXY(curves, e);
      const pts = family.bases[drag.basis].opacity;
      const i = drag.index;
      // Points stay sorted: a point moves between its neighbours.
      const lo = i > 0 ? pts[i - 1][0] : Math.min(hist.lo, pts[i][0]);
      const hi = i + 1 < pts.length ? pts[i + 1][0] : Math.max(hist.hi, pts[i][0]);
      pts[i] = [clamp(vOf(x), lo, hi), clamp(aOf(y), 0, Math.min(1, yMax))];
      commit();
    });
    const end = () => {
      if (!drag || drag.kind !== 'point') return;
      drag = null;
      // Room above a point pushed to the top.
      if (family.bases.some((b) => b.opacity.some(([, a]) => a >= 0.95 * yMax)) && yMax < 1) fitYScale();
      commit();
    };
    curves.addEventListener('pointerup', end);
    curves.addEventListener('pointercancel', end);
    curves.addEventListener('dblclick', (e) => {
      const { x, y } = canvasXY(curves, e);
      if (hitPoint(x, y)) return;
      remember();
      const pts = family.bases[selBasis].opacity;
      const p = [vOf(x), clamp(aOf(y), 0, Math.min(1, yMax))];
      let at = pts.findIndex(([v]) => v > p[0]);
      if (at < 0) at = pts.length;
      pts.splice(at, 0, p);
      selPoint = { basis: selBasis, index: at };
      commit();
    });
    curves.addEventListener('contextmenu', (e) => {
      e.preventDefault();
      const { x, y } = canvasXY(curves, e);
      const hit = hitPoint(x, y);
      if (hit) removePoint(hit);
    });
    curves.addEventListener('keydown', (e) => {
      if ((e.key === 'Delete' || e.key === 'Backspace') && selPoint) {
        e.preventDefault();
        removePoint(selPoint);
      }
    });
    $('tf-basis').addEventListener('change', () => {
      selBasis = Number($('tf-basis').value);
      selPoint = null;
      draw();
    });
  }

  // ---- colour bar ----
  function hitStop(x) {
    let best = null;
    family.color.forEach((p, i) => {
      const d = Math.abs(xOf(p[0]) - x);
      if (d <= HIT_PX && (!best || d < best.d)) best = { index: i, d };
    });
    return best;
  }

  function bindBar() {
    bar.addEventListener('pointerdown', (e) => {
      if (e.button !== 0) return;
      const { x } = canvasXY(bar, e);
      const hit = hitStop(x);
      if (!hit) return;
      selStop = hit.index;
      showStopColour();
      remember();
      drag = { kind: 'stop', index: hit.index };
      bar.setPointerCapture(e.pointerId);
      e.preventDefault();
      drawBar();
    });
    bar.addEventListener('pointermove', (e) => {
      if (!drag || drag.kind !== 'stop') return;
      const { x } = canvasXY(bar, e);
      const c = family.color;
      const i = drag.index;
      const lo = i > 0 ? c[i - 1][0] : Math.min(hist.lo, c[i][0]);
      const hi = i + 1 < c.length ? c[i + 1][0] : Math.max(hist.hi, c[i][0]);
      c[i][0] = clamp(vOf(x), lo, hi);
      commit();
    });
    const end = () => {
      if (!drag || drag.kind !== 'stop') return;
      drag = null;
      commit();
    };
    bar.addEventListener('pointerup', end);
    bar.addEventListener('pointercancel', end);
    bar.addEventListener('dblclick', (e) => {
      const { x } = canvasXY(bar, e);
      if (hitStop(x)) return;
      remember();
      const v = vOf(x);
      const c = family.color;
      let at = c.findIndex(([w]) => w > v);
      if (at < 0) at = c.length;
      c.splice(at, 0, [v, ...colourAt(v)]);
      selStop = at;
      showStopColour();
      commit();
    });
    bar.addEventListener('contextmenu', (e) => {
      e.preventDefault();
      const hit = hitStop(canvasXY(bar, e).x);
      if (!hit) return;
      if (family.color.length <= 1) {
        message('the colour map keeps at least one stop');
        return;
      }
      remember();
      family.color.splice(hit.index, 1);
      showStopColour();
      commit();
    });
    $('tf-stop-color').addEventListener('input', () => {
      const h = $('tf-stop-color').value;
      const rgb = [1, 3, 5].map((k) => parseInt(h.slice(k, k + 2), 16) / 255);
      remember();
      family.color[selStop] = [family.color[selStop][0], ...rgb];
      commit();
    });
    $('tf-preset').addEventListener('change', () => {
      const stops = PRESETS[$('tf-preset').value];
      if (!stops) return;
      remember();
      family.color = stops.map((rgb, i) => [hist.lo + (span() * i) / (stops.length - 1), ...rgb]);
      $('tf-preset').value = '';
      showStopColour();
      commit();
    });
  }

  // ---- undo, load, save, rebuild ----
  function bindButtons() {
    $('tf-undo').addEventListener('click', undoLast);
    document.addEventListener('keydown', (e) => {
      const typing = e.target instanceof HTMLInputElement && e.target.type === 'text';
      if ((e.ctrlKey || e.metaKey) && !e.shiftKey && e.key.toLowerCase() === 'z' && !typing) {
        e.preventDefault();
        undoLast();
      }
    });
    $('tf-save').addEventListener('click', () => {
      const blob = new Blob([tfApi.saved()], { type: 'application/json' });
      const a = document.createElement('a');
      a.href = URL.createObjectURL(blob);
      a.download = 'family.json';
      document.body.append(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
    });
    $('tf-load').addEventListener('change', async () => {
      const file = $('tf-load').files[0];
      $('tf-load').value = '';
      if (!file) return;
      const text = await file.text();
      // The server checks it as `--tf` does; on a refusal the old family stays.
      post(text, async (ok) => {
        if (!ok) return;
        const res = await fetch('/api/tf', { cache: 'no-store' });
        remember();
        family = await res.json();
        const v = window.pofvr.view;
        v.setBases(family.bases.map((b, i) => ({ name: b.name, weight: family.weights[i] })));
        selPoint = null;
        afterReplace();
        message(`loaded ${file.name}`, true);
        v.requestFrame(false);
      });
    });
    $('tf-rebuild').addEventListener('click', rebuild);
  }

  async function rebuild() {
    const res = await fetch('/api/pofs/rebuild', { method: 'POST', headers: { 'Content-Type': 'application/json' } });
    if (!res.ok && res.status !== 409) {
      message(`rebuild refused (HTTP ${res.status}): ${(await res.text()).trim()}`);
      return;
    }
    $('tf-rebuild').disabled = true;
    const prog = $('tf-progress');
    prog.hidden = false;
    for (;;) {
      const r = await (await fetch('/api/pofs', { cache: 'no-store' })).json();
      const b = r.build;
      prog.max = Math.max(b.total, 1);
      prog.value = b.done;
      prog.title = `${b.done} of ${b.total} bricks`;
      if (!b.running) {
        prog.hidden = true;
        $('tf-rebuild').disabled = false;
        if (b.last.error) {
          message('POF build failed: ' + b.last.error);
        } else {
          message(`POFs rebuilt in ${b.last.seconds.toFixed(1)} s`, true);
        }
        // The build swapped in a scene of its own: frames from now on carry its version.
        tfApi.version = r.version;
        showPofs(r.state, r.pof_renders_as);
        window.pofvr.view.requestFrame(false);
        return;
      }
      await new Promise((done) => setTimeout(done, 250));
    }
  }

  async function start() {
    try {
      const [h, f, p] = await Promise.all(['/api/histogram', '/api/tf', '/api/pofs'].map(async (u) => {
        const res = await fetch(u, { cache: 'no-store' });
        if (!res.ok) throw new Error(`${u}: HTTP ${res.status}`);
        return res.json();
      }));
      hist = h;
      family = f;
      tfApi.version = p.version;
      showPofs(p.state, p.pof_renders_as);
    } catch (e) {
      message('transfer-function panel: ' + e.message);
      return;
    }
    showBases();
    showStopColour();
    fitYScale();
    bindCurves();
    bindBar();
    bindButtons();
    draw();
    tfApi.ready = true;
  }

  // Both scripts are deferred, but the browser may answer viewer.js's /api/info (and so fire
  // `pofvr:ready`) while this file is still downloading: start at once if that happened.
  function begin() {
    window.pofvr.tf = tfApi;
    start();
  }
  if (window.pofvr && window.pofvr.ready) begin();
  else window.addEventListener('pofvr:ready', begin, { once: true });
})();
