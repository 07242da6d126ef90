// Entry for the bundled three.js subset used by leaffit_usd/viewer/static/app.js (segmentation
// editor) and by the glTF view test (GLTFLoader, lights, PBR materials).
export {
  Scene, PerspectiveCamera, WebGLRenderer, BufferGeometry, BufferAttribute, Points, PointsMaterial,
  Color, Vector2, Vector3, Raycaster, MOUSE, Box3, Sphere, GridHelper, AxesHelper, Group,
  AmbientLight, DirectionalLight, HemisphereLight, Mesh, InstancedMesh, MeshStandardMaterial,
  SRGBColorSpace, ACESFilmicToneMapping, NoToneMapping,
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
export { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
