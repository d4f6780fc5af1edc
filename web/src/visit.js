// The virtual visit: an orbiting camera over the synthesized site (no camera, no permission,
// or off site). One finger orbits, two fingers zoom and pan (three.js OrbitControls); it turns
// slowly by itself until touched.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

export class VisitView {
  constructor(camera, domElement, site) {
    this.camera = camera;
    const box = site.bounds();
    const centre = box.getCenter(new THREE.Vector3());
    const radius = Math.max(5, box.getSize(new THREE.Vector3()).length() / 2);
    centre.y = Math.min(centre.y, radius * 0.25);
    this.controls = new OrbitControls(camera, domElement);
    this.controls.target.copy(centre);
    this.controls.enableDamping = true;
    this.controls.autoRotate = true;
    this.controls.autoRotateSpeed = 0.4;
    this.controls.maxPolarAngle = Math.PI * 0.49; // stay above the ground
    this.controls.minDistance = radius * 0.3;
    this.controls.maxDistance = radius * 6;
    // From the south-east, a little above eye height of a tall visitor on a hill; further
    // away on a portrait screen so that the whole width of the site fits (fit()).
    this.distanceScale = 1;
    camera.position.copy(centre).add(new THREE.Vector3(radius * 1.3, radius * 0.55, radius * 1.6));
    this.fit();
    camera.near = 0.1;
    camera.far = radius * 40;
    camera.updateProjectionMatrix();
    this.controls.addEventListener('start', () => { this.controls.autoRotate = false; });
    this.controls.update();
  }

  /** Scale the camera's distance to the screen's shape: 1 on a landscape screen, more on a
   * portrait one so that the whole width of the site fits. Called again when the screen turns;
   * keeps whatever orbit and zoom the visitor chose. */
  fit() {
    const scale = Math.max(1, 1.1 / Math.max(0.3, this.camera.aspect));
    const target = this.controls.target;
    this.camera.position.sub(target).multiplyScalar(scale / this.distanceScale).add(target);
    this.distanceScale = scale;
    this.controls.update();
  }

  update() {
    this.controls.update();
  }

  dispose() {
    this.controls.dispose();
  }
}
