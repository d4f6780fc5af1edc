// The sun at the kiosk (docs/sun.md, issue 15 item 6): the fixed view's O' and S' get the
// sun's direct term, per view pixel, from the same shadow maps and penumbra filter as every
// other surface (sun.js). The site model is drawn once from the view's own calibrated camera
// (K and pose of the manifest's view, OpenCV convention, one fragment per pixel centre as the
// bake's rays) into two targets:
//   O_sun = albedo / pi max(0, n . s) V     (every caster: V past the virtual and real ones)
//   S_sun = albedo / pi max(0, n . s) V_r   (the virtual objects left out: the real proxies
//                                            and the ground alone, as the bake's S)
// per unit normal irradiance, so that the kiosk adds E_sun O_sun to O' and E_sun S_sun to S'
// (kiosk.glsl.js) and Eq. 9 then does the rest: on real pixels the ratio becomes
// (O_sky + E_sun cos V) / (S_sky + E_sun cos V_r), Jensen's rule. Pixels that look below the
// horizon past the model see the open ground (y = the ground's height, normal +Y), as the
// bake's open-ground pixels. The targets follow the sun (rendered with the shadow maps, when
// it moved), never the frames or the sun's irradiance (a uniform).
import * as THREE from 'three';
import { plainVertex as viewVertex, sunCommon } from './materials.glsl.js';
import { RGBE_ENCODE } from './relight.glsl.js';
import { worldFromPixel } from './relight.js';
import { findDaylit, meshAlbedo } from './site.js';
import { LAYER, SUN_DEFINES, SunShadows, sunUniforms } from './sun.js';

const GROUND_LAYER = 3; // the site's ground in the view pass (not a caster)
const NEAR_M = 0.05;

const viewFragment = (encodeRGBE) => /* glsl */ `
uniform vec3 albedo;
uniform vec3 viewOrigin;
uniform float realOnly; // 1: V past the real proxies alone (S), 0: past every caster (O)
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunCommon}
${encodeRGBE ? RGBE_ENCODE : ''}
void main() {
  // The side facing the view, as the bake's view rays see it (the flipped projection turns
  // the winding, so not gl_FrontFacing).
  vec3 n = normalize(vNormalW);
  if (dot(n, vPositionW - viewOrigin) > 0.0) n = -n;
  float v = realOnly > 0.5 ? sunVisibilityReal(vPositionW, n) : sunVisibilityAll(vPositionW, n);
  vec3 e = albedo / 3.14159265 * max(dot(n, sunDirection), 0.0) * v;
  gl_FragColor = ${encodeRGBE ? 'encodeRGBE(e)' : 'vec4(e, 1.0)'};
}
`;

// The open ground beyond the model: every pixel whose ray goes down meets y = groundY.
const openVertex = /* glsl */ `
varying vec3 vNormalW; // sunCommon's facingNormal names it
void main() {
  vNormalW = vec3(0.0, 1.0, 0.0);
  gl_Position = vec4(position.xy, 0.0, 1.0);
}
`;

const openFragment = (encodeRGBE) => /* glsl */ `
uniform vec3 albedo;
uniform vec3 viewOrigin;
uniform mat3 worldFromPixel; // R K^-1: pixel (u, v, 1), v from the top, to a world ray
uniform float groundY;
uniform float realOnly;
varying vec3 vNormalW; // unused here
${sunCommon}
${encodeRGBE ? RGBE_ENCODE : ''}
void main() {
  // The target's rows are the view's rows from the top (the projection below flips y), so
  // gl_FragCoord is the pixel centre (u, v) the bake's ray goes through.
  vec3 dir = worldFromPixel * vec3(gl_FragCoord.xy, 1.0);
  vec3 e = vec3(0.0);
  if (dir.y < 0.0) {
    vec3 p = viewOrigin + dir * ((groundY - viewOrigin.y) / dir.y);
    vec3 n = vec3(0.0, 1.0, 0.0);
    float v = realOnly > 0.5 ? sunVisibilityReal(p, n) : sunVisibilityAll(p, n);
    e = albedo / 3.14159265 * max(sunDirection.y, 0.0) * v;
  }
  gl_FragColor = ${encodeRGBE ? 'encodeRGBE(e)' : 'vec4(e, 1.0)'};
}
`;

/** A projection of OpenCV camera coordinates (+X right, +Y down, +Z forward) to clip space
 * whose NDC y runs down the image: image row 0 lands on the target's row 0, as the relight
 * targets store a view (rows from the top). */
function opencvProjection(view, far) {
  const [[fx, s, cx], [, fy, cy]] = view.K;
  const { width: W, height: H } = view;
  const n = NEAR_M;
  return new THREE.Matrix4().set(
    2 * fx / W, 2 * s / W, 2 * cx / W - 1, 0,
    0, 2 * fy / H, 2 * cy / H - 1, 0,
    0, 0, (far + n) / (far - n), -2 * far * n / (far - n),
    0, 0, 1, 0,
  );
}

export class KioskSun {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {object} gltf the site model (site.glb)
   * @param {object} manifest
   * @param {object} view the manifest's view
   * @param {{type: number, rgbe: boolean}} format the relight targets' format
   */
  constructor(renderer, gltf, manifest, view, format) {
    this.renderer = renderer;
    this.view = view;
    this.format = format;
    this.root = gltf.scene;
    this.scene = new THREE.Scene();
    this.scene.add(this.root);
    this.uniforms = sunUniforms();
    this.realOnly = { value: 0 };
    const W = view.world_from_camera;
    const cameraToWorld = new THREE.Matrix4().set(...W.flat());
    const origin = new THREE.Vector3().setFromMatrixPosition(cameraToWorld);
    const shared = { ...this.uniforms, realOnly: this.realOnly, viewOrigin: { value: origin } };
    const casters = { virtual: [], real: [] };
    this.materials = [];
    const meshes = [];
    this.root.traverse((o) => { if (o.isMesh) meshes.push(o); });
    this.root.updateMatrixWorld(true);
    const box = new THREE.Box3();
    let groundY = 0;
    for (const mesh of meshes) {
      const role = findDaylit(mesh)?.role;
      mesh.frustumCulled = false;
      if (role !== 'virtual' && role !== 'real' && role !== 'ground') {
        mesh.visible = false; // shadowing planes: not surfaces of the view
        continue;
      }
      mesh.material = this._material(viewVertex, viewFragment(format.rgbe), { ...shared, albedo: { value: meshAlbedo(mesh) } },
        role === 'ground');
      mesh.material.side = THREE.DoubleSide;
      box.expandByObject(mesh);
      if (role === 'ground') {
        mesh.layers.set(GROUND_LAYER);
        groundY = new THREE.Box3().setFromObject(mesh).max.y;
      } else {
        casters[role].push(mesh);
      }
    }
    // The open ground: a full-screen triangle drawn first, under the model.
    const open = new THREE.BufferGeometry();
    open.setAttribute('position', new THREE.Float32BufferAttribute([-1, -1, 0, 3, -1, 0, -1, 3, 0], 3));
    const openMaterial = this._material(openVertex, openFragment(format.rgbe), {
      ...shared,
      albedo: { value: new THREE.Vector3(...manifest.ground.albedo) },
      worldFromPixel: { value: worldFromPixel(view) },
      groundY: { value: groundY },
    }, true);
    openMaterial.depthTest = false;
    openMaterial.depthWrite = false;
    this.openMesh = new THREE.Mesh(open, openMaterial);
    this.openMesh.frustumCulled = false;
    this.openMesh.renderOrder = -1;
    this.openMesh.layers.set(GROUND_LAYER);
    this.scene.add(this.openMesh);
    // The view's camera: pose and intrinsics of the manifest, set once.
    this.camera = new THREE.Camera();
    this.camera.matrixAutoUpdate = false;
    this.camera.matrixWorldAutoUpdate = false;
    this.camera.matrixWorld.copy(cameraToWorld);
    this.camera.matrixWorldInverse.copy(cameraToWorld).invert();
    const far = Math.max(100, 2 * (box.isEmpty() ? 0 : box.distanceToPoint(origin) + box.getSize(new THREE.Vector3()).length()));
    this.camera.projectionMatrix.copy(opencvProjection(view, far));
    this.camera.projectionMatrixInverse.copy(this.camera.projectionMatrix).invert();
    const target = () => {
      const t = new THREE.WebGLRenderTarget(view.width, view.height, {
        type: format.type, format: THREE.RGBAFormat, depthBuffer: true, stencilBuffer: false,
        minFilter: format.rgbe ? THREE.NearestFilter : THREE.LinearFilter,
        magFilter: format.rgbe ? THREE.NearestFilter : THREE.LinearFilter, generateMipmaps: false,
      });
      t.texture.colorSpace = THREE.NoColorSpace;
      return t;
    };
    this.targets = { O: target(), S: target() };
    this.shadows = new SunShadows(renderer, this.scene, casters, this.uniforms, { groundY });
    this.shadows.setMaterials(this.materials);
    this.on = false; // a sun is drawn
    this.renders = 0; // view passes rendered (they follow the sun, not the frames)
    this._mapsRendered = -1;
  }

  /** A view-pass material; `ground` for the flat ground, which reads the sun's ground
   * visibility map at full resolution (SUN_GROUND 1: the value at each pixel's centre ray, as
   * the bake's views are; the visit's frames read it prefiltered, SUN_GROUND 2). */
  _material(vertexShader, fragmentShader, uniforms, ground = false) {
    const m = new THREE.ShaderMaterial({
      uniforms, vertexShader, fragmentShader, defines: { ...SUN_DEFINES, SUN_GROUND: ground ? 1 : 0 },
    });
    this.materials.push(m);
    return m;
  }

  /**
   * The applied sun ({direction, normalIrradiance} or null: none, night, a version-1 server).
   * Returns whether a sun is drawn; renders the view's sun targets when the maps moved.
   */
  setSun(sun) {
    this.shadows.setSun(sun?.direction ?? [0, 0, 0], sun?.normalIrradiance ?? [0, 0, 0]);
    this.on = !!this.shadows.on;
    if (this.on && this.shadows.renders !== this._mapsRendered) {
      this._mapsRendered = this.shadows.renders;
      this.render();
    }
    return this.on;
  }

  /** The sun's normal irradiance (RGB W/m^2) to multiply the targets by (0 when none). */
  get irradiance() {
    return this.uniforms.sunIrradiance.value;
  }

  render() {
    const { renderer, camera } = this;
    const saved = { target: renderer.getRenderTarget(), autoClear: renderer.autoClear };
    const clear = renderer.getClearColor(new THREE.Color());
    const alpha = renderer.getClearAlpha();
    renderer.setClearColor(0x000000, 0);
    renderer.autoClear = false;
    for (const [key, layers] of [['O', [LAYER.virtual, LAYER.real, GROUND_LAYER]], ['S', [LAYER.real, GROUND_LAYER]]]) {
      this.realOnly.value = key === 'S' ? 1 : 0;
      camera.layers.disableAll();
      for (const l of layers) camera.layers.enable(l);
      renderer.setRenderTarget(this.targets[key]);
      renderer.clear(true, true, false);
      renderer.render(this.scene, camera);
    }
    renderer.setClearColor(clear, alpha);
    renderer.autoClear = saved.autoClear;
    renderer.setRenderTarget(saved.target);
    this.renders += 1;
  }

  dispose() {
    this.shadows.dispose();
    for (const t of Object.values(this.targets)) t.dispose();
    for (const m of this.materials) m.dispose();
    this.openMesh.geometry.dispose();
    this.root.traverse((o) => { if (o.isMesh) o.geometry.dispose(); });
  }
}
