// The sun's bounce (docs/sun.md, item 5): sunlight reflected once off sunlit ground, walls and
// models. The bake keeps, for every patch the sun can be in, that patch's one-bounce image of
// each atlas stack (manifest `atlases[i].sun_bounce[stack]`, images only, no low-rank base)
// and of each fixed view's O and S (`views[i].sun_bounce[stack]`, radiance: the kiosk's);
// the sun's bounce is the image of the patch that holds the sun times E_sun / solid_angle_p
// (the bounce is smooth over neighbouring patches, so spreading the sun over its patch is
// harmless here, unlike for its direct term). One image per stack (its coarse level, and a
// refinement where the bake kept one) is fetched when the sun enters a patch; its target is
// rendered once per sun update. Neighbouring patches may share one image (manifest version 3:
// `lights.image[p]`, the light whose files hold patch p's image, read with p's own scale and
// offset; docs/sun.md, "Shared images"): it is fetched once for all of them.
import * as THREE from 'three';
import { patchContaining } from './lightmath.js';
import { RGBE_ENCODE } from './relight.glsl.js';
import { FullscreenPass, makeTarget } from './passes.js';

const CACHE_PER_STACK = 4; // the sun stays tens of minutes in a patch

function bounceFragment(encodeRGBE) {
  return /* glsl */ `
precision highp float;
uniform sampler2D level0;
uniform sampler2D level1;
uniform vec3 weight0;
uniform vec3 weight1;
uniform vec3 constantTerm;
out vec4 outColor;
${encodeRGBE ? RGBE_ENCODE : ''}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 e = constantTerm + texelFetch(level0, p, 0).rgb * weight0 + texelFetch(level1, p, 0).rgb * weight1;
  outColor = ${encodeRGBE ? 'encodeRGBE(e)' : 'vec4(e, 1.0)'};
}
`;
}

/** One atlas stack's sun bounce: its per-light images, cached, and its target. */
class BounceStack {
  constructor(assets, key, compact, width, height, format) {
    this.assets = assets;
    this.key = key; // e.g. 'ground.I'
    this.compact = compact;
    this.target = makeTarget(width, height, format);
    this.target.texture.name = `${key}.sun_bounce`;
    this.images = new Map(); // light -> Promise of [level textures]
    this.loaded = new Map(); // light -> [level textures], once they arrived
    const dummy = new THREE.DataTexture(new Uint8Array(4), 1, 1);
    dummy.needsUpdate = true;
    this.dummy = dummy;
    this.uniforms = {
      level0: { value: dummy }, level1: { value: dummy },
      weight0: { value: new THREE.Vector3() }, weight1: { value: new THREE.Vector3() },
      constantTerm: { value: new THREE.Vector3() },
    };
    this.pass = new FullscreenPass({ fragmentShader: bounceFragment(format.rgbe), uniforms: this.uniforms });
    this.light = null; // the light whose image the target holds (null: zero)
  }

  has(light) {
    return Array.isArray(this.compact.lights.scale[light]);
  }

  /** The light whose files hold `light`'s image (itself unless shared). */
  holder(light) {
    return this.compact.lights.image?.[light] ?? light;
  }

  /** The textures of `light`'s image once they arrived, else undefined. */
  loadedFor(light) {
    return this.loaded.get(this.holder(light));
  }

  fetch(light) {
    const key = this.holder(light); // images are cached by the light whose files hold them
    if (!this.images.has(key)) {
      // The light's own levels (len(scale[light])): a sun-bounce image whose coarse level
      // suffices as displayed has no refinement file (docs/compact-assets.md).
      const levels = this.compact.lights.scale[light].length;
      const files = this.compact.lights.ktx2.slice(0, levels).map((pattern) => pattern.replace('{index:04d}', String(key).padStart(4, '0')));
      const promise = Promise.all(files.map((f) => this.assets.texture(f))).then((textures) => {
        for (const t of textures) t.minFilter = t.magFilter = THREE.NearestFilter;
        if (this.images.get(key) === promise) this.loaded.set(key, textures);
        return textures;
      });
      promise.catch(() => this.images.delete(key)); // retried with the next sun
      this.images.set(key, promise);
      for (const [old, p] of this.images) {
        if (this.images.size <= CACHE_PER_STACK) break;
        if (old === key) continue;
        p.then((textures) => textures.forEach((t) => t.dispose()), () => {});
        this.images.delete(old);
        this.loaded.delete(old);
      }
    }
    return this.images.get(key);
  }

  /** Render weight (RGB: E_sun / solid angle) times light `light`'s images (`textures`, from
   * fetch); light null: zero. */
  render(renderer, light, textures, weight) {
    const u = this.uniforms;
    if (light === null) {
      u.level0.value = u.level1.value = this.dummy;
      u.weight0.value.set(0, 0, 0);
      u.weight1.value.set(0, 0, 0);
      u.constantTerm.value.set(0, 0, 0);
    } else {
      const { scale, offset } = this.compact.lights;
      const levels = [u.level0, u.level1];
      const weights = [u.weight0, u.weight1];
      const constant = [0, 0, 0];
      for (let level = 0; level < 2; level++) {
        const present = level < textures.length;
        levels[level].value = present ? textures[level] : this.dummy;
        const s = present ? scale[light][level] : [0, 0, 0];
        weights[level].value.set(...s.map((v, c) => v * weight[c]));
        if (present) for (let c = 0; c < 3; c++) constant[c] += offset[light][level][c] * weight[c];
      }
      u.constantTerm.value.set(...constant);
    }
    this.pass.render(renderer, this.target);
    this.light = light;
  }

  dispose() {
    this.target.dispose();
    this.pass.dispose();
    this.dummy.dispose();
    for (const p of this.images.values()) p.then((textures) => textures.forEach((t) => t.dispose()), () => {});
  }
}

export class SunBounce {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {import('./assets.js').Assets} assets with its manifest loaded
   * @param {{rgbe: boolean, type: number}} format the relight targets' format
   * @param {{view?: object, deferred?: string[]}} [options] view: a fixed view of the manifest
   *   (the kiosk's): its O and S stacks' bounce (`views[i].sun_bounce`, radiance) instead of
   *   the atlases'; deferred: stacks ('hull.I', 'hull.d') whose images are neither fetched nor
   *   drawn until `activate` (the hull planes' serve only hull-plane mode)
   */
  constructor(renderer, assets, format, { view = null, deferred = [] } = {}) {
    this.renderer = renderer;
    this.lights = assets.manifest.dome.lights;
    this.stacks = new Map();
    for (const owner of view ? [view] : assets.manifest.atlases) {
      for (const [name, entry] of Object.entries(owner.sun_bounce ?? {})) {
        if (!entry.compact?.lights) continue; // a base-only form this client does not read
        const key = `${owner.id}.${name}`;
        this.stacks.set(key, new BounceStack(assets, key, entry.compact, owner.width, owner.height, format));
      }
    }
    this.patch = null;
    this._asked = 0;
    this.deferred = new Set(deferred);
    this._sun = null;
  }

  /** Fetch and draw the bounce of `keys` too from now on (hull-plane mode chosen): as
   * `update` with the last sun (null when drawn at once, else a Promise). */
  activate(keys) {
    for (const key of keys) this.deferred.delete(key);
    return this.update(this._sun);
  }

  /** The target of an atlas or view stack ('ground.I', 'kiosk.O'), or null when the build
   * has none. */
  texture(key) {
    return this.stacks.get(key)?.target.texture ?? null;
  }

  /**
   * A new sun ({direction, normalIrradiance} or null): every stack's target becomes the bounce
   * of the patch that holds it. Draws at once and returns null when every image it needs is
   * already here (the sun stays tens of minutes in a patch, so nearly always); otherwise
   * returns a Promise that resolves when drawn, after the images arrived.
   */
  update(sun) {
    const up = sun && sun.direction[1] > 0 && sun.normalIrradiance.some((e) => e > 0);
    const p = up ? patchContaining(this.lights, sun.direction) : -1;
    const weight = p >= 0 ? sun.normalIrradiance.map((e) => e / this.lights[p].solid_angle_sr) : null;
    const asked = ++this._asked;
    this._sun = sun;
    const stacks = [...this.stacks.values()];
    const lights = stacks.map((s) => (p >= 0 && s.has(p) && !this.deferred.has(s.key) ? p : null));
    const draw = (images) => {
      stacks.forEach((s, j) => s.render(this.renderer, lights[j], images[j], weight));
      this.patch = p;
    };
    const here = stacks.map((s, j) => (lights[j] === null ? null : s.loadedFor(lights[j])));
    if (here.every((images, j) => lights[j] === null || images)) {
      draw(here);
      return null;
    }
    return Promise.all(stacks.map((s, j) => (lights[j] === null ? null : s.fetch(lights[j])))).then((images) => {
      if (asked === this._asked) draw(images); // else a newer sun came meanwhile: it draws
    });
  }

  dispose() {
    for (const s of this.stacks.values()) s.dispose();
  }
}
