// The kiosk: a fixed, calibrated view (Sato's Camera A) composed with Eq. 9 (kiosk.glsl.js)
// from the relit O' and S' targets, the view's mask, the live site-camera frame P when the
// server streams one, and the occlusion mask of people in front of the virtual objects
// (issue 6), each mask paired with the frame of the same capture time.
import * as THREE from 'three';
import { LINEAR_OF_CODE, luminance } from './colour.js';
import { FullscreenPass, makeTarget } from './passes.js';
import { RATIO_FLOOR_SCENE } from './display.glsl.js';
import { FLOAT_DECODE, RGBE_DECODE } from './relight.glsl.js';
import { kioskFragment, kioskVertex } from './kiosk.glsl.js';

// A frame waits this long for its occlusion mask (the server sends the mask right after the
// frame, after 10-40 ms of processing); then it is shown with the newest older mask.
const MASK_WAIT_MS = 400;
// The camera scale k follows the scene with this time constant.
const CAMERA_SCALE_TAU_S = 2;
const KEEP = 6; // frames and masks kept for pairing

export class Kiosk {
  /**
   * @param {import('./kiosksun.js').KioskSun} [sun] the view's sun term (null: no sun drawn,
   *   O' and S' from the basis alone)
   * @param {import('./sunbounce.js').SunBounce} [bounce] the view's sun bounce (its targets
   *   `${view.id}.O`, `${view.id}.S`; null, or a build without them: none added); the caller
   *   owns it (updates and disposes it)
   */
  constructor(renderer, relighter, view, sun = null, bounce = null) {
    this.renderer = renderer;
    this.relighter = relighter;
    this.view = view;
    this.sun = sun;
    this.bounce = bounce;
    const t = relighter.targets;
    const decode = relighter.format.rgbe ? RGBE_DECODE : FLOAT_DECODE;
    this.frameTex = new THREE.Texture();
    this.frameTex.colorSpace = THREE.SRGBColorSpace;
    this.frameTex.flipY = false;
    this.frameTex.generateMipmaps = false;
    this.frameTex.minFilter = THREE.LinearFilter;
    this.occlusionTex = new THREE.DataTexture(new Uint8Array(1), 1, 1, THREE.RedFormat);
    this.occlusionTex.needsUpdate = true;
    this.black = new THREE.DataTexture(new Uint8Array(4), 1, 1);
    this.black.needsUpdate = true;
    this.uniforms = {
      oTex: { value: t[`${view.id}.O`].texture },
      sTex: { value: t[`${view.id}.S`].texture },
      sunOTex: { value: sun?.targets.O.texture ?? this.black },
      sunSTex: { value: sun?.targets.S.texture ?? this.black },
      sunIrradiance: { value: new THREE.Vector3() },
      bounceOTex: { value: bounce?.texture(`${view.id}.O`) ?? this.black },
      bounceSTex: { value: bounce?.texture(`${view.id}.S`) ?? this.black },
      skyTex: { value: t[`${view.id}.sky`].texture },
      maskTex: { value: relighter.viewSky.get(view.id).mask },
      frameTex: { value: this.frameTex },
      occlusionTex: { value: this.occlusionTex },
      hasFrame: { value: 0 },
      hasOcclusion: { value: 0 },
      cameraScale: { value: 1 },
      strength: { value: 1 },
      outputScale: { value: 1 },
      encodeOutput: { value: 1 },
      ratioFloor: { value: 1e-6 }, // O'/S''s scene floor: RATIO_FLOOR_SCENE x mean S' (onRelight)
      viewport: { value: new THREE.Vector4(0, 0, 1, 1) },
    };
    this.pass = new FullscreenPass({
      uniforms: this.uniforms, vertexShader: kioskVertex, fragmentShader: kioskFragment(decode),
    });
    this.frames = []; // {captureTime, bitmap, sequence, arrivedMs}
    this.masks = []; // {captureTime, width, height, mask, people}
    this.shown = null; // the frame on screen
    this.shownMask = null;
    this.fixedCameraScale = null;
    this.cameraScale = 1;
    this.lastMaskMs = -Infinity;
    this.framesShown = 0;
    this.framesDecoded = 0;
    this.sLowRes = null; // S' on a coarse grid, for the camera scale
  }

  /** For the debug status: whether the sun's bounce is in O' and S'. */
  get sunBounceNote() {
    if (!this.hasSunBounce) {
      return 'absent: the build has no sun-bounce images of this view (baked before 2026-11-25); the sun\'s direct term alone';
    }
    return this.bounce.stacks.get(`${this.view.id}.O`).light != null ? 'drawn' : 'none';
  }

  /** Whether the build has the view's sun-bounce images (absent in builds before 2026-11-25:
   * the kiosk then draws the sun's direct term alone, as before). */
  get hasSunBounce() {
    return !!(this.bounce?.texture(`${this.view.id}.O`) && this.bounce?.texture(`${this.view.id}.S`));
  }

  /** A site-camera JPEG arrived (type-2 message). */
  async addFrame({ jpeg, captureTime, sequence }) {
    let bitmap;
    try {
      bitmap = await createImageBitmap(new Blob([jpeg], { type: 'image/jpeg' }), {
        colorSpaceConversion: 'none', premultiplyAlpha: 'none',
      });
    } catch {
      return; // a frame that does not decode is skipped; the next one comes soon
    }
    this.framesDecoded += 1;
    this.frames.push({ captureTime, bitmap, sequence, arrivedMs: performance.now() });
    while (this.frames.length > KEEP) this.frames.shift().bitmap.close?.();
    this.lastFrameMs = performance.now();
  }

  /** An occlusion mask arrived (type-3 message, decoded). */
  addMask(mask) {
    this.lastMaskMs = performance.now();
    this.masks.push(mask);
    while (this.masks.length > KEEP) this.masks.shift();
  }

  get occlusionActive() {
    return performance.now() - this.lastMaskMs < 5000;
  }

  /** Pick the newest frame that can be shown now and its mask (same capture time). */
  _choose(nowMs) {
    for (let i = this.frames.length - 1; i >= 0; i--) {
      const f = this.frames[i];
      if (this.shown && f.captureTime < this.shown.captureTime) break;
      const exact = this.masks.find((m) => m.captureTime === f.captureTime);
      if (exact) return { frame: f, mask: exact };
      if (!this.occlusionActive || nowMs - f.arrivedMs > MASK_WAIT_MS) {
        const older = this.masks.filter((m) => m.captureTime <= f.captureTime).pop() ?? null;
        return { frame: f, mask: older };
      }
    }
    return null;
  }

  _showFrame({ frame, mask }) {
    if (frame !== this.shown) {
      this.frameTex.image = frame.bitmap;
      this.frameTex.needsUpdate = true;
      this.shown = frame;
      this.framesShown += 1;
      // Free the older bitmaps: they can no longer be shown.
      this.frames = this.frames.filter((f) => {
        if (f.captureTime < frame.captureTime) { f.bitmap.close?.(); return false; }
        return true;
      });
      this._measureCameraScale(frame.bitmap);
    }
    if (mask !== this.shownMask) {
      this.shownMask = mask;
      if (mask) {
        const tex = new THREE.DataTexture(mask.mask, mask.width, mask.height, THREE.RedFormat);
        tex.unpackAlignment = 1; // rows of any width, one byte a pixel
        tex.minFilter = tex.magFilter = THREE.NearestFilter;
        tex.needsUpdate = true;
        this.occlusionTex.dispose();
        this.occlusionTex = tex;
        this.uniforms.occlusionTex.value = tex;
      }
    }
    this.uniforms.hasFrame.value = 1;
    this.uniforms.hasOcclusion.value = mask ? 1 : 0;
  }

  /** No live frame for a while: fall back to the synthesized background. */
  dropFrames() {
    this.uniforms.hasFrame.value = 0;
    this.uniforms.hasOcclusion.value = 0;
    this.shown = null;
  }

  /**
   * After each relight, with the sun applied with it ({direction, normalIrradiance} or null),
   * and again once the sun's bounce for it is drawn (app.js): the view's sun images (rendered
   * again only when the sun moved), and S' (sky, sun, bounce) on a coarse grid for the camera
   * scale.
   */
  onRelight(sun = null) {
    const drawn = this.sun ? this.sun.setSun(sun) : false;
    const E = this.uniforms.sunIrradiance.value;
    if (drawn) E.copy(this.sun.irradiance);
    else E.set(0, 0, 0);
    const { width, height, data } = this.relighter.read(`${this.view.id}.S`); // rows from the top
    if (drawn) {
      const sunS = this.relighter.readTarget(this.sun.targets.S).data;
      for (let p = 0; p < width * height; p++) {
        for (let c = 0; c < 3; c++) data[4 * p + c] += E.getComponent(c) * sunS[4 * p + c];
      }
    }
    const bounceS = this.bounce?.stacks.get(`${this.view.id}.S`);
    if (bounceS?.light != null) { // the sun's bounce drawn for a patch (else the target is zero)
      const b = this.relighter.readTarget(bounceS.target).data;
      for (let p = 0; p < width * height; p++) {
        for (let c = 0; c < 3; c++) data[4 * p + c] += b[4 * p + c];
      }
    }
    const maskData = this._maskPixels();
    const step = Math.max(1, Math.floor(width / 64));
    const samples = [];
    for (let y = step >> 1; y < height; y += step) {
      for (let x = step >> 1; x < width; x += step) {
        const p = 4 * (y * width + x);
        if (maskData && maskData[y * width + x] !== 0) continue;
        samples.push([x / width, y / height, luminance(data[p], data[p + 1], data[p + 2])]);
      }
    }
    this.sLowRes = samples;
    const meanS = samples.reduce((sum, [, , v]) => sum + v, 0) / Math.max(samples.length, 1);
    this.uniforms.ratioFloor.value = Math.max(RATIO_FLOOR_SCENE * meanS, 1e-12);
  }

  _maskPixels() {
    if (this._maskData !== undefined) return this._maskData;
    const bitmap = this.uniforms.maskTex.value.image;
    try {
      const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
      const ctx = canvas.getContext('2d');
      ctx.drawImage(bitmap, 0, 0);
      const rgba = ctx.getImageData(0, 0, bitmap.width, bitmap.height).data;
      this._maskData = new Uint8Array(bitmap.width * bitmap.height);
      for (let i = 0; i < this._maskData.length; i++) this._maskData[i] = rgba[4 * i];
    } catch {
      this._maskData = null;
    }
    return this._maskData;
  }

  /**
   * k, the camera's units per unit radiance, so that virtual pixels k O' sit in the frame's
   * own exposure: sum P / sum S' over real pixels (Sato's photometric calibration, estimated
   * from the live frame), smoothed with a time constant.
   */
  _measureCameraScale(bitmap) {
    if (this.fixedCameraScale !== null || !this.sLowRes?.length) return;
    const w = 64;
    const h = Math.max(1, Math.round((64 * bitmap.height) / bitmap.width));
    this._probe ??= new OffscreenCanvas(w, h);
    if (this._probe.width !== w || this._probe.height !== h) { this._probe.width = w; this._probe.height = h; }
    const ctx = this._probe.getContext('2d', { willReadFrequently: true });
    ctx.drawImage(bitmap, 0, 0, w, h);
    const px = ctx.getImageData(0, 0, w, h).data;
    let sumP = 0;
    let sumS = 0;
    for (const [u, v, s] of this.sLowRes) {
      const i = 4 * (Math.min(h - 1, Math.floor(v * h)) * w + Math.min(w - 1, Math.floor(u * w)));
      sumP += luminance(LINEAR_OF_CODE[px[i]], LINEAR_OF_CODE[px[i + 1]], LINEAR_OF_CODE[px[i + 2]]);
      sumS += s;
    }
    if (sumS <= 0 || sumP <= 0) return;
    const k = sumP / sumS;
    const now = performance.now() / 1000;
    const dt = this._scaleTime === undefined ? Infinity : now - this._scaleTime;
    this._scaleTime = now;
    const a = 1 - Math.exp(-dt / CAMERA_SCALE_TAU_S);
    this.cameraScale = Number.isFinite(dt) ? this.cameraScale + a * (k - this.cameraScale) : k;
  }

  setCameraScale(k) {
    this.fixedCameraScale = k;
    this.cameraScale = k ?? this.cameraScale;
  }

  /** Draw the kiosk picture on the canvas (contain: the whole view, black bars). */
  render({ exposure, strength, frameTimeoutMs = 5000 }) {
    const now = performance.now();
    const choice = this._choose(now);
    if (choice) this._showFrame(choice);
    if (this.shown && now - (this.lastFrameMs ?? 0) > frameTimeoutMs) this.dropFrames();
    const live = this.uniforms.hasFrame.value > 0.5;
    this.uniforms.cameraScale.value = live ? this.cameraScale : 1;
    this.uniforms.outputScale.value = live ? 1 : exposure;
    this.uniforms.strength.value = strength;
    this.uniforms.encodeOutput.value = 1;
    const size = this.renderer.getDrawingBufferSize(new THREE.Vector2());
    const aspect = this.view.width / this.view.height;
    let w = 1;
    let h = 1;
    if (size.x / size.y > aspect) w = (size.y * aspect) / size.x;
    else h = size.x / aspect / size.y;
    this.uniforms.viewport.value.set((1 - w) / 2, (1 - h) / 2, w, h);
    this.pass.render(this.renderer, null);
  }

  /**
   * The linear composite at the view's own resolution (tests): rows from the top, RGBA float.
   * Uses whatever frame and mask are current.
   */
  readComposite({ strength = 1, outputScale = 1 } = {}) {
    const { width, height } = this.view;
    const target = this._readTarget ??= makeTarget(width, height, { type: THREE.FloatType, rgbe: false });
    const u = this.uniforms;
    const saved = [u.encodeOutput.value, u.outputScale.value, u.strength.value, u.cameraScale.value];
    u.encodeOutput.value = 0;
    u.outputScale.value = outputScale;
    u.strength.value = strength;
    u.cameraScale.value = this.uniforms.hasFrame.value > 0.5 ? this.cameraScale : (this.fixedCameraScale ?? 1);
    u.viewport.value.set(0, 0, 1, 1);
    this.pass.render(this.renderer, target);
    [u.encodeOutput.value, u.outputScale.value, u.strength.value, u.cameraScale.value] = saved;
    const gl = this.renderer.getContext();
    const data = new Float32Array(4 * width * height);
    this.renderer.setRenderTarget(target);
    gl.readPixels(0, 0, width, height, gl.RGBA, gl.FLOAT, data);
    this.renderer.setRenderTarget(null);
    // GL rows are bottom first, and the vertex shader put the image's top at the top.
    const out = new Float32Array(data.length);
    const row = 4 * width;
    for (let y = 0; y < height; y++) out.set(data.subarray((height - 1 - y) * row, (height - y) * row), y * row);
    return { width, height, data: out };
  }

  dispose() {
    this.pass.dispose();
    this.black.dispose();
    this.sun?.dispose();
    this.frameTex.dispose();
    this.occlusionTex.dispose();
    this._readTarget?.dispose();
    for (const f of this.frames) f.bitmap.close?.();
  }
}
