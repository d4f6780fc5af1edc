// The phone's pose registered on its own picture, for its estimate of the light (docs/web.md,
// "The phone's own light"). A compass or a tilt a few degrees off puts the model's sunlit and
// shaded surfaces on the wrong pixels, and the sky's estimate, which rests on the shaded ones,
// goes wrong: a tilt 3 degrees off took 27-44 % off it (benchmarks/bench_phone_pose.py). A
// small turn of the camera is, to first order, a shift of the picture; the shift that best
// separates the pool's pixels the model puts in sun from those it puts in shade, in
// log(luminance / albedo), is taken: Fisher's ratio of the two groups, (m1 - m2)^2 / (v1 + v2),
// was 56-79 at the true pose and at most 14 three or more degrees off, on Radiance frames of
// the test site. Where no shift splits them clearly (an overcast sky, no sun) none is taken.
import { srgbToLinear } from './picturemeter.js';

/** The widest turns searched, degrees each way: a phone's compass is often 5-15 degrees off,
 * its tilt (from gravity) a degree or two. */
export const REGISTER_HEADING_DEG = 15;
export const REGISTER_TILT_DEG = 5;
/** Below this best ratio the picture shows no clear sun/shade split: no shift. */
const MIN_FISHER = 8;
/** Fewer pixels than this in either group: no ratio at that shift. */
const MIN_GROUP = 10;
const LINEAR = Float64Array.from({ length: 256 }, (_, v) => srgbToLinear(v / 255));

/**
 * The picture's shift that registers the pool's sun/shade split on it.
 * @param {Uint8ClampedArray} rgba (h, w, 4) sRGB codes, rows from the top
 * @param {number} w
 * @param {number} h
 * @param {{x: number, y: number, albedo: number[]}[]} pool pixels of known surfaces
 *   (phoneestimate.js poolForPose)
 * @param {boolean[]} lit per pool pixel, in sun by the model
 * @param {number} fovDeg the camera's vertical field of view; the copy spans its frustum
 * @param {{clipCode: number, darkCode: number}} usable codes a pixel must stay within
 * @returns {{dx: number, dy: number, fisher: number, fisherAtZero: number}} the shift, pixels
 *   (read the pool's pixel (x, y) at (x + dx, y + dy)), the split's ratio there and unshifted
 */
export function registerShift(rgba, w, h, pool, lit, fovDeg, { clipCode, darkCode }) {
  const logL = new Float64Array(w * h);
  for (let i = 0; i < w * h; i++) {
    const r = rgba[4 * i];
    const g = rgba[4 * i + 1];
    const b = rgba[4 * i + 2];
    logL[i] = Math.max(r, g, b) >= clipCode || Math.min(r, g, b) < darkCode ? NaN
      : Math.log(0.2126 * LINEAR[r] + 0.7152 * LINEAR[g] + 0.0722 * LINEAR[b]);
  }
  const logAlbedo = pool.map((p) => Math.log(0.2126 * p.albedo[0] + 0.7152 * p.albedo[1] + 0.0722 * p.albedo[2]));
  // The turns in pixels (the vertical focal length; the copy has the picture's aspect).
  const f = (h / 2) / Math.tan((fovDeg * Math.PI) / 360);
  const reachX = Math.ceil(f * Math.tan((REGISTER_HEADING_DEG * Math.PI) / 180));
  const reachY = Math.ceil(f * Math.tan((REGISTER_TILT_DEG * Math.PI) / 180));
  let best = { dx: 0, dy: 0, fisher: -Infinity };
  let fisherAtZero = NaN;
  for (let dy = -reachY; dy <= reachY; dy++) {
    for (let dx = -reachX; dx <= reachX; dx++) {
      const fisher = splitRatio(logL, w, h, pool, lit, logAlbedo, dx, dy);
      if (dx === 0 && dy === 0) fisherAtZero = fisher;
      if (fisher > best.fisher) best = { dx, dy, fisher };
    }
  }
  if (!(best.fisher >= MIN_FISHER)) best = { dx: 0, dy: 0, fisher: best.fisher };
  return { ...best, fisherAtZero };
}

/** Fisher's ratio of log(luminance / albedo) between the pool's sunlit and shaded pixels read
 * at a shift (dx, dy); NaN with too few of either. */
function splitRatio(logL, w, h, pool, lit, logAlbedo, dx, dy) {
  const n = [0, 0];
  const sum = [0, 0];
  const sumSq = [0, 0];
  for (let i = 0; i < pool.length; i++) {
    const x = pool[i].x + dx;
    const y = pool[i].y + dy;
    if (x < 0 || y < 0 || x >= w || y >= h) continue;
    const v = logL[y * w + x] - logAlbedo[i];
    if (Number.isNaN(v)) continue;
    const g = lit[i] ? 0 : 1;
    n[g] += 1;
    sum[g] += v;
    sumSq[g] += v * v;
  }
  if (n[0] < MIN_GROUP || n[1] < MIN_GROUP) return NaN;
  const mean = [sum[0] / n[0], sum[1] / n[1]];
  const variance = [sumSq[0] / n[0] - mean[0] ** 2, sumSq[1] / n[1] - mean[1] ** 2];
  return (mean[0] - mean[1]) ** 2 / Math.max(variance[0] + variance[1], 1e-12);
}
