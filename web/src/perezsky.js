// The Perez all-weather sky's shape (Perez, Seals & Michalsky 1993), for the phone's own
// estimate under a clear sky (issue 16; the port of server/perezsky.py, checked against it and
// against Radiance's gendaylit by tests/web/test_phoneestimate_js.py).
//
// Perez, R., R. Seals and J. Michalsky, 1993: "All-weather model for sky luminance
// distribution - preliminary configuration and validation", Solar Energy 50(3), 235-245
// (erratum: Solar Energy 51(5), 423). A sky element at zenith angle Z and angle gamma from the
// sun has the relative luminance of the CIE general sky's form
//   lv(Z, gamma) = (1 + a exp(b / cos Z)) (1 + c exp(d gamma) + e cos^2 gamma)
// whose five parameters each are x1 + x2 Zs + Delta (x3 + x4 Zs) (Zs the sun's zenith angle,
// radians) with the coefficients of the paper's Table 1 for one of eight bins of the sky
// clearness epsilon (the first bin's c and d have their own forms, the paper's equations 7 and
// 8), Delta the sky brightness DHI m / E0 (air mass m, extraterrestrial irradiance E0).
//
// The phone's camera is not calibrated, so its DHI is not in W/m^2: the brightness is taken
// for the clear-sky DNI of Meinel & Meinel (1976) at the sun's air mass and the measured
// DNI / DHI (perezState). Directions: site-frame unit vectors (+X east, +Y up, -Z north).

export const SOLAR_CONSTANT_W_M2 = 1367; // E0 without the year's +-3.4 % (server/perezsky.py)
/** Lower edges of Perez's eight clearness bins (the last open above). */
export const CLEARNESS_BIN_EDGES = [1.0, 1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200];
/** Table 1 of Perez, Seals & Michalsky (1993): per clearness bin, for a, b, c, d, e the four
 * coefficients (x1, x2, x3, x4) of x = x1 + x2 Zs + Delta (x3 + x4 Zs). */
export const PEREZ_1993 = [
  [[1.3525, -0.2576, -0.2690, -1.4366], [-0.7670, 0.0007, 1.2734, -0.1233],
    [2.8000, 0.6004, 1.2375, 1.0000], [1.8734, 0.6297, 0.9738, 0.2809],
    [0.0356, -0.1246, -0.5718, 0.9938]],
  [[-1.2219, -0.7730, 1.4148, 1.1016], [-0.2054, 0.0367, -3.9128, 0.9156],
    [6.9750, 0.1774, 6.4477, -0.1239], [-1.5798, -0.5081, -1.7812, 0.1080],
    [0.2624, 0.0672, -0.2190, -0.4285]],
  [[-1.1000, -0.2515, 0.8952, 0.0156], [0.2782, -0.1812, -4.5000, 1.1766],
    [24.7219, -13.0812, -37.7000, 34.8438], [-5.0000, 1.5218, 3.9229, -2.6204],
    [-0.0156, 0.1597, 0.4199, -0.5562]],
  [[-0.5484, -0.6654, -0.2672, 0.7117], [0.7234, -0.6219, -5.6812, 2.6297],
    [33.3389, -18.3000, -62.2500, 52.0781], [-3.5000, 0.0016, 1.1477, 0.1062],
    [0.4659, -0.3296, -0.0876, -0.0329]],
  [[-0.6000, -0.3566, -2.5000, 2.3250], [0.2937, 0.0496, -5.6812, 1.8415],
    [21.0000, -4.7656, -21.5906, 7.2492], [-3.5000, -0.1554, 1.4062, 0.3988],
    [0.0032, 0.0766, -0.0656, -0.1294]],
  [[-1.0156, -0.3670, 1.0078, 1.4051], [0.2875, -0.5328, -3.8500, 3.3750],
    [14.0000, -0.9999, -7.1406, 7.5469], [-3.4000, -0.1078, -1.0750, 1.5702],
    [-0.0672, 0.4016, 0.3017, -0.4844]],
  [[-1.0000, 0.0211, 0.5025, -0.5119], [-0.3000, 0.1922, 0.7023, -1.6317],
    [19.0000, -5.0000, 1.2438, -1.9094], [-4.0000, 0.0250, 0.3844, 0.2656],
    [1.0468, -0.3788, -2.4517, 1.4656]],
  [[-1.0500, 0.0289, 0.4260, 0.3590], [-0.3250, 0.1156, 0.7781, 0.0025],
    [31.0625, -14.5000, -46.1148, 55.3750], [-7.2312, 0.4050, 13.3500, 0.6234],
    [1.5000, -0.6426, 1.8564, 0.5636]],
];

/** Kasten & Young's (1989) relative optical air mass for a sun elevation (degrees; 38 at the
 * horizon), pvlib's kastenyoung1989 as server/perezsky.py takes it. */
export function airMass(sunElevationDeg) {
  const zDeg = 90 - Math.min(Math.max(sunElevationDeg, 0), 90);
  return 1 / (Math.cos(zDeg * Math.PI / 180) + 0.50572 * (96.07995 - zDeg) ** -1.6364);
}

/** Perez's sky brightness Delta = DHI m / E0 (at least 0.01, the model's range). */
export function skyBrightness(skyHorizontalWm2, sunElevationDeg) {
  return Math.max(skyHorizontalWm2 * airMass(sunElevationDeg) / SOLAR_CONSTANT_W_M2, 0.01);
}

/** The clear sky's direct normal irradiance, W/m^2, for the sun's elevation (degrees):
 * Meinel & Meinel (1976), 1353 x 0.7^(m^0.678). */
export function clearSkyNormalIrradiance(sunElevationDeg) {
  return 1353 * 0.7 ** (airMass(sunElevationDeg) ** 0.678);
}

function clearnessBin(clearness) {
  let k = -1;
  for (const edge of CLEARNESS_BIN_EDGES) if (clearness >= edge) k++;
  return Math.min(Math.max(k, 0), PEREZ_1993.length - 1);
}

/** The all-weather sky's [a, b, c, d, e] for a clearness epsilon, a brightness Delta and the
 * sun's zenith angle (radians). */
export function perezParameters(clearness, brightness, sunZenithRad) {
  const k = clearnessBin(clearness);
  const t = PEREZ_1993[k];
  const z = sunZenithRad;
  const p = t.map((x) => x[0] + x[1] * z + brightness * (x[2] + x[3] * z));
  if (k === 0) { // the overcast bin: the paper's equations 7 and 8
    p[2] = Math.exp((brightness * (t[2][0] + t[2][1] * z)) ** t[2][2]) - t[2][3];
    p[3] = -Math.exp(brightness * (t[3][0] + t[3][1] * z)) + t[3][2] + brightness * t[3][3];
  }
  return p;
}

/**
 * The all-weather sky's relative luminance for one state, 1 at the zenith (the horizon's value
 * below it: callers keep to the upper hemisphere), never negative.
 * @param {number} clearness Perez's epsilon (skyshape.js skyClearness)
 * @param {number} brightness Perez's Delta (skyBrightness)
 * @param {number[]} sun unit direction toward the sun
 * @returns {(d: number[]) => number}
 */
export function perezShape(clearness, brightness, sun) {
  const zSun = Math.acos(Math.min(Math.max(sun[1], 0), 1));
  const [a, b, c, d, e] = perezParameters(clearness, brightness, zSun);
  const lv = (cz, gamma) => (1 + a * Math.exp(b / cz)) * (1 + c * Math.exp(d * gamma) + e * Math.cos(gamma) ** 2);
  const zenith = Math.max(lv(1, zSun), 1e-9);
  return (v) => {
    const cz = Math.min(Math.max(v[1], 1e-2), 1);
    const gamma = Math.acos(Math.min(Math.max(v[0] * sun[0] + v[1] * sun[1] + v[2] * sun[2], -1), 1));
    return Math.max(lv(cz, gamma) / zenith, 0);
  };
}

/**
 * The Perez state [clearness, brightness] of a clear sky the phone measured as a ratio of the
 * sun's normal irradiance to the sky's horizontal irradiance (picture units, whose level is
 * unknown): the clearness from the ratio (skyshape.js skyClearness, passed in), the brightness
 * for the sky of a sun at the clear-sky DNI (clearSkyNormalIrradiance) over that ratio.
 * Rounded (2 and 3 decimals, as the server's _perez_state) so that a state that barely moved
 * reuses the sky's terms.
 */
export function perezState(clearness, ratio, sunUp) {
  const elevationDeg = Math.asin(Math.min(Math.max(sunUp, 0), 1)) * 180 / Math.PI;
  const dhi = clearSkyNormalIrradiance(elevationDeg) / Math.max(ratio, 1e-6);
  return [Math.round(clearness * 100) / 100, Math.round(skyBrightness(dhi, elevationDeg) * 1000) / 1000];
}
