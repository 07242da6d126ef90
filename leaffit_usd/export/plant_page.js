// The LeafFit plant page (leaffit_usd/export/page.py): three.js with the asset embedded as a GLB,
// orbit controls and a wind slider. Every leaf turns about its axis through its pivot by
// strength * sin(2 pi (frequency * t + phase)) -- the same motion as the CPU evaluator and the
// GLSL deformer (leaffit_usd/usd/wind.py) -- the stem stays still.
// window.leaffitPage = { ready, frame(t, strength): render that moment (stops the animation),
//   showLeaves(bool) }; the canvas keeps its drawing buffer (toDataURL reads the last frame).
const text = (id) => document.getElementById(id).textContent;
const THREE = await import(URL.createObjectURL(new Blob([text('three')], { type: 'text/javascript' })));
const wind = JSON.parse(text('wind'));
const glb = Uint8Array.from(atob(text('glb').trim()), (c) => c.charCodeAt(0)).buffer;

const W = window.innerWidth, H = window.innerHeight;
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setSize(W, H);
renderer.outputColorSpace = THREE.SRGBColorSpace;
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf4f4f0);
scene.add(new THREE.HemisphereLight(0xffffff, 0x667755, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(1, 2, 1.5);
scene.add(sun);

const gltf = await new Promise((ok, fail) => new THREE.GLTFLoader().parse(glb, '', ok, fail));
const root = gltf.scene;
scene.add(root);
const box = new THREE.Box3().setFromObject(root);
const c = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
const r = 0.5 * Math.max(size.x, size.y, size.z);
const cam = new THREE.PerspectiveCamera(35, W / H, r / 100, r * 100);
cam.position.copy(c).add(new THREE.Vector3(0, 0.35, 1).normalize().multiplyScalar(1.2 * r / Math.tan(0.5 * 35 * Math.PI / 180)));
cam.lookAt(c);
const controls = new THREE.OrbitControls(cam, renderer.domElement);
controls.target.copy(c);
controls.update();

// the leaves' geometries (one per material side), their rest positions
const leafMeshes = [];
root.traverse((o) => { if (o.isMesh && o.parent && o.parent.name === 'Leaves') leafMeshes.push(o); });
root.traverse((o) => { if (o.isMesh && o.name === 'Leaves') leafMeshes.push(o); });
const geoms = [...new Map(leafMeshes.map((m) => [m.geometry.attributes.position, m.geometry])).values()];
const rest = geoms.map((g) => Float32Array.from(g.attributes.position.array));

function pose(t, strength) {
  const V = wind.verticesPerLeaf;
  geoms.forEach((g, gi) => {
    const p = g.attributes.position.array, p0 = rest[gi];
    for (let j = 0; j < wind.phases.length; j++) {
      const a = strength * Math.sin(2 * Math.PI * (wind.frequency * t + wind.phases[j]));
      const cs = Math.cos(a), sn = Math.sin(a);
      const [px, py, pz] = wind.pivots[j], [ux, uy, uz] = wind.axes[j];
      for (let i = j * V; i < (j + 1) * V; i++) {
        const vx = p0[3 * i] - px, vy = p0[3 * i + 1] - py, vz = p0[3 * i + 2] - pz;
        const d = (ux * vx + uy * vy + uz * vz) * (1 - cs);
        p[3 * i] = px + vx * cs + (uy * vz - uz * vy) * sn + ux * d;
        p[3 * i + 1] = py + vy * cs + (uz * vx - ux * vz) * sn + uy * d;
        p[3 * i + 2] = pz + vz * cs + (ux * vy - uy * vx) * sn + uz * d;
      }
    }
    g.attributes.position.needsUpdate = true;
    g.computeBoundingSphere();
  });
}

const slider = document.getElementById('strength');
let animate = true;
function frame(t, strength) {
  pose(t, strength);
  renderer.render(scene, cam);
}
function loop(ms) {
  if (animate) frame(ms / 1000, Number(slider.value));
  requestAnimationFrame(loop);
}
window.leaffitPage = {
  ready: true, leaves: geoms.length, phases: wind.phases.length,
  frame: (t, strength) => { animate = false; frame(t, strength); return true; },
  showLeaves: (on) => { leafMeshes.forEach((m) => { m.visible = on; }); return true; },
};
requestAnimationFrame(loop);
