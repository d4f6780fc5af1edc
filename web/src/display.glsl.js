// The display's GLSL pieces shared by the visit (site.js) and the kiosk (kiosk.glsl.js): the
// ratio of two irradiances with a relative floor, and the tone map the kiosk applies itself
// (the visit's comes from three.js: renderer.toneMapping = NeutralToneMapping, the same curve).

/** Below this fraction of a pixel's largest denominator channel a channel's ratio tapers to 1. */
export const RATIO_FLOOR = 1e-2;
/** An absolute floor under it (W/m^2, or the view images' units), for an all-black pixel. */
export const RATIO_FLOOR_ABS = 1e-6;
/** The largest ratio kept: light bounced off a virtual object never more than quadruples. */
export const RATIO_MAX = 4.0;

/**
 * safeRatio(num, den), per channel: num / den where den is well above the floor
 * f = RATIO_FLOOR max_c |den_c| + RATIO_FLOOR_ABS; 1 where den <= f (a channel the denominator
 * hardly lights says nothing about the shadow); between f and 2f a smoothstep blend of the two,
 * so no edge appears where a channel crosses the floor. Clamped to [0, RATIO_MAX].
 */
export const SAFE_RATIO = /* glsl */ `
vec3 safeRatio(vec3 num, vec3 den) {
  vec3 a = abs(den);
  float f = ${RATIO_FLOOR.toExponential(6)} * max(max(a.r, a.g), a.b) + ${RATIO_FLOOR_ABS.toExponential(6)};
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
