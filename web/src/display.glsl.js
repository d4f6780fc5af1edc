// The display's GLSL pieces shared by the visit (site.js) and the kiosk (kiosk.glsl.js): the
// ratio of two irradiances with a relative floor, and the tone map the kiosk applies itself
// (the visit's comes from three.js: renderer.toneMapping = NeutralToneMapping, the same curve).

/** Below this fraction of a pixel's largest denominator channel a channel's ratio tapers to 1. */
export const RATIO_FLOOR = 1e-2;
/** ... and below this fraction of the scene's light level (the open ground's irradiance, or
 * its radiance at the kiosk: the `ratioFloor` uniform is this times it) the whole pixel's. */
export const RATIO_FLOOR_SCENE = 1e-3;
/** The largest ratio kept: light bounced off a virtual object never more than quadruples. */
export const RATIO_MAX = 4.0;

/**
 * safeRatio(num, den), per channel: num / den where den is well above the floor
 * f = max(RATIO_FLOOR max_c |den_c|, ratioFloor); 1 where den <= f (a surface the denominator
 * hardly lights, or a channel of it, says nothing about a shadow: 0 / tiny would be black);
 * between f and 2f a smoothstep blend of the two, so no edge appears where the denominator
 * crosses the floor. Clamped to [0, RATIO_MAX]. Needs `uniform float ratioFloor` (> 0).
 */
export const SAFE_RATIO = /* glsl */ `
uniform float ratioFloor; // RATIO_FLOOR_SCENE x the scene's light level (site.js, kiosk.js)
vec3 safeRatio(vec3 num, vec3 den) {
  vec3 a = abs(den);
  float f = max(${RATIO_FLOOR.toExponential(6)} * max(max(a.r, a.g), a.b), max(ratioFloor, 1e-12));
  vec3 w = smoothstep(vec3(f), vec3(2.0 * f), den);
  return clamp(mix(vec3(1.0), num / max(den, vec3(f)), w), 0.0, ${RATIO_MAX.toFixed(1)});
}
`;

/**
 * Khronos PBR Neutral (the tone map three.js calls NeutralToneMapping, written from the
 * Khronos specification): linear radiance times the exposure -> display-linear 0..1.
 */
export const NEUTRAL_TONE_MAP = /* glsl */ `
vec3 neutralToneMap(vec3 c) {
  const float startCompression = 0.8 - 0.04;
  const float desaturation = 0.15;
  float x = min(c.r, min(c.g, c.b));
  float offset = x < 0.08 ? x - 6.25 * x * x : 0.04;
  c -= offset;
  float peak = max(c.r, max(c.g, c.b));
  if (peak < startCompression) return c;
  const float d = 1.0 - startCompression;
  float newPeak = 1.0 - d * d / (peak + d - startCompression);
  c *= newPeak / peak;
  float g = 1.0 - 1.0 / (desaturation * (peak - newPeak) + 1.0);
  return mix(c, vec3(newPeak), g);
}
`;
