// Loads ?glb=URL with three.js's GLTFLoader, frames it from the front (+Z, +Y up), renders once
// and publishes what it saw as window.leaffitGltf (used by the headless-browser test and the
// README screenshot): mesh / instance counts, the leaves' vertex count, and the fraction and
// mean colour of the pixels covered by the leaves alone (stem hidden) over a white background.
import * as THREE from './three.bundle.min.js';

const params = new URLSearchParams(location.search);
const W = Number(params.get('w') || 800), H = Number(params.get('h') || 800);
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setSize(W, H);
renderer.outputColorSpace = THREE.SRGBColorSpace;
renderer.toneMapping = THREE.NoToneMapping;
document.body.appendChild(renderer.domElement);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0xffffff);
scene.add(new THREE.HemisphereLight(0xffffff, 0x667755, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(1, 2, 1.5);
scene.add(sun);

function any(root, pred) {
  let hit = false;
  if (root) root.traverse((o) => { if (pred(o)) hit = true; });
  return hit;
}

function coverage() {
  const gl = renderer.getContext();
  const px = new Uint8Array(W * H * 4);
  gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let n = 0; const sum = [0, 0, 0];
  for (let i = 0; i < px.length; i += 4) {
    if (px[i] < 250 || px[i + 1] < 250 || px[i + 2] < 250) {
      n++; sum[0] += px[i]; sum[1] += px[i + 1]; sum[2] += px[i + 2];
    }
  }
  return { fraction: n / (W * H), mean: sum.map((s) => (n ? s / n : 0)) };
}

new THREE.GLTFLoader().load(params.get('glb'), (gltf) => {
    const root = gltf.scene;
    scene.add(root);
    const box = new THREE.Box3().setFromObject(root);
    const c = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
    const r = 0.5 * Math.max(size.x, size.y, size.z);
    const cam = new THREE.PerspectiveCamera(35, W / H, r / 100, r * 100);
    const view = (params.get('view') || '0,0.35,1').split(',').map(Number);
    const dir = new THREE.Vector3(...view).normalize();
    cam.position.copy(c).addScaledVector(dir, 1.1 * r / Math.tan(0.5 * 35 * Math.PI / 180));
    cam.lookAt(c);
    let meshes = 0, instances = 0, leafVertices = 0, leafMaterials = new Set();
    let stem = null, leaves = null;
    root.traverse((o) => {
      if (o.isMesh) {
        meshes++;
        if (o.isInstancedMesh) instances += o.count;
      }
      if (o.name === 'Stem') stem = o;
      if (o.name === 'Leaves') leaves = o;
    });
    if (leaves) leaves.traverse((o) => {
      if (o.isMesh) {
        leafVertices = Math.max(leafVertices, o.geometry.attributes.position.count);
        leafMaterials.add(o.material.name);
      }
    });
    // pass 1: the leaves alone
    if (stem) stem.visible = false;
    renderer.render(scene, cam);
    const leavesOnly = coverage();
    // pass 2: the whole plant (what the screenshot shows)
    if (stem) stem.visible = true;
    renderer.render(scene, cam);
    window.leaffitGltf = {
      ready: true, meshes, instances, leafVertices, leafMaterials: [...leafMaterials].sort(),
      hasLeaves: !!leaves, hasStem: !!stem, leaves: leavesOnly, all: coverage(),
      vertexColors: any(leaves, (o) => o.isMesh && o.material.vertexColors),
      instanceColors: any(leaves, (o) => o.isInstancedMesh && !!o.instanceColor),
    };
}, undefined, (err) => { window.leaffitGltf = { ready: true, error: String(err) }; });
