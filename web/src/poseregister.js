// The phone's pose registered on its own picture, for its estimate of the light (docs/web.md,
// "The phone's own light"). A compass or a tilt a few degrees off puts the model's sunlit and
// shaded surfaces on the wrong pixels, and the sky's estimate, which rests on the shaded ones,
// goes wrong: a tilt 3 degrees off took 27-44 % off it (benchmarks/bench_phone_pose.py). A
// small turn of the camera is, to first order, a shift of the picture; the shift that best
// separates the pool's pixels the model puts in sun from those it puts in shade, in
// log(luminance / albedo), is taken: Fisher's ratio of the two groups, (m1 - m2)^2 / (v1 + v2),
// was 56-79 at the true pose and at most 14 three or more degrees off, on Radiance frames of
// the test site. Where no shift splits them clearly (an overcast sky, no sun) none is taken.
// Only a split in the sun's sense counts (the model's sunlit pixels brighter per albedo than
// its shaded ones): on the demo's kiosk view at 9:30 a shift of 15 px put the few shaded
// pixels, of the building's darker albedo, on even sunlit ground, a ratio of 365 against the
// true pose's 82, and the estimate read there dropped the sun (docs/web.md).
import { LINEAR_OF_CODE as LINEAR, luminance } from './colour.js';

/** The widest turns searched, degrees each way: a phone's compass is often 5-15 degrees off,
 * its tilt (from gravity) a degree or two. */
export const REGISTER_HEADING_DEG = 15;
export const REGISTER_TILT_DEG = 5;
/** Below this best ratio the picture shows no clear sun/shade split: no shift. */
const MIN_FISHER = 8;
/** Fewer pixels than this in either group: no ratio at that shift. */
const MIN_GROUP = 10;
/** The first pass scores every this many pixels each way (then the best one's neighbours). */
const COARSE_STEP_PX = 2;

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
 * @returns {{dx: number, dy: number, fisher: number, fisherAtZero: number, turnDeg: number[]}}
 *   the shift, whole pixels (read the pool's pixel (x, y) at (x + dx, y + dy)), the split's
 *   ratio there and unshifted, and the turn of the camera that puts the model where the
 *   picture shows it: [to the left, up], degrees, from the shift between pixels ([0, 0]
 *   when none is taken)
 */
export function registerShift(rgba, w, h, pool, lit, fovDeg, { clipCode, darkCode }) {
  const logL = new Float64Array(w * h);
  for (let i = 0; i < w * h; i++) {
    const r = rgba[4 * i];
    const g = rgba[4 * i + 1];
    const b = rgba[4 * i + 2];
    logL[i] = Math.max(r, g, b) >= clipCode || Math.min(r, g, b) < darkCode ? NaN
      : Math.log(luminance(LINEAR[r], LINEAR[g], LINEAR[b]));
  }
  const logAlbedo = pool.map((p) => Math.log(luminance(...p.albedo)));
  // The turns in pixels (the vertical focal length; the copy has the picture's aspect).
  const f = (h / 2) / Math.tan((fovDeg * Math.PI) / 360);
  const reachX = Math.ceil(f * Math.tan((REGISTER_HEADING_DEG * Math.PI) / 180));
  const reachY = Math.ceil(f * Math.tan((REGISTER_TILT_DEG * Math.PI) / 180));
  const nx = 2 * reachX + 1;
  const scores = new Float64Array(nx * (2 * reachY + 1));
  const scored = new Uint8Array(scores.length);
  let best = { dx: 0, dy: 0, fisher: -Infinity };
  const score = (dx, dy) => {
    const k = (dy + reachY) * nx + dx + reachX;
    if (!scored[k]) {
      scores[k] = splitRatio(logL, w, h, pool, lit, logAlbedo, dx, dy);
      scored[k] = 1;
      if (scores[k] > best.fisher) best = { dx, dy, fisher: scores[k] };
    }
    return scores[k];
  };
  // Every COARSE_STEP_PX-th shift, then up the best one's slope a pixel at a time: the split's
  // peak is several pixels wide (a shadow edge's blur and the pool's spread over it), and a
  // pixel-by-pixel search of the whole reach took three times as long at the 384 x 216 copy.
  for (let dy = -Math.floor(reachY / COARSE_STEP_PX) * COARSE_STEP_PX; dy <= reachY; dy += COARSE_STEP_PX) {
    for (let dx = -Math.floor(reachX / COARSE_STEP_PX) * COARSE_STEP_PX; dx <= reachX; dx += COARSE_STEP_PX) score(dx, dy);
  }
  for (let moved = true; moved && best.fisher > -Infinity;) {
    const { dx: cx, dy: cy } = best;
    for (let dy = Math.max(cy - 1, -reachY); dy <= Math.min(cy + 1, reachY); dy++) {
      for (let dx = Math.max(cx - 1, -reachX); dx <= Math.min(cx + 1, reachX); dx++) score(dx, dy);
    }
    moved = best.dx !== cx || best.dy !== cy;
  }
  const fisherAtZero = score(0, 0);
  if (!(best.fisher >= MIN_FISHER)) {
    return { dx: 0, dy: 0, fisher: best.fisher, fisherAtZero, turnDeg: [0, 0] };
  }
  // The peak between pixels (a parabola through the best score and its neighbours), so that
  // the view turned by it lands within a fraction of a pixel and the next search finds 0.
  const at = (dx, dy) => (Math.abs(dx) > reachX || Math.abs(dy) > reachY ? NaN : score(dx, dy));
  const x = best.dx + peakOffset(at(best.dx - 1, best.dy), best.fisher, at(best.dx + 1, best.dy));
  const y = best.dy + peakOffset(at(best.dx, best.dy - 1), best.fisher, at(best.dx, best.dy + 1));
  // A turn by a small angle moves a pixel u from the centre by f (1 + (u / f)^2) per radian:
  // the picture's edges further than its centre (1.25 times over this pool's pixels at a
  // 60-degree field of view, measured against the test's geometry). The shift that registers
  // the pool is their mean's.
  let perRadX = 0;
  let perRadY = 0;
  for (const p of pool) {
    perRadX += f * (1 + ((p.x + 0.5 - w / 2) / f) ** 2);
    perRadY += f * (1 + ((p.y + 0.5 - h / 2) / f) ** 2);
  }
  const deg = (px, perRad) => (px / (perRad / pool.length)) * (180 / Math.PI);
  return { ...best, fisherAtZero, turnDeg: [deg(x, perRadX), deg(y, perRadY)] };
}

/** Where a parabola through (-1, a), (0, b), (1, c) peaks, within [-0.5, 0.5]; 0 where a
 * neighbour is missing or the three make no peak. */
function peakOffset(a, b, c) {
  const curvature = a - 2 * b + c;
  if (!Number.isFinite(curvature) || curvature >= 0) return 0;
  return Math.max(-0.5, Math.min(0.5, (0.5 * (a - c)) / curvature));
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
  // The sun only adds light: where the model's shaded pixels read brighter per albedo than its
  // sunlit ones, the shift puts them on the wrong surfaces (a darker stated albedo read on
  // sunlit ground), however cleanly the two groups split: no split in the sun's sense, 0.
  if (!(mean[0] > mean[1])) return 0;
  return (mean[0] - mean[1]) ** 2 / Math.max(variance[0] + variance[1], 1e-12);
}
