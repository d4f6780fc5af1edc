// GPU passes over every texel: render targets in the relight targets' format (half float, or
// RGBE in RGBA8 where the GPU cannot render to half floats) and a full-screen triangle drawn
// with one shader. Used by the relight pass (relight.js) and by everything that renders into
// a target the same way: the sun (sun.js), its bounce (sunbounce.js), the irradiance targets
// (irradiance.js) and the kiosk (kiosk.js).
import * as THREE from 'three';
import { relightVertex } from './relight.glsl.js';

/** Render-target format: half float where the GPU can render to it, else (or with `rgbe`, a
 * test's stand-in for such a GPU) signed RGBE in RGBA8 (relight.glsl.js). */
export function targetFormat(renderer, rgbe = false) {
  const ext = renderer.extensions;
  const halfFloat = !rgbe && (ext.has('EXT_color_buffer_float') || ext.has('EXT_color_buffer_half_float'));
  return { type: halfFloat ? THREE.HalfFloatType : THREE.UnsignedByteType, rgbe: !halfFloat };
}

export function makeTarget(width, height, format) {
  const target = new THREE.WebGLRenderTarget(width, height, {
    type: format.type,
    format: THREE.RGBAFormat,
    // RGBE cannot be interpolated; half floats can.
    minFilter: format.rgbe ? THREE.NearestFilter : THREE.LinearFilter,
    magFilter: format.rgbe ? THREE.NearestFilter : THREE.LinearFilter,
    depthBuffer: false,
    stencilBuffer: false,
    generateMipmaps: false,
  });
  target.texture.colorSpace = THREE.NoColorSpace;
  return target;
}

/**
 * A full-screen triangle drawn with one GLSL 3 shader: the GPU's way to visit every texel.
 * @param {{fragmentShader: string, uniforms: object, vertexShader?: string}} shaders
 *   (the vertex shader defaults to the relight pass's)
 */
export class FullscreenPass {
  constructor({ fragmentShader, uniforms, vertexShader = relightVertex }) {
    const material = new THREE.RawShaderMaterial({
      glslVersion: THREE.GLSL3, uniforms, vertexShader, fragmentShader, depthTest: false, depthWrite: false,
    });
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.Float32BufferAttribute([-1, -1, 0, 3, -1, 0, -1, 3, 0], 3));
    this.mesh = new THREE.Mesh(geometry, material);
    this.mesh.frustumCulled = false;
    this.scene = new THREE.Scene();
    this.scene.add(this.mesh);
    this.camera = new THREE.Camera();
  }

  render(renderer, target) {
    renderer.setRenderTarget(target);
    renderer.render(this.scene, this.camera);
    renderer.setRenderTarget(null);
  }

  dispose() {
    this.mesh.geometry.dispose();
    this.mesh.material.dispose();
  }
}
