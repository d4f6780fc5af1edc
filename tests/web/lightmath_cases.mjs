// Runs web/src/lightmath.js on the cases given as JSON on stdin and prints the results, for
// tests/web/test_lightmath_js.py to compare with Python's reference.
import { readFileSync } from 'node:fs';
import {
  baseCoefficients, irradianceSH9, LightSmoother, openSkyIrradiance, patchContaining,
  selectionWeights, selectLights, skySH9,
} from '../../web/src/lightmath.js';

const input = JSON.parse(readFileSync(0, 'utf8'));
const out = { select: [], coefficients: [], sh9: [], sh9Known: [], open: [], smoothing: [], patch: [] };
for (const c of input.select ?? []) {
  out.select.push(selectLights(c.r.flat(), selectionWeights(c.solid, c.selectable), c.m));
}
for (const c of input.coefficients ?? []) {
  out.coefficients.push(Array.from(baseCoefficients(Float32Array.from(c.V.flat()), c.k, c.r.flat(), c.selected)));
}
for (const c of input.sh9 ?? []) out.sh9.push(irradianceSH9(skySH9(c.r.flat(), c.sh9), c.normal));
for (const c of input.sh9Known ?? []) {
  const L = skySH9(c.r.flat(), c.sh9);
  out.sh9Known.push(c.normals.map((n) => irradianceSH9(L, n)));
}
for (const c of input.open ?? []) out.open.push(openSkyIrradiance(c.r.flat(), c.cosw));
const s = new LightSmoother(2.0);
s.push([0, 0, 0], 0);
s.push([1, 1, 1], 0);
s.step(2.0);
out.smoothing.push(Array.from(s.value));
for (const c of input.patch ?? []) out.patch.push(patchContaining(c.lights, c.direction));
process.stdout.write(JSON.stringify(out));
