// The site model (site.glb) with daylit's materials, node by node after extras.daylit.role:
//   virtual          lightmapped (albedo / pi x E), or in hull-plane mode shaded from the
//                    light vector's spherical harmonics and darkened by its hull planes
//   real             depth-only occluders over a camera view; lightmapped in the virtual visit
//   ground           the open ground, lit by the open sky (virtual visit only)
//   shadowing-plane  ground/wall planes: alpha = 1 - ratio over the camera view (plus an
//                    additive draw where ratio > 1); in the visit the synthesized real
//                    surface albedo / pi x (D - X). Hull planes: only in hull-plane mode.
import * as THREE from 'three';
import {
  lightmapFragment, openGroundFragment, plainVertex, receiverFragment, sh9Fragment,
  shadowPlaneFragment, skyFragment, skyVertex, uvVertex,
} from './materials.glsl.js';
import { RATIO_FLOOR_SCENE } from './display.glsl.js';
import { FLOAT_DECODE, RGBE_DECODE } from './relight.glsl.js';
import { SUN_DEFINES, sunUniforms } from './sun.js';

export class Site {
  /**
   * @param {object} gltf from GLTFLoader
   * @param {object} manifest
   * @param {import('./relight.js').Relighter} relighter
   * @param {import('./irradiance.js').IrradianceTargets} irradiance what the surfaces read:
   *   the relit sky plus the sun's bounce, per atlas
   */
  constructor(gltf, manifest, relighter, irradiance) {
    this.root = gltf.scene;
    this.manifest = manifest;
    this.relighter = relighter;
    const decode = relighter.format.rgbe ? RGBE_DECODE : FLOAT_DECODE;
    const t = relighter.targets;
    // Shared uniforms: one update reaches every material.
    this.shared = {
      exposure: { value: 1 },
      shading: { value: 1 },
      strength: { value: 1 },
      flatIrradiance: { value: new THREE.Vector3(1, 1, 1) },
      openIrradiance: { value: new THREE.Vector3(1, 1, 1) },
      L: { value: Array.from({ length: 9 }, () => new THREE.Vector3()) },
      linearOut: { value: 0 }, // 1: drawn into the linear HDR frame (hdr.js; setLinearFrame)
      ratioFloor: { value: 1e-6 }, // the shadow ratios' scene floor, W/m^2 (display.glsl.js)
    };
    // The sun (sun.js): direction, irradiance and shadow maps, shared by every material.
    this.sun = sunUniforms();
    this.irradiance = irradiance;
    this.nodes = { virtual: [], real: [], ground: [], plane: [], hull: [], brighten: [] };
    this.groundAlbedo = new THREE.Vector3(...manifest.ground.albedo);
    const meshes = [];
    this.root.traverse((o) => { if (o.isMesh) meshes.push(o); });
    // The flat ground's height: its materials read the sun's ground maps (sun.js).
    this.root.updateMatrixWorld(true);
    const open = meshes.find((m) => findDaylit(m)?.role === 'ground');
    this.groundY = open ? new THREE.Box3().setFromObject(open).max.y : 0;
    // The flat ground reads its visibility prefiltered to the pixel (sun.js).
    const sunDefines = (mesh) => ({ ...SUN_DEFINES, SUN_GROUND: isFlatGround(mesh, this.groundY) ? 2 : 0 });
    for (const mesh of meshes) {
      const info = findDaylit(mesh);
      if (!info) continue;
      const albedo = meshAlbedo(mesh);
      mesh.userData.daylit = info;
      mesh.userData.albedo = albedo;
      if (info.role === 'virtual' || info.role === 'real') {
        mesh.userData.lightmapMaterial = this._lightmap(albedo, decode, irradiance.texture(`${info.atlas}.lit`));
        if (info.role === 'virtual') {
          mesh.userData.sh9Material = this._sh9(albedo);
          this.nodes.virtual.push(mesh);
        } else {
          mesh.userData.depthMaterial = new THREE.MeshBasicMaterial({ colorWrite: false });
          this.nodes.real.push(mesh);
        }
      } else if (info.role === 'ground') {
        mesh.userData.visitMaterial = new THREE.ShaderMaterial({
          uniforms: { ...this.sun, exposure: this.shared.exposure, albedo: { value: albedo }, openIrradiance: this.shared.openIrradiance },
          vertexShader: plainVertex, fragmentShader: openGroundFragment, defines: { ...SUN_DEFINES, SUN_GROUND: 2 },
          polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 4,
        });
        // After the ground and wall planes (2), which cover most of it: the depth test then
        // skips its pixels under them instead of shading them twice.
        mesh.renderOrder = 4;
        this.nodes.ground.push(mesh);
      } else if (info.role === 'shadowing-plane') {
        const withTex = irradiance.texture(`${info.atlas}.with`);
        const withoutTex = irradiance.texture(`${info.atlas}.without`);
        if (!withTex || !withoutTex) continue;
        const dHasReal = info.atlas === 'hull' ? 0 : 1; // hull d: nothing; ground d: real proxies
        const e = { withTex, withoutTex, dHasReal, defines: sunDefines(mesh) };
        mesh.userData.shadowMaterial = this._shadow(decode, e);
        mesh.userData.shadowAlphaMaterial = this._shadow(decode, { ...e, alphaOut: 1 });
        const bright = new THREE.Mesh(mesh.geometry, this._shadow(decode, { ...e, brighten: 1 }));
        bright.renderOrder = 3;
        mesh.add(bright);
        mesh.userData.brightMesh = bright;
        this.nodes.brighten.push(bright);
        mesh.renderOrder = 2;
        if (info.atlas === 'hull') {
          this.nodes.hull.push(mesh);
        } else {
          mesh.userData.receiverMaterial = new THREE.ShaderMaterial({
            uniforms: {
              ...this.sun, exposure: this.shared.exposure, albedo: { value: this._receiverAlbedo(info) },
              irradianceTex: { value: withTex },
            },
            vertexShader: uvVertex, fragmentShader: receiverFragment(decode), side: THREE.DoubleSide,
            defines: { ...e.defines, VIRTUAL_SHADOWS: 1 },
          });
          // The A/B switch: with or without the virtual objects (setShading).
          mesh.userData.receiverIrradiance = { with: withTex, without: withoutTex };
          this.nodes.plane.push(mesh);
        }
      }
    }
    this.sky = this._skyDome(decode, t.dome?.texture);
    this.setMode('visit', 'lightmap');
  }

  _receiverAlbedo(info) {
    if (!info.object) return this.groundAlbedo;
    const real = this.nodes.real.find((m) => m.userData.daylit.object === info.object);
    return real ? real.userData.albedo : this.groundAlbedo;
  }

  _lightmap(albedo, decode, texture) {
    return new THREE.ShaderMaterial({
      uniforms: {
        ...this.sun, exposure: this.shared.exposure, shading: this.shared.shading,
        flatIrradiance: this.shared.flatIrradiance, albedo: { value: albedo },
        irradianceTex: { value: texture },
      },
      vertexShader: uvVertex, fragmentShader: lightmapFragment(decode),
      side: THREE.DoubleSide, defines: { ...SUN_DEFINES },
    });
  }

  _sh9(albedo) {
    return new THREE.ShaderMaterial({
      uniforms: {
        ...this.sun, exposure: this.shared.exposure, shading: this.shared.shading,
        flatIrradiance: this.shared.flatIrradiance, albedo: { value: albedo }, L: this.shared.L,
        groundAlbedo: { value: this.groundAlbedo },
      },
      vertexShader: plainVertex, fragmentShader: sh9Fragment, side: THREE.DoubleSide,
      defines: { ...SUN_DEFINES },
    });
  }

  /**
   * A shadowing plane's material: the darkening draw multiplies the picture by the ratio per
   * channel (alphaOut: black with alpha, for a transparent frame over a passthrough), the
   * brightening draw adds the excess where the ratio is above 1.
   */
  _shadow(decode, { withTex, withoutTex, dHasReal, defines, brighten = 0, alphaOut = 0 }) {
    const blend = brighten ? { blendSrc: THREE.DstColorFactor, blendDst: THREE.OneFactor }
      : alphaOut ? { blendSrc: THREE.SrcAlphaFactor, blendDst: THREE.OneMinusSrcAlphaFactor }
        : { blendSrc: THREE.DstColorFactor, blendDst: THREE.ZeroFactor };
    return new THREE.ShaderMaterial({
      uniforms: {
        ...this.sun, withTex: { value: withTex }, withoutTex: { value: withoutTex }, strength: this.shared.strength,
        brighten: { value: brighten }, alphaOut: { value: alphaOut }, dHasReal: { value: dHasReal },
        linearOut: alphaOut ? { value: 0 } : this.shared.linearOut, ratioFloor: this.shared.ratioFloor,
      },
      vertexShader: uvVertex, fragmentShader: shadowPlaneFragment(decode), defines: { ...defines },
      // A hull plane holds the light on its outer side only, and a ray from outside enters a
      // hull once, through a front face: its back faces would multiply what lies behind a
      // second time, and a bottom face buried in what the object stands on (the hall's walls
      // and columns in its podium: ratio 0) pulled over the floor by the polygon offset drew
      // that floor black. Ground and wall planes are seen from either side.
      transparent: true, depthWrite: false, side: dHasReal ? THREE.DoubleSide : THREE.FrontSide,
      blending: THREE.CustomBlending, blendEquation: THREE.AddEquation, ...blend,
      blendSrcAlpha: THREE.ZeroFactor, blendDstAlpha: THREE.OneFactor,
      polygonOffset: true, polygonOffsetFactor: -1, polygonOffsetUnits: -4,
    });
  }

  _skyDome(decode, texture) {
    if (!texture) return null;
    const sky = new THREE.Mesh(new THREE.SphereGeometry(1, 48, 24), new THREE.ShaderMaterial({
      uniforms: {
        exposure: this.shared.exposure, skyTex: { value: texture }, horizon: { value: new THREE.Vector3() },
        sunDirection: this.sun.sunDirection, sunIrradiance: this.sun.sunIrradiance,
      },
      vertexShader: skyVertex, fragmentShader: skyFragment(decode), side: THREE.BackSide, depthWrite: false,
    }));
    sky.frustumCulled = false;
    sky.renderOrder = -1;
    return sky;
  }

  /**
   * @param {'visit'|'overlay'|'passthrough'} view  visit: the synthesized site; overlay: over a
   *   camera picture drawn into the frame; passthrough: over AR's passthrough (a transparent
   *   frame: shadows as black with alpha)
   * @param {'lightmap'|'hull'} shading the virtual objects' shading (Kakuta's two options)
   */
  setMode(view, shading) {
    this.view = view;
    this.shadingMode = shading;
    const shadowMaterial = (m) => (view === 'passthrough' ? m.userData.shadowAlphaMaterial : m.userData.shadowMaterial);
    const visit = view === 'visit';
    for (const m of this.nodes.virtual) {
      m.material = shading === 'hull' ? m.userData.sh9Material : m.userData.lightmapMaterial;
    }
    for (const m of this.nodes.real) m.material = visit ? m.userData.lightmapMaterial : m.userData.depthMaterial;
    for (const m of this.nodes.ground) {
      m.visible = visit;
      m.material = m.userData.visitMaterial;
    }
    for (const m of this.nodes.plane) {
      const wall = m.userData.daylit.object !== undefined;
      // In the visit the lightmap already carries the walls' shadows; the ground plane becomes
      // the synthesized real surface.
      m.visible = !(visit && wall);
      m.material = visit ? m.userData.receiverMaterial : shadowMaterial(m);
    }
    for (const m of this.nodes.hull) {
      m.visible = shading === 'hull';
      m.material = shadowMaterial(m);
    }
    this._showBrightening();
    if (this.sky) this.sky.visible = visit;
  }

  /**
   * Whether the frame is drawn in linear HDR (hdr.js): the shadowing planes then multiply by
   * their ratio there, ratio > 1 included, and the additive brightening draws are hidden.
   */
  setLinearFrame(on) {
    this.shared.linearOut.value = on ? 1 : 0;
    this._showBrightening();
  }

  _showBrightening() {
    const direct = this.shared.linearOut.value < 0.5;
    for (const m of this.nodes.plane) m.userData.brightMesh.visible = direct && this.view !== 'visit';
    for (const m of this.nodes.hull) m.userData.brightMesh.visible = direct;
  }

  /** New light: the uniforms that come from r directly (SH9, open sky). The sun's come from
   * SunShadows.setSun. groundIrradiance: the open ground's, sun included (W/m^2, RGB), the
   * scale of the shadow ratios' floor. */
  setLight({ L, openIrradiance, flatIrradiance, groundIrradiance = openIrradiance }) {
    const level = (groundIrradiance[0] + groundIrradiance[1] + groundIrradiance[2]) / 3;
    this.shared.ratioFloor.value = Math.max(RATIO_FLOOR_SCENE * level, 1e-9);
    this.shared.L.value.forEach((v, j) => v.set(L[3 * j], L[3 * j + 1], L[3 * j + 2]));
    this.shared.openIrradiance.value.set(...openIrradiance);
    this.shared.flatIrradiance.value.set(...flatIrradiance);
    if (this.sky) {
      // Below the horizon the dome shows the open ground past the site's ground mesh as it
      // looks in the sun (Lambertian: albedo E / pi); without the sun it drew a dark band
      // between the mesh's edge and the horizon on a sunny day.
      const h = groundIrradiance.map((e) => e / Math.PI);
      this.sky.material.uniforms.horizon.value.set(...h.map((v, c) => v * this.groundAlbedo.getComponent(c)));
    }
  }

  /** The A/B switch of the Asuka-Kyo study: shading and shadows of the virtual objects. */
  setShading(on) {
    this.shared.shading.value = on ? 1 : 0;
    this.shared.strength.value = on ? 1 : 0;
    for (const m of this.nodes.plane) {
      const material = m.userData.receiverMaterial;
      if (!material) continue;
      const e = m.userData.receiverIrradiance;
      material.uniforms.irradianceTex.value = on ? e.with : e.without;
      if (material.defines.VIRTUAL_SHADOWS === (on ? 1 : 0)) continue;
      material.defines = { ...material.defines, VIRTUAL_SHADOWS: on ? 1 : 0 };
      material.needsUpdate = true;
    }
  }

  /** Every material that draws the sun (sun.js compiles them with or without it). */
  sunMaterials() {
    const out = new Set();
    this.root.traverse((o) => {
      for (const key of ['lightmapMaterial', 'sh9Material', 'visitMaterial', 'receiverMaterial', 'shadowMaterial', 'shadowAlphaMaterial']) {
        if (o.userData[key]) out.add(o.userData[key]);
      }
      if (o.userData.brightMesh) out.add(o.userData.brightMesh.material);
    });
    return [...out];
  }

  /** Centre and size of the virtual objects (for cameras). */
  bounds() {
    const box = new THREE.Box3();
    for (const m of this.nodes.virtual) box.expandByObject(m);
    return box;
  }
}

/** Whether a mesh lies flat on the ground plane y = groundY (within a millimetre). */
function isFlatGround(mesh, groundY) {
  const box = new THREE.Box3().setFromObject(mesh);
  return Math.abs(box.min.y - groundY) < 1e-3 && Math.abs(box.max.y - groundY) < 1e-3;
}

/** A site.glb mesh's albedo: its material's colour (linear RGB), 0.5 grey without one. */
export function meshAlbedo(mesh) {
  const c = mesh.material?.color;
  return c ? new THREE.Vector3(c.r, c.g, c.b) : new THREE.Vector3(0.5, 0.5, 0.5);
}

/** A site.glb node's `extras.daylit` (role, atlas, object), from it or the nearest ancestor
 * that has one; null for none. */
export function findDaylit(object) {
  for (let o = object; o; o = o.parent) {
    const d = o.userData?.daylit;
    if (d) return d;
  }
  return null;
}
