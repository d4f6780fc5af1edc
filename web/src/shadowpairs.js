// The sun read across shadow edges alone, as a check on the phone's own estimate
// (phoneestimate.js; issue 16): server/shadowpairs.py's rules, for the phone's pool.
//
// Under an overcast sky whatever the sky model gets wrong that differs between sunlit and
// shadowed surfaces is read as sun. Two patches of the same plane a few pixels apart, one
// wholly in the model's shadow and one wholly in sun, see nearly the same sky: the difference
// of their radiances is the sun's, and the sky model enters only through the small difference
// of their sky terms. A pair is:
// - a shaded patch (sun share 0) of a surface that faces the sun (a cast shadow, not the
//   surface's own back),
// - a sunlit patch (sun share 1) of the same surface (the same stated albedo) and plane less
//   than radiusPx pixels away,
// - whose sky views differ by at most maxSkyViewDiff.
// Shapes: m pool samples; P pairs. Directions are site-frame unit vectors.

/** Fewer usable pairs: no check (the view shows too little shadow for it). */
export const MIN_PAIRS = 8;
/** The CIE sky of the pairs' small sky differences (server/shadowpairs.py PAIR_SKY_TYPE). */
export const PAIR_SKY_TYPE = 2;

/**
 * Pairs of pool samples across the model's shadow edges (server/shadowpairs.py shadow_pairs).
 * @param {object[]} samples (m) {x, y: pixel; point: metres; normal: unit; albedo: RGB (the
 *   surface: the same stated albedo); skyView: cosine-weighted open-sky fraction}
 * @param {number[]} sunShare (m) the share of each sample's patch in sun (0 to 1)
 * @param {number[]} sun unit direction toward the sun
 * @param {object} [options] radiusPx (pixels), maxSkyViewDiff, perShaded (each shaded patch
 *   is paired with up to this many of the nearest sunlit ones that qualify)
 * @returns {{shaded: number[], lit: number[]}} pool indices (P) of each pair's two samples
 */
export function shadowPairs(samples, sunShare, sun, { radiusPx = 12, maxSkyViewDiff = 0.1, perShaded = 3 } = {}) {
  const facing = (s) => dot(s.normal, sun) > 0.05;
  const shaded = [];
  const lit = [];
  samples.forEach((s, i) => {
    if (sunShare[i] === 0 && facing(s)) shaded.push(i);
    if (sunShare[i] === 1) lit.push(i);
  });
  const out = { shaded: [], lit: [] };
  const k = Math.min(lit.length, 4 * perShaded);
  for (const i of shaded) {
    const a = samples[i];
    // the k nearest sunlit samples closer than the radius, nearest first (as the server's
    // KD-tree query with its distance bound, which is strict)
    const near = [];
    for (const j of lit) {
      const d = Math.hypot(samples[j].x - a.x, samples[j].y - a.y);
      if (d < radiusPx) near.push([d, j]);
    }
    near.sort((p, q) => p[0] - q[0] || p[1] - q[1]);
    let taken = 0;
    for (const [, j] of near.slice(0, k)) {
      if (taken >= perShaded) break;
      const b = samples[j];
      const offPlane = Math.abs((b.point[0] - a.point[0]) * a.normal[0] + (b.point[1] - a.point[1]) * a.normal[1]
        + (b.point[2] - a.point[2]) * a.normal[2]);
      if (sameAlbedo(a.albedo, b.albedo) && dot(a.normal, b.normal) > 0.999 && offPlane < 0.02
        && Math.abs(a.skyView - b.skyView) <= maxSkyViewDiff) {
        out.shaded.push(i);
        out.lit.push(j);
        taken += 1;
      }
    }
  }
  return out;
}

/**
 * The sun's normal irradiance (grey, the radiances' units x pi) the pairs read: the median over
 * pairs of (L_lit - L_shaded - (sky_lit - sky_shaded)) / (sun_lit - sun_shaded), channels summed
 * (server/shadowpairs.py pair_sun). Arguments (P, 3): the measured radiances, the model sky's
 * radiance at each sample (its bounce included), the radiance per unit sun normal irradiance.
 */
export function pairSun(radianceShaded, radianceLit, skyShaded, skyLit, sunShaded, sunLit) {
  const sum = (r) => r[0] + r[1] + r[2];
  const reads = [];
  radianceShaded.forEach((_, p) => {
    const perSun = sum(sunLit[p]) - sum(sunShaded[p]);
    if (perSun > 1e-9) {
      const contrast = sum(radianceLit[p]) - sum(radianceShaded[p]) - (sum(skyLit[p]) - sum(skyShaded[p]));
      reads.push(contrast / perSun);
    }
  });
  if (!reads.length) return 0;
  reads.sort((p, q) => p - q);
  // numpy's median: the mean of the two middle values of an even count
  const mid = reads.length >> 1;
  return reads.length % 2 ? reads[mid] : 0.5 * (reads[mid - 1] + reads[mid]);
}

/**
 * The sun a picture's shadow-edge pairs read (pairSun) over the fit's sky horizontal
 * irradiance `skyRgb` (picture units), for the estimator `est` (phoneestimate.js
 * PhoneEstimator: its pool, pairs, sun and sky terms, and readSample, which reads and skips
 * pixels as the estimate does, at the registration's `shift`): server/shadowpairs.py
 * pair_sun_ratio. The pairs' small sky differences come from the overcast sky brighter toward
 * the sun (PAIR_SKY_TYPE), the bounce surfaces lit by that sky on their tilt (as in the
 * phone's fit), with the stated albedos.
 * @returns {number|null} null with fewer than MIN_PAIRS usable pairs
 */
export function pairSunRatio(est, rgba, w, h, shift, sun, skyRgb) {
  const { shaded, lit } = est._pairs;
  if (shaded.length < MIN_PAIRS) return null;
  const pool = est.pool;
  const terms = est._sunTerms;
  const { terms: skyTerm, bounce } = est._skyFor(PAIR_SKY_TYPE, sun);
  const model = (i) => {
    const a = pool[i].albedo.map((v) => v / Math.PI);
    return {
      sky: [0, 1, 2].map((c) => a[c] * (skyTerm[i] + bounce[i][c]) * skyRgb[c]),
      sun: [0, 1, 2].map((c) => a[c] * (terms[i].cosI + terms[i].bSun[c])),
    };
  };
  const cols = [[], [], [], [], [], []]; // radiance, sky, sun: shaded and lit
  shaded.forEach((i, p) => {
    const read = [i, lit[p]].map((j) => est.readSample(rgba, w, h, j, shift));
    if (read.includes(null)) return;
    const [s, l] = [i, lit[p]].map(model);
    [read[0], read[1], s.sky, l.sky, s.sun, l.sun].forEach((v, k) => cols[k].push(v));
  });
  if (cols[0].length < MIN_PAIRS) return null;
  return pairSun(...cols) / Math.max((skyRgb[0] + skyRgb[1] + skyRgb[2]) / 3, 1e-12);
}

function sameAlbedo(p, q) {
  return p[0] === q[0] && p[1] === q[1] && p[2] === q[2];
}

function dot(p, q) {
  return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
}
