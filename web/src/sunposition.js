// Where the sun is, in the browser: the phone's own estimate (phoneestimate.js) runs with no
// server, so it needs the sun without one. NOAA's solar calculator (Meeus's low-precision
// formulas; about 0.01 degrees between 1800 and 2100, against pvlib's NREL SPA in
// tests/web/test_sunposition_js.py) with NOAA's refraction, which is what the server's SPA
// adds too (apparent elevation). Directions in the site frame: +X east, +Y up, -Z north.

const RAD = Math.PI / 180;

/**
 * The sun's apparent position.
 * @param {number} latitudeDeg north positive
 * @param {number} longitudeDeg east positive
 * @param {number} unixS seconds since 1970 (UTC)
 * @returns {{azimuthDeg: number, elevationDeg: number, direction: number[]}} azimuth clockwise
 *   from north, apparent (refracted) elevation, and the unit site direction toward the sun
 */
export function sunPosition(latitudeDeg, longitudeDeg, unixS) {
  const jd = unixS / 86400 + 2440587.5;
  const t = (jd - 2451545) / 36525; // Julian centuries since J2000
  const l0 = mod360(280.46646 + t * (36000.76983 + t * 0.0003032)); // mean longitude
  const m = 357.52911 + t * (35999.05029 - 0.0001537 * t); // mean anomaly
  const e = 0.016708634 - t * (0.000042037 + 0.0000001267 * t); // orbit's eccentricity
  const c = Math.sin(m * RAD) * (1.914602 - t * (0.004817 + 0.000014 * t))
    + Math.sin(2 * m * RAD) * (0.019993 - 0.000101 * t) + Math.sin(3 * m * RAD) * 0.000289;
  const omega = 125.04 - 1934.136 * t;
  const lambda = l0 + c - 0.00569 - 0.00478 * Math.sin(omega * RAD); // apparent longitude
  const eps0 = 23 + (26 + (21.448 - t * (46.815 + t * (0.00059 - t * 0.001813))) / 60) / 60;
  const eps = eps0 + 0.00256 * Math.cos(omega * RAD); // obliquity, corrected
  const decl = Math.asin(Math.sin(eps * RAD) * Math.sin(lambda * RAD));
  const y = Math.tan(eps * RAD / 2) ** 2;
  const eotMin = 4 / RAD * (y * Math.sin(2 * l0 * RAD) - 2 * e * Math.sin(m * RAD)
    + 4 * e * y * Math.sin(m * RAD) * Math.cos(2 * l0 * RAD)
    - 0.5 * y * y * Math.sin(4 * l0 * RAD) - 1.25 * e * e * Math.sin(2 * m * RAD));
  const utcMin = ((unixS / 60) % 1440 + 1440) % 1440;
  const solarMin = utcMin + eotMin + 4 * longitudeDeg; // true solar time
  const hourAngle = (solarMin / 4 - 180) * RAD;
  const lat = latitudeDeg * RAD;
  const cosZenith = Math.sin(lat) * Math.sin(decl) + Math.cos(lat) * Math.cos(decl) * Math.cos(hourAngle);
  const elevationDeg = Math.asin(Math.max(-1, Math.min(1, cosZenith))) / RAD;
  const azimuthDeg = mod360(Math.atan2(Math.sin(hourAngle),
    Math.cos(hourAngle) * Math.sin(lat) - Math.tan(decl) * Math.cos(lat)) / RAD + 180);
  const apparent = elevationDeg + refractionDeg(elevationDeg);
  const az = azimuthDeg * RAD;
  const el = apparent * RAD;
  return {
    azimuthDeg, elevationDeg: apparent,
    direction: [Math.cos(el) * Math.sin(az), Math.sin(el), -Math.cos(el) * Math.cos(az)],
  };
}

/** NOAA's atmospheric refraction at a true elevation, degrees (standard air). */
function refractionDeg(elevationDeg) {
  const e = elevationDeg;
  if (e > 85) return 0;
  const te = Math.tan(e * RAD);
  let arcS;
  if (e > 5) arcS = 58.1 / te - 0.07 / te ** 3 + 0.000086 / te ** 5;
  else if (e > -0.575) arcS = 1735 + e * (-518.2 + e * (103.4 + e * (-12.79 + e * 0.711)));
  else arcS = -20.772 / te;
  return arcS / 3600;
}

function mod360(x) {
  return ((x % 360) + 360) % 360;
}
