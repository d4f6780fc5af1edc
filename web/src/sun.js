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
// vector), never per frame. The penumbra filter runs then too, not per frame: once for the
// surface each texel of a depth map sees and once for the ground point under it, into a
// visibility map; a frame reads that map (docs/sun.md, "Visibility maps"), and filters only
// where a surface lies behind the first one the sun meets (inside a shadow's edge).
import * as THREE from 'three';
import {
  CELL, coarseFragment, MAP_SIZE, NORMAL_FRAGMENT, NORMAL_VERTEX, PHONE_MAP_SIZE, visibilityFragment,
} from './sun.glsl.js';
import { FullscreenPass } from './passes.js';

export const LAYER = { virtual: 1, real: 2 }; // caster layers; the 'all' map sees both
const MIN_FIT_ELEVATION_SIN = Math.sin(3 * Math.PI / 180); // shadows of a lower sun are clipped
// Re-render when the sun moved 0.05 deg (a shadow edge 10 m from its caster moves 9 mm / sin
// of the sun's elevation: a fraction of its penumbra; the demo's clock at 20x moves the sun
// that far every 0.6 s).
const RERENDER_COS = Math.cos(0.05 * Math.PI / 180);

/** The defines every material with sunShadowChunk starts with: no sun until SunShadows.setSun
 * brings one (SunShadows.setMaterials). SUN_GROUND 1 marks a material drawn only on the flat
 * ground, which reads the ground's visibility map (sunVisibilityOnGround); 2 the same
 * prefiltered to each pixel's footprint (the frames' materials). */
export const SUN_DEFINES = { SUN: 0, SUN_GROUND: 0, SUN_MAP_SIZE: MAP_SIZE };

/** The maps' size in texels for a device profile: 1024 on a phone (a quarter of the bytes:
 * 24.3 MB instead of 97.3 for two maps and their normals; texels twice as wide, the penumbra's
 * 50 % point 2.0 cm off the oracle's instead of 0.7 cm, test_web_sun.py), 2048 elsewhere. */
export function mapSizeFor(profile) {
  return profile === 'phone' ? PHONE_MAP_SIZE : MAP_SIZE;
}

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
    sunVisibilityA: { value: null },
    sunVisibilityR: { value: null },
    sunGroundA: { value: null },
    sunGroundR: { value: null },
  };
}

/** One caster set's depth map, seen from the sun with an orthographic camera fitted to the
 * casters and to where their shadows can fall, its coarse map and its visibility map. */
class ShadowMap {
  /**
   * @param {number[]} layers the caster layers it sees
   * @param {number} groundY height of the flat ground (m)
   * @param {THREE.WebGLRenderTarget} normals the normals' colour target, shared by the maps
   *   (SunShadows): read only while this map is filtered, so one serves both; each map
   *   attaches its own depth texture to it before it is drawn (`attach`)
   */
  constructor(layers, groundY, normals) {
    this.normals = normals;
    const size = normals.width;
    this.size = size;
    const coarse = size / CELL;
    const depth = new THREE.DepthTexture(size, size, THREE.FloatType);
    depth.minFilter = depth.magFilter = THREE.NearestFilter;
    this.depth = depth;
    const coarseTarget = (w, h) => new THREE.WebGLRenderTarget(w, h, {
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, generateMipmaps: false, depthBuffer: false,
    });
    this.rows = coarseTarget(coarse, size); // reduced along x
    this.coarse = coarseTarget(coarse, coarse); // then along y
    this.reduce = [0, 1].map((pass) => new FullscreenPass({
      fragmentShader: coarseFragment(pass, size),
      uniforms: { source: { value: pass === 0 ? depth : this.rows.texture } },
    }));
    this.groundY = groundY;
    this.visibility = new THREE.WebGLRenderTarget(size, size, {
      type: THREE.UnsignedByteType, depthBuffer: false,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, generateMipmaps: false,
    });
    // Mipmapped: the distant ground reads a prefiltered level (fewer texels far apart to fetch).
    this.groundVisibility = new THREE.WebGLRenderTarget(size, size, {
      type: THREE.UnsignedByteType, format: THREE.RedFormat, depthBuffer: false,
      minFilter: THREE.LinearMipmapNearestFilter, magFilter: THREE.LinearFilter, generateMipmaps: true,
    });
    // World points of a texel (visibilityFragment), set by fit().
    this.axes = Object.fromEntries(['nearOrigin', 'axisU', 'axisV', 'axisDepth', 'groundOrigin',
      'groundAxisU', 'groundAxisV'].map((k) => [k, new THREE.Vector3()]));
    this.matrix = new THREE.Matrix4();
    this.info = new THREE.Vector4(1, 0, 1, 0);
    const uniforms = {
      depthMap: { value: depth }, normalMap: { value: normals.texture },
      coarseMap: { value: this.coarse.texture }, worldToMap: { value: this.matrix },
      mapInfo: { value: this.info },
      ...Object.fromEntries(Object.entries(this.axes).map(([k, v]) => [k, { value: v }])),
    };
    this.visibilityPass = new FullscreenPass({ fragmentShader: visibilityFragment('surface', size), uniforms });
    this.groundPass = new FullscreenPass({ fragmentShader: visibilityFragment('ground', size), uniforms });
    this.camera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0.1, 10);
    this.camera.layers.disableAll();
    for (const layer of layers) this.camera.layers.enable(layer);
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
    this.info.set(2 * half / this.size, cam.near, cam.far - cam.near, 1);
    this._fitAxes(toSun);
  }

  /** A texel's points are affine in its (u, v) in 0..1 (an orthographic view): on the near
   * plane, along the view by the depth map's 0..1, and on the ground plane. */
  _fitAxes(toSun) {
    const cam = this.camera;
    const near = (u, v) => new THREE.Vector3(cam.left + u * (cam.right - cam.left),
      cam.bottom + v * (cam.top - cam.bottom), -cam.near).applyMatrix4(cam.matrixWorld);
    const ground = (u, v) => {
      const w = near(u, v);
      return w.addScaledVector(toSun, -(w.y - this.groundY) / toSun.y);
    };
    const a = this.axes;
    a.nearOrigin.copy(near(0, 0));
    a.axisU.copy(near(1, 0)).sub(a.nearOrigin);
    a.axisV.copy(near(0, 1)).sub(a.nearOrigin);
    a.axisDepth.copy(toSun).multiplyScalar(-(cam.far - cam.near));
    a.groundOrigin.copy(ground(0, 0));
    a.groundAxisU.copy(ground(1, 0)).sub(a.groundOrigin);
    a.groundAxisV.copy(ground(0, 1)).sub(a.groundOrigin);
  }

  /** The coarse map, then the visibility map, from the depth and normals just rendered. */
  filter(renderer) {
    this.reduce[0].render(renderer, this.rows);
    this.reduce[1].render(renderer, this.coarse);
    this.visibilityPass.render(renderer, this.visibility);
    this.groundPass.render(renderer, this.groundVisibility);
  }

  /** The shared normals target, drawn with this map's depth (three.js attaches the depth
   * texture anew when it changed). */
  attach() {
    this.normals.depthTexture = this.depth;
    return this.normals;
  }

  dispose() {
    this.depth.dispose();
    this.rows.dispose();
    this.coarse.dispose();
    for (const pass of this.reduce) pass.dispose();
    this.visibility.dispose();
    this.visibilityPass.dispose();
    this.groundVisibility.dispose();
    this.groundPass.dispose();
  }
}

export class SunShadows {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {THREE.Scene} scene the scene holding the casters
   * @param {{virtual: THREE.Mesh[], real: THREE.Mesh[]}} casters
   * @param {object} uniforms from sunUniforms(), shared with the materials
   * @param {{groundY?: number, siteRoot?: THREE.Object3D}} [options] height of the flat ground
   *   (m), whose visibility the materials with SUN_GROUND 1 read; the object that places the
   *   site in the world (AR moves and turns it; a child of the scene): the maps are rendered in
   *   the site's own frame and the materials' uniforms follow the placement (follow()); the
   *   maps' size in texels (mapSizeFor)
   */
  constructor(renderer, scene, casters, uniforms, { groundY = 0, siteRoot = null, mapSize = MAP_SIZE } = {}) {
    this.mapSize = mapSize;
    this.renderer = renderer;
    this.scene = scene;
    this.uniforms = uniforms;
    this.siteRoot = siteRoot;
    this._placement = null; // the site's placement the uniforms were last set for
    this.maps = {};
    for (const [set, meshes] of Object.entries(casters)) for (const m of meshes) m.layers.enable(LAYER[set]);
    this.casterSets = { all: [...casters.virtual, ...casters.real], real: casters.real };
    this.boxes = this._boxes();
    // One normals target for every map: the maps are drawn and filtered one after the other,
    // and a frame reads only their depth, coarse and visibility maps (a 2048² RGBA8 saved).
    this.normals = new THREE.WebGLRenderTarget(mapSize, mapSize, {
      depthBuffer: true, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, generateMipmaps: false,
    });
    for (const set of Object.keys(this.boxes)) {
      this.maps[set] = new ShadowMap(set === 'all' ? [LAYER.virtual, LAYER.real] : [LAYER.real], groundY, this.normals);
    }
    this.on = null; // whether the materials are compiled with the sun (SUN 1)
    this.materials = []; // every material that draws the sun (setMaterials)
    this.depthPass = new THREE.ShaderMaterial({
      vertexShader: NORMAL_VERTEX, fragmentShader: NORMAL_FRAGMENT, side: THREE.DoubleSide,
      uniforms: { toSun: { value: new THREE.Vector3(0, 1, 0) } },
    });
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
    if (!this.direction || this.direction.dot(s) <= RERENDER_COS) {
      this.direction = s;
      this.render();
    }
    this._sunDirectionSite = s;
    this._placement = null;
    this.follow();
  }

  /**
   * Keep the materials' sun uniforms on the site where it is placed in the world (call before
   * each frame): the maps are in the site's frame, the materials read world positions and
   * normals, so their matrices are the maps' times site-from-world and the sun's direction
   * is turned by the placement. Costs nothing while the placement stays.
   */
  follow() {
    const u = this.uniforms;
    if (!this._sunDirectionSite) return;
    // one matrix kept for the check: no allocation per frame while the placement stays
    const worldFromSite = (this._worldFromSite ??= new THREE.Matrix4()).identity();
    if (this.siteRoot) {
      this.siteRoot.updateMatrix();
      worldFromSite.copy(this.siteRoot.matrix);
    }
    if (this._placement?.equals(worldFromSite)) return;
    this._placement = worldFromSite.clone();
    const siteFromWorld = worldFromSite.clone().invert();
    for (const [set, map] of Object.entries(this.maps)) {
      u[`sunMatrix${set === 'all' ? 'A' : 'R'}`].value.multiplyMatrices(map.matrix, siteFromWorld);
    }
    u.sunDirection.value.copy(this._sunDirectionSite).transformDirection(worldFromSite);
  }

  /** Each caster set's bounding box (world), for the sets that hold any mesh. */
  _boxes() {
    const boxes = {};
    for (const [set, meshes] of Object.entries(this.casterSets)) {
      const box = new THREE.Box3();
      for (const m of meshes) box.expandByObject(m);
      if (!box.isEmpty()) boxes[set] = box;
    }
    return boxes;
  }

  /** The materials that draw the sun: compiled with SUN 0 while there is none (night, a
   * cloud over it), so that they cost nothing then. */
  setMaterials(materials) {
    this.materials = materials;
    for (const m of materials) m.defines = { ...m.defines, SUN_MAP_SIZE: this.mapSize };
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
    const saved = { target: renderer.getRenderTarget(), override: scene.overrideMaterial, auto: scene.matrixWorldAutoUpdate, xr: renderer.xr.enabled };
    // The maps are drawn in the site's own frame: the site put back at the origin meanwhile,
    // and with the renderer's XR off (while a session presents, three.js draws every render
    // with the XR camera, not the sun's).
    const root = this.siteRoot;
    const placed = root && { p: root.position.clone(), q: root.quaternion.clone(), s: root.scale.clone() };
    if (placed) {
      root.position.set(0, 0, 0);
      root.quaternion.identity();
      root.scale.set(1, 1, 1);
      root.updateMatrixWorld(true);
      for (const [set, box] of Object.entries(this._boxes())) this.boxes[set] = box;
    }
    renderer.xr.enabled = false;
    scene.overrideMaterial = this.depthPass;
    this.depthPass.uniforms.toSun.value.copy(this.direction);
    for (const [set, map] of Object.entries(this.maps)) {
      map.fit(this.boxes[set], this.direction);
      renderer.setRenderTarget(map.attach());
      renderer.clear(true, true, false);
      renderer.render(scene, map.camera);
      map.filter(renderer);
      const key = set === 'all' ? 'A' : 'R';
      uniforms[`sunMap${key}`].value = map.depth;
      uniforms[`sunCoarse${key}`].value = map.coarse.texture;
      uniforms[`sunVisibility${key}`].value = map.visibility.texture;
      uniforms[`sunGround${key}`].value = map.groundVisibility.texture;
      uniforms[`sunMatrix${key}`].value.copy(map.matrix);
      uniforms[`sunInfo${key}`].value.copy(map.info);
    }
    scene.overrideMaterial = saved.override;
    renderer.setRenderTarget(saved.target);
    renderer.xr.enabled = saved.xr;
    if (placed) {
      root.position.copy(placed.p);
      root.quaternion.copy(placed.q);
      root.scale.copy(placed.s);
      root.updateMatrixWorld(true);
    }
    this._placement = null; // the materials' matrices: follow() sets them for the placement
    this.renders += 1;
  }

  /** Bytes of GPU memory the maps hold: per map its depth (float32), coarse maps (RGBA8), the
   * surfaces' visibility map (RGBA8) and the ground's (R8 with its mipmaps, a third more);
   * and one RGBA8 normals target they share. */
  get gpuBytes() {
    const size = this.mapSize;
    const texels = size * size;
    const coarse = size / CELL;
    const perMap = texels * (4 + 4) + Math.round(texels * 4 / 3) + (coarse * size + coarse * coarse) * 4;
    return Object.keys(this.maps).length * perMap + texels * 4;
  }

  dispose() {
    for (const map of Object.values(this.maps)) map.dispose();
    this.normals.dispose();
    this.depthPass.dispose();
  }
}
