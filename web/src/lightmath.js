// The light vector's arithmetic, exactly as docs/compact-assets.md and docs/manifest.md state
// it. A pure module (no DOM, no WebGL): the relight pass, the HUD and the Node tests use it.
//
// r is a Float32Array or Float64Array of n x RGB, light-major (r0 g0 b0 r1 g1 b1 ...), in
// W/(m^2 sr) per light (the unit radiance the basis was baked with).

/**
 * A(r): the m lights with the largest max(r_i.R, r_i.G, r_i.B) * weight_i, ties to the lower
 * index, lights scoring 0 never. Returned in increasing index order (daylit.selection
 * .select_lights does the same). The weights are `selectionWeights(...)`.
 * @param {ArrayLike<number>} r n x 3
 * @param {ArrayLike<number>} weightsSr n
 * @param {number} m
 * @returns {number[]}
 */
export function selectLights(r, weightsSr, m) {
  const n = weightsSr.length;
  const scored = [];
  for (let i = 0; i < n; i++) {
    const score = Math.max(r[3 * i], r[3 * i + 1], r[3 * i + 2]) * weightsSr[i];
    if (score > 0) scored.push([score, i]);
  }
  scored.sort((a, b) => (b[0] - a[0]) || (a[1] - b[1]));
  return scored.slice(0, m).map((s) => s[1]).sort((a, b) => a - b);
}

/**
 * Selection weights: each light's solid angle if it can be selected (only those lights have
 * their own images), else 0 (daylit.selection.Selection.weights_sr).
 * @param {ArrayLike<number>} solidAnglesSr n
 * @param {number[] | undefined} selectable manifest compression.selectable_lights (absent:
 *   every light, as in builds made before it existed)
 * @returns {Float64Array}
 */
export function selectionWeights(solidAnglesSr, selectable) {
  const weights = Float64Array.from(solidAnglesSr);
  if (selectable === undefined || selectable === null) return weights;
  const keep = new Uint8Array(weights.length);
  for (const i of selectable) keep[i] = 1;
  for (let i = 0; i < weights.length; i++) if (!keep[i]) weights[i] = 0;
  return weights;
}

/**
 * c = V^T r' with r' = r without the selected lights: k x 3 (Float64Array, row l = c[l] RGB).
 * @param {Float32Array} V n x k row-major (row i = light i)
 * @param {number} k
 * @param {ArrayLike<number>} r n x 3
 * @param {Iterable<number>} selected lights left out of r'
 */
export function baseCoefficients(V, k, r, selected) {
  const n = V.length / k;
  const skip = new Set(selected);
  const c = new Float64Array(3 * k);
  for (let i = 0; i < n; i++) {
    if (skip.has(i)) continue;
    const rr = r[3 * i];
    const rg = r[3 * i + 1];
    const rb = r[3 * i + 2];
    if (rr === 0 && rg === 0 && rb === 0) continue;
    const row = i * k;
    for (let l = 0; l < k; l++) {
      const v = V[row + l];
      c[3 * l] += v * rr;
      c[3 * l + 1] += v * rg;
      c[3 * l + 2] += v * rb;
    }
  }
  return c;
}

/**
 * The constant-folded weights of one compact stack for the relight shader:
 * E(x) = g(x) (sum_j tex_j(x) * layerWeight_j + sum_slots tex_s(x) * slotWeight_s + constant)
 * with layerWeight_j = c[coefficient_j] * scale_j, slotWeight = r_i * scale[i][level] and
 * constant = sum_j c[coefficient_j] * offset_j + sum r_i * offset[i][level].
 * @param {object} compact the manifest's stacks.<X>.compact entry
 * @param {Float64Array} c from baseCoefficients
 * @param {ArrayLike<number>} r n x 3
 * @param {number[]} lights the selected lights whose images are used (each level one slot)
 * @returns {{layerWeights: Float32Array, slotWeights: Float32Array, constant: number[]}}
 */
export function stackWeights(compact, c, r, lights) {
  const layers = compact.layers;
  const layerWeights = new Float32Array(3 * layers.length);
  const constant = [0, 0, 0];
  layers.forEach((layer, j) => {
    const l = layer.coefficient;
    for (let ch = 0; ch < 3; ch++) {
      layerWeights[3 * j + ch] = c[3 * l + ch] * layer.scale[ch];
      constant[ch] += c[3 * l + ch] * layer.offset[ch];
    }
  });
  const levels = compact.lights.ktx2.length;
  const slotWeights = new Float32Array(3 * levels * lights.length);
  lights.forEach((i, s) => {
    for (let level = 0; level < levels; level++) {
      const scale = compact.lights.scale[i][level];
      const offset = compact.lights.offset[i][level];
      for (let ch = 0; ch < 3; ch++) {
        slotWeights[3 * (s * levels + level) + ch] = r[3 * i + ch] * scale[ch];
        constant[ch] += r[3 * i + ch] * offset[ch];
      }
    }
  });
  return { layerWeights, slotWeights, constant };
}

/** Irradiance on an open, upward surface: sum_i r_i cosine_weighted_sr_i (RGB, W/m^2). */
export function openSkyIrradiance(r, cosineWeightedSr) {
  const e = [0, 0, 0];
  for (let i = 0; i < cosineWeightedSr.length; i++) {
    for (let ch = 0; ch < 3; ch++) e[ch] += r[3 * i + ch] * cosineWeightedSr[i];
  }
  return e;
}

/**
 * The sky's radiance in spherical harmonics up to l = 2: L_lm = sum_i r_i sh9_i (9 x RGB,
 * Float32Array, row = coefficient in Ramamoorthi & Hanrahan's order, daylit/spherical.py).
 */
export function skySH9(r, sh9) {
  const L = new Float32Array(27);
  for (let i = 0; i < sh9.length; i++) {
    for (let j = 0; j < 9; j++) {
      const y = sh9[i][j];
      for (let ch = 0; ch < 3; ch++) L[3 * j + ch] += r[3 * i + ch] * y;
    }
  }
  return L;
}

/**
 * The constants c1..c5 of Ramamoorthi & Hanrahan's Eq. 13 (irradiance from the l <= 2
 * coefficients), the one copy that both irradianceSH9 and the shaders' irradianceSH
 * (materials.glsl.js) use.
 */
export const SH9_IRRADIANCE_C = Object.freeze([0.429043, 0.511664, 0.743125, 0.886227, 0.247708]);

/** Unshadowed irradiance for a unit normal from L (skySH9), Ramamoorthi & Hanrahan Eq. 13. */
export function irradianceSH9(L, [x, y, z]) {
  const [c1, c2, c3, c4, c5] = SH9_IRRADIANCE_C;
  const e = [0, 0, 0];
  for (let ch = 0; ch < 3; ch++) {
    const l = (j) => L[3 * j + ch];
    e[ch] = c1 * l(8) * (x * x - y * y) + c3 * l(6) * z * z + c4 * l(0) - c5 * l(6)
      + 2 * c1 * (l(4) * x * y + l(7) * x * z + l(5) * y * z)
      + 2 * c2 * (l(3) * x + l(1) * y + l(2) * z);
  }
  return e;
}

/**
 * Exponential smoothing of the light vector toward each new measurement with time constant
 * tauS (0: follow at once). Holds the smoothed vector; step() advances it to time tS.
 */
export class LightSmoother {
  constructor(tauS = 0) {
    this.tauS = tauS;
    this.value = null; // Float64Array
    this.target = null;
    this.timeS = 0;
  }

  /** A new measured vector arrives at time tS (seconds, any monotonic clock). */
  push(r, tS) {
    if (this.value === null || this.value.length !== r.length) {
      this.value = Float64Array.from(r);
      this.timeS = tS;
    } else {
      this.step(tS);
    }
    this.target = Float64Array.from(r);
  }

  /** Move toward the target until time tS; returns the largest relative change made. */
  step(tS) {
    if (this.value === null) return 0;
    const dt = Math.max(0, tS - this.timeS);
    this.timeS = tS;
    const a = this.tauS > 0 ? 1 - Math.exp(-dt / this.tauS) : 1;
    let change = 0;
    let scale = 1e-12;
    for (let i = 0; i < this.value.length; i++) {
      const d = (this.target[i] - this.value[i]) * a;
      this.value[i] += d;
      change = Math.max(change, Math.abs(d));
      scale = Math.max(scale, Math.abs(this.target[i]));
    }
    return change / scale;
  }

  /** How far the smoothed vector still is from the target, relative to the target's max. */
  remaining() {
    if (this.value === null) return 0;
    let d = 0;
    let scale = 1e-12;
    for (let i = 0; i < this.value.length; i++) {
      d = Math.max(d, Math.abs(this.target[i] - this.value[i]));
      scale = Math.max(scale, Math.abs(this.target[i]));
    }
    return d / scale;
  }
}

/**
 * The patch containing a direction (the first whose three edge planes it lies inside, like
 * daylit.spherical.PatchLookup), or -1 below the horizon or outside every patch.
 * @param {{vertices: number[][]}[]} lights the manifest's dome.lights
 * @param {number[]} direction unit, site frame
 */
export function patchContaining(lights, [x, y, z]) {
  if (y < 0) return -1;
  for (let i = 0; i < lights.length; i++) {
    const v = lights[i].vertices;
    let inside = true;
    for (let e = 0; e < 3 && inside; e++) {
      const a = v[e];
      const b = v[(e + 1) % 3];
      // (a x b) . d >= 0: on the inner side of the great circle through a and b
      const nx = a[1] * b[2] - a[2] * b[1];
      const ny = a[2] * b[0] - a[0] * b[2];
      const nz = a[0] * b[1] - a[1] * b[0];
      inside = nx * x + ny * y + nz * z >= 0;
    }
    if (inside) return i;
  }
  return -1;
}
