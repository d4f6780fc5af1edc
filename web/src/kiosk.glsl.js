// Sato's Eq. 9 at the kiosk's fixed viewpoint, per pixel, in linear light:
//   virtual pixels (mask 255):  k O'            (O' = sum r O, k the camera's scale)
//   real pixels (mask 0):       P O' / S'       (P the live site-camera frame)
//   sky pixels (mask 128):      P
// and where the occlusion mask says a person stands in front: P (the person hides the
// virtual object). Without a live frame the background is synthesized: P = k S', so real
// pixels become k O' and sky pixels k sum r phi (relight.js).
// With a sun (kiosksun.js), O' and S' include its direct term: O' = O_sky + E_sun O_sun and
// S' = S_sky + E_sun S_sun, O_sun and S_sun the view's sun images per unit normal irradiance
// (albedo / pi cos V, with V past every caster, resp. past the real proxies alone), and its
// bounce: O' += B_O and S' += B_S, the view's sun-bounce images of the sun's patch times
// E_sun / solid_angle_p (sunbounce.js; black when the build has none), so the ratio on real
// pixels includes the bounce in both.
// The ratio O'/S' per channel has a relative floor with a smooth taper (display.glsl.js
// safeRatio). The synthesized picture (no live frame) goes through the visit's display
// transform (the exposure, Khronos PBR Neutral, sRGB); over a live frame P is the camera's own
// display-referred picture and k O' is in its units, so only sRGB encoding follows.
// uv: (0, 0) is the top-left corner of the view image; every texture here stores rows top
// first (no flips anywhere), so uv samples the same pixel in all of them.

import { NEUTRAL_TONE_MAP, SAFE_RATIO } from './display.glsl.js';

export const kioskVertex = /* glsl */ `
in vec3 position;
uniform vec4 viewport; // the view's rectangle on the output, in its normalized coordinates
out vec2 vUv;
void main() {
  vec2 corner = position.xy * 0.5 + 0.5;          // 0..1 over the full-screen triangle
  vUv = vec2((corner.x - viewport.x) / viewport.z, 1.0 - (corner.y - viewport.y) / viewport.w);
  gl_Position = vec4(position.xy, 0.0, 1.0);
}
`;

export const kioskFragment = (decode) => /* glsl */ `
precision highp float;
uniform sampler2D oTex;       // O'
uniform sampler2D sTex;       // S'
uniform sampler2D sunOTex;    // O_sun: albedo / pi cos V per unit normal irradiance
uniform sampler2D sunSTex;    // S_sun: the same with V_r (the real proxies only)
uniform vec3 sunIrradiance;   // E_sun, RGB W/m^2; 0 when there is no sun to draw
uniform sampler2D bounceOTex; // B_O: the sun's bounce with the virtual objects, radiance (relight format)
uniform sampler2D bounceSTex; // B_S: without them
uniform sampler2D skyTex;     // sum r phi on sky pixels
uniform sampler2D maskTex;    // 255 virtual, 128 sky, 0 real
uniform sampler2D frameTex;   // P, sRGB-decoded by the GPU (SRGB8_ALPHA8)
uniform sampler2D occlusionTex; // 255 where a person stands in front
uniform float hasFrame;
uniform float hasOcclusion;
uniform float cameraScale;    // k: camera units per unit radiance
uniform float strength;       // 1: virtual shadows on real pixels, 0: off (A/B)
uniform float outputScale;    // display exposure (synthesized picture)
uniform float encodeOutput;   // 1: for the screen (tone map when synthesized, sRGB), 0: linear (read back by tests)
in vec2 vUv;
out vec4 outColor;
${decode}
${SAFE_RATIO}
${NEUTRAL_TONE_MAP}
vec3 srgbEncode(vec3 c) {
  c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}
void main() {
  if (vUv.x < 0.0 || vUv.x > 1.0 || vUv.y < 0.0 || vUv.y > 1.0) { outColor = vec4(0.0, 0.0, 0.0, 1.0); return; }
  vec3 O = decodeTarget(texture(oTex, vUv));
  vec3 S = decodeTarget(texture(sTex, vUv));
  if (sunIrradiance != vec3(0.0)) {
    O += sunIrradiance * decodeTarget(texture(sunOTex, vUv));
    S += sunIrradiance * decodeTarget(texture(sunSTex, vUv));
  }
  O += decodeTarget(texture(bounceOTex, vUv));
  S += decodeTarget(texture(bounceSTex, vUv));
  float m = texture(maskTex, vUv).r;
  bool isVirtual = m > 0.75;
  bool isSky = m > 0.25 && !isVirtual;
  vec3 ratio = mix(vec3(1.0), safeRatio(O, S), strength);
  vec3 c;
  if (hasFrame > 0.5) {
    vec3 P = texture(frameTex, vUv).rgb;
    bool person = hasOcclusion > 0.5 && texture(occlusionTex, vUv).r > 0.5;
    if (person || isSky) c = P;
    else if (isVirtual) c = cameraScale * O;
    else c = P * ratio;
  } else {
    if (isVirtual) c = cameraScale * O;
    else if (isSky) c = cameraScale * decodeTarget(texture(skyTex, vUv));
    else c = cameraScale * S * ratio;
  }
  c *= outputScale;
  if (encodeOutput > 0.5) c = srgbEncode(hasFrame > 0.5 ? c : neutralToneMap(c));
  outColor = vec4(c, 1.0);
}
`;
