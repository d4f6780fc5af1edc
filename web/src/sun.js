// The sun as its own light (docs/sun.md, Jensen et al. 2006): a directional light whose
// shadows come from two depth maps rendered from the sun, one of every caster (virtual models
// and real proxies) and one of the real proxies alone, so that real and virtual shadows can
// meet as they do in reality (a surface needs the first; a shadowing plane over a camera
// picture both: sun past everything, and past what is real). The
// maps are filtered to the penumbra of the sun's 0.53-degree disc (percentage-closer soft
// shadows: a blocker search, then a disc filter whose radius is the receiver-to-blocker
// distance times tan(0.2666 deg)); bake/sunlight.py is the ray-cast oracle of the same term.
//
// Why not three.js's DirectionalLight shadows: their PCF blur is a fixed number of texels,
// not the sun's disc; they need three's lighting chunks in every material; and they cast one
// set of shadows where daylit needs two (all, real).
//
// The scene is static, so the maps are rendered only when the sun moves (a new light
// vector), never per frame; a frame pays only the filter's texture reads.
import * as THREE from 'three';
import { FullscreenPass } from './relight.js';

export const SUN_ANGULAR_RADIUS_DEG = 0.2666;
const TAN_SUN = Math.tan(SUN_ANGULAR_RADIUS_DEG * Math.PI / 180);
const MAP_SIZE = 2048;
// The coarse map: per CELL x CELL block of the depth map, the least and greatest depth over
// the block and CELL texels around it, so one read answers "no caster near" (lit) or "casters
// everywhere near" (umbra) for any search disc of up to CELL texels.
const CELL = 16;
const COARSE = MAP_SIZE / CELL;
export const LAYER = { virtual: 1, real: 2 }; // caster layers; the 'all' map sees both
const MIN_FIT_ELEVATION_SIN = Math.sin(3 * Math.PI / 180); // shadows of a lower sun are clipped
// Re-render when the sun moved 0.05 deg (a shadow edge 10 m from its caster moves 9 mm / sin
// of the sun's elevation: a fraction of its penumbra; the demo's clock at 20x moves the sun
// that far every 0.6 s).
const RERENDER_COS = Math.cos(0.05 * Math.PI / 180);

/**
 * GLSL of the sun term, shared by every material that receives the sun. Uniforms:
 * sunIrradiance (RGB normal irradiance, W/m^2), sunDirection (unit, toward the sun), and per
 * caster set X in {A, R}: sunMapX (depth), sunMatrixX (world -> the sun camera's clip space),
 * sunInfoX = (metres per texel, near m, far - near m, 1 when the map holds casters).
 */
/** Vogel's spiral: `count` evenly spread points on the unit disc, as a GLSL vec2 array. */
function spiral(name, count) {
  const points = Array.from({ length: count }, (_, i) => {
    const r = Math.sqrt((i + 0.5) / count);
    const a = i * 2.39996323;
    return `vec2(${(r * Math.cos(a)).toFixed(6)}, ${(r * Math.sin(a)).toFixed(6)})`;
  });
  return `const vec2 ${name}[${count}] = vec2[](${points.join(', ')});`;
}

const BLOCKER_SAMPLES = 12;
const FILTER_SAMPLES = 32;

// 16-bit depths in two 8-bit channels (RGBA8 renders everywhere; float targets do not).
const PACK16 = /* glsl */ `
vec2 pack16(float units) { return vec2(floor(units / 256.0), mod(units, 256.0)) / 255.0; }
float unpack16(vec2 p) { return (p.x * 65280.0 + p.y * 255.0) / 65535.0; }
`;

/** Reduction of the depth map to its coarse map, along x (pass 0) then y (pass 1). */
function coarseFragment(pass) {
  const read = pass === 0
    ? 'float d = texelFetch(source, ivec2(x, y), 0).r; lo = min(lo, d); hi = max(hi, d);'
    : 'vec4 t = texelFetch(source, ivec2(x, y), 0); lo = min(lo, unpack16(t.rg)); hi = max(hi, unpack16(t.ba));';
  const loop = pass === 0
    ? `int y = int(gl_FragCoord.y); int c = int(gl_FragCoord.x);
  for (int x = max(0, (c - 1) * ${CELL}); x < min(${MAP_SIZE}, (c + 2) * ${CELL}); x++) { ${read} }`
    : `int x = int(gl_FragCoord.x); int c = int(gl_FragCoord.y);
  for (int y = max(0, (c - 1) * ${CELL}); y < min(${MAP_SIZE}, (c + 2) * ${CELL}); y++) { ${read} }`;
  return /* glsl */ `
precision highp float;
precision highp int;
uniform highp sampler2D source;
out vec4 outColor;
${PACK16}
void main() {
  float lo = 1.0;
  float hi = 0.0;
  ${loop}
  // rounded outward: the bounds stay bounds
  outColor = vec4(pack16(floor(lo * 65535.0)), pack16(ceil(hi * 65535.0)));
}
`;
}

/**
 * GLSL of the sun term, shared by every material that receives the sun. Uniforms:
 * sunIrradiance (RGB normal irradiance, W/m^2), sunDirection (unit, toward the sun), and per
 * caster set X in {A (all), R (real)}: sunMapX (depth), sunMatrixX (world -> the sun camera's
 * clip space), sunInfoX = (metres per texel, near m, far - near m, 1 when the map holds
 * casters). Compiled with SUN 0 (materials' define) it draws no sun and costs nothing.
 * Cost: a lit or umbral pixel reads BLOCKER_SAMPLES texels per map; only penumbrae (where the
 * blocker search finds some but not all samples blocked) read FILTER_SAMPLES more.
 */
export const sunShadowChunk = /* glsl */ `
uniform vec3 sunIrradiance;
uniform vec3 sunDirection;
uniform sampler2D sunMapA;
uniform sampler2D sunMapR;
uniform mat4 sunMatrixA;
uniform mat4 sunMatrixR;
uniform vec4 sunInfoA;
uniform vec4 sunInfoR;
uniform sampler2D sunCoarseA;
uniform sampler2D sunCoarseR;
const float TAN_SUN = ${TAN_SUN.toFixed(9)};
${spiral('SUN_BLOCKER_DISC', BLOCKER_SAMPLES)}
${spiral('SUN_FILTER_DISC', FILTER_SAMPLES)}
${PACK16}

// Fraction of the sun's disc seen past one caster set from a world point with normal n.
// One exit and loops whose counts are 0 where they are not needed: a software GPU
// (SwiftShader) runs the code under a branch not taken with its lanes masked, but leaves a
// loop as soon as no lane needs another turn.
float sunVisibilityIn(sampler2D map, sampler2D coarse, mat4 M, vec4 info, vec3 position, vec3 n) {
#if SUN == 0
  return 1.0;
#else
  float texel = info.x;
  vec4 clip = M * vec4(position + n * (1.5 * texel), 1.0);
  vec3 q = clip.xyz * 0.5 + 0.5;
  float depth = info.y + q.z * info.z;   // metres from the sun camera
  float bias = 1.5 * texel;
  float toUv = 1.0 / (texel * ${MAP_SIZE}.0);
  // A blocker lies between the near plane (the casters' nearest point) and the receiver.
  float searchM = max((depth - info.y) * TAN_SUN, 1.5 * texel);
  bool inMap = info.w > 0.5 && q.x > 0.0 && q.y > 0.0 && q.x < 1.0 && q.y < 1.0 && q.z < 1.0;
  float visible = 1.0;
  int blockerCount = inMap ? ${BLOCKER_SAMPLES} : 0;
  if (inMap && searchM <= ${CELL}.0 * texel) {
    // One read of the coarse map settles most pixels: no caster near, or casters all around.
    vec4 bounds = texelFetch(coarse, ivec2(q.xy * ${COARSE}.0), 0);
    bool clear = info.y + unpack16(bounds.rg) * info.z >= depth - bias;
    bool covered = info.y + unpack16(bounds.ba) * info.z < depth - bias;
    if (clear || covered) blockerCount = 0;
    if (covered) visible = 0.0;
  }
  // Interleaved gradient noise turns the spirals from pixel to pixel (no banding).
  float turn = 6.2831853 * fract(52.9829189 * fract(dot(gl_FragCoord.xy, vec2(0.06711056, 0.00583715))));
  mat2 rotate = mat2(cos(turn), sin(turn), -sin(turn), cos(turn));
  // 1. Blockers: any caster nearer than the receiver within the largest penumbra possible.
  float searchUv = searchM * toUv;
  float blockers = 0.0;
  float blockerDepth = 0.0;
  for (int i = 0; i < blockerCount; i++) {
    float z = info.y + texture2D(map, q.xy + rotate * SUN_BLOCKER_DISC[i] * searchUv).r * info.z;
    if (z < depth - bias) { blockers += 1.0; blockerDepth += z; }
  }
  // All blocked: umbra; none: lit; else the penumbra's filter below.
  if (blockerCount > 0 && blockers == ${BLOCKER_SAMPLES}.0) visible = 0.0;
  int filterCount = blockers > 0.0 && blockers < ${BLOCKER_SAMPLES}.0 ? ${FILTER_SAMPLES} : 0;
  // 2. The disc's footprint at the blockers' mean distance: each sample is one direction
  //    within the sun's disc, blocked or not.
  float radiusUv = max((depth - blockerDepth / max(blockers, 1.0)) * TAN_SUN, texel) * toUv;
  float lit = 0.0;
  for (int i = 0; i < filterCount; i++) {
    float z = info.y + texture2D(map, q.xy + rotate * SUN_FILTER_DISC[i] * radiusUv).r * info.z;
    lit += z < depth - bias ? 0.0 : 1.0;
  }
  if (filterCount > 0) visible = lit / ${FILTER_SAMPLES}.0;
  return visible;
#endif
}

// The sun's cosine-weighted normal irradiance on a surface (W/m^2, RGB), unshadowed.
vec3 sunOnSurface(vec3 n) {
#if SUN == 0
  return vec3(0.0);
#else
  return sunIrradiance * max(dot(n, sunDirection), 0.0);
#endif
}
`;

/** The defines every material with sunShadowChunk starts with: no sun until SunShadows.setSun
 * brings one (SunShadows.setMaterials). */
export const SUN_DEFINES = { SUN: 0 };

/** Uniforms of sunShadowChunk, shared by every material (one update reaches them all). */
export function sunUniforms() {
  return {
    sunIrradiance: { value: new THREE.Vector3() },
    sunDirection: { value: new THREE.Vector3(0, 1, 0) },
    sunMapA: { value: null },
    sunMapR: { value: null },
    sunMatrixA: { value: new THREE.Matrix4() },
    sunMatrixR: { value: new THREE.Matrix4() },
    sunInfoA: { value: new THREE.Vector4(1, 0, 1, 0) },
    sunInfoR: { value: new THREE.Vector4(1, 0, 1, 0) },
    sunCoarseA: { value: null },
    sunCoarseR: { value: null },
  };
}

/** One caster set's depth map, seen from the sun with an orthographic camera fitted to the
 * casters and to where their shadows can fall. */
class ShadowMap {
  constructor(layers) {
    this.target = new THREE.WebGLRenderTarget(MAP_SIZE, MAP_SIZE, {
      depthBuffer: true,
      depthTexture: new THREE.DepthTexture(MAP_SIZE, MAP_SIZE, THREE.FloatType),
      minFilter: THREE.NearestFilter,
      magFilter: THREE.NearestFilter,
      generateMipmaps: false,
    });
    const depth = this.target.depthTexture;
    depth.minFilter = depth.magFilter = THREE.NearestFilter;
    const coarseTarget = (w, h) => new THREE.WebGLRenderTarget(w, h, {
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, generateMipmaps: false, depthBuffer: false,
    });
    this.rows = coarseTarget(COARSE, MAP_SIZE); // reduced along x
    this.coarse = coarseTarget(COARSE, COARSE); // then along y
    this.reduce = [0, 1].map((pass) => new FullscreenPass({
      fragmentShader: coarseFragment(pass),
      uniforms: { source: { value: pass === 0 ? depth : this.rows.texture } },
    }));
    this.camera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0.1, 10);
    this.camera.layers.disableAll();
    for (const layer of layers) this.camera.layers.enable(layer);
    this.matrix = new THREE.Matrix4();
    this.info = new THREE.Vector4(1, 0, 1, 0);
  }

  /**
   * Fit the camera to a box of casters (world) and their shadows on the plane y = box.min.y.
   * @param {THREE.Box3} box
   * @param {THREE.Vector3} toSun unit
   */
  fit(box, toSun) {
    const s = toSun.clone();
    if (s.y < MIN_FIT_ELEVATION_SIN) {
      s.y = MIN_FIT_ELEVATION_SIN;
      s.normalize();
    }
    const centre = box.getCenter(new THREE.Vector3());
    const radius = box.getSize(new THREE.Vector3()).length();
    const cam = this.camera;
    cam.position.copy(centre).addScaledVector(toSun, 2 * radius + 10);
    cam.up.set(0, 1, 0);
    if (Math.abs(toSun.y) > 0.99) cam.up.set(0, 0, -1);
    cam.lookAt(centre);
    cam.updateMatrixWorld(true);
    const view = cam.matrixWorldInverse;
    const lo = new THREE.Vector3(Infinity, Infinity, Infinity);
    const hi = new THREE.Vector3(-Infinity, -Infinity, -Infinity);
    const p = new THREE.Vector3();
    for (let i = 0; i < 8; i++) {
      const corner = new THREE.Vector3(i & 1 ? box.max.x : box.min.x, i & 2 ? box.max.y : box.min.y, i & 4 ? box.max.z : box.min.z);
      const ground = corner.clone().addScaledVector(s, -(corner.y - box.min.y) / s.y);
      for (const q of [corner, ground]) {
        p.copy(q).applyMatrix4(view);
        lo.min(p);
        hi.max(p);
      }
    }
    const margin = 0.5;
    const half = Math.max(hi.x - lo.x, hi.y - lo.y) / 2 + margin; // square texels
    const cx = (hi.x + lo.x) / 2;
    const cy = (hi.y + lo.y) / 2;
    Object.assign(cam, {
      left: cx - half, right: cx + half, bottom: cy - half, top: cy + half,
      near: Math.max(0.01, -hi.z - margin), far: -lo.z + margin,
    });
    cam.updateProjectionMatrix();
    this.matrix.multiplyMatrices(cam.projectionMatrix, cam.matrixWorldInverse);
    this.info.set(2 * half / MAP_SIZE, cam.near, cam.far - cam.near, 1);
  }

  /** The coarse map from the depth map just rendered. */
  reduceDepth(renderer) {
    this.reduce[0].render(renderer, this.rows);
    this.reduce[1].render(renderer, this.coarse);
  }

  dispose() {
    this.target.depthTexture.dispose();
    this.target.dispose();
    this.rows.dispose();
    this.coarse.dispose();
    for (const pass of this.reduce) pass.dispose();
  }
}

export class SunShadows {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {THREE.Scene} scene the scene holding the casters
   * @param {{virtual: THREE.Mesh[], real: THREE.Mesh[]}} casters
   * @param {object} uniforms from sunUniforms(), shared with the materials
   */
  constructor(renderer, scene, casters, uniforms) {
    this.renderer = renderer;
    this.scene = scene;
    this.uniforms = uniforms;
    this.maps = {};
    this.boxes = {};
    for (const [set, meshes] of Object.entries(casters)) for (const m of meshes) m.layers.enable(LAYER[set]);
    const sets = { all: [...casters.virtual, ...casters.real], real: casters.real };
    for (const [set, meshes] of Object.entries(sets)) {
      const box = new THREE.Box3();
      for (const m of meshes) box.expandByObject(m);
      if (box.isEmpty()) continue;
      this.boxes[set] = box;
      this.maps[set] = new ShadowMap(set === 'all' ? [LAYER.virtual, LAYER.real] : [LAYER.real]);
    }
    this.on = null; // whether the materials are compiled with the sun (SUN 1)
    this.materials = []; // every material that draws the sun (setMaterials)
    this.depthOnly = new THREE.MeshBasicMaterial({ colorWrite: false, side: THREE.DoubleSide });
    this.direction = null; // the sun direction the maps were rendered for
    this.renders = 0;
  }

  /**
   * A new sun: direction (unit, toward the sun, site frame) and RGB normal irradiance (W/m^2;
   * zeros when it is hidden or set). The maps are rendered again only when it moved.
   */
  setSun(direction, normalIrradiance) {
    const u = this.uniforms;
    const s = new THREE.Vector3(...direction);
    const up = s.lengthSq() > 0 && s.y > 0;
    u.sunIrradiance.value.set(...(up ? normalIrradiance : [0, 0, 0]));
    const on = up && normalIrradiance.some((e) => e > 0);
    this._compileWithSun(on);
    if (!on) return;
    s.normalize();
    u.sunDirection.value.copy(s);
    if (this.direction && this.direction.dot(s) > RERENDER_COS) return;
    this.direction = s;
    this.render();
  }

  /** The materials that draw the sun: compiled with SUN 0 while there is none (night, a
   * cloud over it), so that they cost nothing then. */
  setMaterials(materials) {
    this.materials = materials;
    this.on = null;
  }

  _compileWithSun(on) {
    if (on === this.on) return;
    this.on = on;
    for (const m of this.materials) {
      m.defines = { ...m.defines, SUN: on ? 1 : 0 };
      m.needsUpdate = true;
    }
  }

  render() {
    const { renderer, scene, uniforms } = this;
    const saved = { target: renderer.getRenderTarget(), override: scene.overrideMaterial, auto: scene.matrixWorldAutoUpdate };
    scene.overrideMaterial = this.depthOnly;
    for (const [set, map] of Object.entries(this.maps)) {
      map.fit(this.boxes[set], this.direction);
      renderer.setRenderTarget(map.target);
      renderer.clear(true, true, false);
      renderer.render(scene, map.camera);
      map.reduceDepth(renderer);
      const key = set === 'all' ? 'A' : 'R';
      uniforms[`sunMap${key}`].value = map.target.depthTexture;
      uniforms[`sunCoarse${key}`].value = map.coarse.texture;
      uniforms[`sunMatrix${key}`].value.copy(map.matrix);
      uniforms[`sunInfo${key}`].value.copy(map.info);
    }
    scene.overrideMaterial = saved.override;
    renderer.setRenderTarget(saved.target);
    this.renders += 1;
  }

  /** Bytes of GPU memory the maps hold: depth float32 and the RGBA8 colour three.js attaches,
   * and the coarse maps (RGBA8). */
  get gpuBytes() {
    return Object.keys(this.maps).length * (MAP_SIZE * MAP_SIZE * 8 + (COARSE * MAP_SIZE + COARSE * COARSE) * 4);
  }

  dispose() {
    for (const map of Object.values(this.maps)) map.dispose();
    this.depthOnly.dispose();
  }
}
