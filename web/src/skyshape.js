// The model sky's shape for the phone's own estimate (issue 16; server/skyshape.py's rules):
// a CIE general sky chosen by the estimated ratio of the sun's normal irradiance to the sky's
// horizontal irradiance and Perez's sky clearness, or, under a clear sky, Perez's all-weather
// sky for the measured state (perezsky.js), scaled to an open horizontal irradiance of 1; and
// the fixed grid over the upper hemisphere that each pool sample's open sky is read on
// (phonepool.js). Directions: site-frame unit vectors (+X east, +Y up, -Z north).
import { perezShape } from './perezsky.js';

// server/skyshape.py: the CIE sky by the sun/sky ratio (overcast) and Perez's sky clearness
// (clear from 4.5, the lower edge of Perez's clear bins; a ratio of 3 called Radiance's
// intermediate sky clear once the clear sky's shape had read it high: docs/web.md)
export const OVERCAST_RATIO = 0.5;
export const CLEAR_CLEARNESS = 4.5;
export const OVERCAST_TYPE = 2;
export const CLEAR_TYPE = 12;
// CIE general skies (ISO 15469; daylit/sky.py CIE_SKY_TYPES): a, b, c, d, e
const CIE = { 2: [4.0, -0.7, 2.0, -1.5, 0.15], 7: [0.0, -1.0, 5.0, -2.5, 0.3], 12: [-1.0, -0.32, 10.0, -3.0, 0.45] };
// Zenith steps of the grid a sky is integrated on for its scale (twice as many in azimuth)
const SCALE_GRID_STEPS = 24;

/** Perez's sky clearness ((DHI + DNI) / DHI + 1.041 Z^3) / (1 + 1.041 Z^3), Z the sun's zenith
 * angle (radians), for a ratio DNI / DHI and the sun's unit direction's up component. */
export function skyClearness(ratio, sunUp) {
  const z = Math.acos(Math.min(1, Math.max(0, sunUp)));
  const k = 1.041 * z ** 3;
  return (1 + Math.max(ratio, 0) + k) / (1 + k);
}

/** The CIE sky type for a ratio of sun normal irradiance to sky horizontal irradiance and the
 * sun's up component (server/skyshape.py sky_type_for_ratio). */
export function skyTypeForRatio(ratio, sunUp = 1) {
  if (ratio < OVERCAST_RATIO) return OVERCAST_TYPE;
  return skyClearness(ratio, sunUp) >= CLEAR_CLEARNESS ? CLEAR_TYPE : 7;
}

/**
 * Midpoint directions over the upper hemisphere and their solid angles (server/skyshape.py
 * upper_hemisphere_grid, the same order: zenith rows, then azimuth).
 * @param {number} steps zenith steps (2 steps in azimuth): cells of 90 / steps degrees
 * @returns {{dirs: number[][], sr: Float64Array}} (G, 3) unit directions, (G,) sr
 */
export function upperHemisphereGrid(steps) {
  const dz = Math.PI / 2 / steps;
  const da = Math.PI / steps;
  const dirs = [];
  const sr = new Float64Array(2 * steps * steps);
  for (let i = 0; i < steps; i++) {
    const z = (i + 0.5) * dz;
    for (let j = 0; j < 2 * steps; j++) {
      const az = (j + 0.5) * da;
      sr[dirs.length] = Math.sin(z) * dz * da;
      dirs.push([Math.sin(z) * Math.sin(az), Math.cos(z), -Math.sin(z) * Math.cos(az)]);
    }
  }
  return { dirs, sr };
}

const SCALE_GRID = upperHemisphereGrid(SCALE_GRID_STEPS);

/** A CIE general sky's luminance relative to its zenith, (d: unit direction) => number. */
export function cieShape(type, sun) {
  const [a, b, c, d, e] = CIE[type];
  const zSun = Math.acos(Math.max(-1, Math.min(1, Math.max(sun[1], 0))));
  const grad = (cz) => 1 + a * Math.exp(b / cz);
  const ind = (x) => 1 + c * (Math.exp(d * x) - Math.exp(d * Math.PI / 2)) + e * Math.cos(x) ** 2;
  const norm = ind(zSun) * grad(1);
  const sunUp = sun[1] > 0 ? sun : normalized([sun[0], 0, sun[2]]);
  return (v) => {
    const cz = Math.max(v[1], 1e-6);
    const chi = Math.acos(Math.max(-1, Math.min(1, v[0] * sunUp[0] + v[1] * sunUp[1] + v[2] * sunUp[2])));
    return ind(chi) * grad(cz) / norm;
  };
}

/**
 * A model sky's luminance relative to its zenith, and the factor to an open horizontal
 * irradiance of 1 (server/skyshape.py unit_sky): the CIE general sky of this type, or with
 * `perez` = [clearness, brightness] Perez's all-weather sky of that state.
 * @returns {{rel: (d: number[]) => number, toUnit: number}}
 */
export function unitSky(type, sun, perez = null) {
  const rel = perez ? perezShape(perez[0], perez[1], sun) : cieShape(type, sun);
  let sum = 0;
  SCALE_GRID.dirs.forEach((v, g) => { sum += rel(v) * v[1] * SCALE_GRID.sr[g]; });
  return { rel, toUnit: 1 / sum };
}

function normalized(v) {
  const l = Math.hypot(...v) || 1;
  return v.map((x) => x / l);
}
