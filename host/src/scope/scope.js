// fpi scope: live oscilloscope page for the piezo-stage controller.
// Reads /info once, then the binary /stream into per-channel rings, and draws
// a time plot, a spectrum and an X–Y plot on every animation frame.
'use strict';

/* ------------------------------------------------------------------ */
/* Constants                                                          */
/* ------------------------------------------------------------------ */

const RING_CAP = 1 << 20;                // samples kept per channel
const MAGIC = 0x31504353;                // "SCP1" read as a little-endian u32
const HEADER_BYTES = 28;                 // seven u32
const MAX_MESSAGE_BYTES = 64 << 20;      // a larger message is a protocol error
const RETRY_MS = 2000;                   // stream reconnection period
const STALL_MS = 1000;                   // no data for this long is shown as a stall

const TIMEBASES = [1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1, 0.2, 0.5, 1, 2, 5, 10];
const DEFAULT_SPAN_S = 0.05;
const MIN_SPAN_SAMPLES = 8;
const MAX_SPAN_SAMPLES = RING_CAP / 2;   // leaves room to pan and for pre-trigger data
const WHEEL_NOTCH = 100;                 // wheel deltaY of one notch
const WHEEL_ZOOM = 2 ** 0.25;            // span factor per notch
const MAX_WHEEL_NOTCHES = 3;             // per event

const FFT_SIZES = [4096, 8192, 16384, 32768];
const DEFAULT_FFT = 16384;
const SPECTRUM_PERIOD_MS = 250;
const SPECTRUM_FLOOR = 1e-30;            // keeps log10 finite
const SPECTRUM_DB_SPAN_MAX = 160;

const XY_MAX_POINTS = 20000;
const Y_DIVS = 8;                        // vertical divisions of a manual scale
const AUTO_MARGIN = 0.05;                // auto-scale margin, fraction of the range
const AUTO_KEEP_FILL = 0.8;              // auto range is kept while data fill it this much

const MODES = ['roll', 'auto', 'normal', 'single'];
const TRIGGER_HYSTERESIS = 0.01;         // fraction of the recent peak-to-peak
const AUTO_TIMEOUT_SPANS = 2;
const RESCAN_SPANS = 4;                  // data searched again after a trigger change
const TRIGGER_QUEUE_STEPS = 2048;        // pending triggers kept per post-trigger span
const PP_WINDOW_MIN = 1 << 14;           // samples for the recent peak-to-peak
const PP_WINDOW_MAX = 1 << 16;

const MEASURE_POINTS = 512;              // screen positions of the stillness measures
const GAP_MARKS_MAX = 256;
const STATUS_PERIOD_MS = 250;
const RATE_PERIOD_MS = 1000;
const ENVELOPE_MIN_SAMPLES_PER_PX = 2;   // below this, traces are drawn sample to sample
const DOT_MIN_PX_PER_SAMPLE = 8;         // above this, samples are marked with dots

const COLORS = ['#f5c542', '#42d4f5', '#f55f8d', '#7df542', '#b78cff', '#ff9f43', '#e6e6e6'];
const THEME = {
  bg: '#121821', plot: '#090c11', grid: '#1c2533', border: '#2f3b4f',
  label: '#8b98a9', text: '#c9d1d9', trigger: '#ff9f43', gap: '#ff4d4d', cursor: 'rgba(255,255,255,0.45)',
  legendBg: 'rgba(9,12,17,0.78)', peak: '#ff9f43',
};
const FONT = '12px system-ui, -apple-system, "Segoe UI", sans-serif';
const FONT_BOLD = '600 12px system-ui, -apple-system, "Segoe UI", sans-serif';
const MAIN_MARGIN = { l: 72, r: 14, t: 10, b: 36 };
const PANEL_MARGIN = { l: 58, r: 12, t: 10, b: 32 };

/* ------------------------------------------------------------------ */
/* State                                                              */
/* ------------------------------------------------------------------ */

// What the server announced and what the stream reported.
const stream = {
  tickRate: 0, sampleRate: 0, board: '', names: [],
  gaps: 0, missing: 0, dropped: 0, error: null, fatal: false, lastData: 0,
};

// Per-channel sample rings; sample number i (counted from load) is at i % RING_CAP.
const ring = { data: [], ticks: new Uint32Array(RING_CAP), total: 0, newestTick: 0, dec: 1, gapMarks: [] };

// User settings (controls and URL query).
const settings = {
  mode: 'roll', paused: false, spanS: DEFAULT_SPAN_S,
  trigChannel: 0, level: NaN, edge: 'rising', pre: 0.5,
  specChannel: 0, fftN: DEFAULT_FFT, specKind: 'amp', showSpectrum: true, showXY: true,
  xChannel: 0, yChannel: 0, axisChannel: 0, reportMs: 0, notes: [],
  toutQuery: null,
};

// The board's trigger output as the server last said it (GET/POST /trigger), and
// the last refusal.
const tout = { settings: null, error: null };

// Per-channel display state: {name, unit, color, visible, auto, perDiv, offset, range, env, ui}.
let channels = [];

// Trigger search and the triggered-frame measures.
const trig = {
  scanPos: 0, armed: false, queue: [], head: 0,
  shown: null, singleDone: false, frames: 0, trace: null, stillness: null,
};

// Roll-mode motion measure.
const roll = { trace: null, motion: null };

// Spectrum computation (tables for one FFT length) and its last result.
const spec = {
  n: 0, win: null, sumW: 0, sumW2: 0, re: null, im: null, cos: null, sin: null, rev: null,
  db: null, rate: 0, valid: false, peakHz: null, peakDb: null, last: -Infinity, dirty: true, note: '',
};

// Frame and rate statistics.
const stats = { frames: 0, fps: 0, receivedPerS: 0, mark: 0, markFrames: 0, markTotal: 0, lastStatus: 0 };

// Main-plot interaction: frozen view while paused, cursor, drag.
const interact = { frozen: null, lastView: null, cursorX: null, dragX: null };

// Canvases: {canvas, ctx, w, h, dpr} in CSS pixels.
const surfaces = {};

// Scratch buffers of the stillness measures.
const measureScratch = { a: new Float32Array(MEASURE_POINTS), b: new Float32Array(MEASURE_POINTS) };

/* ------------------------------------------------------------------ */
/* Small helpers                                                      */
/* ------------------------------------------------------------------ */

const $ = (id) => document.getElementById(id);
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));
const withMinus = (s) => s.replace(/-/g, '\u2212');

// Creates an element with properties and children.
function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  e.append(...children);
  return e;
}

// Replaces a select's options by [value, label] pairs and selects value.
function fillSelect(select, options, value) {
  select.textContent = '';
  for (const [v, label] of options) select.append(new Option(label, String(v)));
  select.value = String(value);
}

// 1-2-5 step close to range / count.
function niceStep(range, count) {
  const raw = range / count;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const norm = raw / mag;
  return (norm < 1.5 ? 1 : norm < 3 ? 2 : norm < 7 ? 5 : 10) * mag;
}

// Smallest 1-2-5 value not below v.
function niceCeil(v) {
  const mag = 10 ** Math.floor(Math.log10(v));
  const norm = v / mag;
  return (norm <= 1 ? 1 : norm <= 2 ? 2 : norm <= 5 ? 5 : 10) * mag;
}

// Multiples of step within [lo, hi].
function ticksBetween(lo, hi, step) {
  const out = [];
  const k0 = Math.ceil(lo / step - 1e-9);
  const k1 = Math.floor(hi / step + 1e-9);
  for (let k = k0; k <= k1 && out.length < 200; k++) out.push(k * step);
  return out;
}

// Tick label with as many decimals as the step needs.
function fmtTick(v, step) {
  if (Math.abs(v) < step * 1e-6) v = 0;
  if (Math.abs(v) >= 1e6 || step < 1e-5) return withMinus(v.toExponential(2));
  const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  return withMinus(v.toFixed(decimals));
}

// Value with about `digits` significant digits.
function fmtValue(v, digits = 4) {
  if (!Number.isFinite(v)) return '—';
  if (v !== 0 && (Math.abs(v) >= 1e6 || Math.abs(v) < 1e-4)) return withMinus(v.toExponential(digits - 1));
  return withMinus(String(Number(v.toPrecision(digits))));
}

// Sample count with thousands separators.
const fmtCount = (n) => Math.round(n).toLocaleString('en-US');

// Frequency as Hz or kHz.
function fmtFreq(f, digits = 4) {
  return f >= 1000 ? `${fmtValue(f / 1000, digits)} kHz` : `${fmtValue(f, digits)} Hz`;
}

// Duration with a unit fitting its size.
function fmtDuration(s) {
  const u = timeUnit(s);
  return `${fmtValue(s / u.scale, 3)} ${u.name}`;
}

// Display unit for times around `span` seconds.
function timeUnit(span) {
  if (span >= 2) return { scale: 1, name: 's' };
  if (span >= 2e-3) return { scale: 1e-3, name: 'ms' };
  return { scale: 1e-6, name: 'µs' };
}

// Channel label "name (unit)".
function chanLabel(c) {
  const ch = channels[c];
  return ch.unit ? `${ch.name} (${ch.unit})` : ch.name;
}

/* ------------------------------------------------------------------ */
/* Sample ring                                                        */
/* ------------------------------------------------------------------ */

// Allocates one ring per channel.
function ringInit(nch) {
  ring.data = Array.from({ length: nch }, () => new Float32Array(RING_CAP));
  ring.total = 0;
  ring.gapMarks = [];
}

// Oldest sample number still in the rings.
const oldestIndex = () => Math.max(0, ring.total - RING_CAP);

// Linear interpolation of channel c at fractional sample number x; NaN outside the rings.
function interpAt(c, x) {
  const lo = oldestIndex();
  const hi = ring.total - 1;
  if (!(x >= lo && x <= hi)) return NaN;
  const i = Math.min(Math.floor(x), hi - 1);
  if (i < lo) return ring.data[c][lo % RING_CAP];
  const f = x - i;
  const d = ring.data[c];
  const a = d[i % RING_CAP];
  return a + (d[(i + 1) % RING_CAP] - a) * f;
}

// Sample numbers [first, last] of the view's span that are still in the rings.
function viewIndices(view) {
  return {
    first: Math.max(oldestIndex(), Math.ceil(view.start)),
    last: Math.min(ring.total - 1, Math.floor(view.start + view.S)),
  };
}

// Copies `count` samples of all channels from a message into the rings.
function appendSamples(dv, offset, count, firstTick, dec) {
  const nch = ring.data.length;
  if (ring.total > 0 && firstTick !== ((ring.newestTick + ring.dec) >>> 0)) markGap(ring.total);
  let p = ring.total % RING_CAP;
  let o = offset;
  for (let k = 0; k < count; k++) {
    for (let c = 0; c < nch; c++) {
      ring.data[c][p] = dv.getFloat32(o, true);
      o += 4;
    }
    ring.ticks[p] = (firstTick + k * dec) >>> 0;
    if (++p === RING_CAP) p = 0;
  }
  ring.total += count;
  ring.newestTick = (firstTick + (count - 1) * dec) >>> 0;
  if (dec !== ring.dec) {
    ring.dec = dec;
    stream.sampleRate = stream.tickRate / dec;
  }
}

// Remembers where the ticks jumped, to mark it on the plot.
function markGap(index) {
  ring.gapMarks.push(index);
  if (ring.gapMarks.length > GAP_MARKS_MAX) ring.gapMarks.shift();
}

/* ------------------------------------------------------------------ */
/* Stream reading and message reassembly                              */
/* ------------------------------------------------------------------ */

// Bytes received but not yet parsed: buf[start, end).
const parser = { buf: new Uint8Array(1 << 16), dv: null, start: 0, end: 0 };
parser.dv = new DataView(parser.buf.buffer);

// Appends a reader chunk, compacting or growing the buffer as needed.
function parserAppend(chunk) {
  const live = parser.end - parser.start;
  if (parser.end + chunk.length > parser.buf.length) {
    let cap = parser.buf.length;
    while (cap < live + chunk.length) cap *= 2;
    if (cap === parser.buf.length) {
      parser.buf.copyWithin(0, parser.start, parser.end);
    } else {
      const grown = new Uint8Array(cap);
      grown.set(parser.buf.subarray(parser.start, parser.end));
      parser.buf = grown;
      parser.dv = new DataView(grown.buffer);
    }
    parser.start = 0;
    parser.end = live;
  }
  parser.buf.set(chunk, parser.end);
  parser.end += chunk.length;
}

// Parses every complete message; returns a protocol error text or null.
function parseMessages() {
  const nch = ring.data.length;
  const dv = parser.dv;
  while (parser.end - parser.start >= HEADER_BYTES) {
    const o = parser.start;
    const magic = dv.getUint32(o, true);
    if (magic !== MAGIC) {
      return `protocol error: bad magic 0x${magic.toString(16).padStart(8, '0')} (expected 0x${MAGIC.toString(16)})`;
    }
    const count = dv.getUint32(o + 4, true);
    const bytes = HEADER_BYTES + count * nch * 4;
    if (bytes > MAX_MESSAGE_BYTES) return `protocol error: message of ${count} samples`;
    if (parser.end - o < bytes) break;
    const firstTick = dv.getUint32(o + 8, true);
    const dec = dv.getUint32(o + 12, true);
    if (dec === 0) return 'protocol error: decimation 0';
    stream.gaps = dv.getUint32(o + 16, true);
    stream.missing = dv.getUint32(o + 20, true);
    stream.dropped = dv.getUint32(o + 24, true);
    if (count > 0) appendSamples(dv, o + HEADER_BYTES, count, firstTick, dec);
    parser.start += bytes;
    stream.lastData = performance.now();
  }
  if (parser.start === parser.end) parser.start = parser.end = 0;
  return null;
}

// Reads /stream forever: reconnects every RETRY_MS after an end, stops on a protocol error.
async function runStream() {
  for (;;) {
    try {
      const resp = await fetch('/stream', { cache: 'no-store' });
      if (!resp.ok || !resp.body) throw new Error(`HTTP ${resp.status}`);
      stream.error = null;
      parser.start = parser.end = 0;
      const reader = resp.body.getReader();
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        parserAppend(value);
        const err = parseMessages();
        if (err) {
          stream.error = err;
          stream.fatal = true;
          reader.cancel().catch(() => {});
          return;
        }
      }
      stream.error = 'stream ended';
    } catch (e) {
      stream.error = `stream ended (${e.message})`;
    }
    await sleep(RETRY_MS);
    if (await channelsChanged()) {
      location.reload();
      return;
    }
  }
}

// Fetches and checks /info.
async function fetchInfo() {
  const resp = await fetch('/info', { cache: 'no-store' });
  if (!resp.ok) throw new Error(`HTTP ${resp.status}`);
  const info = await resp.json();
  const rate = Number(info.rate_hz);
  const dec = Number(info.decimation);
  if (!(rate > 0) || !(dec >= 1) || !Array.isArray(info.channels) || info.channels.length === 0) {
    throw new Error('malformed /info');
  }
  return info;
}

// True when the server now announces other channels or another rate (the page must restart).
async function channelsChanged() {
  try {
    const info = await fetchInfo();
    return Number(info.rate_hz) !== stream.tickRate
      || info.channels.map((c) => String(c.name)).join(',') !== stream.names.join(',');
  } catch (e) {
    return false;
  }
}

/* ------------------------------------------------------------------ */
/* Settings: defaults and URL query                                   */
/* ------------------------------------------------------------------ */

// First channel whose name starts with one of the prefixes, in preference order.
function preferredChannel(prefixes, fallback) {
  for (const prefix of prefixes) {
    const c = stream.names.findIndex((n) => n.startsWith(prefix));
    if (c >= 0) return c;
  }
  return fallback;
}

// Default channel choices for this board.
function applyDefaults() {
  const nch = stream.names.length;
  settings.specChannel = preferredChannel(['x_fhps', 'x_sensor', 'x_est'], 0);
  settings.trigChannel = settings.specChannel;
  settings.xChannel = preferredChannel(['voltage_V'], 0);
  settings.yChannel = preferredChannel(['x_fhps_um', 'x_est_um'], Math.min(1, nch - 1));
  settings.axisChannel = 0;
}

// Applies the URL query; unknown values are noted in the status line.
function applyQuery() {
  const q = new URLSearchParams(location.search);
  const note = (key) => settings.notes.push(`ignored ${key}=${q.get(key)}`);
  const channelParam = (key, apply) => {
    if (!q.has(key)) return;
    const c = stream.names.indexOf(q.get(key));
    if (c >= 0) apply(c); else note(key);
  };
  const numberParam = (key, ok, apply) => {
    if (!q.has(key)) return;
    const v = Number(q.get(key));
    if (q.get(key) !== '' && ok(v)) apply(v); else note(key);
  };
  if (q.has('mode')) {
    if (MODES.includes(q.get('mode'))) settings.mode = q.get('mode'); else note('mode');
  }
  if (q.has('edge')) {
    if (['rising', 'falling'].includes(q.get('edge'))) settings.edge = q.get('edge'); else note('edge');
  }
  channelParam('trigger', (c) => { settings.trigChannel = c; });
  channelParam('spectrum', (c) => { settings.specChannel = c; });
  channelParam('x', (c) => { settings.xChannel = c; });
  channelParam('y', (c) => { settings.yChannel = c; });
  numberParam('level', Number.isFinite, (v) => { settings.level = v; });
  numberParam('pre', (v) => v >= 0 && v <= 1, (v) => { settings.pre = v; });
  numberParam('span', (v) => v > 0, (v) => {
    settings.spanS = clampSpan(v);
    if (settings.spanS !== v) settings.notes.push(`span limited to ${fmtDuration(settings.spanS)}`);
  });
  numberParam('fft', (v) => FFT_SIZES.includes(v), (v) => { settings.fftN = v; });
  numberParam('report', (v) => v >= 10, (v) => { settings.reportMs = v; });
  // tout=MODE[,key=value…]: the triggers set as the panel sets them (for tests;
  // `input=` takes a name, the levels numbers).
  if (q.has('tout')) {
    const [mode, ...pairs] = q.get('tout').split(',');
    const body = { mode };
    for (const p of pairs) {
      const [k, v] = p.split('=');
      body[k] = k === 'input' ? v : Number(v);
    }
    settings.toutQuery = body;
  }
}

// Span limited to what the rings can show.
function clampSpan(s) {
  const rate = stream.sampleRate;
  return clamp(s, MIN_SPAN_SAMPLES / rate, MAX_SPAN_SAMPLES / rate);
}

/* ------------------------------------------------------------------ */
/* Controls                                                           */
/* ------------------------------------------------------------------ */

// Fills the selectors and binds every control.
function buildControls() {
  const chanOptions = stream.names.map((n, c) => [c, n]);
  fillSelect($('mode'), MODES.map((m) => [m, m]), settings.mode);
  fillSelect($('trig-ch'), chanOptions, settings.trigChannel);
  fillSelect($('spec-ch'), chanOptions, settings.specChannel);
  fillSelect($('xy-x'), chanOptions, settings.xChannel);
  fillSelect($('xy-y'), chanOptions, settings.yChannel);
  fillSelect($('spec-n'), FFT_SIZES.map((n) => [n, String(n)]), settings.fftN);
  $('trig-edge').value = settings.edge;
  $('trig-pre').value = String(Math.round(settings.pre * 100));
  showLevel();
  showSpan();
  bindControls();
  buildChannelPanel();
  applyPanelVisibility();
}

// Reacts to the control bar and panel selectors.
function bindControls() {
  $('run').onclick = togglePause;
  $('mode').onchange = (e) => setMode(e.target.value);
  $('span').onchange = (e) => setSpan(Number(e.target.value), null);
  $('trig-ch').onchange = (e) => { settings.trigChannel = Number(e.target.value); showLevel(); triggerChanged(); };
  $('trig-level').onchange = (e) => {
    const v = Number(e.target.value);
    if (e.target.value !== '' && Number.isFinite(v)) { settings.level = v; triggerChanged(); } else showLevel();
  };
  $('trig-50').onclick = () => { settings.level = NaN; autoLevel(); triggerChanged(); };
  $('trig-edge').onchange = (e) => { settings.edge = e.target.value; triggerChanged(); };
  $('trig-pre').onchange = (e) => {
    const v = Number(e.target.value);
    if (e.target.value !== '' && v >= 0 && v <= 100) { settings.pre = v / 100; triggerChanged(); }
    e.target.value = String(Math.round(settings.pre * 100));
  };
  $('rearm').onclick = rearm;
  $('show-spectrum').onchange = (e) => { settings.showSpectrum = e.target.checked; applyPanelVisibility(); };
  $('show-xy').onchange = (e) => { settings.showXY = e.target.checked; applyPanelVisibility(); };
  $('csv').onclick = exportCsv;
  $('png').onclick = exportPng;
  $('spec-ch').onchange = (e) => { settings.specChannel = Number(e.target.value); spec.dirty = true; };
  $('spec-n').onchange = (e) => { settings.fftN = Number(e.target.value); prepareSpectrum(settings.fftN); };
  $('spec-kind').onchange = (e) => { settings.specKind = e.target.value; spec.dirty = true; };
  $('xy-x').onchange = (e) => { settings.xChannel = Number(e.target.value); xyRanges.x.valid = false; };
  $('xy-y').onchange = (e) => { settings.yChannel = Number(e.target.value); xyRanges.y.valid = false; };
  document.addEventListener('keydown', (e) => {
    const tag = e.target.tagName;
    if (e.code === 'Space' && tag !== 'INPUT' && tag !== 'SELECT' && tag !== 'BUTTON') {
      e.preventDefault();
      togglePause();
    }
  });
  bindMainCanvas();
}

// Shows the trigger level and its unit.
function showLevel() {
  $('trig-level').value = Number.isFinite(settings.level) ? String(Number(settings.level.toPrecision(6))) : '';
  $('trig-unit').textContent = channels[settings.trigChannel].unit;
}

// Shows the span in the timebase selector (a "zoom" entry when not a 1-2-5 step).
function showSpan() {
  const options = TIMEBASES.filter((s) => clampSpan(s) === s).map((s) => [s, fmtDuration(s)]);
  const match = options.find(([s]) => Math.abs(s / settings.spanS - 1) < 1e-9);
  if (!match) options.unshift([settings.spanS, `${fmtDuration(settings.spanS)} (zoom)`]);
  fillSelect($('span'), options, match ? match[0] : settings.spanS);
}

// Shows or hides the spectrum and X–Y panels.
function applyPanelVisibility() {
  const layout = $('layout');
  layout.classList.toggle('no-spectrum', !settings.showSpectrum);
  layout.classList.toggle('no-xy', !settings.showXY);
  $('show-spectrum').checked = settings.showSpectrum;
  $('show-xy').checked = settings.showXY;
  spec.dirty = true;
}

// One block per channel: visibility, colour, axis choice, auto or manual scale.
function buildChannelPanel() {
  const list = $('channel-list');
  list.textContent = '';
  channels.forEach((ch, c) => {
    const visible = el('input', { type: 'checkbox', checked: ch.visible, title: 'Show' });
    const color = el('input', { type: 'color', value: ch.color, title: 'Colour' });
    const axis = el('input', { type: 'radio', name: 'axis', checked: c === settings.axisChannel });
    const auto = el('input', { type: 'checkbox', checked: ch.auto });
    const perDiv = el('input', { type: 'number', step: 'any', min: '0', title: 'units per division' });
    const offset = el('input', { type: 'number', step: 'any', title: 'value at the centre line' });
    const range = el('div', { className: 'chan-range' });
    const block = el('div', { className: 'chan' },
      el('div', { className: 'chan-row' }, visible, color,
        el('span', { className: 'chan-name', textContent: ch.name, title: chanLabel(c) }),
        el('label', { className: 'axis', title: 'Label the value axis with this channel' }, axis, 'axis')),
      el('div', { className: 'chan-row' },
        el('label', {}, auto, 'auto'),
        el('label', {}, perDiv, `${ch.unit}/div`)),
      el('div', { className: 'chan-row' }, el('label', { title: 'value at the centre line' }, 'centre', offset, ch.unit)),
      range);
    block.style.setProperty('--chan-color', ch.color);
    ch.ui = { auto, perDiv, offset, range };
    visible.onchange = () => { ch.visible = visible.checked; };
    color.oninput = () => { ch.color = color.value; block.style.setProperty('--chan-color', ch.color); spec.dirty = true; };
    axis.onchange = () => { settings.axisChannel = c; };
    auto.onchange = () => setAutoScale(c, auto.checked);
    perDiv.onchange = () => { const v = Number(perDiv.value); if (v > 0) ch.perDiv = v; showScale(c); };
    offset.onchange = () => { const v = Number(offset.value); if (offset.value !== '' && Number.isFinite(v)) ch.offset = v; showScale(c); };
    list.append(block);
    showScale(c);
  });
}

// Switches a channel between auto-scale and a manual scale seeded from the current range.
function setAutoScale(c, on) {
  const ch = channels[c];
  ch.auto = on;
  if (!on && ch.range.valid) {
    ch.perDiv = niceCeil((ch.range.hi - ch.range.lo) / Y_DIVS);
    ch.offset = Number(((ch.range.lo + ch.range.hi) / 2).toPrecision(4));
  }
  ch.range.valid = false;
  showScale(c);
}

// Shows a channel's scale controls (manual inputs disabled under auto-scale).
function showScale(c) {
  const ch = channels[c];
  ch.ui.auto.checked = ch.auto;
  ch.ui.perDiv.disabled = ch.auto;
  ch.ui.offset.disabled = ch.auto;
  ch.ui.perDiv.value = String(ch.perDiv);
  ch.ui.offset.value = String(ch.offset);
}

// Shows each channel's displayed range in the channel panel.
function showRanges() {
  for (const ch of channels) {
    const r = ch.range;
    ch.ui.range.textContent = r.valid && ch.visible
      ? `${fmtValue(r.lo)} … ${fmtValue(r.hi)} ${ch.unit}${ch.auto ? ' (auto)' : ''}` : '';
  }
}

/* ------------------------------------------------------------------ */
/* Pause, mode, span                                                  */
/* ------------------------------------------------------------------ */

// Freezes the view where it is, or resumes the live view.
function togglePause() {
  settings.paused = !settings.paused;
  if (settings.paused) {
    interact.frozen = interact.lastView ? { ...interact.lastView, fresh: false } : null;
  } else {
    interact.frozen = null;
    restartTriggerScan();
  }
  $('run').textContent = settings.paused ? 'Run' : 'Pause';
  $('run').classList.toggle('active', settings.paused);
  $('main-canvas').classList.toggle('pannable', settings.paused);
}

// Changes the acquisition mode; triggered modes start afresh.
function setMode(mode) {
  settings.mode = mode;
  $('mode').value = mode;
  trig.shown = null;
  trig.singleDone = false;
  triggerChanged();
}

// Arms single mode for the next trigger.
function rearm() {
  if (settings.mode !== 'single') setMode('single');
  trig.singleDone = false;
  restartTriggerScan();
}

// Sets the span; a paused view zooms about the sample under `anchorX` (CSS px) or its centre.
function setSpan(spanS, anchorX) {
  settings.spanS = clampSpan(spanS);
  const f = interact.frozen;
  if (f) {
    const r = plotRect(surfaces.main, MAIN_MARGIN);
    const frac = anchorX === null ? 0.5 : clamp((anchorX - r.x) / r.w, 0, 1);
    const anchor = f.start + frac * f.S;
    f.S = settings.spanS * stream.sampleRate;
    f.start = anchor - frac * f.S;
    clampFrozen(f);
    spec.dirty = true;
  }
  showSpan();
  resetMeasures();
}

/* ------------------------------------------------------------------ */
/* Trigger                                                            */
/* ------------------------------------------------------------------ */

// Trigger settings changed: search recent data again and restart the measures.
function triggerChanged() {
  restartTriggerScan();
  resetMeasures();
}

// Clears pending triggers and scans again: the last few spans, or only new data in single mode.
function restartTriggerScan() {
  const S = settings.spanS * stream.sampleRate;
  trig.queue = [];
  trig.head = 0;
  trig.armed = false;
  trig.scanPos = settings.mode === 'single'
    ? ring.total : Math.max(oldestIndex() + 1, Math.floor(ring.total - RESCAN_SPANS * S));
}

// Drops the reference traces of the stillness and motion measures.
function resetMeasures() {
  trig.trace = null;
  roll.trace = null;
}

// Peak-to-peak of a channel over its most recent samples.
function recentPeakToPeak(c, S) {
  const n = Math.min(Math.max(Math.ceil(S), PP_WINDOW_MIN), PP_WINDOW_MAX, ring.total - oldestIndex());
  const d = ring.data[c];
  let lo = Infinity;
  let hi = -Infinity;
  let p = (ring.total - n) % RING_CAP;
  for (let k = 0; k < n; k++) {
    const v = d[p];
    if (v < lo) lo = v;
    if (v > hi) hi = v;
    if (++p === RING_CAP) p = 0;
  }
  return hi > lo ? hi - lo : 0;
}

// Sets the level to the middle of the trigger channel's recent range.
function autoLevel() {
  const c = settings.trigChannel;
  const n = Math.min(PP_WINDOW_MAX, ring.total - oldestIndex());
  if (n === 0) return;
  const d = ring.data[c];
  let lo = Infinity;
  let hi = -Infinity;
  for (let i = ring.total - n; i < ring.total; i++) {
    const v = d[i % RING_CAP];
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  if (hi >= lo) {
    settings.level = Number(((lo + hi) / 2).toPrecision(4));
    showLevel();
  }
}

// Fractional position between samples k-1 (value a) and k (value b) where the level is crossed.
function crossing(k, a, b, level) {
  const f = (level - a) / (b - a);
  return k - 1 + (Number.isFinite(f) ? clamp(f, 0, 1) : 1);
}

// Queues a trigger point, thinned so the queue stays short whatever the trigger rate.
function pushTrigger(T, minGap) {
  const q = trig.queue;
  if (q.length > trig.head && T - q[q.length - 1] < minGap) return;
  q.push(T);
}

// Scans the samples received since the last scan for level crossings with hysteresis.
function scanTriggers(S) {
  const total = ring.total;
  let k = Math.max(trig.scanPos, oldestIndex() + 1);
  const level = settings.level;
  if (k >= total || !Number.isFinite(level)) {
    trig.scanPos = total;
    return;
  }
  const d = ring.data[settings.trigChannel];
  // A falling edge is a rising edge of the negated signal.
  const sign = settings.edge === 'rising' ? 1 : -1;
  const lvl = sign * level;
  const armLevel = lvl - TRIGGER_HYSTERESIS * recentPeakToPeak(settings.trigChannel, S);
  const minGap = Math.max(1, (1 - settings.pre) * S) / TRIGGER_QUEUE_STEPS;
  let armed = trig.armed;
  let p = k % RING_CAP;
  let prev = sign * d[(p === 0 ? RING_CAP : p) - 1];
  for (; k < total; k++) {
    const v = sign * d[p];
    if (!armed) {
      armed = v < armLevel;
    } else if (v >= lvl) {
      pushTrigger(crossing(k, prev, v, lvl), minGap);
      armed = false;
    }
    prev = v;
    if (++p === RING_CAP) p = 0;
  }
  trig.armed = armed;
  trig.scanPos = total;
}

// Takes the newest queued trigger whose frame is complete (post-trigger part received).
function takeCompleteTrigger(S) {
  const pre = settings.pre * S;
  const post = S - pre;
  const newest = ring.total - 1;
  const oldest = oldestIndex();
  const q = trig.queue;
  let found = null;
  while (trig.head < q.length && q[trig.head] + post <= newest) {
    const T = q[trig.head++];
    if (T - pre - 1 >= oldest) found = T;
  }
  if (trig.head > 1024) {
    trig.queue = q.slice(trig.head);
    trig.head = 0;
  }
  return found;
}

/* ------------------------------------------------------------------ */
/* View: which samples the main plot shows                            */
/* ------------------------------------------------------------------ */
// A view is {kind: 'empty'|'wait'|'roll'|'trig', start, S, ref, trigger, fresh}:
// start = fractional sample number at the left edge, S = span in samples,
// ref = sample number of t = 0, trigger = trigger point or null, fresh = a new triggered frame.

// The view of this frame.
function computeView() {
  const S = settings.spanS * stream.sampleRate;
  if (interact.frozen) return clampFrozen(interact.frozen);
  if (ring.total === 0) return { kind: 'empty', start: -S, S, ref: 0, trigger: null, fresh: false };
  if (!Number.isFinite(settings.level)) autoLevel();
  if (settings.mode === 'roll') return rollView(S);
  return triggeredView(S);
}

// Newest sample at the right edge.
function rollView(S) {
  const newest = ring.total - 1;
  return { kind: 'roll', start: newest - S, S, ref: newest, trigger: null, fresh: false };
}

// Auto, normal and single modes.
function triggeredView(S) {
  let fresh = false;
  if (settings.mode === 'single' && trig.singleDone) {
    trig.scanPos = ring.total;   // a stopped single acquisition ignores new data
  } else {
    scanTriggers(S);
    const T = takeCompleteTrigger(S);
    if (T !== null) {
      trig.shown = T;
      fresh = true;
      trig.frames++;
      if (settings.mode === 'single') trig.singleDone = true;
    }
  }
  const T = trig.shown;
  const pre = settings.pre * S;
  if (settings.mode === 'auto') {
    const stale = T === null || ring.total - 1 - (T + S - pre) > AUTO_TIMEOUT_SPANS * S;
    if (stale) return rollView(S);
  }
  if (T === null || T - pre - 1 < oldestIndex()) {
    return { kind: 'wait', start: ring.total - 1 - S, S, ref: ring.total - 1, trigger: null, fresh: false };
  }
  return { kind: 'trig', start: T - pre, S, ref: T, trigger: T, fresh };
}

// Keeps a paused view inside the rings.
function clampFrozen(f) {
  const lo = oldestIndex();
  const hi = Math.max(lo, ring.total - 1 - f.S);
  if (f.kind !== 'empty' && f.kind !== 'wait') f.start = clamp(f.start, lo, hi);
  return f;
}

/* ------------------------------------------------------------------ */
/* Canvas surfaces                                                    */
/* ------------------------------------------------------------------ */

// Registers a canvas that follows its box's size.
function addSurface(name, canvas) {
  const s = { canvas, ctx: canvas.getContext('2d'), w: 0, h: 0, dpr: 1 };
  surfaces[name] = s;
  new ResizeObserver(() => { s.resized = true; spec.dirty = true; }).observe(canvas);
  s.resized = true;
}

// Matches a canvas's backing store to its CSS size and the device pixel ratio.
function fitSurface(s) {
  if (!s.resized && s.dpr === window.devicePixelRatio) return;
  s.resized = false;
  s.dpr = window.devicePixelRatio || 1;
  s.w = Math.max(1, s.canvas.clientWidth);
  s.h = Math.max(1, s.canvas.clientHeight);
  s.canvas.width = Math.round(s.w * s.dpr);
  s.canvas.height = Math.round(s.h * s.dpr);
}

// Starts drawing a surface: CSS-pixel transform and background.
function beginSurface(s) {
  const ctx = s.ctx;
  ctx.setTransform(s.dpr, 0, 0, s.dpr, 0, 0);
  ctx.fillStyle = THEME.bg;
  ctx.fillRect(0, 0, s.w, s.h);
  ctx.font = FONT;
  return ctx;
}

// Plot rectangle inside margins.
function plotRect(s, m) {
  return { x: m.l, y: m.t, w: Math.max(1, s.w - m.l - m.r), h: Math.max(1, s.h - m.t - m.b) };
}

// Plot background.
function fillPlot(ctx, r) {
  ctx.fillStyle = THEME.plot;
  ctx.fillRect(r.x, r.y, r.w, r.h);
}

// Vertical grid lines with labels below: marks = [{x, label}].
function gridX(ctx, r, marks, title) {
  ctx.strokeStyle = THEME.grid;
  ctx.lineWidth = 1;
  ctx.beginPath();
  for (const m of marks) {
    const x = Math.round(m.x) + 0.5;
    ctx.moveTo(x, r.y);
    ctx.lineTo(x, r.y + r.h);
  }
  ctx.stroke();
  ctx.fillStyle = THEME.label;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'top';
  const right = ctx.canvas.width / ctx.getTransform().a;
  for (const m of marks) {
    if (!m.label) continue;
    const half = ctx.measureText(m.label).width / 2 + 1;
    ctx.fillText(m.label, clamp(m.x, half, right - half), r.y + r.h + 4);
  }
  ctx.textAlign = 'right';
  ctx.fillText(title, r.x + r.w, r.y + r.h + 19);
}

// Horizontal grid lines with labels at the left: marks = [{y, label}].
function gridY(ctx, r, marks, color) {
  ctx.strokeStyle = THEME.grid;
  ctx.lineWidth = 1;
  ctx.beginPath();
  for (const m of marks) {
    const y = Math.round(m.y) + 0.5;
    ctx.moveTo(r.x, y);
    ctx.lineTo(r.x + r.w, y);
  }
  ctx.stroke();
  ctx.fillStyle = color;
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  for (const m of marks) if (m.label) ctx.fillText(m.label, r.x - 5, m.y);
}

// Rotated axis title at the left of a plot.
function axisTitleY(ctx, r, text, color) {
  ctx.save();
  ctx.translate(12, r.y + r.h / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.fillStyle = color;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, 0, 0);
  ctx.restore();
}

// Plot frame.
function strokeFrame(ctx, r) {
  ctx.strokeStyle = THEME.border;
  ctx.lineWidth = 1;
  ctx.strokeRect(r.x + 0.5, r.y + 0.5, r.w - 1, r.h - 1);
}

// Centred message in a plot.
function plotMessage(ctx, r, text) {
  ctx.fillStyle = THEME.label;
  ctx.font = FONT_BOLD;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, r.x + r.w / 2, r.y + r.h / 2);
  ctx.font = FONT;
}

// Value → y pixel for a range {lo, hi}.
function yMapper(range, r) {
  const k = r.h / (range.hi - range.lo);
  return (v) => r.y + r.h - (v - range.lo) * k;
}

/* ------------------------------------------------------------------ */
/* Scales                                                             */
/* ------------------------------------------------------------------ */

// Auto range: data range plus margin, kept while the data stay inside and fill most of it.
function autoRange(range, lo, hi) {
  if (!(hi >= lo)) return;
  const extent = hi > lo ? hi - lo : Math.abs(hi) * 1e-3 || 1e-3;
  const tlo = lo - AUTO_MARGIN * extent;
  const thi = hi + AUTO_MARGIN * extent;
  const keep = range.valid && lo >= range.lo && hi <= range.hi && thi - tlo >= AUTO_KEEP_FILL * (range.hi - range.lo);
  if (keep) return;
  range.lo = tlo;
  range.hi = thi;
  range.valid = true;
}

// Updates a channel's displayed range from the visible data's extent.
function updateChannelRange(c, lo, hi) {
  const ch = channels[c];
  if (ch.auto) {
    autoRange(ch.range, lo, hi);
  } else {
    ch.range.lo = ch.offset - (ch.perDiv * Y_DIVS) / 2;
    ch.range.hi = ch.offset + (ch.perDiv * Y_DIVS) / 2;
    ch.range.valid = true;
  }
}

// Value-axis ticks of a channel: its divisions under a manual scale, nice steps otherwise.
function valueTicks(c) {
  const ch = channels[c];
  const r = ch.range;
  if (!ch.auto) {
    const out = [];
    for (let k = -Y_DIVS / 2; k <= Y_DIVS / 2; k++) out.push(ch.offset + k * ch.perDiv);
    return { values: out, step: ch.perDiv };
  }
  const step = niceStep(r.hi - r.lo, Y_DIVS);
  return { values: ticksBetween(r.lo, r.hi, step), step };
}

// The channel labelling the value axis: the chosen one if visible, else the first visible.
function axisChannel() {
  if (channels[settings.axisChannel].visible) return settings.axisChannel;
  const c = channels.findIndex((ch) => ch.visible);
  return c >= 0 ? c : settings.axisChannel;
}

/* ------------------------------------------------------------------ */
/* Main plot                                                          */
/* ------------------------------------------------------------------ */

// Per-column min–max envelopes of each channel, sized to the plot width.
function ensureEnvelopes(cols) {
  for (const ch of channels) {
    if (!ch.env || ch.env.min.length !== cols) {
      ch.env = { min: new Float32Array(cols), max: new Float32Array(cols), lineMode: true };
    }
  }
}

// Scans a channel's visible samples: envelope per pixel column (or line mode) and its range.
function scanTrace(c, view, cols) {
  const d = ring.data[c];
  const e = channels[c].env;
  const { first, last } = viewIndices(view);
  let lo = Infinity;
  let hi = -Infinity;
  e.lineMode = view.S / cols < ENVELOPE_MIN_SAMPLES_PER_PX;
  let p = first % RING_CAP;
  if (e.lineMode) {
    for (let i = first; i <= last; i++) {
      const v = d[p];
      if (v < lo) lo = v;
      if (v > hi) hi = v;
      if (++p === RING_CAP) p = 0;
    }
  } else {
    e.min.fill(Infinity);
    e.max.fill(-Infinity);
    const spc = view.S / cols;
    let prev = first - 1 >= oldestIndex() ? d[(p === 0 ? RING_CAP : p) - 1] : NaN;
    let i = first;
    for (let col = Math.max(0, Math.floor((first - view.start) / spc)); col < cols && i <= last; col++) {
      const end = col === cols - 1 ? last : Math.min(last, Math.ceil(view.start + (col + 1) * spc) - 1);
      let mn = Infinity;
      let mx = -Infinity;
      for (; i <= end; i++) {
        const v = d[p];
        if (v < mn) mn = v;
        if (v > mx) mx = v;
        if (++p === RING_CAP) p = 0;
      }
      if (mn < lo) lo = mn;
      if (mx > hi) hi = mx;
      // Each column reaches to the previous sample so neighbouring columns join.
      e.min[col] = prev < mn ? prev : mn;
      e.max[col] = prev > mx ? prev : mx;
      prev = d[(p === 0 ? RING_CAP : p) - 1];
    }
  }
  updateChannelRange(c, lo, hi);
}

// Draws one channel: min–max envelope per column, or sample-to-sample lines when zoomed in.
function drawTrace(ctx, r, c, view) {
  const ch = channels[c];
  const e = ch.env;
  const d = ring.data[c];
  const y = yMapper(ch.range, r);
  ctx.strokeStyle = ch.color;
  ctx.fillStyle = ch.color;
  ctx.lineWidth = 1;
  ctx.beginPath();
  if (e.lineMode) {
    const first = Math.max(oldestIndex(), Math.floor(view.start));
    const last = Math.min(ring.total - 1, Math.ceil(view.start + view.S));
    const kx = r.w / view.S;
    let p = first % RING_CAP;
    let pen = false;
    for (let i = first; i <= last; i++) {
      const v = d[p];
      const x = r.x + (i - view.start) * kx;
      if (v === v) {
        if (pen) ctx.lineTo(x, y(v)); else ctx.moveTo(x, y(v));
        pen = true;
      } else pen = false;
      if (++p === RING_CAP) p = 0;
    }
    ctx.stroke();
    if (kx >= DOT_MIN_PX_PER_SAMPLE) drawDots(ctx, d, first, last, view, r, kx, y);
  } else {
    fillEnvelope(ctx, r, e, y);
  }
}

// Fills each run of columns between its upper and lower envelope (at least 1 px thick).
function fillEnvelope(ctx, r, e, y) {
  const cols = e.min.length;
  let col = 0;
  while (col < cols) {
    while (col < cols && !(e.max[col] >= e.min[col])) col++;
    const begin = col;
    while (col < cols && e.max[col] >= e.min[col]) col++;
    if (col === begin) break;
    ctx.beginPath();
    for (let k = begin; k < col; k++) ctx.lineTo(r.x + k, y(e.max[k]) - 0.5);
    ctx.lineTo(r.x + col, y(e.max[col - 1]) - 0.5);
    ctx.lineTo(r.x + col, y(e.min[col - 1]) + 0.5);
    for (let k = col - 1; k >= begin; k--) ctx.lineTo(r.x + k, y(e.min[k]) + 0.5);
    ctx.closePath();
    ctx.fill();
  }
}

// Marks each sample with a dot (when zoomed in far).
function drawDots(ctx, d, first, last, view, r, kx, y) {
  let p = first % RING_CAP;
  for (let i = first; i <= last; i++) {
    const v = d[p];
    if (v === v) ctx.fillRect(r.x + (i - view.start) * kx - 1.5, y(v) - 1.5, 3, 3);
    if (++p === RING_CAP) p = 0;
  }
}

// Time grid and labels (t = 0 at the trigger point, or at the newest sample in roll mode).
function drawTimeGrid(ctx, r, view) {
  const rate = stream.sampleRate;
  const t0 = (view.start - view.ref) / rate;
  const span = view.S / rate;
  const unit = timeUnit(span);
  const step = niceStep(span, Math.max(2, Math.floor(r.w / 110)));
  const marks = ticksBetween(t0, t0 + span, step).map((t) => ({
    x: r.x + ((t - t0) / span) * r.w,
    label: fmtTick(t / unit.scale, step / unit.scale),
  }));
  const origin = view.trigger !== null ? 'trigger' : 'newest sample';
  gridX(ctx, r, marks, `time (${unit.name}), 0 = ${origin}`);
}

// Value grid, labels and title of the axis channel.
function drawValueGrid(ctx, r, c) {
  const ch = channels[c];
  if (!ch.range.valid) {
    gridY(ctx, r, Array.from({ length: Y_DIVS + 1 }, (_, k) => ({ y: r.y + (k * r.h) / Y_DIVS, label: '' })), ch.color);
    return;
  }
  const y = yMapper(ch.range, r);
  const { values, step } = valueTicks(c);
  gridY(ctx, r, values.map((v) => ({ y: y(v), label: fmtTick(v, step) })), ch.color);
  axisTitleY(ctx, r, chanLabel(c), ch.color);
}

// Red dashed lines where the ticks jumped (missed samples).
function drawGapMarks(ctx, r, view) {
  const kx = r.w / view.S;
  ctx.save();
  ctx.strokeStyle = THEME.gap;
  ctx.fillStyle = THEME.gap;
  ctx.setLineDash([4, 3]);
  ctx.textAlign = 'center';
  ctx.textBaseline = 'bottom';
  for (const g of ring.gapMarks) {
    const x = r.x + (g - 0.5 - view.start) * kx;
    if (x < r.x || x > r.x + r.w) continue;
    ctx.beginPath();
    ctx.moveTo(x, r.y + 14);
    ctx.lineTo(x, r.y + r.h);
    ctx.stroke();
    ctx.fillText('gap', x, r.y + 13);
  }
  ctx.restore();
}

// Trigger point (triangle and line) and level (dashed line with a "T" tab).
function drawTriggerMarks(ctx, r, view) {
  if (settings.mode === 'roll') return;
  ctx.save();
  ctx.strokeStyle = THEME.trigger;
  ctx.fillStyle = THEME.trigger;
  ctx.setLineDash([5, 4]);
  if (view.trigger !== null) {
    const x = r.x + ((view.trigger - view.start) / view.S) * r.w;
    ctx.globalAlpha = 0.55;
    ctx.beginPath();
    ctx.moveTo(x, r.y);
    ctx.lineTo(x, r.y + r.h);
    ctx.stroke();
    ctx.globalAlpha = 1;
    ctx.beginPath();
    ctx.moveTo(x - 6, r.y);
    ctx.lineTo(x + 6, r.y);
    ctx.lineTo(x, r.y + 9);
    ctx.fill();
  }
  const ch = channels[settings.trigChannel];
  if (ch.visible && ch.range.valid && Number.isFinite(settings.level)) {
    const y = yMapper(ch.range, r)(settings.level);
    if (y >= r.y && y <= r.y + r.h) {
      ctx.globalAlpha = 0.7;
      ctx.beginPath();
      ctx.moveTo(r.x, y);
      ctx.lineTo(r.x + r.w, y);
      ctx.stroke();
      ctx.globalAlpha = 1;
      ctx.setLineDash([]);
      const tx = r.x + r.w;
      ctx.beginPath();
      ctx.moveTo(tx, y - 7);
      ctx.lineTo(tx - 12, y - 7);
      ctx.lineTo(tx - 18, y);
      ctx.lineTo(tx - 12, y + 7);
      ctx.lineTo(tx, y + 7);
      ctx.fill();
      ctx.fillStyle = THEME.plot;
      ctx.font = FONT_BOLD;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'middle';
      ctx.fillText('T', tx - 8, y + 1);
    }
  }
  ctx.restore();
}

// Legend: colour, name and scale of each visible channel.
function drawLegend(ctx, r) {
  const lines = [];
  for (const ch of channels) {
    if (!ch.visible || !ch.range.valid) continue;
    const scale = ch.auto
      ? `auto ${fmtValue(ch.range.lo)} … ${fmtValue(ch.range.hi)} ${ch.unit}`
      : `${fmtValue(ch.perDiv)} ${ch.unit}/div, centre ${fmtValue(ch.offset)} ${ch.unit}`;
    lines.push({ color: ch.color, text: `${ch.name}  ${scale}` });
  }
  if (lines.length === 0) return;
  const w = Math.max(...lines.map((l) => ctx.measureText(l.text).width)) + 30;
  const h = lines.length * 16 + 6;
  ctx.fillStyle = THEME.legendBg;
  ctx.fillRect(r.x + 6, r.y + 6, w, h);
  ctx.textAlign = 'left';
  ctx.textBaseline = 'middle';
  lines.forEach((l, k) => {
    const y = r.y + 14 + k * 16;
    ctx.fillStyle = l.color;
    ctx.fillRect(r.x + 12, y - 1, 12, 3);
    ctx.fillStyle = THEME.text;
    ctx.fillText(l.text, r.x + 30, y);
  });
}

// State badge at the top right: ROLL, AUTO, TRIG'D, WAIT, STOP, PAUSED.
function drawBadge(ctx, r, view) {
  let text;
  if (view.kind === 'roll') text = settings.mode === 'auto' ? 'AUTO' : 'ROLL';
  else if (view.kind === 'trig') text = settings.mode === 'single' && trig.singleDone ? 'STOP' : "TRIG'D";
  else text = 'WAIT';
  if (settings.paused) text += ' · PAUSED';
  ctx.font = FONT_BOLD;
  const w = ctx.measureText(text).width + 14;
  ctx.fillStyle = settings.paused || text === 'STOP' ? '#5a3b12' : '#18324d';
  ctx.fillRect(r.x + r.w - w - 6, r.y + 6, w, 18);
  ctx.fillStyle = THEME.text;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, r.x + r.w - 6 - w / 2, r.y + 15.5);
  ctx.font = FONT;
}

// Cursor line and a readout of every visible channel at the sample under the mouse.
function drawCursor(ctx, r, view) {
  const mx = interact.cursorX;
  if (mx === null || mx < r.x || mx > r.x + r.w || interact.dragX !== null) return;
  const i = Math.round(view.start + ((mx - r.x) / r.w) * view.S);
  if (i < oldestIndex() || i >= ring.total) return;
  const rate = stream.sampleRate;
  const t = (i - view.ref) / rate;
  const unit = timeUnit(view.S / rate);
  const lines = [{ color: THEME.text, text: `t = ${fmtValue(t / unit.scale, 5)} ${unit.name}` }];
  channels.forEach((ch, c) => {
    if (ch.visible) lines.push({ color: ch.color, text: `${ch.name} = ${fmtValue(ring.data[c][i % RING_CAP], 5)} ${ch.unit}` });
  });
  ctx.strokeStyle = THEME.cursor;
  ctx.setLineDash([2, 3]);
  ctx.beginPath();
  ctx.moveTo(Math.round(mx) + 0.5, r.y);
  ctx.lineTo(Math.round(mx) + 0.5, r.y + r.h);
  ctx.stroke();
  ctx.setLineDash([]);
  const w = Math.max(...lines.map((l) => ctx.measureText(l.text).width)) + 12;
  const h = lines.length * 16 + 6;
  const bx = mx + 10 + w > r.x + r.w ? mx - 10 - w : mx + 10;
  const by = r.y + r.h - h - 8;
  ctx.fillStyle = THEME.legendBg;
  ctx.fillRect(bx, by, w, h);
  ctx.textAlign = 'left';
  ctx.textBaseline = 'middle';
  lines.forEach((l, k) => {
    ctx.fillStyle = l.color;
    ctx.fillText(l.text, bx + 6, by + 11 + k * 16);
  });
}

// Draws the main time plot for a view.
function drawMain(view) {
  const s = surfaces.main;
  const ctx = beginSurface(s);
  const r = plotRect(s, MAIN_MARGIN);
  fillPlot(ctx, r);
  const live = view.kind === 'roll' || view.kind === 'trig';
  const cols = Math.max(1, Math.floor(r.w));
  ensureEnvelopes(cols);
  if (live) channels.forEach((ch, c) => { if (ch.visible) scanTrace(c, view, cols); });
  drawTimeGrid(ctx, r, view);
  drawValueGrid(ctx, r, axisChannel());
  if (live) {
    ctx.save();
    ctx.beginPath();
    ctx.rect(r.x, r.y, r.w, r.h);
    ctx.clip();
    channels.forEach((ch, c) => { if (ch.visible) drawTrace(ctx, r, c, view); });
    ctx.restore();
    drawGapMarks(ctx, r, view);
  } else {
    plotMessage(ctx, r, view.kind === 'wait' ? 'waiting for trigger…' : 'waiting for data…');
  }
  strokeFrame(ctx, r);
  if (live) drawLegend(ctx, r);
  drawTriggerMarks(ctx, r, view);
  drawBadge(ctx, r, view);
  if (live) drawCursor(ctx, r, view);
}

// Mouse: wheel zoom, drag to pan while paused, cursor readout.
function bindMainCanvas() {
  const canvas = $('main-canvas');
  const localX = (e) => e.clientX - canvas.getBoundingClientRect().left;
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const notches = clamp(e.deltaY / WHEEL_NOTCH, -MAX_WHEEL_NOTCHES, MAX_WHEEL_NOTCHES);
    setSpan(settings.spanS * WHEEL_ZOOM ** notches, localX(e));
  }, { passive: false });
  canvas.addEventListener('pointermove', (e) => {
    interact.cursorX = localX(e);
    const f = interact.frozen;
    if (interact.dragX !== null && f) {
      const r = plotRect(surfaces.main, MAIN_MARGIN);
      f.start -= ((interact.cursorX - interact.dragX) / r.w) * f.S;
      interact.dragX = interact.cursorX;
      clampFrozen(f);
      spec.dirty = true;
    }
  });
  canvas.addEventListener('pointerleave', () => { interact.cursorX = null; });
  canvas.addEventListener('pointerdown', (e) => {
    if (!interact.frozen) return;
    interact.dragX = localX(e);
    canvas.setPointerCapture(e.pointerId);
    canvas.classList.add('panning');
  });
  const endDrag = () => { interact.dragX = null; canvas.classList.remove('panning'); };
  canvas.addEventListener('pointerup', endDrag);
  canvas.addEventListener('pointercancel', endDrag);
}

/* ------------------------------------------------------------------ */
/* Stillness and motion measures                                      */
/* ------------------------------------------------------------------ */

// The trigger channel's trace at MEASURE_POINTS screen positions of a view.
function sampleTrace(view, out) {
  const c = settings.trigChannel;
  for (let j = 0; j < MEASURE_POINTS; j++) out[j] = interpAt(c, view.start + ((j + 0.5) / MEASURE_POINTS) * view.S);
  return out;
}

// RMS difference of two traces over their joint peak-to-peak (null when undefined).
function traceDifference(a, b) {
  let sum = 0;
  let n = 0;
  let lo = Infinity;
  let hi = -Infinity;
  for (let j = 0; j < MEASURE_POINTS; j++) {
    const x = a[j];
    const y = b[j];
    if (!(Number.isFinite(x) && Number.isFinite(y))) continue;
    sum += (x - y) * (x - y);
    n++;
    lo = Math.min(lo, x, y);
    hi = Math.max(hi, x, y);
  }
  if (n === 0) return null;
  if (!(hi > lo)) return sum === 0 ? 0 : null;
  return Math.sqrt(sum / n) / (hi - lo);
}

// Updates the stillness (new triggered frames) or roll motion (roll frames) from the drawn view.
function measureFrame(view) {
  if (view.kind === 'trig' && view.fresh) {
    const cur = sampleTrace(view, trig.trace === measureScratch.a ? measureScratch.b : measureScratch.a);
    if (trig.trace) trig.stillness = traceDifference(trig.trace, cur);
    trig.trace = cur;
  }
  if (view.kind === 'roll') {
    const cur = sampleTrace(view, roll.trace === measureScratch.a ? measureScratch.b : measureScratch.a);
    if (roll.trace) roll.motion = traceDifference(roll.trace, cur);
    roll.trace = cur;
  } else {
    roll.trace = null;
  }
}

/* ------------------------------------------------------------------ */
/* Spectrum                                                           */
/* ------------------------------------------------------------------ */

// Window, twiddle and bit-reversal tables for an n-point FFT.
function prepareSpectrum(n) {
  spec.n = n;
  spec.win = new Float64Array(n);
  spec.sumW = 0;
  spec.sumW2 = 0;
  for (let i = 0; i < n; i++) {
    const w = 0.5 - 0.5 * Math.cos((2 * Math.PI * i) / n);
    spec.win[i] = w;
    spec.sumW += w;
    spec.sumW2 += w * w;
  }
  spec.re = new Float64Array(n);
  spec.im = new Float64Array(n);
  spec.cos = new Float64Array(n / 2);
  spec.sin = new Float64Array(n / 2);
  for (let k = 0; k < n / 2; k++) {
    spec.cos[k] = Math.cos((2 * Math.PI * k) / n);
    spec.sin[k] = Math.sin((2 * Math.PI * k) / n);
  }
  const bits = Math.log2(n);
  spec.rev = new Uint32Array(n);
  for (let i = 0; i < n; i++) {
    let r = 0;
    for (let b = 0; b < bits; b++) r |= ((i >> b) & 1) << (bits - 1 - b);
    spec.rev[i] = r;
  }
  spec.db = new Float32Array(n / 2 + 1);
  spec.valid = false;
  spec.dirty = true;
}

// In-place iterative radix-2 FFT (forward, e^{-2πi kn/N}).
function fft(re, im) {
  const n = re.length;
  const { rev, cos, sin } = spec;
  for (let i = 0; i < n; i++) {
    const j = rev[i];
    if (j > i) {
      let t = re[i]; re[i] = re[j]; re[j] = t;
      t = im[i]; im[i] = im[j]; im[j] = t;
    }
  }
  for (let size = 2; size <= n; size <<= 1) {
    const half = size >> 1;
    const step = n / size;
    for (let i = 0; i < n; i += size) {
      for (let j = 0, k = 0; j < half; j++, k += step) {
        const a = i + j;
        const b = a + half;
        const wr = cos[k];
        const wi = -sin[k];
        const xr = re[b] * wr - im[b] * wi;
        const xi = re[b] * wi + im[b] * wr;
        re[b] = re[a] - xr;
        im[b] = im[a] - xi;
        re[a] += xr;
        im[a] += xi;
      }
    }
  }
}

// Spectrum of the N samples ending at `end` (exclusive): mean removed, Hann window,
// one-sided amplitude (dB re 1 unit) or PSD (dB re 1 unit²/Hz), and the interpolated peak.
function computeSpectrum(end) {
  const n = spec.n;
  const c = settings.specChannel;
  const begin = end - n;
  if (begin < oldestIndex()) {
    spec.valid = false;
    spec.note = `collecting ${fmtCount(n)} samples…`;
    return;
  }
  const d = ring.data[c];
  let mean = 0;
  let finite = 0;
  for (let i = begin; i < end; i++) {
    const v = d[i % RING_CAP];
    if (Number.isFinite(v)) { mean += v; finite++; }
  }
  mean = finite ? mean / finite : 0;
  const { re, im, win } = spec;
  for (let k = 0; k < n; k++) {
    const v = d[(begin + k) % RING_CAP];
    re[k] = (Number.isFinite(v) ? v - mean : 0) * win[k];
    im[k] = 0;
  }
  fft(re, im);
  const rate = stream.sampleRate;
  const psd = settings.specKind === 'psd';
  for (let k = 0; k <= n / 2; k++) {
    const one = k === 0 || k === n / 2 ? 1 : 2;
    const mag2 = re[k] * re[k] + im[k] * im[k];
    spec.db[k] = psd
      ? 10 * Math.log10(Math.max(SPECTRUM_FLOOR, (one * mag2) / (rate * spec.sumW2)))
      : 20 * Math.log10(Math.max(SPECTRUM_FLOOR, (one * Math.sqrt(mag2)) / spec.sumW));
  }
  spec.rate = rate;
  spec.channel = c;
  spec.kind = settings.specKind;
  spec.valid = true;
  spec.note = '';
  findPeak();
}

// Highest bin above the first, refined by a parabola through it and its neighbours.
function findPeak() {
  const db = spec.db;
  let k = 2;
  for (let i = 3; i < spec.n / 2; i++) if (db[i] > db[k]) k = i;
  const a = db[k - 1];
  const b = db[k];
  const c = db[k + 1];
  const denom = a - 2 * b + c;
  const delta = denom !== 0 ? clamp((0.5 * (a - c)) / denom, -0.5, 0.5) : 0;
  spec.peakHz = ((k + delta) * spec.rate) / spec.n;
  spec.peakDb = b - 0.25 * (a - c) * delta;
}

// Axis label of the spectrum's values: dB re 1 unit (amplitude) or re 1 unit²/Hz (PSD).
function spectrumUnit() {
  const unit = channels[spec.channel].unit || 'unit';
  return spec.kind === 'psd' ? `dB re 1 ${unit}²/Hz` : `dB re 1 ${unit}`;
}

// Peak text: "peak 200.1 Hz, −12.0 dB" (dB/Hz for a PSD).
function peakText() {
  const db = withMinus(spec.peakDb.toFixed(1));
  return `peak ${fmtFreq(spec.peakHz, 5)}, ${db} ${spec.kind === 'psd' ? 'dB/Hz' : 'dB'}`;
}

// Draws the spectrum on a log frequency axis from rate/N to Nyquist.
function drawSpectrum() {
  const s = surfaces.spec;
  const ctx = beginSurface(s);
  const r = plotRect(s, PANEL_MARGIN);
  fillPlot(ctx, r);
  if (!spec.valid) {
    plotMessage(ctx, r, spec.note || 'no data');
    strokeFrame(ctx, r);
    return;
  }
  const n = spec.n;
  const f1 = spec.rate / n;
  const fN = spec.rate / 2;
  const kx = r.w / Math.log(fN / f1);
  const xOf = (f) => r.x + Math.log(f / f1) * kx;
  let top = -Infinity;
  let bottom = Infinity;
  for (let k = 1; k <= n / 2; k++) {
    top = Math.max(top, spec.db[k]);
    bottom = Math.min(bottom, spec.db[k]);
  }
  top = Math.ceil((top + 5) / 10) * 10;
  bottom = Math.max(Math.floor(bottom / 10) * 10, top - SPECTRUM_DB_SPAN_MAX);
  const y = yMapper({ lo: bottom, hi: top }, r);
  drawFrequencyGrid(ctx, r, f1, fN, xOf);
  const dbStep = niceStep(top - bottom, Math.max(2, Math.floor(r.h / 28)));
  gridY(ctx, r, ticksBetween(bottom, top, dbStep).map((v) => ({ y: y(v), label: fmtTick(v, dbStep) })), THEME.label);
  axisTitleY(ctx, r, spectrumUnit(), THEME.label);
  ctx.save();
  ctx.beginPath();
  ctx.rect(r.x, r.y, r.w, r.h);
  ctx.clip();
  drawSpectrumTrace(ctx, r, xOf, y);
  drawPeakMark(ctx, xOf(spec.peakHz), y(spec.peakDb));
  ctx.restore();
  strokeFrame(ctx, r);
  drawSpectrumCaption(ctx, r);
}

// Peak readout and analysis settings at the top right of the spectrum plot.
function drawSpectrumCaption(ctx, r) {
  ctx.textAlign = 'right';
  ctx.textBaseline = 'top';
  ctx.font = FONT_BOLD;
  ctx.fillStyle = THEME.peak;
  ctx.fillText(peakText(), r.x + r.w - 6, r.y + 5);
  ctx.font = FONT;
  ctx.fillStyle = THEME.label;
  ctx.fillText(`${channels[spec.channel].name} · ${fmtValue(spec.rate / spec.n, 3)} Hz/bin · Hann`, r.x + r.w - 6, r.y + 21);
}

// Spectrum trace: bins joined, the maximum kept where several share a pixel column.
function drawSpectrumTrace(ctx, r, xOf, y) {
  ctx.strokeStyle = channels[spec.channel].color;
  ctx.lineWidth = 1;
  ctx.beginPath();
  let col = -1;
  let best = -Infinity;
  let started = false;
  const flush = () => {
    if (col < 0) return;
    if (started) ctx.lineTo(col + 0.5, y(best)); else ctx.moveTo(col + 0.5, y(best));
    started = true;
  };
  for (let k = 1; k <= spec.n / 2; k++) {
    const x = Math.floor(xOf((k * spec.rate) / spec.n));
    if (x !== col) { flush(); col = x; best = -Infinity; }
    if (spec.db[k] > best) best = spec.db[k];
  }
  flush();
  ctx.stroke();
}

// Ring around the spectral peak.
function drawPeakMark(ctx, x, y) {
  ctx.strokeStyle = THEME.peak;
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ctx.arc(x, y, 5, 0, 2 * Math.PI);
  ctx.stroke();
}

// Decade grid lines (labelled) and 2…9 minor lines of a log frequency axis.
function drawFrequencyGrid(ctx, r, f1, fN, xOf) {
  const marks = [];
  for (let dec = 10 ** Math.floor(Math.log10(f1)); dec <= fN; dec *= 10) {
    for (let m = 1; m <= 9; m++) {
      const f = dec * m;
      if (f >= f1 && f <= fN) marks.push({ x: xOf(f), label: m === 1 ? fmtFreq(f) : '' });
    }
  }
  gridX(ctx, r, marks, 'frequency (Hz, log)');
}

/* ------------------------------------------------------------------ */
/* X–Y plot                                                           */
/* ------------------------------------------------------------------ */

const xyRanges = { x: { valid: false }, y: { valid: false } };

// Plots Y against X over the main view's samples (every k-th sample beyond XY_MAX_POINTS).
function drawXY(view) {
  const s = surfaces.xy;
  const ctx = beginSurface(s);
  const r = plotRect(s, PANEL_MARGIN);
  fillPlot(ctx, r);
  const cx = settings.xChannel;
  const cy = settings.yChannel;
  const { first, last } = viewIndices(view);
  const count = last - first + 1;
  if (view.kind === 'empty' || view.kind === 'wait' || count < 2) {
    plotMessage(ctx, r, 'no samples on screen');
    strokeFrame(ctx, r);
    $('xy-count').textContent = '';
    return;
  }
  const stride = Math.ceil(count / XY_MAX_POINTS);
  const dx = ring.data[cx];
  const dy = ring.data[cy];
  let xlo = Infinity, xhi = -Infinity, ylo = Infinity, yhi = -Infinity;
  for (let i = first; i <= last; i += stride) {
    const x = dx[i % RING_CAP];
    const y = dy[i % RING_CAP];
    if (x < xlo) xlo = x;
    if (x > xhi) xhi = x;
    if (y < ylo) ylo = y;
    if (y > yhi) yhi = y;
  }
  autoRange(xyRanges.x, xlo, xhi);
  autoRange(xyRanges.y, ylo, yhi);
  if (!xyRanges.x.valid || !xyRanges.y.valid) {
    plotMessage(ctx, r, 'no finite samples');
    return;
  }
  const X = xyRanges.x;
  const Y = xyRanges.y;
  const kx = r.w / (X.hi - X.lo);
  const yOf = yMapper(Y, r);
  const xStep = niceStep(X.hi - X.lo, Math.max(2, Math.floor(r.w / 80)));
  const yStep = niceStep(Y.hi - Y.lo, Math.max(2, Math.floor(r.h / 28)));
  gridX(ctx, r, ticksBetween(X.lo, X.hi, xStep).map((v) => ({ x: r.x + (v - X.lo) * kx, label: fmtTick(v, xStep) })), chanLabel(cx));
  gridY(ctx, r, ticksBetween(Y.lo, Y.hi, yStep).map((v) => ({ y: yOf(v), label: fmtTick(v, yStep) })), THEME.label);
  axisTitleY(ctx, r, chanLabel(cy), THEME.label);
  ctx.save();
  ctx.beginPath();
  ctx.rect(r.x, r.y, r.w, r.h);
  ctx.clip();
  ctx.strokeStyle = channels[cy].color;
  ctx.globalAlpha = 0.85;
  ctx.lineWidth = 1;
  ctx.beginPath();
  let pen = false;
  for (let i = first; i <= last; i += stride) {
    const x = dx[i % RING_CAP];
    const y = dy[i % RING_CAP];
    if (x === x && y === y) {
      if (pen) ctx.lineTo(r.x + (x - X.lo) * kx, yOf(y)); else ctx.moveTo(r.x + (x - X.lo) * kx, yOf(y));
      pen = true;
    } else pen = false;
  }
  ctx.stroke();
  ctx.restore();
  strokeFrame(ctx, r);
  const shown = Math.ceil(count / stride);
  $('xy-count').textContent = stride > 1
    ? `${fmtCount(shown)} of ${fmtCount(count)} samples (every ${stride}th)` : `${fmtCount(count)} samples`;
}

/* ------------------------------------------------------------------ */
/* Export                                                             */
/* ------------------------------------------------------------------ */

// Saves a blob under a name.
function download(blob, name) {
  const url = URL.createObjectURL(blob);
  const a = el('a', { href: url, download: name });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}

// File name with the local date and time.
function exportName(ext) {
  const d = new Date();
  const p = (v) => String(v).padStart(2, '0');
  return `fpi-scope-${d.getFullYear()}${p(d.getMonth() + 1)}${p(d.getDate())}-${p(d.getHours())}${p(d.getMinutes())}${p(d.getSeconds())}.${ext}`;
}

// Shortest decimal text that reads back as the same f32.
function fmtF32(v) {
  if (!Number.isFinite(v)) return String(v);
  for (let p = 7; p < 9; p++) {
    const s = v.toPrecision(p);
    if (Math.fround(Number(s)) === v) return String(Number(s));
  }
  return String(Number(v.toPrecision(9)));
}

// CSV of every sample on screen at full rate: t_s from the ticks, then each channel.
function exportCsv() {
  const view = interact.lastView;
  if (!view || view.kind === 'empty' || view.kind === 'wait') return;
  const { first, last } = viewIndices(view);
  if (last < first) return;
  const nch = channels.length;
  const tick0 = ring.ticks[first % RING_CAP];
  const decimals = Math.max(6, Math.ceil(Math.log10(stream.tickRate)) + 1);
  const parts = [`t_s,${stream.names.join(',')}\n`];
  let lines = [];
  for (let i = first; i <= last; i++) {
    const p = i % RING_CAP;
    let line = (((ring.ticks[p] - tick0) >>> 0) / stream.tickRate).toFixed(decimals);
    for (let c = 0; c < nch; c++) line += `,${fmtF32(ring.data[c][p])}`;
    lines.push(line);
    if (lines.length === 4096) { parts.push(`${lines.join('\n')}\n`); lines = []; }
  }
  if (lines.length) parts.push(`${lines.join('\n')}\n`);
  download(new Blob(parts, { type: 'text/csv' }), exportName('csv'));
}

// One PNG: the main plot, the visible panels below it side by side, and a caption line.
function exportPng() {
  const main = surfaces.main.canvas;
  const panels = [];
  if (settings.showSpectrum) panels.push(surfaces.spec.canvas);
  if (settings.showXY) panels.push(surfaces.xy.canvas);
  const dpr = surfaces.main.dpr;
  const W = main.width;
  const cellW = panels.length ? Math.floor(W / panels.length) : 0;
  const rowH = panels.length ? Math.max(...panels.map((p) => Math.round((p.height * cellW) / p.width))) : 0;
  const captionH = Math.round(24 * dpr);
  const out = el('canvas', { width: W, height: main.height + rowH + captionH });
  const ctx = out.getContext('2d');
  ctx.fillStyle = THEME.bg;
  ctx.fillRect(0, 0, out.width, out.height);
  ctx.drawImage(main, 0, 0);
  panels.forEach((p, k) => ctx.drawImage(p, k * cellW, main.height, cellW, Math.round((p.height * cellW) / p.width)));
  ctx.scale(dpr, dpr);
  ctx.font = FONT;
  ctx.fillStyle = THEME.text;
  ctx.textBaseline = 'middle';
  const peak = spec.valid ? ` · spectrum ${channels[spec.channel].name}: ${peakText()}` : '';
  ctx.fillText(`fpi scope · ${stream.board} · ${fmtCount(stream.sampleRate)} S/s · ${settings.mode} · ${new Date().toLocaleString()}${peak}`,
    8, (main.height + rowH + captionH / 2) / dpr);
  out.toBlob((blob) => download(blob, exportName('png')), 'image/png');
}

/* ------------------------------------------------------------------ */
/* Status line and self-report                                        */
/* ------------------------------------------------------------------ */

// Samples/s and frames/s over the last second.
function updateRates() {
  const now = performance.now();
  const dt = (now - stats.mark) / 1000;
  if (dt <= 0) return;
  stats.fps = (stats.frames - stats.markFrames) / dt;
  stats.receivedPerS = (ring.total - stats.markTotal) / dt;
  stats.mark = now;
  stats.markFrames = stats.frames;
  stats.markTotal = ring.total;
}

// Text of the trigger state.
function triggerState() {
  const view = interact.lastView;
  switch (settings.mode) {
    case 'auto': return view && view.kind === 'trig' ? 'auto: triggered' : 'auto: untriggered, rolling';
    case 'normal': return view && view.kind === 'trig' ? 'normal: triggered' : 'normal: waiting for trigger';
    case 'single': return trig.singleDone ? 'single: stopped (re-arm)' : 'single: armed';
    default: return 'roll';
  }
}

// Sets a status field's text and its red highlight.
function statusField(id, text, bad) {
  const e = $(id);
  e.textContent = text;
  e.classList.toggle('bad', Boolean(bad));
}

// Stream error, or a stall of the running stream, as shown in the status line.
function errorText() {
  if (stream.error) return stream.error + (stream.fatal ? ' (reading stopped)' : `, retrying every ${RETRY_MS / 1000} s`);
  const quiet = performance.now() - stream.lastData;
  return ring.total > 0 && quiet > STALL_MS ? `no data for ${(quiet / 1000).toFixed(1)} s` : '';
}

// Refreshes the status line.
function updateStatus() {
  statusField('st-rate', `${fmtCount(stats.receivedPerS)} S/s (${fmtCount(stream.sampleRate)} nominal)`);
  statusField('st-total', `${fmtCount(ring.total)} samples`);
  statusField('st-gaps', `gaps ${fmtCount(stream.gaps)}`, stream.gaps > 0);
  statusField('st-missing', `missing ${fmtCount(stream.missing)}`, stream.missing > 0);
  statusField('st-dropped', `dropped ${fmtCount(stream.dropped)}`, stream.dropped > 0);
  statusField('st-fps', `${stats.fps.toFixed(0)} fps`);
  statusField('st-state', settings.mode === 'roll' ? 'roll' : `${triggerState()} · ${fmtCount(trig.frames)} triggered frames`);
  statusField('st-paused', settings.paused ? 'paused' : '');
  statusField('st-error', errorText(), true);
  statusField('st-note', settings.notes.join(' · '));
  statusField('st-board', stream.board);
  showRanges();
}

// What the page shows, for automated tests.
function buildReport() {
  return {
    samples: ring.total,
    last_tick: ring.newestTick,
    rate_hz: stream.sampleRate,
    gaps: stream.gaps,
    missing: stream.missing,
    dropped: stream.dropped,
    frames: stats.frames,
    fps: stats.fps,
    received_per_s: stats.receivedPerS,
    mode: settings.mode,
    paused: settings.paused,
    error: stream.error,
    spectrum: {
      channel: stream.names[settings.specChannel],
      n: spec.n,
      resolution_hz: stream.sampleRate / spec.n,
      peak_hz: spec.valid ? spec.peakHz : null,
      peak_db: spec.valid ? spec.peakDb : null,
    },
    trigger: {
      channel: stream.names[settings.trigChannel],
      level: Number.isFinite(settings.level) ? settings.level : null,
      edge: settings.edge,
      pre: settings.pre,
      triggered_frames: trig.frames,
      stillness: trig.stillness,
    },
    roll_motion: roll.motion,
    trigger_output: { settings: tout.settings, error: tout.error },
  };
}

// Posts the report; a failure is shown in the status line.
async function postReport() {
  try {
    const resp = await fetch('/report', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(buildReport()),
    });
    if (!resp.ok) throw new Error(`HTTP ${resp.status}`);
    settings.notes = settings.notes.filter((n) => !n.startsWith('report'));
  } catch (e) {
    if (!settings.notes.some((n) => n.startsWith('report'))) settings.notes.push(`report failed: ${e.message}`);
  }
}

/* ------------------------------------------------------------------ */
/* The board's trigger output                                         */
/* ------------------------------------------------------------------ */

// Shows the levels of mode `mode` only.
function showToutLevels(mode) {
  for (const l of $('tout').querySelectorAll('label[data-for]')) {
    l.classList.toggle('off', !l.dataset.for.split(' ').includes(mode));
  }
}

// Fills the panel from the board's settings (levels in nm on the board, µm here).
function showTout(s) {
  tout.settings = s;
  $('tout-mode').value = s.mode;
  $('tout-step').value = String(s.step_nm / 1000);
  $('tout-band').value = String(s.band_nm / 1000);
  $('tout-low').value = String(s.low_nm / 1000);
  $('tout-high').value = String(s.high_nm / 1000);
  $('tout-pulse').value = String(s.pulse_ticks);
  $('tin').value = s.input;
  showToutLevels(s.mode);
}

// What the panel says under its controls: the board's settings, or why a change was refused.
function showToutState() {
  const st = $('tout-state');
  st.classList.toggle('bad', tout.error !== null);
  st.textContent = tout.error
    ?? (tout.settings ? `board: output ${tout.settings.mode}, input starts ${tout.settings.input}` : '');
}

// GET /trigger (body null) or POST it; the panel shows the outcome.
async function toutRequest(body) {
  try {
    const init = body === null ? { cache: 'no-store' }
      : { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) };
    const resp = await fetch('/trigger', init);
    const text = await resp.text();
    if (!resp.ok) throw new Error(text || `HTTP ${resp.status}`);
    showTout(JSON.parse(text));
    tout.error = null;
  } catch (e) {
    tout.error = e.message;
  }
  showToutState();
}

// The panel's settings as POST /trigger takes them.
function toutBody() {
  const mode = $('tout-mode').value;
  const num = (id) => Number($(id).value);
  const body = { mode, input: $('tin').value };
  if (mode === 'travel') body.step_um = num('tout-step');
  if (mode === 'on_target') body.band_um = num('tout-band');
  if (mode === 'window') { body.low_um = num('tout-low'); body.high_um = num('tout-high'); }
  if (mode === 'travel' || mode === 'point') body.pulse_ticks = num('tout-pulse');
  return body;
}

// Binds the panel and reads the board's settings (then applies a `tout=` query).
async function startTout() {
  $('tout-mode').onchange = (e) => showToutLevels(e.target.value);
  $('tout-set').onclick = () => toutRequest(toutBody());
  await toutRequest(null);
  if (settings.toutQuery) await toutRequest(settings.toutQuery);
}

/* ------------------------------------------------------------------ */
/* Frame loop and start-up                                            */
/* ------------------------------------------------------------------ */

// Recomputes the spectrum a few times a second (while paused: when the view changed).
function updateSpectrumPanel(now, view) {
  if (!spec.dirty && now - spec.last < SPECTRUM_PERIOD_MS) return;
  if (!settings.paused || spec.dirty) computeSpectrum(spectrumEnd(view));
  if (settings.showSpectrum) drawSpectrum();
  spec.last = now;
  spec.dirty = false;
}

// End (exclusive) of the spectrum's samples: the newest, or the paused view's right edge.
function spectrumEnd(view) {
  if (!settings.paused || view.kind === 'empty' || view.kind === 'wait') return ring.total;
  return Math.min(ring.total, Math.floor(view.start + view.S) + 1);
}

// One animation frame: view, main plot, panels, measures, status.
function frame(now) {
  requestAnimationFrame(frame);
  for (const s of Object.values(surfaces)) fitSurface(s);
  const view = computeView();
  interact.lastView = view;
  drawMain(view);
  measureFrame(view);
  if (settings.showXY) drawXY(view);
  updateSpectrumPanel(now, view);
  stats.frames++;
  if (now - stats.lastStatus >= STATUS_PERIOD_MS) {
    updateStatus();
    stats.lastStatus = now;
  }
}

// Channel display state from /info.
function makeChannels(info) {
  return info.channels.map((c, k) => ({
    name: String(c.name), unit: String(c.unit ?? ''), color: COLORS[k % COLORS.length],
    visible: true, auto: true, perDiv: 1, offset: 0, range: { lo: 0, hi: 1, valid: false }, env: null, ui: null,
  }));
}

// Loads /info (retrying), sets everything up and starts the stream and the frame loop.
async function start() {
  let info;
  for (;;) {
    try {
      info = await fetchInfo();
      break;
    } catch (e) {
      stream.error = `cannot load /info (${e.message})`;
      statusField('st-error', `${stream.error}, retrying every ${RETRY_MS / 1000} s`, true);
      await sleep(RETRY_MS);
    }
  }
  stream.error = null;
  stream.tickRate = Number(info.rate_hz);
  ring.dec = Number(info.decimation);
  stream.sampleRate = stream.tickRate / ring.dec;
  stream.board = String(info.board ?? '');
  stream.names = info.channels.map((c) => String(c.name));
  channels = makeChannels(info);
  ringInit(channels.length);
  applyDefaults();
  applyQuery();
  prepareSpectrum(settings.fftN);
  buildControls();
  addSurface('main', $('main-canvas'));
  addSurface('spec', $('spec-canvas'));
  addSurface('xy', $('xy-canvas'));
  stats.mark = performance.now();
  setInterval(updateRates, RATE_PERIOD_MS);
  if (settings.reportMs > 0) setInterval(postReport, settings.reportMs);
  requestAnimationFrame(frame);
  runStream();
  startTout();
}

start();
