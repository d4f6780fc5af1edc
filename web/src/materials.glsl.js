// Shaders of the surfaces drawn every frame. They only sample the relight targets
// (relight.js), so their cost does not depend on the number of lights, and the sun's shadow
// maps (sun.js). Output is linear radiance times the exposure, then three.js's tone mapping
// and sRGB encoding.
import { SH9_IRRADIANCE_C } from './lightmath.js';
import { SAFE_RATIO } from './display.glsl.js';
import { sunShadowChunk } from './sun.glsl.js';

const common = /* glsl */ `
uniform float exposure;
`;

// The flat ground's point in the sun's two maps (SUN_GROUND 2): affine in the world point, so
// interpolated exactly from the vertices instead of a matrix product per pixel.
const sunGroundVertex = /* glsl */ `
#if SUN_GROUND == 2
uniform mat4 sunMatrixA;
uniform mat4 sunMatrixR;
varying vec4 vSunGroundUv; // 0..1 in map A (xy) and map R (zw)
#endif
`;
const sunGroundVertexMain = /* glsl */ `
#if SUN_GROUND == 2
  vSunGroundUv = vec4((sunMatrixA * world).xy, (sunMatrixR * world).xy) * 0.5 + 0.5;
#endif
`;

export const uvVertex = /* glsl */ `
varying vec2 vUv;
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunGroundVertex}
void main() {
  vUv = uv;
  vNormalW = normalize(mat3(modelMatrix) * normal);
  vec4 world = modelMatrix * vec4(position, 1.0);
  vPositionW = world.xyz;
  ${sunGroundVertexMain}
  gl_Position = projectionMatrix * viewMatrix * world;
}
`;

// The sun's visibility past both caster sets, and the facing normal of a double-sided face.
export const sunCommon = /* glsl */ `
${sunShadowChunk}
// Past every caster (virtual and real), and past the real ones alone: on the flat ground
// (SUN_GROUND 1; 2: prefiltered, at the point the vertex shader found) and on any other
// surface from the visibility maps (sun.js).
#if SUN_GROUND == 2
varying vec4 vSunGroundUv;
float sunVisibilityAll(vec3 p, vec3 n) { return sunVisibilityOnGroundPrefiltered(sunGroundA, sunInfoA, vSunGroundUv.xy); }
float sunVisibilityReal(vec3 p, vec3 n) { return sunVisibilityOnGroundPrefiltered(sunGroundR, sunInfoR, vSunGroundUv.zw); }
#elif SUN_GROUND == 1
float sunVisibilityAll(vec3 p, vec3 n) { return sunVisibilityOnGround(sunGroundA, sunMatrixA, sunInfoA, p); }
float sunVisibilityReal(vec3 p, vec3 n) { return sunVisibilityOnGround(sunGroundR, sunMatrixR, sunInfoR, p); }
#else
float sunVisibilityAll(vec3 p, vec3 n) { return sunVisibilityOnSurface(sunMapA, sunCoarseA, sunVisibilityA, sunMatrixA, sunInfoA, p, n); }
float sunVisibilityReal(vec3 p, vec3 n) { return sunVisibilityOnSurface(sunMapR, sunCoarseR, sunVisibilityR, sunMatrixR, sunInfoR, p, n); }
#endif
vec3 facingNormal() {
  vec3 n = normalize(vNormalW);
  return gl_FrontFacing ? n : -n;
}
`;

export const plainVertex = /* glsl */ `
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunGroundVertex}
void main() {
  vNormalW = normalize(mat3(modelMatrix) * normal);
  vec4 world = modelMatrix * vec4(position, 1.0);
  vPositionW = world.xyz;
  ${sunGroundVertexMain}
  gl_Position = projectionMatrix * viewMatrix * world;
}
`;

function output(expr) {
  return /* glsl */ `
  gl_FragColor = vec4(${expr}, 1.0);
  #include <tonemapping_fragment>
  #include <colorspace_fragment>
`;
}

/**
 * A surface lit from its lightmap and the sun: albedo / pi x (E + E_sun cos V), E the sky's
 * irradiance plus the sun's bounce (irradiance.js: one read), V the sun's visibility past the
 * virtual and the real casters. With shading off (the A/B switch) it shows albedo / pi x
 * flatIrradiance: no shading, no shadows.
 */
export const lightmapFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D irradianceTex; // the atlas's 'lit' target (irradiance.js)
uniform vec3 albedo;
uniform vec3 flatIrradiance;
uniform float shading; // 1 shaded from the lightmap, 0 flat
varying vec2 vUv;
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunCommon}
void main() {
  vec3 n = facingNormal();
  vec3 sun = sunOnSurface(n);
  sun *= sunVisibilityAll(vPositionW, n);
  vec3 e = mix(flatIrradiance, decodeTarget(texture2D(irradianceTex, vUv)) + sun, shading);
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/**
 * The sky's unshadowed irradiance on a unit normal n (world frame) from its spherical
 * harmonics L[9] (RGB, Ramamoorthi & Hanrahan's order and Eq. 13, the constants those of
 * lightmath.js): the GLSL twin of lightmath.js irradianceSH9, W/m^2 for L in W/(m^2 sr).
 */
const [c1, c2, c3, c4, c5] = SH9_IRRADIANCE_C.map((c) => c.toFixed(6));
export const irradianceSHChunk = /* glsl */ `
uniform vec3 L[9];
vec3 irradianceSH(vec3 n) {
  const float c1 = ${c1}, c2 = ${c2}, c3 = ${c3}, c4 = ${c4}, c5 = ${c5};
  float x = n.x, y = n.y, z = n.z;
  return c1 * L[8] * (x * x - y * y) + c3 * L[6] * z * z + c4 * L[0] - c5 * L[6]
    + 2.0 * c1 * (L[4] * x * y + L[7] * x * z + L[5] * y * z)
    + 2.0 * c2 * (L[3] * x + L[1] * y + L[2] * z);
}
`;

/**
 * Hull-plane mode (Kakuta): the virtual object's unshadowed shading from the light vector
 * (spherical harmonics of the sky, Ramamoorthi & Hanrahan Eq. 13, from the manifest's sh9)
 * and the unshadowed sun, darkened by the hull planes drawn over it (whose ratio carries the
 * sun's shadows, shadowPlaneFragment).
 */
export const sh9Fragment = /* glsl */ `
${common}
uniform vec3 albedo;
uniform vec3 flatIrradiance;
uniform float shading;
uniform vec3 groundAlbedo;
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunShadowChunk}
${irradianceSHChunk}
void main() {
  vec3 n = normalize(vNormalW);
  if (!gl_FrontFacing) n = -n;
  // The sun's bounce off the open ground, as the hull planes' d holds it (docs/sun.md).
  vec3 bounce = groundAlbedo * sunIrradiance * max(sunDirection.y, 0.0) * 0.5 * (1.0 - n.y);
  vec3 e = mix(flatIrradiance, max(irradianceSH(n), vec3(0.0)) + sunOnSurface(n) + bounce, shading);
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/**
 * A shadowing plane (Kakuta Eq. 2, 4, with the sun apart as in Jensen 2006), per channel in
 * linear light:
 *   ratio = (E_with + S V) / (E_without + S Vd)
 * with E_with and E_without the irradiance without the sun's direct term with and without the
 * virtual objects (the sky's part from the basis, D - X and D, plus the sun's bounce with and
 * without them: irradiance.js), S the sun's irradiance on the plane unshadowed, V its
 * visibility past every caster and Vr past the real ones, and Vd = Vr where `d` holds the
 * real proxies (ground and wall planes), 1 where it holds nothing (hull planes). Inside a real
 * shadow the ratio is the sky's alone: a virtual shadow never darkens what the real scene
 * already shadows.
 * The ratio has a relative floor with a smooth taper where `absent` is small (safeRatio,
 * display.glsl.js).
 * Drawn into the linear HDR frame (hdr.js; linearOut = 1) the plane multiplies the radiance
 * under it by the ratio per channel (blending DstColor, Zero), ratio > 1 included: exact, and
 * the brightening draw is hidden. Without a half-float frame (the fallback: drawn straight to
 * the screen, after tone mapping and sRGB) it multiplies the encoded picture by
 * ratio^(1/2.2) per channel, and where ratio > 1 a second, additive draw of the same plane
 * (brighten = 1) adds the excess (blending DstColor, One): approximate (docs/web.md). Over a
 * passthrough (AR, transparent frame) it can only be black with alpha 1 - luminance ratio.
 */
export const shadowPlaneFragment = (decode) => /* glsl */ `
${decode}
uniform sampler2D withTex;    // E_with (irradiance.js)
uniform sampler2D withoutTex; // E_without
uniform float strength;      // 1 shown, 0 hidden (the A/B switch)
uniform float brighten;      // 0: the darkening draw, 1: the brightening draw
uniform float alphaOut;      // 1: black with alpha (AR), 0: a factor to multiply by
uniform float dHasReal;      // 1: d holds the real proxies (ground, walls); 0: nothing (hull)
uniform float linearOut;     // 1: drawn into the linear HDR frame (hdr.js): the ratio itself
varying vec2 vUv;
${SAFE_RATIO}
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunCommon}
void main() {
  vec3 n = facingNormal();
  vec3 S = sunOnSurface(n);
  float all = sunVisibilityAll(vPositionW, n);
  float vr = sunVisibilityReal(vPositionW, n);
  vec3 present = decodeTarget(texture2D(withTex, vUv)) + S * all;
  vec3 absent = decodeTarget(texture2D(withoutTex, vUv)) + S * mix(1.0, vr, dHasReal);
  vec3 ratio = mix(vec3(1.0), safeRatio(present, absent), strength);
  if (linearOut > 0.5) {
    gl_FragColor = vec4(brighten > 0.5 ? vec3(0.0) : ratio, 1.0);
    return;
  }
  vec3 encoded = pow(ratio, vec3(1.0 / 2.2));
  if (brighten > 0.5) {
    gl_FragColor = vec4(max(encoded - 1.0, 0.0), 1.0);
  } else if (alphaOut > 0.5) {
    gl_FragColor = vec4(0.0, 0.0, 0.0, 1.0 - min(dot(encoded, vec3(0.2126, 0.7152, 0.0722)), 1.0));
  } else {
    gl_FragColor = vec4(min(encoded, 1.0), 1.0);
  }
}
`;

/**
 * A real receiving surface in the virtual visit (no camera view to blend over): the
 * synthesized real scene under the same sky and sun, albedo / pi x (E_with + S V); with the
 * virtual objects' shading switched off (compiled with VIRTUAL_SHADOWS 0, and given
 * E_without: Site.setShading) albedo / pi x (E_without + S Vr).
 */
export const receiverFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D irradianceTex; // E_with, or E_without with the switch off (irradiance.js)
uniform vec3 albedo;
varying vec2 vUv;
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunCommon}
void main() {
  vec3 n = facingNormal();
  vec3 sun = sunOnSurface(n);
#if VIRTUAL_SHADOWS == 1
  sun *= sunVisibilityAll(vPositionW, n);
#else
  sun *= sunVisibilityReal(vPositionW, n); // the A/B switch's "off": the real shadows only
#endif
  vec3 e = decodeTarget(texture2D(irradianceTex, vUv)) + sun;
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/**
 * The open ground beyond the atlases: lit by the open sky, sum r_i cosine_weighted_sr_i, and
 * the sun with the shadows of every caster.
 */
export const openGroundFragment = /* glsl */ `
${common}
uniform vec3 albedo;
uniform vec3 openIrradiance;
varying vec3 vNormalW;
varying vec3 vPositionW;
${sunCommon}
void main() {
  vec3 n = vec3(0.0, 1.0, 0.0);
  vec3 sun = sunOnSurface(n);
  sun *= sunVisibilityAll(vPositionW, n);
  ${output('albedo / 3.14159265 * (openIrradiance + sun) * exposure')}
}
`;

/** The sky dome of the virtual visit, from the relit equirectangular sky image. */
export const skyVertex = /* glsl */ `
varying vec3 vDir;
void main() {
  vDir = position;
  vec4 p = projectionMatrix * mat4(mat3(viewMatrix)) * vec4(position, 1.0);
  gl_Position = p.xyww;
}
`;

export const skyFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D skyTex;
uniform vec3 horizon;
uniform vec3 sunDirection;
uniform vec3 sunIrradiance;
varying vec3 vDir;
const float COS_SUN = ${Math.cos(0.2666 * Math.PI / 180).toFixed(9)};
const float SUN_SR = ${(2 * Math.PI * (1 - Math.cos(0.2666 * Math.PI / 180))).toExponential(9)};
void main() {
  vec3 w = normalize(vDir);
  float elevation = asin(clamp(w.y, 0.0, 1.0));
  float azimuth = atan(w.x, -w.z);
  if (azimuth < 0.0) azimuth += 6.28318530718;
  vec3 sky = decodeTarget(texture2D(skyTex, vec2(azimuth / 6.28318530718, elevation / 1.57079632679)));
  if (dot(w, sunDirection) > COS_SUN) sky += sunIrradiance / SUN_SR; // the disc: white after tone mapping
  if (w.y < 0.0) sky = horizon;
  ${output('sky * exposure')}
}
`;
