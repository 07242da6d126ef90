// leaffit-usd edit — back-to-front order of the splats, off the page's thread.
// Messages in: {positions: Float32Array (N*3, display frame)} once; then {id, view: 16 floats}
// (the camera's world -> view matrix, column-major). Out: {id, order: Uint32Array (N)}, the
// Gaussian indices from the farthest to the nearest along the view direction: a counting sort
// on 16-bit depth keys (two passes over N, ~10 ms for 1M Gaussians).
let pos = null;
let counts = new Uint32Array(65536);

function sortByDepth(v) {
  const n = pos.length / 3;
  const a = v[2], b = v[6], c = v[10];  // view-space z = a x + b y + c z + v[14] (negative ahead)
  const depth = new Float32Array(n);
  let lo = Infinity, hi = -Infinity;
  for (let i = 0, o = 0; i < n; i++, o += 3) {
    const z = a * pos[o] + b * pos[o + 1] + c * pos[o + 2];
    depth[i] = z;
    if (z < lo) lo = z;
    if (z > hi) hi = z;
  }
  const scale = hi > lo ? 65535 / (hi - lo) : 0;
  const keys = new Uint16Array(n);
  counts.fill(0);
  for (let i = 0; i < n; i++) {
    const k = ((depth[i] - lo) * scale) | 0;  // most negative z (farthest) -> key 0
    keys[i] = k;
    counts[k]++;
  }
  for (let k = 0, sum = 0; k < 65536; k++) { const c0 = counts[k]; counts[k] = sum; sum += c0; }
  const order = new Uint32Array(n);
  for (let i = 0; i < n; i++) order[counts[keys[i]]++] = i;
  return order;
}

onmessage = (e) => {
  const m = e.data;
  if (m.positions) { pos = m.positions; return; }
  if (m.view && pos) {
    const order = sortByDepth(m.view);
    postMessage({ id: m.id, order }, [order.buffer]);
  }
};
