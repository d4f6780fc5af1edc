// The robust fit of the phone's own estimate (phoneestimate.js; issue 16): a few
// non-negative unknowns from a few hundred samples with outliers (people, wrong pixels, what
// the model gets wrong), as server/robustfit.py and server/sceneestimate.py solve it. RANSAC
// on the channel sum for the first inliers, iteratively reweighted least squares with Tukey's
// biweight on residuals relative to the fit, and an exact non-negative least squares for up to
// three columns (every subset's normal equations). Shapes: n samples; columns are arrays (n,).

/** Overcast: the sun is kept only if the sunlit samples are this much brighter than the
 * shaded ones against the sky alone. */
export const SUN_CONTRAST = 0.15;

/**
 * Fit the sun and the sky to the samples' linear RGB values (server/sceneestimate.py's solve):
 * the inliers by RANSAC on the channel sum (sun and model sky), IRLS with Tukey's biweight on
 * the sum with three columns (sun, model sky, isotropic sky) for the weights and the model
 * sky's share, then each channel's sun and sky (the two skies blended by that share) with
 * those weights. Under the overcast type the sun is kept only when it halves the residual.
 * @param {number[][]} values (n, 3) linear RGB
 * @param {number[][]} sunCol (n, 3) radiance per unit sun normal irradiance
 * @param {number[][]} skyCol (n, 3) radiance per unit horizontal irradiance of the model sky
 * @param {number[][]} isoCol (n, 3) the same of an isotropic sky
 * @param {(share: number) => number} follow the model share to use given this fit's (kept
 *   across estimates by the caller: one picture's samples determine it poorly)
 * @param {boolean} [allowSun] false: the sky alone (the shadow-edge pairs read no sun,
 *   shadowpairs.js), fitted as under the overcast test
 * @param {number[]|null} [groups] (n) 0 or 1: samples of group 1 (the single pixels of the
 *   shade top-up, phoneshade.js) start as inliers and have their own residual scale (as
 *   server/shapefit.py: judged on the pool's scale nearly all of them were dropped and the
 *   few kept set the sky)
 * @returns {{sun: number[], sky: number[], weights: number[], share: number}}
 */
export function robustFit(values, sunCol, skyCol, isoCol, rand, overcast = false, follow = (x) => x, allowSun = true, groups = null) {
  const sum = (r) => r[0] + r[1] + r[2];
  const a = sunCol.map(sum);
  const c = skyCol.map(sum);
  const u = isoCol.map(sum);
  const y = values.map(sum);
  const group = groups ?? y.map(() => 0);
  const inliers = ransacInliers(a, c, y, rand).map((ok, i) => (ok || group[i] === 1 ? 1 : 0));
  const { x, w } = irls([a, c, u], y, inliers, group);
  const share = follow(x[1] + x[2] > 0 ? x[1] / (x[1] + x[2]) : 1);
  const blend = skyCol.map((r, i) => r.map((v, ch) => share * v + (1 - share) * isoCol[i][ch]));
  const sun = [0, 0, 0];
  const sky = [0, 0, 0];
  const channel = (cols, ch) => cols.map((r) => r[ch]);
  for (let ch = 0; ch < 3; ch++) {
    [sun[ch], sky[ch]] = nonneg([channel(sunCol, ch), channel(blend, ch)], channel(values, ch), w);
  }
  if (overcast || !allowSun) {
    // Under heavy cloud sunlit and shadowed surfaces look alike (Jensen et al.): the sun is
    // kept only when, against the sky alone (fitted with its own outliers), the samples the
    // sun would reach are brighter than the shaded ones by more than SUN_CONTRAST. (A test on
    // the residuals with the sun's fit's weights favours the sun: the shaded samples the sky
    // model gets wrong are that fit's outliers, and a small sun then fits the rest.)
    const b = blend.map(sum);
    const { w: w2 } = irls([b], y, inliers.map(() => 1), group);
    const skyOnly = [0, 1, 2].map((ch) => nonneg([channel(blend, ch)], channel(values, ch), w2)[0]);
    const q = y.map((v, i) => v / Math.max([0, 1, 2].reduce((t, ch) => t + skyOnly[ch] * blend[i][ch], 0), 1e-12));
    const top = Math.max(...a);
    const lit = median(q.filter((_, i) => a[i] > 0.25 * top));
    const shade = median(q.filter((_, i) => a[i] <= 0.25 * top));
    if (!allowSun || !(lit > (1 + SUN_CONTRAST) * shade)) {
      sun.fill(0);
      sky.splice(0, 3, ...skyOnly);
      return { sun, sky, weights: w2, share };
    }
  }
  return { sun, sky, weights: w, share };
}


/** IRLS with Tukey's biweight on residuals relative to the fit (server/robustfit.py):
 * y ~ sum_j x_j cols[j], x >= 0, from the weights w0; returns x and the final weights. Each
 * of `groups`' (n) values has its own residual scale (the median absolute deviation of its
 * samples'), so that one group's noise does not make the other's samples outliers. */
function irls(cols, y, w0, groups = null, iterations = 12, tukey = 4.685) {
  let w = w0.slice();
  let x = cols.map(() => 0);
  const group = groups ?? y.map(() => 0);
  const names = [...new Set(group)];
  const floor = 1e-9 + 0.02 * median(y.map(Math.abs));
  for (let it = 0; it < iterations; it++) {
    x = nonneg(cols, y, w);
    const rel = y.map((v, i) => {
      const fit = cols.reduce((s, col, j) => s + col[i] * x[j], 0);
      return (v - fit) / Math.max(Math.abs(fit), floor);
    });
    const scales = new Map(names.map((g) => {
      const good = rel.filter((_, i) => w[i] > 0 && group[i] === g).map(Math.abs);
      return [g, Math.max(good.length ? 1.4826 * median(good) : 1, 0.01)];
    }));
    w = rel.map((r, i) => {
      const t = r / (tukey * scales.get(group[i]));
      return Math.abs(t) < 1 ? (1 - t * t) ** 2 : 0;
    });
  }
  return { x, w };
}

/** Weighted non-negative least squares of y ~ sum_j x_j cols[j] for a few columns (at most
 * 3): the normal equations on every subset of the columns, the feasible solution with the
 * least residual (exact for so few unknowns, as scipy's NNLS). */
function nonneg(cols, y, w) {
  const p = cols.length;
  const gram = cols.map((ci) => cols.map((cj) => ci.reduce((s, v, k) => s + w[k] * v * cj[k], 0)));
  const rhs = cols.map((ci) => ci.reduce((s, v, k) => s + w[k] * v * y[k], 0));
  let best = new Array(p).fill(0);
  let bestR = residual(cols, y, w, best);
  for (let mask = 1; mask < 1 << p; mask++) {
    const idx = [...Array(p).keys()].filter((j) => mask & (1 << j));
    const sol = solveSmall(idx.map((i) => idx.map((j) => gram[i][j])), idx.map((i) => rhs[i]));
    if (!sol || sol.some((v) => !(v >= 0))) continue;
    const x = new Array(p).fill(0);
    idx.forEach((j, k) => { x[j] = sol[k]; });
    const r = residual(cols, y, w, x);
    if (r < bestR) {
      bestR = r;
      best = x;
    }
  }
  return best;
}

/** Gaussian elimination with partial pivoting of a small system; null when singular. */
function solveSmall(m, b) {
  const n = b.length;
  const a = m.map((row, i) => [...row, b[i]]);
  const scale = Math.max(...a.map((row) => Math.max(...row.slice(0, n).map(Math.abs))), 1e-300);
  for (let c = 0; c < n; c++) {
    let piv = c;
    for (let r = c + 1; r < n; r++) if (Math.abs(a[r][c]) > Math.abs(a[piv][c])) piv = r;
    if (Math.abs(a[piv][c]) < 1e-12 * scale) return null;
    [a[c], a[piv]] = [a[piv], a[c]];
    for (let r = 0; r < n; r++) {
      if (r === c) continue;
      const f = a[r][c] / a[c][c];
      for (let k = c; k <= n; k++) a[r][k] -= f * a[c][k];
    }
  }
  return a.map((row, i) => row[n] / row[i]);
}

function residual(cols, y, w, x) {
  let s = 0;
  for (let i = 0; i < y.length; i++) {
    let fit = 0;
    for (let j = 0; j < cols.length; j++) fit += cols[j][i] * x[j];
    s += w[i] * (y[i] - fit) ** 2;
  }
  return s;
}

/** The inliers (within 8 % relative) of the best of 150 two-sample fits, one sample with sun
 * and one without (server/robustfit.py ransac_fit), and of the no-sun hypotheses. */
function ransacInliers(a, c, y, rand, hypotheses = 150, tolerance = 0.08) {
  const top = Math.max(...a);
  const all = y.map((_, i) => i);
  let sunny = top > 0 ? all.filter((i) => a[i] > 0.25 * top) : all;
  let shade = top > 0 ? all.filter((i) => a[i] <= 0.25 * top) : all;
  if (!sunny.length || !shade.length) sunny = shade = all;
  let best = null;
  let bestCount = -1;
  const pick = (list) => list[Math.floor(rand() * list.length)];
  for (let h = 0; h < 2 * hypotheses; h++) {
    const j = pick(shade);
    let x1 = 0;
    let x2 = y[j] / Math.max(c[j], 1e-12);
    if (h < hypotheses) {
      const i = pick(sunny);
      const det = a[i] * c[j] - a[j] * c[i];
      if (Math.abs(det) < 1e-12) continue;
      x1 = Math.max((y[i] * c[j] - y[j] * c[i]) / det, 0);
      x2 = Math.max((a[i] * y[j] - a[j] * y[i]) / det, 0);
    }
    let count = 0;
    const inside = y.map((v, k) => {
      const fit = x1 * a[k] + x2 * c[k];
      const ok = Math.abs(v - fit) <= tolerance * Math.max(fit, 1e-9);
      count += ok;
      return ok;
    });
    if (count > bestCount) {
      bestCount = count;
      best = inside;
    }
  }
  return best;
}


/** The median of an array (the upper one of an even count). */
export function median(v) {
  if (!v.length) return 0;
  const s = v.slice().sort((p, q) => p - q);
  return s[s.length >> 1];
}
