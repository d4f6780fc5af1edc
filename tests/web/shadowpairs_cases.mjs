// Runs web/src/shadowpairs.js and the phone estimate's sun share (phoneestimate.js poolForPose,
// sunTerms) in Node on the cases given as JSON on stdin:
// `pairs` {samples [{x, y, point, normal, albedo, skyView}], share, sun, radiusPx} -> the pairs;
// `pairSun` {radianceShaded, radianceLit, skyShaded, skyLit, sunShaded, sunLit} -> the sun read;
// `pool` {meshes [{vertices, faces, albedo}], eye, target, fovDeg, width, height, farAlbedo,
// sun} -> the camera's world matrix, and per pool sample its pixel, point, normal, albedo, sky
// view, patch share in sun and the centre's flag, with the pool's own pairs (and with
// `perez` [clearness, brightness], each sample's irradiance from the open sky it sees under
// that Perez sky per unit open horizontal irradiance, phonepool.js skyTerms).
// `shade` {meshes, eye, target, fovDeg, width, height, sun, type, normals} -> the camera's world
// matrix, the pixels wholly in the model's shadow (phoneshade.js) as [x, y], and the CIE sky
// `type`'s irradiance on unobstructed surfaces of the unit `normals` per unit open horizontal
// irradiance (phonepool.js skyBounceTerms, one sample bouncing off each normal alone).
// For tests/web/test_phoneestimate_js.py.
import { readFileSync } from 'node:fs';
import * as THREE from 'three';
import { pairRadiusPx } from '../../web/src/phoneestimate.js';
import { poolForPose, skyBounceTerms, skyTerms, sunTerms } from '../../web/src/phonepool.js';
import { viewHits, whollyShadedPixels } from '../../web/src/phoneshade.js';
import { unitSky } from '../../web/src/skyshape.js';
import { proxiesOf } from './proxymeshes.mjs';
import { pairSun, shadowPairs } from '../../web/src/shadowpairs.js';

const c = JSON.parse(readFileSync(0, 'utf8'));
const out = {};
if (c.pairs) {
  const { samples, share, sun, radiusPx } = c.pairs;
  out.pairs = shadowPairs(samples, share, sun, { radiusPx });
}
if (c.pairSun) {
  const p = c.pairSun;
  out.pairSun = pairSun(p.radianceShaded, p.radianceLit, p.skyShaded, p.skyLit, p.sunShaded, p.sunLit);
}
if (c.pool) {
  const p = c.pool;
  const proxies = proxiesOf(p.meshes);
  const camera = new THREE.PerspectiveCamera(p.fovDeg, p.width / p.height, 0.1, 1000);
  camera.position.set(...p.eye);
  camera.lookAt(...p.target);
  camera.updateMatrixWorld();
  const pool = poolForPose(proxies, camera, p.width, p.height, p.farAlbedo);
  const terms = sunTerms(proxies, pool, p.sun);
  const pairs = shadowPairs(pool, terms.map((t) => t.share), p.sun, { radiusPx: pairRadiusPx(p.height) });
  const sky = p.perez ? skyTerms(pool, unitSky(12, p.sun, p.perez)) : null;
  out.pool = {
    matrixWorld: camera.matrixWorld.toArray(),
    samples: pool.map((s, i) => ({
      x: s.x, y: s.y, point: s.point, normal: s.normal, albedo: s.albedo, skyView: s.skyView,
      share: terms[i].share, litCentre: terms[i].litCentre, cosI: terms[i].cosI,
      skyTerm: sky?.[i],
    })),
    pairs,
  };
}
if (c.shade) {
  const p = c.shade;
  const proxies = proxiesOf(p.meshes);
  const camera = new THREE.PerspectiveCamera(p.fovDeg, p.width / p.height, 0.1, 1000);
  camera.position.set(...p.eye);
  camera.lookAt(...p.target);
  camera.updateMatrixWorld();
  const hits = viewHits(proxies, camera, p.width, p.height);
  const pixels = whollyShadedPixels(proxies, hits, p.sun).map((k) => [k % p.width, Math.floor(k / p.width)]);
  // one sample per normal, its one bounce ray meeting a surface of that tilt of albedo 1
  const samples = p.normals.map((_, i) => ({ rays: 1, bounce: [{ albedo: [1, 1, 1], tilt: i }] }));
  const tilted = skyBounceTerms(samples, unitSky(p.type, p.sun), p.normals).map((b) => b[0]);
  out.shade = { matrixWorld: camera.matrixWorld.toArray(), pixels, tilted };
}
console.log(JSON.stringify(out));
