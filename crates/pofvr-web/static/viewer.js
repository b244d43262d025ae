// pofvr viewer: asks the server for frames as PNG and shows the figures it sends along.
//
// Requests are coalesced to one per animation frame; the server drops any request that a
// newer one from this client overtakes before it starts (answered 204), so nothing queues.
// Tests and the benchmark watch `window.pofvr` and the `pofvr:frame` event; the
// transfer-function panel (tf-editor.js) starts on `pofvr:ready` and asks for frames
// through `window.pofvr.view`.
'use strict';

(() => {
  const LOW_RES_DIVISOR = 4;
  const SETTLE_MS = 180;
  const ORBIT_DEG_PER_PX = 0.4;

  const $ = (id) => document.getElementById(id);
  const img = $('frame');
  const clientId = 'c' + Math.random().toString(36).slice(2, 12);

  const state = {
    az: 30, el: 20, zoom: 1, proj: 'ortho', size: 512,
    weights: [], threshold: 0.95, cull: 'none', shade: false, overlay: false,
  };
  let defaults = null;
  let limits = { zoom: [0.1, 20] };

  // What the page exposes for tests and measurements.
  const api = {
    clientId,
    requested: 0, // sequence number of the newest request sent
    shown: 0, // sequence number of the frame on screen
    frames: 0, // frames shown so far
    lowFrames: 0, // of which low-resolution (while dragging)
    lastLow: null, // the last low-resolution frame shown
    last: null, // {seq, low, stats, shownAt} of the frame on screen
    blob: null, // its PNG
    errors: 0,
    ready: false,
  };
  window.pofvr = api;

  let seq = 0;
  let rafPending = false;
  let pendingLow = false;
  let settleTimer = 0;

  function setStatus(msg) {
    $('status').textContent = msg;
  }

  function frameQuery(s, low) {
    const side = low ? Math.max(32, Math.round(state.size / LOW_RES_DIVISOR)) : state.size;
    return new URLSearchParams({
      az: s.az.toFixed(3), el: s.el.toFixed(3), zoom: s.zoom.toFixed(4),
      w: side, h: side, proj: s.proj,
      weights: s.weights.map((k) => k.toFixed(4)).join(','),
      threshold: s.threshold.toFixed(4), cull: s.cull,
      shade: s.shade ? 1 : 0, overlay: s.overlay ? 1 : 0,
      client: clientId, seq: String(s.seq),
    });
  }

  function frameUrl(s, low) {
    return '/api/frame?' + frameQuery(s, low).toString();
  }

  // Asks for a frame of the current state at the next animation frame; a full-resolution
  // ask wins over a low-resolution one made in the same animation frame.
  function requestFrame(low) {
    pendingLow = rafPending ? pendingLow && low : low;
    if (rafPending) return;
    rafPending = true;
    requestAnimationFrame(() => {
      rafPending = false;
      send(pendingLow);
    });
  }

  async function send(low) {
    const mySeq = ++seq;
    api.requested = mySeq;
    const sentAt = performance.now();
    let res;
    try {
      res = await fetch(frameUrl({ ...state, seq: mySeq }, low), { cache: 'no-store' });
    } catch (e) {
      api.errors++;
      setStatus('server unreachable: ' + e.message);
      return;
    }
    if (res.status === 204) return; // overtaken by a newer request of ours
    if (!res.ok) {
      api.errors++;
      setStatus(`frame: HTTP ${res.status}: ${(await res.text()).trim()}`);
      return;
    }
    let stats = null;
    try {
      stats = JSON.parse(res.headers.get('x-pofvr-stats') || 'null');
    } catch (e) {
      stats = null;
    }
    const blob = await res.blob();
    if (mySeq < api.shown) return; // a newer frame is already on screen
    const url = URL.createObjectURL(blob);
    const previous = img.src;
    img.onload = () => {
      if (previous.startsWith('blob:')) URL.revokeObjectURL(previous);
      const shownAt = performance.now();
      api.shown = mySeq;
      api.frames++;
      api.last = { seq: mySeq, low, stats, shownAt, sentAt };
      api.blob = blob; // the PNG on screen, as the server sent it
      if (low) {
        api.lowFrames++;
        api.lastLow = api.last;
      }
      img.dataset.seq = String(mySeq);
      img.dataset.low = low ? '1' : '0';
      setStatus('');
      showFigures(stats, shownAt - sentAt, low);
      window.dispatchEvent(new CustomEvent('pofvr:frame', { detail: api.last }));
    };
    img.onerror = () => {
      api.errors++;
      setStatus('frame could not be decoded');
    };
    img.src = url;
  }

  const fmt = (x, digits = 1) => (Number.isFinite(x) ? x.toFixed(digits) : '–');

  function showFigures(s, roundTrip, low) {
    $('fig-roundtrip-ms').textContent = fmt(roundTrip);
    if (!s) return;
    $('fig-frame-ms').textContent = fmt(s.frame_ms);
    $('fig-resolution').textContent = `${s.width}×${s.height}${low ? ' (dragging)' : ''}`;
    $('fig-sps').textContent = (s.samples_per_second / 1e6).toFixed(1) + ' M';
    $('fig-ranks').textContent = s.ranks;
    $('fig-visible').textContent = s.bricks.visible;
    $('fig-culled').textContent = s.bricks.culled;
    // Verified frames: what predicted the cull, and what verification found it culled wrongly.
    $('fig-repaired').textContent = s.predictor ? s.bricks.repaired : '–';
    $('fig-predictor').textContent = s.predictor || '–';
    // Stale POFs bound other bases: the server culls with `verified` instead, and says so.
    const fallback = s.cull_requested && s.cull_requested !== s.cull;
    const note = $('culling-note');
    if (fallback) {
      note.hidden = false;
      note.textContent = `the POFs are for other bases than the family's: ${s.cull_requested} culls as ${s.cull} (rebuild POFs to cull with them again)`;
    } else if (note.dataset.fallback === '1') {
      note.hidden = true;
    }
    note.dataset.fallback = fallback ? '1' : '0';
    $('fig-empty').textContent = s.bricks.empty;
    $('fig-total').textContent = s.bricks.total;
    const t = s.times;
    $('fig-cull-ms').textContent = fmt(t.cull_ms, 2);
    $('fig-raycast-ms').textContent = fmt(t.raycast_ms, 1);
    $('fig-composite-ms').textContent = fmt(t.composite_ms, 2);
    $('fig-encode-ms').textContent = fmt(t.encode_ms, 1);
    const parts = { cull: t.cull_ms, raycast: t.raycast_ms, composite: t.composite_ms, encode: t.encode_ms };
    const sum = Object.values(parts).reduce((a, b) => a + b, 0) || 1;
    for (const [k, v] of Object.entries(parts)) {
      document.querySelector('#split-bar .' + k).style.width = (100 * v / sum).toFixed(2) + '%';
    }
  }

  function applySize() {
    img.style.width = state.size + 'px';
    img.style.height = state.size + 'px';
  }

  // Full resolution once the pointer or wheel has been still for a moment.
  function settleLater() {
    clearTimeout(settleTimer);
    settleTimer = setTimeout(() => requestFrame(false), SETTLE_MS);
  }

  function bindCamera() {
    let drag = null;
    img.addEventListener('pointerdown', (e) => {
      drag = { x: e.clientX, y: e.clientY, az: state.az, el: state.el };
      img.setPointerCapture(e.pointerId);
      img.classList.add('dragging');
      e.preventDefault();
    });
    img.addEventListener('pointermove', (e) => {
      if (!drag) return;
      state.az = drag.az - (e.clientX - drag.x) * ORBIT_DEG_PER_PX;
      state.az = ((state.az % 360) + 540) % 360 - 180;
      state.el = Math.max(-90, Math.min(90, drag.el + (e.clientY - drag.y) * ORBIT_DEG_PER_PX));
      requestFrame(true);
      settleLater();
    });
    const end = () => {
      if (!drag) return;
      drag = null;
      img.classList.remove('dragging');
      clearTimeout(settleTimer);
      requestFrame(false);
    };
    img.addEventListener('pointerup', end);
    img.addEventListener('pointercancel', end);
    $('stage').addEventListener('wheel', (e) => {
      e.preventDefault();
      const z = state.zoom * Math.exp(-e.deltaY * 0.0015);
      state.zoom = Math.max(limits.zoom[0], Math.min(limits.zoom[1], z));
      requestFrame(true);
      settleLater();
    }, { passive: false });
    $('reset').addEventListener('click', () => {
      state.az = defaults.az;
      state.el = defaults.el;
      state.zoom = 1;
      requestFrame(false);
    });
  }

  // One slider per basis; called again when a family with other bases is loaded.
  function buildWeights(bases, maxWeight) {
    const box = $('weights');
    box.replaceChildren();
    bases.forEach((b, i) => {
      const label = document.createElement('label');
      const out = document.createElement('output');
      out.id = `weight-${i}-value`;
      out.textContent = b.weight.toFixed(2);
      const input = document.createElement('input');
      input.type = 'range';
      input.className = 'weight';
      input.id = `weight-${i}`;
      input.dataset.index = String(i);
      input.min = '0';
      input.max = String(Math.min(maxWeight, Math.max(4, 2 * b.weight)));
      input.step = '0.01';
      input.value = String(b.weight);
      input.setAttribute('aria-label', `weight of ${b.name}`);
      input.addEventListener('input', () => {
        state.weights[i] = Number(input.value);
        out.textContent = state.weights[i].toFixed(2);
        requestFrame(false);
      });
      label.append(document.createTextNode(b.name + ' '), out, input);
      box.append(label);
    });
    state.weights = bases.map((b) => b.weight);
  }

  function bindControls(info) {
    buildWeights(info.bases, info.limits.max_weight);

    const cull = $('cull');
    for (const m of info.cull_modes) {
      const o = document.createElement('option');
      o.value = m;
      o.textContent = m;
      o.disabled = !info.cull_modes_available.includes(m);
      cull.append(o);
    }
    state.cull = info.defaults.cull;
    cull.value = state.cull;
    cull.addEventListener('change', () => {
      state.cull = cull.value;
      requestFrame(false);
    });
    const th = $('threshold');
    th.min = String(Math.max(0.5, info.limits.threshold[0]));
    th.value = String(info.defaults.threshold);
    state.threshold = info.defaults.threshold;
    $('threshold-value').textContent = state.threshold.toFixed(3);
    th.addEventListener('input', () => {
      state.threshold = Number(th.value);
      $('threshold-value').textContent = state.threshold.toFixed(3);
      requestFrame(false);
    });
    for (const [id, key] of [['shade', 'shade'], ['overlay', 'overlay']]) {
      $(id).addEventListener('change', () => {
        state[key] = $(id).checked;
        requestFrame(false);
      });
    }
    $('shade').checked = info.defaults.shade;
    state.shade = info.defaults.shade;
    $('proj').addEventListener('change', () => {
      state.proj = $('proj').value;
      requestFrame(false);
    });
    $('size').addEventListener('change', () => {
      state.size = Number($('size').value);
      applySize();
      requestFrame(false);
    });
    if (!info.pofs_loaded) {
      const note = $('culling-note');
      note.hidden = false;
      note.textContent = 'pof and pof-set need precomputed POFs (serve --pof FILE.pof); exact is the slow oracle.';
    }
  }

  async function start() {
    let info;
    try {
      const res = await fetch('/api/info', { cache: 'no-store' });
      if (!res.ok) throw new Error(`HTTP ${res.status}`);
      info = await res.json();
    } catch (e) {
      setStatus('could not load /api/info: ' + e.message);
      return;
    }
    defaults = info.defaults;
    limits = info.limits;
    state.az = defaults.az;
    state.el = defaults.el;
    const v = info.volume;
    $('volume-name').textContent =
      `${v.source} · ${v.dims.join('×')} ${v.data_type} · ${info.bricks.total} bricks of ${info.bricks.size}³`;
    bindControls(info);
    bindCamera();
    applySize();
    api.view = {
      state,
      requestFrame,
      settleLater,
      // The query of the frame on screen, for /api/camera.
      query: () => frameQuery({ ...state, seq: api.shown }, false),
      setBases: (bases) => buildWeights(bases, info.limits.max_weight),
      setCullAvailable: (modes) => {
        for (const o of $('cull').options) o.disabled = !modes.includes(o.value);
      },
    };
    api.ready = true;
    window.dispatchEvent(new CustomEvent('pofvr:ready', { detail: info }));
    requestFrame(false);
  }

  start();
})();
