// The phone's own estimate of the sun and the sky from its camera picture (issue 16; after
// Jensen, Andersen & Madsen 2006, as the server's server/sceneestimate.py, whose model this
// follows): with no server sky (offline, a site without cameras, or ?sky=phone), camera mode
// lights the hall with what this reads from the picture. docs/web.md, "The phone's own light".
//
// A Lambertian surface of albedo rho seen by the camera has the radiance
//   L = rho / pi * (E_sun (cos_i in_sun + B_sun) + k (S + B_sky))
// E_sun the sun's normal irradiance, k the sky's horizontal irradiance, S the model sky's
// irradiance on the point per unit k over the directions it sees open sky, B one bounce off the
// surfaces it sees instead (sunlit where the sun reaches them; lit by the model sky on their
// own tilt, phonepool.js skyBounceTerms; an isotropic sky's in the isotropic column). Linear in
// (E_sun, k): a few hundred pixels of the build's real proxies and ground, some in sun and
// some in shadow, give both; people and wrong pixels are outliers of a robust
// fit (RANSAC, then IRLS with Tukey's biweight on relative residuals, as server/robustfit.py).
// As on the server, a pixel's in_sun is the share of the 3 x 3 about it in sun, and a sun the
// fit finds is kept only if pairs of pixels across the model's shadow edges show it
// (shadowpairs.js).
//
// A phone's camera is not calibrated: its exposure and gain are unknown, so the fit's absolute
// level is in the picture's units. What it must get right is the sun/sky ratio and the sky's
// shape (skyshape.js: a CIE sky of the type the ratio gives, server/skyshape.py's rule,
// blended with an isotropic sky by a share fitted and followed across estimates; under a
// clear sky then Perez's all-weather sky for the clearness that fit measured, perezsky.js,
// fitted once more and taken whole, as the server's); the level is set to a nominal one
// (NOMINAL_GLOBAL_W_M2) and the picture meter (picturemeter.js) exposes the hall at the
// picture's level, which removes any common scale.
//
// Costs: what depends on the pose (the pool of pixels, their surfaces, their open sky on a
// fixed grid and their bounce rays: phonepool.js) is computed again only when the pose moved
// (POSE_TOLERANCE_*); what depends on the sun when it moved; an estimate reads its share of
// the pool's pixels and solves a small robust fit (robustfit.js), two more under a clear sky
// (the Perez sky's terms again when its state moved). The rays are cast against the proxies'
// triangles by proxyrays.js.
// Directions: site-frame unit vectors (+X east, +Y up, -Z north); irradiances W/m^2.
import * as THREE from 'three';
import { LINEAR_OF_CODE, luminance } from './colour.js';
import { perezState } from './perezsky.js';
import { dot, mulberry32, poolForPose, skyBounceTerms, skyTerms, sunTerms } from './phonepool.js';
import { MIN_TOP_UP, SHADE_TARGET, shadeSamples, viewHits, whollyShadedPixels } from './phoneshade.js';
import { registerShift } from './poseregister.js';
import { Proxies } from './proxyrays.js';
import { robustFit } from './robustfit.js';
import { pairSunRatio, shadowPairs } from './shadowpairs.js';
import { CLEAR_TYPE, OVERCAST_TYPE, skyClearness, skyTypeForRatio, unitSky } from './skyshape.js';

// (the pool's and the sky shape's parts, from their modules, for the Node cases)
export { PATCH_PX, POOL_SIZE, poolForPose, sunTerms } from './phonepool.js';
export { skyClearness, skyTypeForRatio, unitSky } from './skyshape.js';

/** The estimated copy of the picture, pixels (w, h). At 192 x 108 a shadow a metre wide ten
 * metres off (the demo's kiosk view: its tree's shadow at 9:30) was one or two pixels high:
 * a few dozen pool pixels mostly in shade, and a sky that moved by up to 27 % from one pool
 * of pixels to the next; at twice that, up to 13 %, median 3-5 % (docs/benchmarks.md, "The
 * phone's copy at 384 x 216"). */
export const ESTIMATE_SIZE = [384, 216];
/** A new estimate at most this often, seconds (the sky changes over minutes; a phone's CPU). */
export const ESTIMATE_PERIOD_S = 2;
const MIN_SAMPLES = 30; // fewer usable pixels: no estimate
const MIN_SUNLIT = 10; // fewer sunlit ones: the sun cannot be told from the sky
// Fewer usable pixels mostly in shadow (a share in sun below 0.5): no estimate, the sky cannot
// be told from the sun. The server has no such floor: its 3 x 3 patches at 320 x 180 find a few
// on a shadow one or two pixels high; the phone's copy of the same view finds none, and without
// the share in sun it took those pixels for shade and read a sky twice too bright.
const MIN_SHADED = 10;
const CLIP_CODE = 250; // a pixel with a channel at or above this code is clipped
const DARK_CODE = 3;
const POSE_TOLERANCE_DEG = 1.0;
const POSE_TOLERANCE_M = 0.2;
const SUN_TOLERANCE_DEG = 0.1;
// The shadow-edge pairs' check (shadowpairs.js): a sun the pairs read below PAIR_FLOOR of the
// sky is dropped (the server's pair_floor). The server pairs patches less than 12 px apart at
// 320 x 180 through 75 degrees (3.3 degrees at the centre); camera mode's 60-degree vertical
// field over the copy's 216 rows has 187 px per radian there, so the same angle is 10.8 px: 11.
export const PAIR_FLOOR = 0.05;
export const PAIR_RADIUS_PX = 11;
/** The pairs' radius for a copy `heightPx` rows high, pixels: PAIR_RADIUS_PX at ESTIMATE_SIZE,
 * the same angle at another size (the benchmarks' baseline copy, the Node cases' views). */
export function pairRadiusPx(heightPx) {
  return Math.round(PAIR_RADIUS_PX * heightPx / ESTIMATE_SIZE[1]);
}
const SHARE_MEMORY = 0.8; // per estimate, the weight of the past in the model sky's share
/** The level the estimate is scaled to: a sun and sky giving this on open ground. */
export const NOMINAL_GLOBAL_W_M2 = 500;

/** Reads a camera picture and estimates its sun and sky (camera mode without a server sky). */
export class PhoneEstimator {
  /**
   * @param {THREE.Mesh[]} meshes the real proxies and the ground (site.js nodes.real, .ground)
   * @param {number[]} farAlbedo the build's ground albedo (manifest.ground.albedo)
   */
  constructor(meshes, farAlbedo) {
    this.proxies = new Proxies(meshes);
    this.farAlbedo = farAlbedo;
    this.pool = null;
    this._pose = null;
    this._sun = null;
    this._sunTerms = null; // the pool's (register, the pairs)
    this._hits = null; // what each pixel of the copy sees (phoneshade.js viewHits), per pose
    this._shade = []; // the shade top-up's samples for this sun (phoneshade.js)
    this.samples = []; // the pool, then the top-up: what an estimate reads (indices: rows)
    this._terms = []; // their sun terms
    this._pairs = null; // the pool's shadow-edge pairs for this sun (shadowpairs.js)
    this._skies = new Map();
    this._share = new Map(); // per sky type, the model sky's share (the rest isotropic)
    this.rand = null; // the estimate's random draws, seeded afresh for each view (_poolFor)
    this.last = null; // the last estimate
    this.registerPose = true; // poseregister.js (benchmarks switch it off for a baseline)
    this.poolSeed = 1; // the pool's random draws (phonepool.js; benchmarks vary it)
    this.perezClear = true; // the clear sky's Perez fit (benchmarks switch it off for a baseline)
    // The shade top-up (phoneshade.js), off: measured on the demo's 40-light draft, at the
    // copy's 192 x 108 it read the kiosk view's clear sky at 9:30 higher (6 of 18 estimates
    // within 10 % against 8 without) and let an overcast sun through there (38-40 % of the
    // sky in 3 of 18), though it helped the visitor centre's clear sky (docs/benchmarks.md, "The
    // phone's bounce surfaces on their tilt, and its shade top-up"); debug.phoneEstimateParts switches it on for the benchmarks.
    this.shadeTopUp = false;
    this.bounceOnTilt = true; // bounce surfaces lit by the model sky on their tilt (else isotropic)
  }

  /** The view was turned (its registration): the next estimate makes the pool of the new pose,
   * however small the turn (a pool kept from the pose before would register the picture
   * against that pose, and the turn would be counted twice). */
  forgetPose() {
    this._pose = null;
  }

  _poolFor(camera, w, h) {
    camera.updateMatrixWorld();
    const m = camera.matrixWorld.clone();
    const p = this._pose;
    const moved = !p || new THREE.Vector3().setFromMatrixPosition(m).distanceTo(new THREE.Vector3().setFromMatrixPosition(p.m)) > POSE_TOLERANCE_M
      || new THREE.Quaternion().setFromRotationMatrix(m).angleTo(new THREE.Quaternion().setFromRotationMatrix(p.m)) > POSE_TOLERANCE_DEG * Math.PI / 180
      || Math.abs(camera.fov - p.fov) > 0.01 || Math.abs(camera.aspect - p.aspect) > 0.001 || w !== p.w || h !== p.h;
    if (moved) {
      // A new view starts afresh: its pool, its random draws and its followed shares depend on
      // the pose alone, not on how many views or estimates came before (a test's result must
      // not depend on how many estimates the machine managed before the pose was set).
      this.pool = poolForPose(this.proxies, camera, w, h, this.farAlbedo, this.poolSeed);
      this._pose = { m, fov: camera.fov, aspect: camera.aspect, w, h, 
        // the pose as the pool saw it, for the top-up's view (what Vector3.unproject reads)
        view: { matrixWorld: m, projectionMatrixInverse: camera.projectionMatrixInverse.clone() } };
      this._hits = null;
      this._sun = null;
      this._share.clear();
      this.rand = mulberry32(7);
    }
    return this.pool;
  }

  _termsFor(sun) {
    if (!this._sun || dot(this._sun, sun) < Math.cos(SUN_TOLERANCE_DEG * Math.PI / 180)) {
      this._sunTerms = sunTerms(this.proxies, this.pool, sun);
      this._pairs = shadowPairs(this.pool, this._sunTerms.map((t) => t.share), sun, { radiusPx: pairRadiusPx(this._pose.h) });
      this._shade = this._topUp(sun);
      this.samples = this.pool.concat(this._shade);
      this._terms = this._sunTerms.concat(sunTerms(this.proxies, this._shade, sun));
      this._skies.clear();
      this._sun = sun.slice();
    }
    return this._sunTerms;
  }

  /** The pool's shade topped up for this sun (phoneshade.js; server/sceneestimate.py): where
   * fewer than SHADE_TARGET of its samples are mostly in shadow, as many more single pixels
   * wholly in the model's shadow as the view has, up to SHADE_TARGET in all. */
  _topUp(sun) {
    const need = SHADE_TARGET - this._sunTerms.filter((t) => t.share < 0.5).length;
    if (!this.shadeTopUp || need <= 0) return [];
    const { view, w, h } = this._pose;
    this._hits ??= viewHits(this.proxies, view, w, h);
    const pixels = whollyShadedPixels(this.proxies, this._hits, sun);
    if (pixels.length < MIN_TOP_UP) return [];
    return shadeSamples(this.proxies, this._hits, pixels, need, this.poolSeed, this.farAlbedo);
  }

  /** The model sky of CIE type `type` (or with `perez` = [clearness, brightness] Perez's
   * all-weather sky of that state) and its terms per pool sample; kept while the sun holds
   * (the Perez sky's while its state does too). */
  _skyFor(type, sun, perez = null) {
    const key = perez ? `perez ${perez[0]} ${perez[1]}` : type;
    if (!this._skies.has(key)) {
      if (perez) for (const k of this._skies.keys()) if (typeof k === 'string') this._skies.delete(k);
      const sky = unitSky(type, sun, perez);
      // the bounce surfaces lit by this sky on their tilt (or, switched off, by an isotropic
      // sky on it: the estimate before 2026-12-06, which read the clear sky 7-9 % low)
      const bounce = this.bounceOnTilt ? skyBounceTerms(this.samples, sky, this.proxies.tilts)
        : this._terms.map((t) => t.bSky);
      this._skies.set(key, { sky, terms: skyTerms(this.samples, sky), bounce });
    }
    return this._skies.get(key);
  }

  /** Sample indices (the pool's, then the top-up's), as many mostly in sun (share from 0.5) as mostly in shadow where the pool
   * has them (the shadowed ones are what tells the sky from the sun; a view of mostly sunlit
   * ground would otherwise let the sunlit majority set the fit, server/sceneestimate.py's
   * _pick). */
  _balanced(terms) {
    const lit = [];
    const shade = [];
    terms.forEach((t, i) => (t.share >= 0.5 ? lit : shade).push(i));
    const [small, large] = lit.length < shade.length ? [lit, shade] : [shade, lit];
    const take = Math.max(small.length, MIN_SAMPLES);
    for (let i = large.length - 1; i > 0; i--) { // a seeded shuffle of the larger group
      const j = Math.floor(this.rand() * (i + 1));
      [large[i], large[j]] = [large[j], large[i]];
    }
    return [...small, ...large.slice(0, take)];
  }

  /**
   * The pose registered on the picture (poseregister.js): the shift that puts the model's sun
   * and shade on the picture's, and the camera's turn that would put the model there. Alone
   * where a server sky lights the hall (the view still follows the picture); the estimate's
   * first step otherwise, which reads the pool's pixels at the shift. Arguments as
   * estimate()'s.
   * @returns {{dx, dy, fisher, fisherAtZero, turnDeg}} (registerShift; no shift when
   *   registerPose is off)
   */
  register(rgba, w, h, camera, sun) {
    const pool = this._poolFor(camera, w, h);
    const terms = this._termsFor(sun);
    return this.registerPose
      ? registerShift(rgba, w, h, pool, terms.map((t) => t.litCentre), camera.fov,
        { clipCode: CLIP_CODE, darkCode: DARK_CODE })
      : { dx: 0, dy: 0, fisher: NaN, fisherAtZero: NaN, turnDeg: [0, 0] };
  }

  /**
   * One estimate.
   * @param {Uint8ClampedArray} rgba (h, w, 4) sRGB codes of the picture, rows from the top
   * @param {number} w
   * @param {number} h
   * @param {THREE.Camera} camera the pose the picture was taken with
   * @param {number[]} sun unit site direction toward the sun
   * @returns {object|null} {sunNormal: RGB, skyHorizontal: RGB (picture units x pi), ratio
   *   (luminance E_sun / k), skyType, used, sunlit, inlierFraction, pool, shiftPx (the
   *   registration's [dx, dy], pixels of the copy), turnDeg (the camera's turn that puts the
   *   model on the picture: [left, up], degrees), fisher, fisherAtZero, pairs (the pose's
   *   shadow-edge pairs), pairRatio (the sun they read over the sky; null: no check)}; null
   *   when the picture has too few usable pixels of known surfaces, or too few in shadow, or
   *   when the sky's type does not settle (the last fit's ratio gives another type: no shape
   *   is borne out, the sun cannot be told from the sky)
   */
  estimate(rgba, w, h, camera, sun) {
    const shift = this.register(rgba, w, h, camera, sun);
    const pool = this.pool;
    const terms = this._terms;
    const values = [];
    const rows = [];
    for (const i of this._balanced(terms)) {
      const v = readPixel(rgba, w, h, this.samples[i], shift);
      if (v === null) continue;
      values.push(v);
      rows.push(i);
    }
    // what the last estimate read (debug.js phoneEstimateWhy: why none was made)
    this.why = { used: rows.length, shaded: rows.filter((i) => terms[i].share < 0.5).length,
      topUp: rows.filter((i) => this.samples[i].shade).length, shadeSamples: this._shade.length, types: [] };
    if (rows.length < MIN_SAMPLES || this.why.shaded < MIN_SHADED) {
      this.last = null;
      return null;
    }
    const sunlit = rows.filter((i) => terms[i].cosI > 0.05).length;
    let type = CLEAR_TYPE;
    let fit = null;
    let settled = false;
    for (let iteration = 0; iteration < 3 && !settled; iteration++) {
      fit = this._fit(type, rows, values, sun, sunlit);
      const next = skyTypeForRatio(luma(fit.sun) / Math.max(luma(fit.sky), 1e-12), sun[1]);
      this.why.types.push([type, luma(fit.sun) / Math.max(luma(fit.sky), 1e-12)]);
      settled = next === type;
      type = next;
    }
    if (!settled) {
      this.last = null;
      return null;
    }
    // Under a clear sky the shape is Perez's all-weather sky for the state the CIE clear sky's
    // fit measured (its clearness from the sun/sky ratio; server/sceneestimate.py), fitted
    // again with it, once, and taken whole (share 1): the CIE clear sky is one fixed shape,
    // which put a shaded north wall 0.47-0.54 of the horizontal irradiance where the
    // all-weather sky gives 0.56-0.60 (docs/server.md)
    if (this.perezClear && type === CLEAR_TYPE && Math.max(...fit.sun) > 0) {
      const ratio = luma(fit.sun) / Math.max(luma(fit.sky), 1e-12);
      fit = this._fit(type, rows, values, sun, sunlit, true, perezState(skyClearness(ratio, sun[1]), ratio, sun[1]));
    }
    // The sky model's errors read as sun; the shadow edges alone say whether there is one
    // (shadowpairs.js; the server's pair_floor)
    let pairRatio = null;
    if (Math.max(...fit.sun) > 0) {
      pairRatio = pairSunRatio(this, rgba, w, h, shift, sun, fit.sky);
      if (pairRatio !== null && pairRatio < PAIR_FLOOR) fit = this._fit(OVERCAST_TYPE, rows, values, sun, sunlit, false);
    }
    const inliers = fit.weights.filter((x) => x > 0.5).length;
    this.last = {
      sunNormal: fit.sun, skyHorizontal: fit.sky, ratio: luma(fit.sun) / Math.max(luma(fit.sky), 1e-12),
      skyType: fit.type, perez: fit.perez, modelShare: fit.share, used: rows.length, sunlit, inlierFraction: inliers / rows.length, pool: pool.length,
      shiftPx: [shift.dx, shift.dy], turnDeg: shift.turnDeg, fisher: shift.fisher, fisherAtZero: shift.fisherAtZero,
      pairs: this._pairs.shaded.length, pairRatio, topUp: rows.filter((i) => i >= pool.length).length,
    };
    return this.last;
  }

  /** The robust fit (robustfit.js) of the samples `rows` (pool indices) and their linear
   * `values` with the sky's shape of CIE type `type` (blended with an isotropic sky by a share
   * followed across estimates), or with `perez` that Perez sky whole; without a sun where
   * allowSun is false. */
  _fit(type, rows, values, sun, sunlit, allowSun = true, perez = null) {
    const samples = this.samples;
    const terms = this._terms;
    const { terms: sky, bounce } = this._skyFor(type, sun, perez);
    const sunCol = rows.map((i) => [0, 1, 2].map((c) => (sunlit < MIN_SUNLIT ? 0
      : samples[i].albedo[c] * (terms[i].cosI + terms[i].bSun[c]) / Math.PI)));
    const skyCol = rows.map((i) => [0, 1, 2].map((c) => samples[i].albedo[c] * (sky[i] + bounce[i][c]) / Math.PI));
    // the isotropic part of the sky: the sky view factor (Perez and Hay-Davies split the
    // sky the same way), its bounce surfaces lit by an isotropic sky; its share beside the
    // model's is followed across estimates
    const isoCol = rows.map((i) => [0, 1, 2].map((c) => samples[i].albedo[c] * (samples[i].skyView + terms[i].bSky[c]) / Math.PI));
    // the top-up's single shaded pixels: their own residual scale (robustfit.js groups)
    const groups = rows.map((i) => (samples[i].shade ? 1 : 0));
    const previous = this._share.get(type);
    const follow = perez ? () => 1
      : (share) => (previous === undefined ? share : SHARE_MEMORY * previous + (1 - SHARE_MEMORY) * share);
    const fit = robustFit(values, sunCol, skyCol, isoCol, this.rand, type === OVERCAST_TYPE, follow, allowSun, groups);
    if (!perez) this._share.set(type, fit.share);
    fit.type = type;
    fit.perez = perez;
    return fit;
  }

  /** Sample i's pixel of the picture at the registration's shift, linear RGB; null where
   * it falls outside the picture or is clipped (a channel at CLIP_CODE or more) or black. */
  readSample(rgba, w, h, i, shift) {
    return readPixel(rgba, w, h, this.samples[i], shift);
  }

  /**
   * The estimate as the light the client draws (the server's layout, lightstream.js): the
   * sky's patch radiances (n x 3, W/(m^2 sr)) and the sun, scaled to NOMINAL_GLOBAL_W_M2.
   * @param {object[]} lights the manifest's dome lights (centroid, cosine_weighted_sr)
   * @param {number[]} sun unit direction
   * @returns {{rgb: Float32Array, sun: {direction, normalIrradiance, source, estimated}}}
   */
  lightVector(estimate, lights, sun) {
    const { rel, toUnit } = unitSky(estimate.skyType, sun, estimate.perez);
    const share = estimate.modelShare;
    const raw = lights.map((l) => (l.centroid[1] > 0 ? share * rel(l.centroid) * toUnit + (1 - share) / Math.PI : 0));
    const open = raw.reduce((s, v, i) => s + v * lights[i].cosine_weighted_sr, 0);
    const up = Math.max(sun[1], 0);
    const global = luma(estimate.skyHorizontal) + luma(estimate.sunNormal) * up;
    const scale = global > 0 ? NOMINAL_GLOBAL_W_M2 / global : 0;
    const rgb = new Float32Array(3 * lights.length);
    raw.forEach((v, i) => {
      for (let c = 0; c < 3; c++) rgb[3 * i + c] = v / open * estimate.skyHorizontal[c] * scale;
    });
    return {
      rgb,
      sun: { direction: sun.slice(), normalIrradiance: estimate.sunNormal.map((e) => e * scale), source: 'phone', estimated: true },
    };
  }
}

// ------------------------------------------------------------------------------ small helpers

/** A pool sample's pixel of the picture at the registration's shift, linear RGB; null where it
 * falls outside the picture or is clipped (a channel at CLIP_CODE or more) or black. */
function readPixel(rgba, w, h, sample, shift) {
  const x = sample.x + shift.dx;
  const y = sample.y + shift.dy;
  if (x < 0 || y < 0 || x >= w || y >= h) return null;
  const k = 4 * (y * w + x);
  const codes = [rgba[k], rgba[k + 1], rgba[k + 2]];
  if (Math.max(...codes) >= CLIP_CODE || Math.min(...codes) < DARK_CODE) return null;
  return codes.map((v) => LINEAR_OF_CODE[v]);
}

function luma(rgb) {
  return luminance(rgb[0], rgb[1], rgb[2]);
}
