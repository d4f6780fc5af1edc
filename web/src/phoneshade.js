// Pixels wholly in the model's shadow for the current sun: the phone estimate's pool topped up
// (issue 16; server/shadepool.py's rules, for phoneestimate.js).
//
// The estimate tells the sky from the sun by surfaces in shadow. Its pool is random pixels of
// the picture's copy whose corners see one plane (phonepool.js), and a sample counts as shaded
// when most of its 3 x 3 patch is (PATCH_PX). A view whose shade is thin or broken (the demo's
// kiosk view: the tree's shadow on the ground one or two pixels high, the shaded side of a
// canopy of faces a few pixels across) has few such samples or none, and the sky is then read
// from sunlit ground, where the sun and the sky are nearly collinear (docs/web.md).
//
// viewHits finds, once per pose, what every pixel of the copy sees (the triangle through its
// centre, seen from the front); whollyShadedPixels, per sun, those that see a known surface in
// the model's shadow (facing away from the sun, or a ray toward it blocked by the proxies) with
// all eight neighbours in shadow too (the pixel, and what JPEG's blocks and the lens mix into
// it, is shade), away from the copy's edge; shadeSamples makes samples of some of them, each
// read alone and modelled by its own centre: its point, normal, open sky, and its bounce
// through SHADE_RAYS_FACTOR times the pool's directions (a shaded pixel's light is mostly the
// bounce from the sunlit ground it sees: the sky read from it moves with the bounce's
// quadrature error). The robust fit judges them on their own residual scale (robustfit.js
// groups). Directions: site-frame unit vectors (+X east, +Y up, -Z north); points metres.
import * as THREE from 'three';
import { HEMISPHERE_RAYS, SURFACE_OFFSET_M, dot, mulberry32, sampleAt } from './phonepool.js';

/** An estimate's samples in shade wanted: below this many in the pool, the top-up adds single
 * pixels up to it (the server's half of its 500 samples). */
export const SHADE_TARGET = 250;
/** Fewer wholly shaded pixels than this in the view: no top-up. The demo's kiosk view at 14:30
 * has 23 at the copy's 192 x 108 (the tree's shadow one or two pixels high, the canopy's
 * shaded side), and with them the phone read the clear sky +1 to +22 % (2 of 18 estimates
 * within 10 %); without, it makes no estimate there. The server's 17 such pixels on its
 * kiosk view at 9:30 left the sky's standard error at 3.6-6.5 % (docs/benchmarks.md). */
export const MIN_TOP_UP = 50;
/** A shade sample's bounce rays over a pool sample's (server/sceneestimate.py
 * SHADE_HEMISPHERE_FACTOR). */
export const SHADE_RAYS_FACTOR = 5;
const FRONT_COS = 0.05; // a surface seen more grazing than this is not used
const MARGIN_PX = 1; // the neighbours within this many pixels must be in shadow too
const BORDER_PX = 2; // and the pixel this far from the copy's edge

/**
 * What every pixel of the copy sees (once per pose).
 * @param {import('./proxyrays.js').Proxies} proxies
 * @param {{matrixWorld: THREE.Matrix4, projectionMatrixInverse: THREE.Matrix4}} camera the
 *   pose (world) and projection of the picture, as the pool was made with (a THREE.Camera, or
 *   a copy of those two matrices)
 * @param {number} w copy width, pixels
 * @param {number} h copy height
 * @returns {{w, h, tri: Int32Array, point: Float64Array}} per pixel (row-major from the top)
 *   the triangle seen through its centre (-1: none, or seen from behind or grazing) and the
 *   point (3 per pixel, metres)
 */
export function viewHits(proxies, camera, w, h) {
  const origin = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld);
  const o = origin.toArray();
  const ray = new THREE.Vector3();
  const tri = new Int32Array(w * h).fill(-1);
  const point = new Float64Array(3 * w * h);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const d = ray.set((x + 0.5) / w * 2 - 1, 1 - (y + 0.5) / h * 2, 0.5).unproject(camera)
        .sub(origin).normalize().toArray();
      const t = proxies.cast(o, d);
      if (t < 0 || dot(proxies.normalOf(t), d) > -FRONT_COS) continue;
      const k = y * w + x;
      tri[k] = t;
      for (let c = 0; c < 3; c++) point[3 * k + c] = o[c] + d[c] * proxies.hitT;
    }
  }
  return { w, h, tri, point };
}

/**
 * The pixels that see a known surface wholly in the model's shadow for a sun (server/shadepool.py
 * wholly_shaded_pixels): in shadow themselves and every pixel within MARGIN_PX, and at least
 * BORDER_PX from the copy's edge.
 * @param {ReturnType<typeof viewHits>} hits
 * @param {number[]} sun unit direction toward the sun
 * @returns {number[]} pixel indices (y w + x); none when the sun is down
 */
export function whollyShadedPixels(proxies, hits, sun) {
  const { w, h, tri, point } = hits;
  if (sun[1] <= 0) return [];
  const shaded = new Uint8Array(w * h);
  for (let k = 0; k < w * h; k++) {
    if (tri[k] < 0) continue;
    const n = proxies.normalOf(tri[k]);
    if (dot(n, sun) <= 0) {
      shaded[k] = 1;
      continue;
    }
    const start = [0, 1, 2].map((c) => point[3 * k + c] + SURFACE_OFFSET_M * n[c]);
    if (proxies.cast(start, sun, true) >= 0) shaded[k] = 1;
  }
  const out = [];
  const b = Math.max(BORDER_PX, MARGIN_PX);
  for (let y = b; y < h - b; y++) {
    for (let x = b; x < w - b; x++) {
      let all = true;
      for (let dy = -MARGIN_PX; dy <= MARGIN_PX && all; dy++) {
        for (let dx = -MARGIN_PX; dx <= MARGIN_PX && all; dx++) all = shaded[(y + dy) * w + x + dx] === 1;
      }
      if (all) out.push(y * w + x);
    }
  }
  return out;
}

/**
 * Samples of up to `count` of the wholly shaded pixels (at random, seeded), each its centre's
 * surface with its bounce through SHADE_RAYS_FACTOR x HEMISPHERE_RAYS directions
 * (phonepool.js sampleAt; its patch the centre alone: it is read alone).
 * @param {number[]} pixels whollyShadedPixels' indices
 * @returns {object[]} samples as phonepool.js poolForPose's, with shade: true
 */
export function shadeSamples(proxies, hits, pixels, count, seed, farAlbedo) {
  const pick = pixels.slice();
  const rand = mulberry32(seed + 5);
  const n = Math.min(count, pick.length);
  for (let i = 0; i < n; i++) { // a seeded partial shuffle: the first n at random
    const j = i + Math.floor(rand() * (pick.length - i));
    [pick[i], pick[j]] = [pick[j], pick[i]];
  }
  const jitter = mulberry32(seed + 6);
  return pick.slice(0, n).sort((p, q) => p - q).map((k) => {
    const point = [0, 1, 2].map((c) => hits.point[3 * k + c]);
    const s = sampleAt(proxies, k % hits.w, Math.floor(k / hits.w), hits.tri[k], point, [point],
      SHADE_RAYS_FACTOR * HEMISPHERE_RAYS, jitter, farAlbedo);
    s.shade = true;
    return s;
  });
}
