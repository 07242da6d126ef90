// leaffit-usd edit — the page. Talks only to its own server (relative URLs keep the token).
// Picking and geodesic selections run server-side (BVH + heat geodesics); the page draws the
// capture as sorted, alpha-blended splats (splats.js; dots as an option), sends rays, shows the
// selection the server returns and the fitted leaf of the checked instance (api/leaf).
import * as THREE from './three.bundle.min.js';
import { OverlayRenderer, SplatRenderer, parseSplats } from './splats.js';

const $ = (id) => document.getElementById(id);
const statusEl = $('status');

function setStatus(text, error = false) {
  statusEl.textContent = text;
  statusEl.classList.toggle('error', error);
}

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
  };
  const r = await fetch('api/' + path, init);
  const type = r.headers.get('Content-Type') || '';
  if (!r.ok) {
    let msg = `${r.status} ${r.statusText}`;
    if (type.includes('json')) msg = (await r.json()).error || msg;
    throw new Error(msg);
  }
  return type.includes('json') ? r.json() : r.arrayBuffer();
}

const b64bytes = (s) => Uint8Array.from(atob(s), (c) => c.charCodeAt(0));

// ---- state ------------------------------------------------------------------------------
const S = {
  n: 0, meta: null, positions: null, rgb: null,
  labels: null, selBits: null, previewBits: null, leaves: [], stemCount: 0,
  tool: 'brush', busy: false, gesture: null, lastPickMs: 0, lastUpdateMs: 0, ready: false,
  drawn: false, firstFrameMs: null, splitSeed: null, preview: null, previewSeq: 0, opSeq: 0,
};

function selected(i, bits) {
  return (bits[i >> 3] >> (7 - (i & 7))) & 1;
}

function leafColor(label) {
  // golden-angle hues: neighbouring labels get distinct colours
  // (hues near yellow are skipped: yellow marks the selection, as in the paper's GUI)
  const c = new THREE.Color();
  let h = (label * 0.61803398875 + 0.08) % 1;
  if (h > 0.1 && h < 0.21) h += 0.11;
  c.setHSL(h, 0.62, 0.52);
  return c;
}

// ---- scene ------------------------------------------------------------------------------
const view = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true, alpha: false });
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.autoClear = false;
renderer.setClearColor(0x1d1f21, 1);
view.appendChild(renderer.domElement);
const gl = renderer.getContext();
const splats = new SplatRenderer(gl);
const overlay = new OverlayRenderer(gl);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(40, 1, 0.005, 50);
const controls = new THREE.OrbitControls(camera, renderer.domElement);
controls.enableDamping = false;
const geometry = new THREE.BufferGeometry();
const material = new THREE.PointsMaterial({ size: 0.006, vertexColors: true, sizeAttenuation: true });
const points = new THREE.Points(geometry, material);
points.visible = false;
scene.add(points);
const dotsMode = () => $('dots').checked;

// back-to-front order from the worker; a new sort is asked for whenever the view has changed
const sorter = new Worker(new URL('./sort-worker.js', import.meta.url));
const sortState = { busy: false, stale: false, id: 0 };
function requestSort() {
  if (!S.n || dotsMode()) return;
  if (sortState.busy) { sortState.stale = true; return; }
  sortState.busy = true;
  sortState.stale = false;
  camera.updateMatrixWorld();
  sorter.postMessage({ id: ++sortState.id, view: Float32Array.from(camera.matrixWorldInverse.elements) });
}
sorter.onmessage = (e) => {
  splats.setOrder(e.data.order);
  sortState.busy = false;
  if (sortState.stale) requestSort();
  render();
};

function drawFrame() {
  camera.updateMatrixWorld();
  const size = renderer.getDrawingBufferSize(new THREE.Vector2());
  renderer.setRenderTarget(null);
  renderer.clear();
  if (!dotsMode()) {
    renderer.resetState();
    splats.draw(camera, size.x, size.y);
  }
  renderer.resetState();
  points.visible = dotsMode();
  renderer.render(scene, camera);
  renderer.resetState();
  overlay.draw(camera, size.x, size.y);
  renderer.resetState();
  if (S.n && (dotsMode() || splats.hasOrder) && S.firstFrameMs === null) {
    S.firstFrameMs = performance.now();  // ms since the page started loading
    S.drawn = true;
  }
}

let renderQueued = false;
function render() {
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(() => { renderQueued = false; drawFrame(); });
}
controls.addEventListener('change', () => { requestSort(); render(); });

function resize() {
  const w = view.clientWidth || 1, h = view.clientHeight || 1;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  render();
}
new ResizeObserver(resize).observe(view);

function setTool(tool) {
  S.tool = tool;
  if (tool !== 'split' && S.splitSeed !== null) { S.splitSeed = null; markSeed(null); }
  if (tool === 'orbit') {
    controls.mouseButtons = { LEFT: THREE.MOUSE.ROTATE, MIDDLE: THREE.MOUSE.DOLLY, RIGHT: THREE.MOUSE.PAN };
  } else {
    controls.mouseButtons = { LEFT: -1, MIDDLE: THREE.MOUSE.PAN, RIGHT: THREE.MOUSE.ROTATE };
  }
  renderer.domElement.style.cursor = tool === 'orbit' ? 'grab' : 'crosshair';
}

const TINT = 0.55;  // how much of the label colour replaces a splat's own (tint on)

function recolor() {
  // tint per Gaussian (RGBA8: label colour, its weight): the selection in yellow, leaves in their
  // colour, the stem darkened; with the tint off only the selection is marked
  if (!S.n) return;
  const tint = new Uint8Array(4 * S.n);
  const tinted = $('tint').checked && S.labels;
  const bits = S.previewBits || S.selBits;
  const cache = new Map();
  const w = Math.round(255 * TINT);
  for (let i = 0; i < S.n; i++) {
    const o = 4 * i;
    if (bits && selected(i, bits)) { tint[o] = 255; tint[o + 1] = 219; tint[o + 2] = 26; tint[o + 3] = 230; continue; }
    if (!tinted) continue;
    const lab = S.labels[i];
    if (lab === 0) { tint[o + 3] = w; continue; }  // black at 55%: the stem, darkened
    let c = cache.get(lab);
    if (!c) { c = leafColor(lab); cache.set(lab, [255 * c.r, 255 * c.g, 255 * c.b]); c = cache.get(lab); }
    tint[o] = c[0]; tint[o + 1] = c[1]; tint[o + 2] = c[2]; tint[o + 3] = w;
  }
  splats.setTint(tint);
  if (dotsMode()) {
    const a = geometry.getAttribute('color').array;
    for (let i = 0; i < S.n; i++) {
      const t = tint[4 * i + 3] / 255;
      for (let k = 0; k < 3; k++) a[3 * i + k] = ((1 - t) * S.rgba[4 * i + k] + t * tint[4 * i + k]) / 255;
    }
    geometry.getAttribute('color').needsUpdate = true;
  }
  render();
}

// ---- state from the server ----------------------------------------------------------------
function applyState(st) {
  S.labels = new Int32Array(b64bytes(st.labels).buffer);
  S.selBits = b64bytes(st.selection);
  S.previewBits = null;
  S.leaves = st.leaves;
  S.stemCount = st.stem;
  S.state = st;
  $('sel-count').textContent = st.selected;
  $('undo').disabled = !st.can_undo;
  $('redo').disabled = !st.can_redo;
  $('save').textContent = st.dirty ? 'Save*' : 'Save';
  $('next-doubtful').disabled = !doubtfulLeaves().length;
  renderLeafList();
  recolor();
  S.opSeq = st.n_ops;
  updatePreview();
}

// ---- the fitted leaf of the checked instance ----------------------------------------------
// The server fits the template to the checked leaf (fast path, see viewer/leaf_preview.py) and
// returns the deformed sheet, display frame; it is drawn over the splats as a translucent
// sheet with its grid lines. Asked for again after every edit (cached server-side by the leaf's
// Gaussians, so an edit elsewhere costs nothing).
async function updatePreview() {
  const ch = checkedLeaves();
  const want = $('fit').checked && S.ready && ch.length === 1 ? ch[0] : null;
  const seq = ++S.previewSeq;
  if (want === null) { overlay.remove('leaf-fill'); overlay.remove('leaf-grid'); S.preview = null; render(); return; }
  const t0 = performance.now();
  let res;
  try { res = await api('leaf', { label: want }); } catch (e) { setStatus(String(e.message || e), true); return; }
  if (seq !== S.previewSeq) return;  // a newer request is on its way
  if (res.none) {
    overlay.remove('leaf-fill'); overlay.remove('leaf-grid');
    S.preview = { label: want, none: res.none, ops: S.opSeq, ms: performance.now() - t0 };
    status(res.none);
    render();
    return;
  }
  const v = new Float32Array(b64bytes(res.vertices).buffer);
  overlay.set('leaf-fill', v, new Uint32Array(b64bytes(res.faces).buffer), 'TRIANGLES', [0.35, 0.85, 1.0, 0.18]);
  overlay.set('leaf-grid', v, new Uint32Array(b64bytes(res.edges).buffer), 'LINES', [0.55, 0.95, 1.0, 0.85]);
  S.preview = { label: want, vertices: v.length / 3, ops: S.opSeq, ms: performance.now() - t0,
    serverMs: res.ms, fallback: res.fallback, error: res.error };
  status();
  render();
}

// ---- confidence ---------------------------------------------------------------------------
// Each leaf row carries the confidence of the segmentation the session started from (null for
// leaves made by edits) and a doubtful flag (confidence below meta.doubtful_below).
const confKey = (r) => (r.confidence === null || r.confidence === undefined ? 2 : r.confidence);

function doubtfulLeaves() {
  // doubtful leaves, least confident first
  return S.leaves.filter((r) => r.doubtful).sort((a, b) => confKey(a) - confKey(b) || a.label - b.label);
}

function leafRows() {
  const rows = [...S.leaves];
  if ($('sort-conf').checked) rows.sort((a, b) => confKey(a) - confKey(b) || a.label - b.label);
  return rows;
}

function leafSphere(label) {
  // centre and radius (display frame) of the bounding box of a leaf's Gaussians, or null
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  let n = 0;
  for (let i = 0; i < S.n; i++) {
    if (S.labels[i] !== label) continue;
    n++;
    for (let k = 0; k < 3; k++) {
      const v = S.positions[3 * i + k];
      if (v < lo[k]) lo[k] = v;
      if (v > hi[k]) hi[k] = v;
    }
  }
  if (!n) return null;
  const c = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  return { center: c, radius: 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) };
}

function focusLeaf(label) {
  // point the camera at a leaf, keeping the viewing direction; close enough to fill the view
  const s = leafSphere(label);
  if (!s) return;
  const dir = camera.position.clone().sub(controls.target).normalize();
  controls.target.copy(s.center);
  camera.position.copy(s.center).addScaledVector(dir, Math.max(3.2 * s.radius, 0.12));
  controls.update();
  render();
}

function showLeaf(label) {
  // check this leaf only (Merge/Split/Delete act on it), scroll its row into view, look at it
  for (const cb of $('leaves').querySelectorAll('input')) cb.checked = +cb.dataset.label === label;
  updatePreview();
  const row = $('leaves').querySelector(`.leaf[data-label="${label}"]`);
  if (row && row.scrollIntoView) row.scrollIntoView({ block: 'nearest' });
  focusLeaf(label);
}

function nextDoubtful() {
  const list = doubtfulLeaves();
  if (!list.length) return setStatus('no doubtful leaf');
  const ch = checkedLeaves();
  const at = ch.length === 1 ? list.findIndex((r) => r.label === ch[0]) : -1;
  const r = list[(at + 1) % list.length];
  showLeaf(r.label);
  status(`leaf ${r.label}: confidence ${r.confidence.toFixed(2)} (doubtful ${list.indexOf(r) + 1} of ${list.length})`);
}

function homeView() {
  if (!S.home) return;
  controls.target.copy(S.home.target);
  camera.position.copy(S.home.position);
  controls.update();
  render();
}

function renderLeafList() {
  const box = $('leaves');
  const checked = new Set([...box.querySelectorAll('input:checked')].map((e) => +e.dataset.label));
  box.textContent = '';
  const least = S.state ? S.state.least_confident : null;
  const rows = [{ label: 0, count: S.stemCount, confidence: null, doubtful: false }, ...leafRows()];
  for (const { label, count, confidence, doubtful } of rows) {
    const row = document.createElement('div');
    row.className = 'leaf';
    row.classList.toggle('doubtful', !!doubtful);
    row.classList.toggle('least', label !== 0 && label === least);
    row.dataset.label = label;
    const cb = document.createElement('input');
    cb.type = 'checkbox';
    cb.dataset.label = label;
    cb.disabled = label === 0;
    cb.checked = checked.has(label);
    cb.addEventListener('change', updatePreview);
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = label === 0 ? '#555' : '#' + leafColor(label).getHexString();
    const name = document.createElement('span');
    name.textContent = label === 0 ? `Stem / unassigned (${count})` : `Leaf ${label} (${count})`;
    name.title = 'click: select this leaf (Shift: add)';
    name.addEventListener('click', (e) =>
      runOp({ op: 'select_leaf', label, mode: e.shiftKey ? 'add' : 'replace' }));
    row.append(cb, sw, name);
    if (label !== 0) {
      const known = confidence !== null && confidence !== undefined;
      const conf = document.createElement('span');
      conf.className = 'conf';
      conf.textContent = known ? confidence.toFixed(2) : '–';
      row.title = known
        ? `confidence ${confidence.toFixed(2)}` + (doubtful ? ' — doubtful: check this leaf' : '') +
          (label === least ? ' (the least confident)' : '')
        : 'confidence unknown (a leaf made or reshaped by edits, or none given)';
      row.append(conf);
      if (doubtful) {
        const badge = document.createElement('span');
        badge.className = 'badge';
        badge.textContent = '?';
        row.append(badge);
      }
    }
    box.append(row);
  }
  $('leaf-count').textContent = `(${S.leaves.length})`;
  const target = $('target');
  const keep = target.value;
  target.textContent = '';
  const opts = [['new', 'new leaf'], ['0', 'stem'],
    ...S.leaves.map((l) => [String(l.label), `leaf ${l.label}` + (l.doubtful ? ' ?' : '')])];
  for (const [v, t] of opts) {
    const o = document.createElement('option');
    o.value = v; o.textContent = t;
    target.append(o);
  }
  if ([...target.options].some((o) => o.value === keep)) target.value = keep;
}

function checkedLeaves() {
  return [...$('leaves').querySelectorAll('input:checked')].map((e) => +e.dataset.label).sort((a, b) => a - b);
}

async function runOp(op) {
  try {
    const st = await api('op', { op });
    S.lastUpdateMs = st.ms;
    applyState(st);
    status();
  } catch (e) { setStatus(String(e.message || e), true); }
}

function confidenceLine() {
  const least = S.state ? S.state.least_confident : null;
  const row = S.leaves.find((r) => r.label === least);
  if (!row) return '';
  const k = doubtfulLeaves().length;
  return `\nleaf ${least} is the least confident (${row.confidence.toFixed(2)})` +
    (k ? ` · ${k} doubtful ${k > 1 ? 'leaves' : 'leaf'} marked ?` : '');
}

function previewLine() {
  const p = S.preview;
  if (!p || p.none) return '';
  return `\nfitted leaf ${p.label}: ${p.ms.toFixed(0)} ms` + (p.fallback ? ' (rigid: degenerate leaf)' : '');
}

function status(extra = '') {
  setStatus(`${S.n} Gaussians · ${S.leaves.length} leaves · ${S.state ? S.state.n_ops : 0} edits\n` +
    `pick ${S.lastPickMs.toFixed(1)} ms · update ${S.lastUpdateMs.toFixed(1)} ms` + previewLine() +
    confidenceLine() + (extra ? `\n${extra}` : ''));
}

// ---- picking and tools ------------------------------------------------------------------
const raycaster = new THREE.Raycaster();
function rayAt(clientX, clientY) {
  const r = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  return { origin: raycaster.ray.origin.toArray(), direction: raycaster.ray.direction.toArray() };
}

async function pickAt(x, y) {
  const res = await api('pick', rayAt(x, y));
  S.lastPickMs = res.ms;
  return res.index;
}

function currentMode(e) {
  if (e.shiftKey) return 'add';
  if (e.altKey) return 'erase';
  return document.querySelector('input[name=mode]:checked').value;
}

function farEnough(a, b, d) {
  // brush stamps closer than d (display frame = plant heights) add nothing visible: skip them,
  // which keeps strokes (and their replay) short
  if (a === b) return false;
  const p = S.positions;
  const dx = p[3 * a] - p[3 * b], dy = p[3 * a + 1] - p[3 * b + 1], dz = p[3 * a + 2] - p[3 * b + 2];
  return dx * dx + dy * dy + dz * dz >= d * d;
}

async function step() {
  // process the latest pointer position of the gesture (one request in flight at a time)
  const g = S.gesture;
  if (!g || S.busy || !g.pending) return;
  const { x, y } = g.pending;
  g.pending = null;
  S.busy = true;
  try {
    const idx = await pickAt(x, y);
    if (idx >= 0) {
      if (g.op.op === 'drag') g.op.target = idx;
      else if (farEnough(g.op.centers[g.op.centers.length - 1], idx, 0.3 * g.op.radius)) g.op.centers.push(idx);
      const res = await api('preview', { op: g.op });
      S.lastUpdateMs = res.ms;
      if (S.gesture === g) {
        S.previewBits = b64bytes(res.selection);
        $('sel-count').textContent = res.selected;
        recolor();
      }
      status();
    }
  } catch (e) { setStatus(String(e.message || e), true); }
  S.busy = false;
  if (g.pending) step();
  else if (g.finish) g.finish();
}

// ---- click-to-split: one click on each of the two leaves merged into one instance ------------
function markSeed(idx) {
  if (idx === null) { overlay.remove('seed'); render(); return; }
  const p = S.positions;
  overlay.set('seed', new Float32Array([p[3 * idx], p[3 * idx + 1], p[3 * idx + 2]]), null, 'POINTS',
    [1.0, 0.3, 0.9, 1.0], 12);
  render();
}

async function splitClick(e) {
  let idx;
  try { idx = await pickAt(e.clientX, e.clientY); } catch (err) { return setStatus(String(err.message || err), true); }
  if (!(idx >= 0)) return setStatus('nothing under the cursor');
  const lab = S.labels[idx];
  if (S.splitSeed === null) {
    if (lab === 0) return setStatus('click on a leaf (this is the stem / unassigned)', true);
    S.splitSeed = idx;
    markSeed(idx);
    return status(`split leaf ${lab}: now click on the other leaf inside it (Esc: cancel)`);
  }
  const a = S.splitSeed;
  S.splitSeed = null;
  markSeed(null);
  await runOp({ op: 'split_at', seeds: [a, idx] });
}

renderer.domElement.addEventListener('pointerdown', async (e) => {
  if (e.button !== 0 || S.tool === 'orbit' || !S.ready) return;
  e.preventDefault();
  if (S.tool === 'split') { splitClick(e); return; }
  const radius = +$('radius').value;
  const mode = currentMode(e);
  const g = { op: null, pending: null, finish: null };
  S.gesture = g;
  S.busy = true;
  let idx;
  try { idx = await pickAt(e.clientX, e.clientY); } catch (err) { setStatus(String(err), true); }
  S.busy = false;
  if (!(idx >= 0)) { S.gesture = null; setStatus('nothing under the cursor'); return; }
  g.op = S.tool === 'drag'
    ? { op: 'drag', source: idx, target: idx, mode }
    : { op: 'brush', centers: [idx], radius, mode };
  g.pending = { x: e.clientX, y: e.clientY };
  if (!g.released) step();
  if (g.released) commit(g);
});

renderer.domElement.addEventListener('pointermove', (e) => {
  const g = S.gesture;
  if (!g || !g.op) return;
  g.pending = { x: e.clientX, y: e.clientY };
  step();
});

function commit(g) {
  const done = () => {
    if (S.gesture !== g) return;
    S.gesture = null;
    runOp(g.op);
  };
  if (S.busy || g.pending) { g.finish = done; if (!S.busy) step(); } else done();
}

window.addEventListener('pointerup', (e) => {
  const g = S.gesture;
  if (!g || e.button !== 0) return;
  g.released = true;
  if (g.op) commit(g);
});

// ---- buttons and keys -------------------------------------------------------------------
function assign() {
  const v = $('target').value;
  runOp({ op: 'assign', label: v === 'new' ? 'new' : +v });
}
$('assign').addEventListener('click', assign);
$('clear').addEventListener('click', () => runOp({ op: 'clear' }));
$('merge').addEventListener('click', () => {
  const ls = checkedLeaves();
  if (ls.length < 2) return setStatus('check at least two leaves to merge', true);
  runOp({ op: 'merge', labels: ls });
});
$('split').addEventListener('click', () => {
  const ls = checkedLeaves();
  if (ls.length !== 1) return setStatus('check exactly one leaf to split by the selection', true);
  runOp({ op: 'split', label: ls[0] });
});
$('delete').addEventListener('click', async () => {
  for (const l of checkedLeaves()) await runOp({ op: 'delete', label: l });
});
$('undo').addEventListener('click', async () => { applyState(await api('undo', {})); status(); });
$('redo').addEventListener('click', async () => { applyState(await api('redo', {})); status(); });
async function save() {
  try {
    const res = await api('save', {});
    applyState(res.state);
    $('outputs').textContent = `saved ${res.edits} (${res.operations} edits) and ${res.labels} (${res.leaves} leaves)`;
    status('saved');
  } catch (e) { setStatus(String(e.message || e), true); }
}
$('save').addEventListener('click', save);
$('quit').addEventListener('click', async () => {
  if (S.state && S.state.dirty && !window.confirm('Quit without saving the last edits?')) return;
  await api('stop', {}).catch(() => null);
  S.ready = false;
  setStatus('The server has stopped; you can close this tab.');
});
$('tint').addEventListener('change', recolor);
$('dots').addEventListener('change', () => { recolor(); requestSort(); render(); });
$('fit').addEventListener('change', updatePreview);
$('sort-conf').addEventListener('change', renderLeafList);
$('next-doubtful').addEventListener('click', nextDoubtful);
$('home').addEventListener('click', homeView);
for (const r of document.querySelectorAll('input[name=tool]')) r.addEventListener('change', () => setTool(r.value));
$('radius').addEventListener('input', () => { $('radius-value').textContent = (+$('radius').value).toFixed(3); });
window.addEventListener('keydown', (e) => {
  if (e.target.tagName === 'INPUT' && e.target.type === 'text') return;
  const k = e.key.toLowerCase();
  if ((e.ctrlKey || e.metaKey) && k === 'z') { e.preventDefault(); $(e.shiftKey ? 'redo' : 'undo').click(); }
  else if ((e.ctrlKey || e.metaKey) && k === 'y') { e.preventDefault(); $('redo').click(); }
  else if ((e.ctrlKey || e.metaKey) && k === 's') { e.preventDefault(); save(); }
  else if (k === 'enter') assign();
  else if (k === 'escape' && S.splitSeed !== null) { S.splitSeed = null; markSeed(null); status('split cancelled'); }
  else if (k === 'escape') runOp({ op: 'clear' });
  else if (k === 'x') { document.querySelector('input[value=split]').click(); }
  else if (k === 'b') { document.querySelector('input[value=brush]').click(); }
  else if (k === 'd') { document.querySelector('input[value=drag]').click(); }
  else if (k === 'v') { document.querySelector('input[value=orbit]').click(); }
  else if (k === 'n') nextDoubtful();
  else if (k === 'h') homeView();
});
window.addEventListener('beforeunload', (e) => { if (S.state && S.state.dirty) e.preventDefault(); });

// ---- start ------------------------------------------------------------------------------
function robustSphere(pos) {
  // centre and radius of the 2nd..98th percentile box of (a subsample of) the points
  const n = pos.length / 3, step = Math.max(1, Math.floor(n / 20000));
  const axes = [[], [], []];
  for (let i = 0; i < n; i += step) for (let k = 0; k < 3; k++) axes[k].push(pos[3 * i + k]);
  const lo = [], hi = [];
  for (const a of axes) {
    a.sort((x, y) => x - y);
    lo.push(a[Math.floor(0.02 * (a.length - 1))]);
    hi.push(a[Math.ceil(0.98 * (a.length - 1))]);
  }
  const c = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  const r = 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  return { center: c, radius: Math.max(r, 1e-3) };
}

async function main() {
  const meta = await api('meta');
  S.meta = meta;
  S.n = meta.n;
  $('input-name').textContent = meta.input;
  $('radius').value = meta.brush_radius;
  $('radius-value').textContent = (+meta.brush_radius).toFixed(3);
  $('outputs').textContent = `Save writes ${meta.edits_out} and ${meta.labels_out}`;
  const sp = parseSplats(await api('splats'), S.n);
  S.positions = sp.positions;
  S.rgba = sp.rgba;
  splats.setData(sp, S.n);
  sorter.postMessage({ positions: Float32Array.from(S.positions) });  // a copy: the page keeps its own
  geometry.setAttribute('position', new THREE.BufferAttribute(S.positions, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(3 * S.n), 3));
  geometry.computeBoundingSphere();
  material.size = Math.min(0.02, Math.max(0.002, 2.2 / Math.sqrt(S.n)));
  // camera: look at the plant from the side (perpendicular to up), a little from above
  const up = new THREE.Vector3(...meta.up).normalize();
  const side = Math.abs(up.z) < 0.9 ? new THREE.Vector3(0, 0, 1) : new THREE.Vector3(0, 1, 0);
  const dir = side.sub(up.clone().multiplyScalar(side.dot(up))).normalize();
  const sphere = robustSphere(S.positions);  // floaters do not decide the framing
  camera.up.copy(up);
  controls.target.copy(sphere.center);
  camera.position.copy(sphere.center).addScaledVector(dir, sphere.radius * 2.2).addScaledVector(up, sphere.radius * 1.0);
  camera.lookAt(sphere.center);
  controls.update();
  S.home = { target: controls.target.clone(), position: camera.position.clone() };
  setTool(document.querySelector('input[name=tool]:checked').value);
  recolor();  // the capture's own colours until the labels come
  resize();
  requestSort();
  // the session may still be starting (segmentation, geodesics): the capture is shown meanwhile
  let st = await api('state');
  while (!st.ready) {
    if (st.failed) return setStatus('could not start: ' + st.failed, true);
    setStatus(`${S.n} Gaussians · preparing the editor: ${st.phase}…`);
    await new Promise((r) => setTimeout(r, 250));
    st = await api('state');
  }
  S.ready = true;
  applyState(st);
  // open on the least confident leaf: checked, in view
  if (st.least_confident !== null && st.least_confident !== undefined) showLeaf(st.least_confident);
  status();
}

// A small hook for tests and scripting: where a Gaussian is on screen, and the state.
window.leaffit = {
  get ready() { return S.ready; },
  get busy() { return S.busy || !!S.gesture; },
  get drawn() { return S.drawn; },  // the first frame of the capture is on screen
  get firstFrameMs() { return S.firstFrameMs; },  // when it was (ms since navigation start)
  preview() { return S.preview; },  // the fitted leaf shown: {label, vertices, ops, ms, ...} or null
  mode() { return dotsMode() ? 'dots' : 'splats'; },
  screenOf(i) {
    const v = new THREE.Vector3(S.positions[3 * i], S.positions[3 * i + 1], S.positions[3 * i + 2]).project(camera);
    const r = renderer.domElement.getBoundingClientRect();
    return { x: r.left + (v.x + 1) / 2 * r.width, y: r.top + (1 - v.y) / 2 * r.height, visible: Math.abs(v.z) <= 1 };
  },
  pick(x, y) { return pickAt(x, y); },  // Gaussian index under client point (x, y), or -1
  labels() { return Array.from(S.labels); },
  checked() { return checkedLeaves(); },  // labels of the checked leaves
  target() { return controls.target.toArray(); },  // what the camera looks at (display frame)
  state() { return S.state; },
};

main().catch((e) => setStatus('failed to load: ' + (e.message || e), true));
