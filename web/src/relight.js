// The relight pass: on each new light vector, the weighted sums of every basis stack are
// rendered once into cached render targets (Kakuta Fig. 6); frames in between only sample
// those targets, so the cost of a frame does not depend on the number of lights.
//
// Per stack (docs/compact-assets.md): A(r) the selected lights, r' = r without them,
// c = V^T r' (k x RGB, in JavaScript), then on the GPU
//   E(x) = g(x) (sum_j c[coef_j] (tex_j(x) scale_j + offset_j) + sum_{i in A} r_i B~_i(x)).
// For a shadowing atlas the `I` entry encodes Delta = d - I: its target holds X = sum r Delta
// and the `d` target D = sum r d, so alpha = X / D and I = D - X (materials.js).
//
// A stack's own number of selected lights is its manifest entry's `selected_lights` (absent:
// the build's). Since 2026-11-24 the atlases select none (they are relit with the sky
// without the sun's disc; the sun is drawn apart, sun.js): a base and V, nothing on demand.
// The fixed views keep one, the sun's patch: their bases are still fitted with the sun in its
// patch, though the kiosk now draws the sun itself (kiosksun.js; docs/sun.md, "Not done yet").
//
// Selected lights' own images are fetched on demand and kept in a small cache. When a newly
// selected light's images have not arrived yet, the previous exact result stays on screen
// (the relight of this vector waits for them); only before the very first picture does the
// pass run at once with the missing lights left in r' (summed by the low-rank base, a coarse
// stand-in), so something appears while they load.
import * as THREE from 'three';
import { baseCoefficients, selectionWeights, selectLights, stackWeights } from './lightmath.js';
import { FullscreenPass, makeTarget, targetFormat } from './passes.js';
import {
  decodeRGBE, domeSkyFragment, relightFragment, skyInvWidth2, viewSkyFragment,
} from './relight.glsl.js';

const LIGHT_CACHE_PER_STACK = 12; // selected_lights per vector (0 or 1); the sun moves one patch in tens of minutes


/** A one-layer KTX2 array comes out of KTX2Loader as a 2D texture: the same level data as a
 * 2D array of one layer, which the relight shader samples. */
function asArray(texture) {
  if (texture.isCompressedArrayTexture || texture.isDataArrayTexture) return texture;
  const array = new THREE.CompressedArrayTexture(texture.mipmaps, texture.image.width, texture.image.height, 1, texture.format, texture.type);
  array.name = texture.name;
  array.colorSpace = texture.colorSpace;
  array.generateMipmaps = false;
  array.needsUpdate = true;
  return array;
}

/** One compact stack: its textures, V, light-image cache, target and shader. */
class RelightStack {
  constructor(assets, key, compact, width, height, format, selectedCount) {
    this.assets = assets;
    this.key = key; // e.g. 'ground.I'
    this.compact = compact;
    this.width = width;
    this.height = height;
    this.format = format;
    this.levels = compact.lights.ktx2.length;
    this.m = compact.selected_lights ?? selectedCount; // this stack's selected lights
    this.slots = this.m * this.levels;
    this.k = compact.v.shape[1];
    this.coarse = false; // drawing from the coarse start (loadCoarse) until load replaces it
    this.lights = new Map(); // light index -> [texture per level]
    this.pending = new Map(); // light index -> Promise
    this.target = makeTarget(width, height, format);
    this.target.texture.name = key;
    this.applied = null; // {sequence, exact}
  }

  /** The full stack: every base layer (replaces a coarse start, if any). */
  async load() {
    const loads = [this.assets.texture(this.compact.ktx2), this.assets.matrix(this.compact.v)];
    // Builds from 2026-11-24: base layers past the first few in a second, ETC1S array, whose
    // layers follow the first array's in compact.layers (docs/compact-assets.md).
    loads.push(this.compact.etc1s ? this.assets.texture(this.compact.etc1s.ktx2) : null);
    loads.push(this.gain ?? (this.compact.gain ? this.assets.sharedTexture(this.compact.gain.ktx2) : null));
    const [base, V, etc1s, gain] = await Promise.all(loads);
    this._setUp({ base, V, k: this.compact.v.shape[1], etc1s, gain, layers: this.compact.layers, coarse: false });
  }

  /**
   * A coarse start (bake/coarse.py, `compact.coarse`): the first few base layers and their V
   * columns, a few hundred kilobytes, drawn until `load` brings the full stack. False if the
   * build has none for this stack.
   */
  async loadCoarse() {
    const coarse = this.compact.coarse;
    if (!coarse) return false;
    const [base, V, gain] = await Promise.all([
      this.assets.texture(coarse.ktx2), this.assets.matrix(coarse.v),
      this.compact.gain ? this.assets.sharedTexture(this.compact.gain.ktx2) : null,
    ]);
    this._setUp({ base: asArray(base), V, k: coarse.v.shape[1], etc1s: null, gain, layers: this.compact.layers.slice(0, coarse.layers), coarse: true });
    return true;
  }

  /** Textures in place, uniforms and the pass built (again, when the full stack replaces
   * the coarse one; the coarse textures are freed). */
  _setUp({ base, V, k, etc1s, gain, layers, coarse }) {
    const [n] = this.compact.v.shape;
    const path = coarse ? this.compact.coarse.v.path : this.compact.v.path;
    if (V.length !== n * k) throw new Error(`${path}: ${V.length} values, expected ${n} x ${k}`);
    const old = [this.base, this.etc1s].filter((t) => t && t !== base && t !== etc1s);
    this.pass?.dispose();
    for (const t of old) t.dispose();
    this.base = base;
    this.V = V;
    this.k = k;
    this.etc1s = etc1s ?? null;
    this.gain = gain ?? null;
    this.coarse = coarse;
    this.drawnCompact = { ...this.compact, layers }; // stackWeights reads the layers drawn
    for (const t of [base, etc1s, gain]) if (t) t.minFilter = t.magFilter = THREE.NearestFilter;
    this.dummy ??= new THREE.DataTexture(new Uint8Array(4), 1, 1);
    this.dummy.needsUpdate = true;
    const uniforms = {
      baseTex: { value: base },
      ...(etc1s ? { etc1sTex: { value: etc1s } } : {}),
      layerWeight: { value: Array.from({ length: layers.length }, () => new THREE.Vector3()) },
      constantTerm: { value: new THREE.Vector3() },
    };
    if (this.slots) {
      uniforms.slotWeight = { value: Array.from({ length: this.slots }, () => new THREE.Vector3()) };
      for (let s = 0; s < this.slots; s++) uniforms[`slot${s}`] = { value: this.dummy };
    }
    if (this.gain) {
      const gainLayers = this.compact.gain.layers;
      uniforms.gainTex = { value: this.gain };
      uniforms.gainScale = { value: gainLayers.map((l) => new THREE.Vector3(...l.scale)) };
      uniforms.gainOffset = { value: gainLayers.map((l) => new THREE.Vector3(...l.offset)) };
    }
    this.pass = new FullscreenPass({
      uniforms,
      fragmentShader: relightFragment({
        layers: layers.length, etc1sLayers: etc1s ? this.compact.etc1s.layers : 0,
        slots: this.slots, gain: !!this.gain, encodeRGBE: this.format.rgbe,
      }),
    });
  }

  /** Start fetching the images of these lights (cached, at most once each). */
  fetchLights(indices) {
    for (const i of indices) {
      if (this.lights.has(i) || this.pending.has(i)) continue;
      const files = this.compact.lights.ktx2.map((pattern) => pattern.replace('{index:04d}', String(i).padStart(4, '0')));
      const promise = Promise.all(files.map((f) => this.assets.texture(f))).then((textures) => {
        for (const t of textures) t.minFilter = t.magFilter = THREE.NearestFilter;
        this.lights.set(i, textures);
        this.pending.delete(i);
        return textures;
      }, (err) => {
        this.pending.delete(i);
        throw err;
      });
      this.pending.set(i, promise);
    }
    return Promise.all(indices.map((i) => this.pending.get(i) ?? this.lights.get(i)));
  }

  /** Drop cached light images beyond the cache size, keeping the ones in use. */
  trimCache(keep) {
    if (this.lights.size <= LIGHT_CACHE_PER_STACK) return;
    for (const [i, textures] of this.lights) {
      if (this.lights.size <= LIGHT_CACHE_PER_STACK) break;
      if (keep.includes(i)) continue;
      for (const t of textures) t.dispose();
      this.lights.delete(i);
    }
  }

  /** Render the weighted sum for r with the selected lights that are loaded. */
  render(renderer, r, selected) {
    const loaded = selected.filter((i) => this.lights.has(i));
    const c = baseCoefficients(this.V, this.k, r, loaded); // lights not loaded stay in r'
    const w = stackWeights(this.drawnCompact, c, r, loaded);
    const u = this.pass.mesh.material.uniforms;
    u.layerWeight.value.forEach((v, j) => v.set(w.layerWeights[3 * j], w.layerWeights[3 * j + 1], w.layerWeights[3 * j + 2]));
    u.constantTerm.value.set(...w.constant);
    for (let s = 0; s < this.slots; s++) {
      const light = loaded[Math.floor(s / this.levels)];
      const level = s % this.levels;
      u[`slot${s}`].value = light === undefined ? this.dummy : this.lights.get(light)[level];
      const v = u.slotWeight.value[s];
      if (light === undefined) v.set(0, 0, 0);
      else v.set(w.slotWeights[3 * s], w.slotWeights[3 * s + 1], w.slotWeights[3 * s + 2]);
    }
    this.pass.render(renderer, this.target);
    return loaded.length === selected.length && !this.coarse;
  }

  dispose() {
    this.target.dispose();
    this.pass?.dispose();
    for (const t of [this.base, this.etc1s, this.gain, this.dummy]) t?.dispose();
    for (const textures of this.lights.values()) for (const t of textures) t.dispose();
  }
}

/**
 * All relight targets of a build: `targets['ground.I']` etc. (I of a shadowing atlas holds
 * Delta = d - I, see above), `targets['kiosk.sky']` for each view's sky pixels and
 * `targets.dome` (an equirectangular image of the sky for the virtual visit).
 */
export class Relighter {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {import('./assets.js').Assets} assets with its manifest loaded
   * @param {{stacks?: string[], deferred?: string[], views?: boolean, dome?: boolean,
   *   rgbe?: boolean}} which stacks to relight (default: every stack of every atlas and view);
   *   `deferred` ones get their target now but load nothing until `activate` asks for them
   *   (the hull planes, needed only in hull-plane mode, are a phone's largest download);
   *   `rgbe`: RGBA8 targets even where half float would do (tests)
   */
  constructor(renderer, assets, which = {}) {
    this.renderer = renderer;
    this.assets = assets;
    this.manifest = assets.manifest;
    this.format = targetFormat(renderer, which.rgbe ?? false);
    this.m = this.manifest.compression.selected_lights;
    this.selectionWeights = selectionWeights(
      this.manifest.dome.lights.map((l) => l.solid_angle_sr),
      this.manifest.compression.selectable_lights,
    );
    this.n = this.manifest.dome.count;
    this.stacks = new Map();
    const wanted = which.stacks ?? null;
    this.deferred = new Set(which.deferred ?? []);
    this.activating = new Map(); // key -> Promise of its load
    for (const entry of [...this.manifest.atlases, ...this.manifest.views]) {
      for (const [name, stack] of Object.entries(entry.stacks)) {
        const key = `${entry.id}.${name}`;
        if (wanted && !wanted.includes(key)) continue;
        this.stacks.set(key, new RelightStack(assets, key, stack.compact, entry.width, entry.height, this.format, this.m));
      }
    }
    this.targets = {};
    for (const [key, s] of this.stacks) this.targets[key] = s.target;
    this.viewSky = new Map();
    if (which.views ?? true) {
      for (const view of this.manifest.views) {
        if (wanted && !wanted.some((k) => k.startsWith(`${view.id}.`))) continue;
        this.viewSky.set(view.id, { view, target: makeTarget(view.width, view.height, this.format) });
        this.targets[`${view.id}.sky`] = this.viewSky.get(view.id).target;
      }
    }
    this.wantDome = which.dome ?? true;
    if (this.wantDome) this.targets.dome = makeTarget(256, 64, this.format);
    this.lightTex = null;
    this.latest = null; // {r, sequence}: the newest vector asked for
    this.applied = null; // {sequence, exact, selected, perStack, r}
    this.relights = 0;
    this.lastRelightMs = 0;
    this.waitingForLights = 0;
    this.onApplied = null; // callback after a relight
    // Draw from the coarse starts first: the app decides per link (startmode.js).
    this.coarseStart = true;
    this._toRefine = null; // stacks drawn from their coarse start, to load in full
    this._refineSoon = null; // the timer that will call _refine after this frame
    this.refined = null; // Promise: every stack loaded in full (after the first picture)
    this.onRefineError = null; // (err): a full stack failed; the coarse one stays, tried again
  }

  /** True while some stack is drawn from its coarse start. */
  get coarse() {
    return [...this.stacks.values()].some((s) => s.pass && s.coarse);
  }

  /** Fetch the full stacks (once the first picture is drawn) and draw each as it arrives. */
  _refine() {
    const stacks = this._toRefine;
    this._toRefine = null;
    const redraw = () => {
      if (this.latest) this.update(this.latest.r, this.latest.sequence, true);
    };
    this.refined = Promise.all(stacks.map((s) => s.load().then(redraw))).catch((err) => {
      this._toRefine = stacks.filter((s) => s.coarse); // tried again after the next light
      this.refined = null;
      this.onRefineError?.(err);
    });
  }

  /** The stacks that are loaded and relit (every one but the deferred not yet activated). */
  active() {
    return [...this.stacks.values()].filter((s) => s.pass);
  }

  /**
   * Load the stacks (not the deferred ones) and the sky passes. With `coarse` (the default)
   * and a build whose every such stack has a coarse start (bake/coarse.py), only those load
   * now; the full stacks are fetched once the first picture is drawn (so that they do not
   * share a slow link with it) and each replaces its coarse one as it arrives, drawn again
   * with the newest light (`refined` settles when all have: docs/web.md, "A coarse start").
   */
  async load() {
    const now = [...this.stacks.values()].filter((s) => !this.deferred.has(s.key));
    const coarse = this.coarseStart && now.length > 0 && now.every((s) => s.compact.coarse);
    if (coarse) {
      await Promise.all(now.map((s) => s.loadCoarse()));
      this._toRefine = now;
    } else {
      await Promise.all(now.map((s) => s.load()));
    }
    const n = this.n;
    this.lightData = new Float32Array(4 * n * 2);
    this.manifest.dome.lights.forEach((l, i) => this.lightData.set([...l.centroid, 1], 4 * (n + i)));
    this.lightTex = new THREE.DataTexture(this.lightData, n, 2, THREE.RGBAFormat, THREE.FloatType);
    this.lightTex.minFilter = this.lightTex.magFilter = THREE.NearestFilter;
    const invWidth2 = skyInvWidth2(n);
    for (const entry of this.viewSky.values()) {
      const { view } = entry;
      const maskBitmap = await this.assets.image(view.mask);
      const mask = new THREE.Texture(maskBitmap);
      mask.flipY = false;
      mask.colorSpace = THREE.NoColorSpace;
      mask.minFilter = mask.magFilter = THREE.NearestFilter;
      mask.generateMipmaps = false;
      mask.needsUpdate = true;
      entry.mask = mask;
      entry.pass = new FullscreenPass({
        fragmentShader: viewSkyFragment({ lights: n, encodeRGBE: this.format.rgbe }),
        uniforms: {
          lightTex: { value: this.lightTex },
          maskTex: { value: mask },
          worldFromPixel: { value: worldFromPixel(view) },
          invWidth2: { value: invWidth2 },
          size: { value: new THREE.Vector2(view.width, view.height) },
        },
      });
    }
    if (this.wantDome) {
      this.domePass = new FullscreenPass({
        fragmentShader: domeSkyFragment({ lights: n, encodeRGBE: this.format.rgbe }),
        uniforms: {
          lightTex: { value: this.lightTex },
          invWidth2: { value: invWidth2 },
          size: { value: new THREE.Vector2(256, 64) },
        },
      });
    }
  }

  /**
   * Ask for a relight with the vector r (n x RGB). Returns a promise that settles when a
   * relight with this vector (or a newer one) has been drawn exactly, or with missing lights
   * summed by the base when nothing was drawn before. `force`: draw again even if this
   * vector is already drawn (stacks were added).
   */
  update(r, sequence = 0, force = false) {
    if (r.length !== 3 * this.n) throw new Error(`light vector of ${r.length / 3} lights, the build has ${this.n}`);
    const selected = selectLights(r, this.selectionWeights, this.m);
    const perStack = new Map(); // stack key -> the lights it selects (its own m)
    for (const s of this.stacks.values()) {
      perStack.set(s.key, s.m === this.m ? selected : selectLights(r, this.selectionWeights, s.m));
    }
    this.latest = { r: Float64Array.from(r), sequence, selected, perStack };
    const loaded = (s, v) => v.perStack.get(s.key).every((i) => s.lights.has(i));
    const stacks = this.active();
    const ready = stacks.every((s) => loaded(s, this.latest));
    if (ready || this.applied === null) this._render(this.latest);
    if (ready) return Promise.resolve(this.applied);
    this.waitingForLights += 1;
    const want = this.latest;
    return Promise.all(stacks.map((s) => s.fetchLights(perStack.get(s.key)))).then(() => {
      // Newer vectors may have come meanwhile: draw the newest whose lights are all here.
      const newest = this.latest;
      const newestReady = stacks.every((s) => loaded(s, newest));
      if (newestReady && (force || this.applied === null || !this.applied.exact || this.applied.sequence !== newest.sequence)) {
        this._render(newest);
      } else if (this.applied?.sequence !== want.sequence) {
        this._render(want);
      }
      for (const s of stacks) s.trimCache(newest.perStack.get(s.key));
      return this.applied;
    });
  }

  _render({ r, sequence, selected, perStack }) {
    const t0 = performance.now();
    const renderer = this.renderer;
    const autoClear = renderer.autoClear;
    renderer.autoClear = false;
    let exact = true;
    for (const s of this.active()) exact = s.render(renderer, r, perStack.get(s.key)) && exact;
    if (this.lightTex) {
      for (let i = 0; i < this.n; i++) this.lightData.set([r[3 * i], r[3 * i + 1], r[3 * i + 2], 1], 4 * i);
      this.lightTex.needsUpdate = true;
      for (const entry of this.viewSky.values()) entry.pass.render(renderer, entry.target);
      if (this.domePass) this.domePass.render(renderer, this.targets.dome);
    }
    renderer.autoClear = autoClear;
    this.relights += 1;
    this.lastRelightMs = performance.now() - t0; // CPU side only; the GPU runs on
    this.applied = { sequence, exact, coarse: this.coarse, selected, perStack, r };
    this.onApplied?.(this.applied);
    // The full arrays are asked for once this picture is on the screen (the frame that
    // relit is still being drawn: a request now would start before it and share the link).
    if (this._toRefine && !this.refined && !this._refineSoon) {
      this._refineSoon = setTimeout(() => {
        this._refineSoon = null;
        if (this._toRefine && !this.refined) this._refine();
      }, 0);
    }
  }

  /**
   * Load deferred stacks (keys, or every deferred one) and relight them with the newest
   * vector and its light images. Resolves when they are drawn; safe to call repeatedly.
   */
  activate(keys = [...this.deferred]) {
    return Promise.all(keys.map((key) => {
      const stack = this.stacks.get(key);
      if (!stack) return Promise.reject(new Error(`no stack ${key} in this build`));
      if (!this.activating.has(key)) {
        this.activating.set(key, stack.load().catch((err) => {
          this.activating.delete(key); // a later call tries again
          throw err;
        }));
      }
      return this.activating.get(key);
    })).then(() => (this.latest ? this.update(this.latest.r, this.latest.sequence, true) : null));
  }

  /** Read one target back as float RGBA rows from the top (tests and the benchmark). */
  read(key) {
    return this.readTarget(this.targets[key]);
  }

  /** Any relight-format render target read back as float32 RGBA (see read). */
  readTarget(target) {
    const { width, height } = target;
    const gl = this.renderer.getContext();
    this.renderer.setRenderTarget(target);
    let out;
    if (this.format.rgbe) {
      const bytes = new Uint8Array(4 * width * height);
      gl.readPixels(0, 0, width, height, gl.RGBA, gl.UNSIGNED_BYTE, bytes);
      out = new Float32Array(4 * width * height);
      for (let p = 0; p < width * height; p++) {
        out.set(decodeRGBE(bytes[4 * p], bytes[4 * p + 1], bytes[4 * p + 2], bytes[4 * p + 3]), 4 * p);
        out[4 * p + 3] = 1;
      }
    } else {
      out = new Float32Array(4 * width * height);
      gl.readPixels(0, 0, width, height, gl.RGBA, gl.FLOAT, out);
    }
    this.renderer.setRenderTarget(null);
    return { width, height, data: out };
  }

  /** Wait for the GPU to finish the last relight (for timing only). */
  finish() {
    const gl = this.renderer.getContext();
    const px = new Uint8Array(4);
    // A 1-pixel read forces the queued passes to complete.
    const target = [...this.stacks.values()][0]?.target;
    if (!target) return;
    this.renderer.setRenderTarget(target);
    if (this.format.rgbe) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    else gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, new Float32Array(4));
    this.renderer.setRenderTarget(null);
  }

  dispose() {
    clearTimeout(this._refineSoon);
    this._refineSoon = null;
    this._toRefine = null; // a refinement not yet asked for is not asked for by a disposed relighter
    for (const s of this.stacks.values()) s.dispose();
    for (const entry of this.viewSky.values()) {
      entry.target.dispose();
      entry.pass?.dispose();
      entry.mask?.dispose();
    }
    this.targets.dome?.dispose();
    this.domePass?.dispose();
    this.lightTex?.dispose();
  }
}

/** R K^-1 of a view (OpenCV camera: +X right, +Y down, +Z forward) as a THREE.Matrix3. */
export function worldFromPixel(view) {
  const K = new THREE.Matrix3().set(...view.K.flat());
  const W = view.world_from_camera;
  const R = new THREE.Matrix3().set(W[0][0], W[0][1], W[0][2], W[1][0], W[1][1], W[1][2], W[2][0], W[2][1], W[2][2]);
  return R.multiply(K.invert());
}
