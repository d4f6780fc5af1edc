// The phone or tablet camera without WebXR (iOS Safari): the rear camera through getUserMedia
// as the background, the view turned by the device's orientation (deviceorientation, W3C
// convention: alpha about z, beta about x, gamma about y). The visitor stands at a standpoint
// on the site (the kiosk's view by default); drag with one finger to turn the model until it
// sits on the real site (a heading offset), with two fingers to move the standpoint. Where the
// phone estimates its own light, the picture registers the view too (`turnBy`: the compass's
// heading error and the tilt's, poseregister.js). The alignment is kept in localStorage.
import * as THREE from 'three';
import { PictureMeter } from './picturemeter.js';
import { REGISTER_HEADING_DEG, REGISTER_TILT_DEG } from './poseregister.js';

const STORAGE_KEY = 'daylit.alignment.camera';

export class CameraView {
  /** Resolves when the camera runs; rejects (no permission, no camera) so the caller falls back. */
  static async open(camera, domElement, manifest, scene) {
    if (!navigator.mediaDevices?.getUserMedia) throw new Error('this browser gives no camera access');
    const stream = await navigator.mediaDevices.getUserMedia({
      video: { facingMode: 'environment', width: { ideal: 1280 } }, audio: false,
    });
    const view = new CameraView(camera, domElement, manifest, scene, stream);
    await view.video.play();
    await view.requestOrientation();
    return view;
  }

  constructor(camera, domElement, manifest, scene, stream) {
    this.camera = camera;
    this.dom = domElement;
    this.scene = scene;
    this.stream = stream;
    this.video = document.createElement('video');
    this.video.playsInline = true;
    this.video.muted = true;
    this.video.srcObject = stream;
    this.texture = new THREE.VideoTexture(this.video);
    this.meter = new PictureMeter(this.video); // the exposure from the picture (app.js)
    this.texture.colorSpace = THREE.SRGBColorSpace;
    this.previousBackground = scene.background;
    scene.background = this.texture;
    const view = manifest.views[0];
    const start = view ? view.world_from_camera.map((row) => row[3]).slice(0, 3) : [0, 1.6, 20];
    // headingDeg: the visitor's turn about the vertical; registeredHeadingDeg, registeredTiltDeg:
    // the picture's (turnBy), about the vertical (a compass's error) and up about the camera's
    // own horizontal axis (a tilt sensor's), each within the registration's search range.
    this.alignment = { headingDeg: 0, registeredHeadingDeg: 0, registeredTiltDeg: 0, position: [start[0], 1.6, start[2]], ...load() };
    this.orientation = null;
    // A device without the sensors (and headless Chromium) sends one event of nulls, which
    // may arrive after real readings: it must not turn the view back to level.
    this._onOrientation = (e) => { if (e.alpha !== null) this.orientation = e; };
    this._onScreen = () => {};
    this._touches = new Map();
    this._onPointerDown = (e) => this._touches.set(e.pointerId, [e.clientX, e.clientY]);
    this._onPointerUp = (e) => { this._touches.delete(e.pointerId); save(this.alignment); };
    this._onPointerMove = (e) => this._drag(e);
    domElement.addEventListener('pointerdown', this._onPointerDown);
    domElement.addEventListener('pointerup', this._onPointerUp);
    domElement.addEventListener('pointercancel', this._onPointerUp);
    domElement.addEventListener('pointermove', this._onPointerMove);
    camera.near = 0.1;
    camera.far = 2000;
    camera.fov = 60;
    camera.updateProjectionMatrix();
  }

  async requestOrientation() {
    // iOS asks for permission (inside the tap that opened the camera); others just send events.
    const ask = globalThis.DeviceOrientationEvent?.requestPermission;
    if (typeof ask === 'function') {
      try {
        await ask();
      } catch {
        // without it the view stays level; dragging still turns it
      }
    }
    addEventListener('deviceorientation', this._onOrientation);
  }

  _drag(e) {
    const last = this._touches.get(e.pointerId);
    if (!last) return;
    const dx = e.clientX - last[0];
    const dy = e.clientY - last[1];
    this._touches.set(e.pointerId, [e.clientX, e.clientY]);
    if (this._touches.size === 1) {
      this.alignment.headingDeg += dx * 0.15;
    } else {
      // Two fingers: walk the standpoint in the view's ground plane, half a metre per 50 px of
      // the fingers' mean motion (each finger's event moves it by its share). The heading from
      // the view direction: the camera's Euler y is not its heading once it faces south.
      const forward = this.camera.getWorldDirection(new THREE.Vector3()).setY(0);
      if (forward.lengthSq() < 1e-6) return; // looking straight down or up: no heading
      forward.normalize();
      const along = -dy / 100 / this._touches.size;
      const side = dx / 100 / this._touches.size;
      this.alignment.position[0] += along * forward.x - side * forward.z;
      this.alignment.position[2] += along * forward.z + side * forward.x;
    }
  }

  update() {
    const o = this.orientation;
    const q = new THREE.Quaternion();
    if (o && o.alpha !== null) {
      // The standard device-orientation to camera quaternion (as three.js's former
      // DeviceOrientationControls): ZXY Euler from alpha, beta, gamma, then the camera looks
      // out of the back of the device, then the screen's own rotation.
      const euler = new THREE.Euler(THREE.MathUtils.degToRad(o.beta), THREE.MathUtils.degToRad(o.alpha), -THREE.MathUtils.degToRad(o.gamma), 'YXZ');
      q.setFromEuler(euler);
      q.multiply(new THREE.Quaternion(-Math.sqrt(0.5), 0, 0, Math.sqrt(0.5)));
      const screenDeg = screen.orientation?.angle ?? 0;
      q.multiply(new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3(0, 0, 1), -THREE.MathUtils.degToRad(screenDeg)));
    }
    const a = this.alignment;
    const heading = new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3(0, 1, 0), THREE.MathUtils.degToRad(a.headingDeg + a.registeredHeadingDeg));
    const tilt = new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3(1, 0, 0), THREE.MathUtils.degToRad(a.registeredTiltDeg));
    this.camera.quaternion.copy(heading.multiply(q).multiply(tilt));
    this.camera.position.set(...this.alignment.position);
  }

  /**
   * Turn the view so that the model lies where the picture shows the site (the registration's
   * turn, poseregister.js): leftDeg to the left (taken as the compass's error, about the
   * vertical: a turn about the vertical moves the picture by cos(pitch) of it), upDeg up
   * (the tilt's, about the camera's horizontal axis). Kept with the alignment; the sums stay
   * within the registration's search range, so that pictures it misreads (the phone pointed
   * away from the site) cannot turn the view further than one search could turn it back.
   */
  turnBy(leftDeg, upDeg) {
    const pitch = Math.asin(THREE.MathUtils.clamp(this.camera.getWorldDirection(new THREE.Vector3()).y, -1, 1));
    const a = this.alignment;
    a.registeredHeadingDeg = THREE.MathUtils.clamp(a.registeredHeadingDeg + leftDeg / Math.max(Math.cos(pitch), 0.5),
      -REGISTER_HEADING_DEG, REGISTER_HEADING_DEG);
    a.registeredTiltDeg = THREE.MathUtils.clamp(a.registeredTiltDeg + upDeg, -REGISTER_TILT_DEG, REGISTER_TILT_DEG);
    save(a);
    this.update();
  }

  resetAlignment() {
    localStorage.removeItem(STORAGE_KEY);
    Object.assign(this.alignment, { headingDeg: 0, registeredHeadingDeg: 0, registeredTiltDeg: 0 });
  }

  dispose() {
    removeEventListener('deviceorientation', this._onOrientation);
    this.dom.removeEventListener('pointerdown', this._onPointerDown);
    this.dom.removeEventListener('pointerup', this._onPointerUp);
    this.dom.removeEventListener('pointercancel', this._onPointerUp);
    this.dom.removeEventListener('pointermove', this._onPointerMove);
    for (const track of this.stream.getTracks()) track.stop();
    this.scene.background = this.previousBackground;
    this.texture.dispose();
  }
}

function load() {
  try {
    return JSON.parse(localStorage.getItem(STORAGE_KEY) ?? '{}');
  } catch {
    return {};
  }
}

function save(alignment) {
  try {
    localStorage.setItem(STORAGE_KEY, JSON.stringify(alignment));
  } catch {
    // private browsing: the alignment lasts for this visit only
  }
}
