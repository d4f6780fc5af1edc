// Colour arithmetic every part of the client shares: the sRGB transfer curve and the
// luminance of linear RGB (Rec. 709 primaries, as sRGB's). One place, so that the exposure, the
// phone's estimate, its pose registration and the kiosk's camera scale weigh colours alike.

/** Luminance weights of linear R, G, B (Rec. 709). */
export const LUMA = Object.freeze([0.2126, 0.7152, 0.0722]);

/** Luminance of linear RGB (any unit: it is kept). */
export function luminance(r, g, b) {
  return LUMA[0] * r + LUMA[1] * g + LUMA[2] * b;
}

/** sRGB-encoded value in [0, 1] to linear (IEC 61966-2-1). */
export function srgbToLinear(v) {
  return v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4;
}

/** Linear values of the 256 sRGB codes, for reading pictures a pixel at a time. */
export const LINEAR_OF_CODE = Float64Array.from({ length: 256 }, (_, v) => srgbToLinear(v / 255));
