// Runs web/src/phoneestimate.js's sky and web/src/proxyrays.js's ray caster in Node on the cases given as JSON on stdin:
// `skies` [{type, sun, dirs}] -> the CIE sky's relative luminance at dirs and its factor to a
// unit horizontal irradiance; `cast` {meshes [{vertices, faces, albedo}], origins, dirs} ->
// the first triangle each ray meets (its distance, -1 for none) and whether any is met;
// `types` [{ratio, sunUp}] -> Perez's clearness and the CIE sky type the estimate takes;
// `perez` [{clearness, brightness, sun, dirs}] -> perezsky.js's all-weather sky's relative
// luminance at dirs, its parameters and skyshape.js's factor to a unit horizontal irradiance;
// `airMass` [elevation degrees] -> perezsky.js's air mass.
// For tests/web/test_phoneestimate_js.py.
import { readFileSync } from 'node:fs';
import { airMass, perezParameters, perezShape } from '../../web/src/perezsky.js';
import { skyClearness, skyTypeForRatio, unitSky } from '../../web/src/skyshape.js';
import { proxiesOf } from './proxymeshes.mjs';

const c = JSON.parse(readFileSync(0, 'utf8'));
const skies = c.skies.map(({ type, sun, dirs }) => {
  const s = unitSky(type, sun);
  return { rel: dirs.map((d) => s.rel(d)), toUnit: s.toUnit };
});
const proxies = proxiesOf(c.cast.meshes);
const first = [];
const any = [];
c.cast.origins.forEach((o, i) => {
  const tri = proxies.cast(o, c.cast.dirs[i]);
  first.push(tri >= 0 ? proxies.hitT : -1);
  any.push(proxies.cast(o, c.cast.dirs[i], true) >= 0);
});
const types = (c.types ?? []).map(({ ratio, sunUp }) => ({
  clearness: skyClearness(ratio, sunUp), type: skyTypeForRatio(ratio, sunUp),
}));
const perez = (c.perez ?? []).map(({ clearness, brightness, sun, dirs }) => {
  const rel = perezShape(clearness, brightness, sun);
  return {
    rel: dirs.map((d) => rel(d)), toUnit: unitSky(12, sun, [clearness, brightness]).toUnit,
    params: perezParameters(clearness, brightness, Math.acos(Math.min(Math.max(sun[1], 0), 1))),
  };
});
const air = (c.airMass ?? []).map(airMass);
console.log(JSON.stringify({ skies, first, any, types, perez, airMass: air }));
