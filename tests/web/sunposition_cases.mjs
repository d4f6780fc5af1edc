// Runs web/src/sunposition.js on the cases given as JSON on stdin ([[lat, lon, unix_s], ...])
// and prints [[azimuth_deg, elevation_deg, x, y, z], ...], for tests/web/test_sunposition_js.py.
import { readFileSync } from 'node:fs';
import { sunPosition } from '../../web/src/sunposition.js';

const cases = JSON.parse(readFileSync(0, 'utf8'));
console.log(JSON.stringify(cases.map(([lat, lon, t]) => {
  const p = sunPosition(lat, lon, t);
  return [p.azimuthDeg, p.elevationDeg, ...p.direction];
})));
