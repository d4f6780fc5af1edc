// AR's exposure from the passthrough camera's own picture (docs/web.md, "Exposure"), as camera
// mode meters its video (picturemeter.js): the passthrough was exposed by the phone's camera,
// and the virtual hall over it must sit at that exposure. A page sees the passthrough only
// through WebXR raw camera access (the optional session feature 'camera-access', Chrome on
// Android since 107; its camera prompt): three.js (WebXRManager) then hands each frame's
// camera image to the page as an opaque texture, valid within that frame. The meter draws it
// into a METER_SIZE target, reads it back and takes the ground's median level from the view's
// pose and projection (the camera image is aligned with the view). Without the feature (a
// browser without it, the permission refused) nothing is read and the exposure stays the
// camera meter's assumption (exposure.js).
//
// Orientation: the image is sampled as a GL texture whose first row (v = 0) is the picture's
// bottom, as a quad drawn with it shows the picture upright (the WebXR samples' convention).
import * as THREE from 'three';
import { groundLevel, METER_PERIOD_S, METER_SIZE } from './picturemeter.js';

const VERTEX = /* glsl */ `
varying vec2 vUv;
void main() {
  vUv = uv;
  gl_Position = vec4(position.xy, 0.0, 1.0);
}`;

const FRAGMENT = /* glsl */ `
uniform sampler2D map;
varying vec2 vUv;
void main() {
  gl_FragColor = texture2D(map, vUv); // the camera's codes as they are: no colour conversion
}`;

/** Meters the passthrough camera's picture of the session's first view, at most every
 * METER_PERIOD_S; the same interface as PictureMeter (app.js _updateExposure). */
export class XRPictureMeter {
  /** @param {THREE.WebGLRenderer} renderer the renderer presenting the session */
  constructor(renderer) {
    this.renderer = renderer;
    const [w, h] = METER_SIZE;
    this.target = new THREE.WebGLRenderTarget(w, h, { depthBuffer: false });
    this.material = new THREE.ShaderMaterial({
      uniforms: { map: { value: null } }, vertexShader: VERTEX, fragmentShader: FRAGMENT,
      depthTest: false, depthWrite: false,
    });
    this.quad = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), this.material);
    this.quad.frustumCulled = false;
    this.scene = new THREE.Scene().add(this.quad);
    this.orthographic = new THREE.OrthographicCamera();
    this.pixels = new Uint8Array(4 * w * h);
    this.rows = new Uint8ClampedArray(4 * w * h);
    this.reading = null; // the last groundLevel (or null)
    this.lastS = -Infinity;
    this.reads = 0; // pictures metered (status, tests)
  }

  /** Whether the session gives the page its camera images. */
  get available() {
    const features = this.renderer.xr.getSession()?.enabledFeatures;
    return !!features?.includes('camera-access');
  }

  /**
   * @param {THREE.Camera} _camera unused: the view's own camera is the picture's
   * @param {number} nowS seconds; with `force` the picture is metered whatever the time
   * @returns {{level: number, pixels: number}|null} the latest reading
   */
  read(_camera, nowS, force = false) {
    if (!force && nowS - this.lastS < METER_PERIOD_S) return this.reading;
    const picture = this._picture();
    if (!picture) return this.reading;
    this.lastS = nowS;
    this.reading = groundLevel(picture, ...METER_SIZE, this.renderer.xr.getCamera().cameras[0]);
    this.reads += 1;
    return this.reading;
  }

  /** This frame's camera picture at METER_SIZE, sRGB codes, rows from the top; or null. */
  _picture() {
    const xr = this.renderer.xr;
    if (!this.available || !xr.isPresenting) return null;
    let view;
    try {
      view = xr.getFrame()?.getViewerPose(xr.getReferenceSpace())?.views[0];
    } catch {
      return null; // outside the session's frame callback: no picture to read
    }
    const texture = view?.camera ? xr.getCameraTexture(view.camera) : null;
    if (!texture?.sourceTexture) return null;
    this.material.uniforms.map.value = texture;
    // Drawn as a plain render to a texture: with XR on, three.js would draw it once per eye
    // with the eyes' viewports (the usual switch, as three.js's own Reflector does).
    const renderer = this.renderer;
    const previous = renderer.getRenderTarget();
    xr.enabled = false;
    try {
      renderer.setRenderTarget(this.target);
      renderer.render(this.scene, this.orthographic);
      renderer.readRenderTargetPixels(this.target, 0, 0, ...METER_SIZE, this.pixels);
    } finally {
      renderer.setRenderTarget(previous);
      xr.enabled = true;
    }
    const [w, h] = METER_SIZE;
    for (let y = 0; y < h; y++) { // GL's rows from the bottom, the meter's from the top
      this.rows.set(this.pixels.subarray(4 * w * (h - 1 - y), 4 * w * (h - y)), 4 * w * y);
    }
    return this.rows;
  }

  dispose() {
    this.target.dispose();
    this.material.dispose();
    this.quad.geometry.dispose();
  }
}
