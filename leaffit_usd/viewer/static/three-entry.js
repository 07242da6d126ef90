// Entry for the bundled three.js subset used by leaffit_usd/viewer/static/app.js.
export {
  Scene, PerspectiveCamera, WebGLRenderer, BufferGeometry, BufferAttribute, Points, PointsMaterial,
  Color, Vector2, Vector3, Raycaster, MOUSE, Box3, Sphere, GridHelper, AxesHelper, Group,
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
