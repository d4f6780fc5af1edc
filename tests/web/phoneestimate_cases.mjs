// Runs web/src/phoneestimate.js in Node on one case given as JSON on stdin: the proxies'
// triangles {vertices (v, 3), faces (f, 3), albedo (3)} per mesh, the ground albedo, a camera
// {matrixWorld (16, column-major), fovDeg, aspect}, a picture {w, h, rgba: flat sRGB codes},
// the sun direction and how many estimates; prints the estimates (and the light vector of the
// last one when `lights` is given). For tests/web/test_phoneestimate_js.py.
import { readFileSync } from 'node:fs';
import * as THREE from 'three';
import { PhoneEstimator } from '../../web/src/phoneestimate.js';

const c = JSON.parse(readFileSync(0, 'utf8'));
const meshes = c.meshes.map((m) => {
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(m.vertices.flat(), 3));
  g.setIndex(m.faces.flat());
  const mesh = new THREE.Mesh(g);
  mesh.userData.albedo = new THREE.Vector3(...m.albedo);
  return mesh;
});
const camera = new THREE.PerspectiveCamera(c.camera.fovDeg, c.camera.aspect, 0.1, 2000);
new THREE.Matrix4().fromArray(c.camera.matrixWorld).decompose(camera.position, camera.quaternion, camera.scale);
camera.updateMatrixWorld(true);
const estimator = new PhoneEstimator(meshes, c.groundAlbedo);
const rgba = Uint8ClampedArray.from(c.picture.rgba);
const out = { estimates: [] };
if (c.forceType) estimator.forceType = c.forceType;
for (let i = 0; i < (c.count ?? 1); i++) {
  out.estimates.push(estimator.estimate(rgba, c.picture.w, c.picture.h, camera, c.sun));
}
if (c.lights && out.estimates.at(-1)) out.light = estimator.lightVector(out.estimates.at(-1), c.lights, c.sun);
out.light &&= { rgb: Array.from(out.light.rgb), sun: out.light.sun };
out.pool = estimator.pool.map((s) => ({ x: s.x, y: s.y, normal: s.normal, albedo: s.albedo, sky: s.skyDirs.length, bounce: s.bounce.length }));
if (c.fit) out.fit = { ...estimator.lastFit, terms: estimator._sunTerms };
console.log(JSON.stringify(out));
