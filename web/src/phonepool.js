// The pool of a pose for the phone's own estimate (issue 16; phoneestimate.js): which pixels
// of the picture's copy see a known surface away from its edges, their surface points, normals
// and albedos, what their hemispheres see (the open sky on a fixed grid, one bounce through
// each sample's own jittered directions), and the model's terms per sample that depend on the
// sun (share in sun, one bounce) and on the sky's shape (irradiance from the open sky it sees).
// As server/scenesamples.py: the sky on a fixed grid of 3.75-degree cells (SKY_GRID_STEPS),
// the bounce directions jittered per sample (one set shared by every sample put the same
// quadrature error on all of them, which the fit read as sky). The rays are cast against the
// proxies' triangles by proxyrays.js. Directions: site-frame unit vectors (+X east, +Y up,
// -Z north); points metres.
import * as THREE from 'three';
import { upperHemisphereGrid } from './skyshape.js';

export const POOL_SIZE = 2000; // candidate pixels of known surfaces per pose
export const HEMISPHERE_RAYS = 64; // per sample, its own jittered set: the one bounce
// Zenith steps of the fixed grid each sample's open sky is read on (twice as many in azimuth:
// 3.75-degree cells, 1152 directions; server/scenesamples.py SKY_GRID_STEPS). 64 cosine-
// distributed directions put 0.93 to 1.06 of an open plane's irradiance on it depending on
// where the sun's circumsolar peak fell between them, and misread what blocks the sky near the
// sun. Only the cells in front of a sample are cast.
export const SKY_GRID_STEPS = 24;
const EDGE_PX = 1.5; // a pixel's corners this far away must see the same plane
export const SURFACE_OFFSET_M = 0.01;
// A sample's sun is the share in sun of the (2 PATCH_PX + 1)^2 pixel centres about it
// (server/sceneestimate.py in_sun): the pixel is read where the registration puts it, which is
// within about a pixel of the copy, so a pixel next to a shadow edge, or on a shadow a pixel or
// two wide, is partly sun; and a patch counts as wholly shaded or sunlit for the shadow-edge
// pairs only when it stays so a pixel either way.
export const PATCH_PX = 1;

/** The sky grid the pool's open sky is read on: {dirs (G, 3), sr (G,), azimuth (G,): atan2(z,
 * x), radians}. */
export const SKY_GRID = upperHemisphereGrid(SKY_GRID_STEPS);
SKY_GRID.azimuth = Float64Array.from(SKY_GRID.dirs, (d) => Math.atan2(d[2], d[0]));
const SCRATCH_CELLS = new Uint16Array(SKY_GRID.dirs.length);
const SCRATCH_WEIGHTS = new Float32Array(SKY_GRID.dirs.length);

/**
 * The pool of pixels of a pose.
 * @param {import('./proxyrays.js').Proxies} proxies
 * @param {THREE.Camera} camera the pose (world) and projection of the picture
 * @param {number} w copy width, pixels
 * @param {number} h copy height
 * @param {number[]} farAlbedo the open ground past the proxies (the build's ground albedo)
 * @returns {object[]} samples {x, y, point, normal, albedo, skyCells: Uint16Array (the grid
 *   cells of open sky in front of it), skyWeight: Float32Array (their cos x sr), bounce:
 *   [{point|null, normal, albedo, tilt}] (of rays = HEMISPHERE_RAYS cosine-distributed rays,
 *   those that meet a surface or the open ground below the horizon), patch: the
 *   (2 PATCH_PX + 1)^2 points about the pixel on its plane, skyView: the cosine-weighted
 *   open-sky fraction} (sampleAt)
 */
export function poolForPose(proxies, camera, w, h, farAlbedo, seed = 1) {
  camera.updateMatrixWorld();
  const origin = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld).toArray();
  const ray = new THREE.Vector3();
  const rayAt = (x, y) => ray.set(x / w * 2 - 1, 1 - y / h * 2, 0.5).unproject(camera)
    .sub(new THREE.Vector3(...origin)).normalize().toArray();
  const rand = mulberry32(seed);
  const jitter = mulberry32(seed + 1); // the samples' bounce directions
  const pool = [];
  for (let tries = 0; tries < 4 * POOL_SIZE && pool.length < POOL_SIZE; tries++) {
    const x = 2 + Math.floor(rand() * (w - 4));
    const y = 2 + Math.floor(rand() * (h - 4));
    const d = rayAt(x + 0.5, y + 0.5);
    const tri = proxies.cast(origin, d);
    if (tri < 0) continue;
    const n = proxies.normalOf(tri);
    if (dot(n, d) > -0.05) continue; // seen from behind or edge-on
    const point = add(origin, d, proxies.hitT);
    let same = true;
    for (const [dx, dy] of [[-1, -1], [1, -1], [-1, 1], [1, 1]]) {
      const dc = rayAt(x + 0.5 + dx * EDGE_PX, y + 0.5 + dy * EDGE_PX);
      const t2 = proxies.cast(origin, dc);
      if (t2 < 0 || dot(proxies.normalOf(t2), n) < 0.999
        || Math.abs(proxies.planeDistance(tri, add(origin, dc, proxies.hitT))) > 0.02) {
        same = false;
        break;
      }
    }
    if (!same) continue;
    // the points seen through the patch's pixel centres, on the sample's plane (the corner
    // rays above keep the patch on it: server/scenesamples.py patch_points_m)
    const patch = [];
    for (let dy = -PATCH_PX; dy <= PATCH_PX; dy++) {
      for (let dx = -PATCH_PX; dx <= PATCH_PX; dx++) {
        const dp = rayAt(x + 0.5 + dx, y + 0.5 + dy);
        patch.push(add(origin, dp, dot(sub(point, origin), n) / dot(dp, n)));
      }
    }
    pool.push(sampleAt(proxies, x, y, tri, point, patch, HEMISPHERE_RAYS, jitter, farAlbedo));
  }
  return pool;
}

/**
 * A sample of pixel (x, y) that sees triangle `tri` at `point` (metres): what its hemisphere
 * sees (server/scenesamples.py samples_at): its open sky on the fixed grid, and one bounce
 * through `rays` cosine-distributed directions of its own (jittered by `jitter`, a seeded
 * generator) off the surfaces they meet, or the open ground far off below the horizon.
 * @param {number[][]} patch the points (metres) its sun share is read over
 * @returns {object} {x, y, point, normal, albedo, skyCells, skyWeight, bounce: [{point|null,
 *   normal, albedo, tilt: the surface's index in proxies.tilts, -1 the far ground}], rays,
 *   patch, skyView} (poolForPose's samples)
 */
export function sampleAt(proxies, x, y, tri, point, patch, rays, jitter, farAlbedo) {
  const n = proxies.normalOf(tri);
  const start = add(point, n, SURFACE_OFFSET_M);
  const [t1, t2] = tangents(n);
  const bounce = [];
  for (const l of cosineDirections(rays, jitter)) { // this sample's own set
    const dir = [0, 1, 2].map((c) => l[0] * t1[c] + l[1] * t2[c] + l[2] * n[c]);
    const hit = proxies.cast(start, dir);
    if (hit >= 0) {
      bounce.push({ point: add(start, dir, proxies.hitT), normal: proxies.normalOf(hit), albedo: proxies.albedoOf(hit), tilt: proxies.tiltOf[hit] });
    } else if (dir[1] <= 0) {
      bounce.push({ point: null, normal: [0, 1, 0], albedo: farAlbedo, tilt: -1 }); // the open ground far off
    }
  }
  const { skyCells, skyWeight } = openSky(proxies, start, n);
  return {
    x, y, point, normal: n, albedo: proxies.albedoOf(tri), skyCells, skyWeight, bounce, rays, patch,
    skyView: skyWeight.reduce((v, w) => v + w, 0) / Math.PI,
  };
}

/** The sky grid's cells in front of a surface (unit normal n) open from `start` (a shadow ray
 * meets nothing), and their cos x sr (server/scenesamples.py open_sky_weights). A ray is cast
 * only toward cells some proxy's box can reach from `start` (reachable): the same answer, at a
 * fraction of the rays (a ground sample sees most of its sky past every box). */
export function openSky(proxies, start, n) {
  const boxes = reachable(proxies, start);
  const { dirs, sr, azimuth } = SKY_GRID;
  let count = 0;
  for (let g = 0; g < dirs.length; g++) {
    const dir = dirs[g];
    const c = n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2];
    if (c <= 0) continue;
    let cast = false;
    for (let k = 0; k < boxes.length && !cast; k++) {
      const b = boxes[k];
      if (dir[1] > b.up) continue;
      let delta = azimuth[g] - b.centre;
      if (delta > Math.PI) delta -= 2 * Math.PI;
      else if (delta < -Math.PI) delta += 2 * Math.PI;
      cast = b.over || (delta >= b.lo && delta <= b.hi);
    }
    if (!cast || proxies.cast(start, dir, true) < 0) {
      SCRATCH_CELLS[count] = g;
      SCRATCH_WEIGHTS[count++] = c * sr[g];
    }
  }
  return { skyCells: SCRATCH_CELLS.slice(0, count), skyWeight: SCRATCH_WEIGHTS.slice(0, count) };
}

/** The proxies' boxes an upward ray from point p can meet, each as {up: the largest up
 * component of such a ray (the box's top over the nearest point of its footprint), centre,
 * lo, hi: the azimuths (radians, atan2(z, x)) its footprint spans, lo and hi about centre;
 * over: p is over the footprint, every azimuth}. Boxes wholly below p are left out. */
export function reachable(proxies, p) {
  const out = [];
  const pad = 1e-6;
  for (const { lo, hi } of proxies.groups) {
    const dy = hi[1] - p[1];
    if (dy <= 0) continue;
    const dx = Math.max(lo[0] - p[0], 0, p[0] - hi[0]);
    const dz = Math.max(lo[2] - p[2], 0, p[2] - hi[2]);
    const up = dy / Math.hypot(dx, dy, dz) + pad;
    if (dx === 0 && dz === 0) {
      out.push({ up, over: true, centre: 0, lo: 0, hi: 0 });
      continue;
    }
    const centre = Math.atan2((lo[2] + hi[2]) / 2 - p[2], (lo[0] + hi[0]) / 2 - p[0]);
    let a = Infinity;
    let b = -Infinity;
    for (const x of [lo[0], hi[0]]) {
      for (const z of [lo[2], hi[2]]) {
        let delta = Math.atan2(z - p[2], x - p[0]) - centre;
        delta -= 2 * Math.PI * Math.round(delta / (2 * Math.PI));
        a = Math.min(a, delta);
        b = Math.max(b, delta);
      }
    }
    out.push({ up, over: false, centre, lo: a - pad, hi: b + pad });
  }
  return out;
}

/** The terms of the model that depend on the sun, per sample: share, the share of its patch
 * in sun (0 to 1); cosI, the sun's cosine times that share; litCentre, whether the pixel's own
 * point is in sun (the registration's split); and the one bounce per unit sun normal
 * irradiance and per unit sky irradiance (RGB). */
export function sunTerms(proxies, pool, sun) {
  const up = sun[1] > 0;
  const lit = (point, normal) => {
    const c = dot(normal, sun);
    if (!up || c <= 0) return 0;
    if (point === null) return c;
    return proxies.cast(add(point, normal, SURFACE_OFFSET_M), sun, true) < 0 ? c : 0;
  };
  return pool.map((s) => {
    const bSun = [0, 0, 0];
    const bSky = [0, 0, 0];
    for (const b of s.bounce) {
      const l = lit(b.point, b.normal);
      const tilt = 0.5 * (1 + b.normal[1]); // an isotropic sky on the bounce surface's tilt
      for (let c = 0; c < 3; c++) {
        bSun[c] += b.albedo[c] * l / s.rays;
        bSky[c] += b.albedo[c] * tilt / s.rays;
      }
    }
    const share = s.patch.reduce((acc, p) => acc + (lit(p, s.normal) > 0 ? 1 : 0), 0) / s.patch.length;
    return { cosI: Math.max(dot(s.normal, sun), 0) * share, share, litCentre: lit(s.point, s.normal) > 0, bSun, bSky };
  });
}

/** Per sample, the model sky's irradiance per unit open horizontal irradiance from the open
 * sky it sees: its grid cells' cos x sr times the sky's relative radiance there, over an open
 * horizontal plane's on the same grid (server/sceneestimate.py sky_term). `sky.rel` a
 * relative radiance (skyshape.js unitSky). */
export function skyTerms(pool, sky) {
  const rel = new Float64Array(SKY_GRID.dirs.length);
  let open = 0;
  SKY_GRID.dirs.forEach((d, g) => {
    rel[g] = sky.rel(d);
    open += d[1] * SKY_GRID.sr[g] * rel[g];
  });
  return pool.map((s) => {
    let sum = 0;
    for (let k = 0; k < s.skyCells.length; k++) sum += s.skyWeight[k] * rel[s.skyCells[k]];
    return sum / open;
  });
}

/**
 * Per sample, the one bounce per unit open horizontal irradiance of the model sky (RGB): the
 * mean over its bounce rays of the albedo times the sky's irradiance on the bounce surface's
 * own tilt, unobstructed and nothing from below the horizon (server/sceneestimate.py
 * _sky_term_of, tilted_irradiance); an isotropic sky gives sunTerms' bSky. Under an overcast
 * sky three times as bright at the zenith as at the horizon a wall gets about 0.4 of the
 * horizontal irradiance, not 0.5; under a clear sky a wall facing the sun much more.
 * The tilt's irradiance is summed on the pool's sky grid, once per distinct normal.
 * @param {object[]} samples (m) with bounce [{albedo, tilt}] and rays (sampleAt)
 * @param {{rel: (d: number[]) => number}} sky a relative radiance (skyshape.js unitSky)
 * @param {number[][]} tilts (u, 3) the unit normals bounce.tilt indexes (proxies.tilts)
 * @returns {number[][]} (m, 3)
 */
export function skyBounceTerms(samples, sky, tilts) {
  const { dirs, sr } = SKY_GRID;
  const weight = new Float64Array(dirs.length); // rel x sr per cell
  let open = 0;
  dirs.forEach((d, g) => {
    weight[g] = sky.rel(d) * sr[g];
    open += d[1] * weight[g];
  });
  const onTilt = new Float64Array(tilts.length).fill(NaN); // only the tilts some bounce meets
  const irradiance = (k) => {
    if (Number.isNaN(onTilt[k])) {
      const n = tilts[k];
      let sum = 0;
      for (let g = 0; g < dirs.length; g++) {
        const c = n[0] * dirs[g][0] + n[1] * dirs[g][1] + n[2] * dirs[g][2];
        if (c > 0) sum += c * weight[g];
      }
      onTilt[k] = sum / open;
    }
    return onTilt[k];
  };
  return samples.map((s) => {
    const out = [0, 0, 0];
    for (const b of s.bounce) {
      const e = b.tilt < 0 ? 1 : irradiance(b.tilt); // the far ground: an open horizontal plane
      for (let c = 0; c < 3; c++) out[c] += b.albedo[c] * e / s.rays;
    }
    return out;
  });
}

// ------------------------------------------------------------------------------ small helpers

export function dot(p, q) {
  return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
}

function sub(p, q) {
  return [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
}

function add(p, d, t) {
  return [p[0] + d[0] * t, p[1] + d[1] * t, p[2] + d[2] * t];
}

function normalized(v) {
  const l = Math.hypot(...v) || 1;
  return v.map((x) => x / l);
}

function tangents(n) {
  const helper = Math.abs(n[1]) < 0.9 ? [0, 1, 0] : [1, 0, 0];
  const t = normalized([helper[1] * n[2] - helper[2] * n[1], helper[2] * n[0] - helper[0] * n[2], helper[0] * n[1] - helper[1] * n[0]]);
  return [t, [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]]];
}

/** Stratified cosine-distributed directions about +Z, (count, 3). */
function cosineDirections(count, rand) {
  const side = Math.max(1, Math.floor(Math.sqrt(count)));
  const rows = Math.ceil(count / side);
  const out = [];
  for (let i = 0; i < count; i++) {
    const u = ((i % side) + rand()) / side;
    const v = (Math.floor(i / side) + rand()) / rows;
    const r = Math.sqrt(u);
    out.push([r * Math.cos(2 * Math.PI * v), r * Math.sin(2 * Math.PI * v), Math.sqrt(Math.max(0, 1 - u))]);
  }
  return out;
}

/** A small seeded generator (the pool is the same for the same pose: reproducible tests). */
export function mulberry32(seed) {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}
