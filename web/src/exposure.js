// The display exposure from the measured light (docs/web.md, "Exposure"): a photographic
// meter on the open ground whose key depends on how bright the ground is, so that dusk looks
// like dusk and night dark, while a clear and an overcast noon both look like day.
//
//   L_v   = K_LM_PER_W x luminance(albedo / pi x E_ground)        cd/m^2, the ground's luminance
//   key   = 1.03 - 2 / (2 + log10(L_v + 1))                        Krawczyk, Myszkowski & Seidel
//                                                                  2005, Eq. 11 (lightness
//                                                                  perception: dim scenes get a
//                                                                  low key)
//   level = DISPLAY_KEY x key / KEY_DAY                            the ground's display level
//   exposure = level / luminance(albedo / pi x E_ground)           radiance units -> display
//
// At daylight levels (L_v ~ 1000-5000 cd/m^2) key ~ KEY_DAY and the ground shows near
// DISPLAY_KEY as before (an overcast noon, ~1300 cd/m^2, at 0.96 of it); at sunset (~30 cd/m^2)
// at 0.7 of it, in civil twilight (~1) a quarter, at night (~0.01) a twentieth: the picture
// darkens with the light as the eye sees it, instead of every light looking like noon.
// E_ground is in the light vector's units (W/m^2 of broadband daylight); K_LM_PER_W converts
// them with one luminous efficacy for daylight, an approximation (direct sun ~95 lm/W, diffuse
// sky ~125: Littlefair 1985), within 0.15 decade of the key's input.

import { LUMA } from './colour.js';

export const DISPLAY_KEY = 0.18;   // the open ground's display level in daylight (linear)
export const K_LM_PER_W = 110;     // luminous efficacy of daylight, lm/W

/** Krawczyk et al.'s key for a luminance in cd/m^2. */
export function lightnessKey(luminanceCdM2) {
  return 1.03 - 2 / (2 + Math.log10(Math.max(0, luminanceCdM2) + 1));
}

const KEY_DAY = lightnessKey(3000); // the key of a sunlit ground (0.20 albedo, ~47000 lux)

/**
 * The display exposure (multiplies radiance, W/(m^2 sr)) for the open ground's irradiance.
 * @param {number[]} groundIrradiance RGB W/m^2 on the open ground, sun included
 * @param {number[]} albedo the ground's RGB albedo
 * @param {'scene'|'camera'} meter 'scene': the lightness key (the visit, the kiosk's
 *   synthesized picture); 'camera': a camera's auto exposure, the ground always at
 *   DISPLAY_KEY (virtual objects over a camera picture, which its own meter exposed so)
 * @returns {number} 1 when there is no light to meter
 */
export function exposureFor(groundIrradiance, albedo, meter = 'scene') {
  const radiance = groundRadiance(groundIrradiance, albedo);
  if (!(radiance > 0)) return 1;
  if (meter === 'camera') return DISPLAY_KEY / radiance;
  const level = DISPLAY_KEY * Math.max(lightnessKey(K_LM_PER_W * radiance), 0) / KEY_DAY;
  return Math.max(level, 1e-4) / radiance;
}

/**
 * The exposure that draws the modelled open ground at the level a camera's picture shows it
 * (picturemeter.js): the virtual objects then sit at the picture's own exposure.
 * @param {number} level the picture's ground, display-linear luminance 0..1
 * @param {number[]} groundIrradiance RGB W/m^2 on the open ground, sun included
 * @param {number[]} albedo the ground's RGB albedo
 * @returns {number|null} null when there is no light to meter
 */
export function exposureFromPicture(level, groundIrradiance, albedo) {
  const radiance = groundRadiance(groundIrradiance, albedo);
  return radiance > 0 && level > 0 ? level / radiance : null;
}

/** The open ground's luminance in the light vector's radiance units, W/(m^2 sr). */
function groundRadiance(groundIrradiance, albedo) {
  return LUMA.reduce((s, w, c) => s + w * albedo[c] * groundIrradiance[c], 0) / Math.PI;
}
