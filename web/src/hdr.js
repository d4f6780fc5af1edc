// The frame in linear HDR (docs/web.md, "How the picture is displayed"): the scene is drawn into
// a half-float target as linear radiance times the exposure, the shadowing planes multiply it
// there per channel by their ratio (blending DstColor, Zero: exact in linear light, ratio > 1
// kept), and one pass maps it to the screen: Khronos PBR Neutral and sRGB in the visit; sRGB
// alone over a camera picture, whose colours are already the camera's own display-referred
// ones (the shadows darken its linear values; the virtual objects are drawn at its exposure).
import * as THREE from 'three';
import { FullScreenQuad } from 'three/addons/postprocessing/Pass.js';
import { NEUTRAL_TONE_MAP } from './display.glsl.js';

const displayFragment = /* glsl */ `
uniform sampler2D frame;
uniform float toneMap; // 1: Neutral, then sRGB; 0: sRGB only
varying vec2 vUv;
${NEUTRAL_TONE_MAP}
vec3 srgbEncode(vec3 c) {
  c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}
void main() {
  vec3 c = texture2D(frame, vUv).rgb;
  gl_FragColor = vec4(srgbEncode(toneMap > 0.5 ? neutralToneMap(c) : c), 1.0);
}
`;

const displayVertex = /* glsl */ `
varying vec2 vUv;
void main() {
  vUv = uv;
  gl_Position = vec4(position.xy, 0.0, 1.0);
}
`;

export class HdrFrame {
  /** Whether the GPU can render (and blend) into half-float targets: else the frame is drawn
   * straight to the screen as before (docs/web.md, Known limits). */
  static supported(renderer) {
    const ext = renderer.extensions;
    return ext.has('EXT_color_buffer_float') || ext.has('EXT_color_buffer_half_float');
  }

  /** The same question before the renderer exists (its canvas's antialias depends on the
   * answer), asked of a throwaway 1 x 1 WebGL2 context. */
  static probe() {
    const gl = document.createElement('canvas').getContext('webgl2');
    if (!gl) return false;
    const names = gl.getSupportedExtensions() ?? [];
    gl.getExtension('WEBGL_lose_context')?.loseContext();
    return names.includes('EXT_color_buffer_float') || names.includes('EXT_color_buffer_half_float');
  }

  /** MSAA samples of the linear frame, as the canvas's own antialias: 4, but none on a
   * software GPU (SwiftShader, llvmpipe), where 4x MSAA made a frame 1.7-3.2 times slower
   * (docs/benchmarks.md), none at the kiosk (its passes are full-screen quads), and none on a
   * phone (profile 'phone'): 4 samples of RGBA16F colour and depth at its 780 x 1688 are 63 MB,
   * 40 % of the 150 MB budget, where each drawn pixel is half a CSS pixel (docs/web.md, "GPU
   * memory"). */
  static defaultSamples(renderer, kiosk = false, profile = 'desktop') {
    if (kiosk || profile === 'phone') return 0;
    const gl = renderer.getContext();
    const info = gl.getExtension('WEBGL_debug_renderer_info');
    const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    return /swiftshader|llvmpipe|software/i.test(name) ? 0 : 4;
  }

  constructor(renderer, { samples = 4 } = {}) {
    this.renderer = renderer;
    this.target = new THREE.WebGLRenderTarget(1, 1, {
      type: THREE.HalfFloatType, format: THREE.RGBAFormat, samples,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: true,
    });
    this.material = new THREE.ShaderMaterial({
      uniforms: { frame: { value: this.target.texture }, toneMap: { value: 1 } },
      vertexShader: displayVertex, fragmentShader: displayFragment,
      depthTest: false, depthWrite: false, toneMapped: false,
    });
    this.quad = new FullScreenQuad(this.material);
  }

  /**
   * Draw `scene` from `camera` in linear HDR, then to the screen.
   * @param {boolean} toneMap Neutral tone mapping (the visit) or none (over a camera picture)
   */
  render(scene, camera, toneMap) {
    const renderer = this.renderer;
    const size = renderer.getDrawingBufferSize(new THREE.Vector2());
    if (this.target.width !== size.x || this.target.height !== size.y) this.target.setSize(size.x, size.y);
    renderer.setRenderTarget(this.target);
    renderer.render(scene, camera);
    renderer.setRenderTarget(null);
    this.material.uniforms.toneMap.value = toneMap ? 1 : 0;
    this.quad.render(renderer);
  }

  dispose() {
    this.target.dispose();
    this.material.dispose();
    this.quad.dispose();
  }
}
