// The build's real proxies and its ground as one triangle list, for the rays of the phone's
// own estimate (phoneestimate.js; issue 16): which surface a pixel sees, what a point's
// hemisphere sees, whether the sun reaches a point. Moller-Trumbore over the triangles, culled
// per mesh by its box; world metres. Why not three's Raycaster: a cast here allocates nothing,
// the hit triangle's index gives its albedo and plane directly, and a shadow ray stops at the
// first blocker, where Raycaster sorts every hit of every mesh into new objects.
import * as THREE from 'three';

/** The real proxies and the ground as one triangle list for ray casts (world metres). */
export class Proxies {
  /**
   * @param {THREE.Mesh[]} meshes the build's real proxies and its ground, userData.albedo a
   *   THREE.Vector3 (site.js)
   */
  constructor(meshes) {
    const tris = [];
    const groups = [];
    for (const mesh of meshes) {
      mesh.updateMatrixWorld(true);
      const g = mesh.geometry;
      const pos = g.attributes.position;
      const index = g.index ? g.index.array : Array.from({ length: pos.count }, (_, i) => i);
      const albedo = mesh.userData.albedo?.toArray?.() ?? [0.2, 0.2, 0.2];
      const first = tris.length;
      const box = new THREE.Box3();
      for (let f = 0; f + 2 < index.length; f += 3) {
        const v = [0, 1, 2].map((k) => new THREE.Vector3().fromBufferAttribute(pos, index[f + k]).applyMatrix4(mesh.matrixWorld));
        const n = new THREE.Vector3().subVectors(v[1], v[0]).cross(new THREE.Vector3().subVectors(v[2], v[0]));
        if (n.lengthSq() < 1e-12) continue;
        n.normalize();
        for (const p of v) box.expandByPoint(p);
        tris.push({ v, n, albedo });
      }
      groups.push({ first, last: tris.length, box: box.expandByScalar(1e-3) });
    }
    const t = tris.length;
    this.count = t;
    this.v0 = new Float64Array(3 * t);
    this.e1 = new Float64Array(3 * t);
    this.e2 = new Float64Array(3 * t);
    this.normal = new Float64Array(3 * t);
    this.albedo = new Float64Array(3 * t);
    tris.forEach(({ v, n, albedo }, i) => {
      for (let c = 0; c < 3; c++) {
        const k = 3 * i + c;
        this.v0[k] = v[0].getComponent(c);
        this.e1[k] = v[1].getComponent(c) - v[0].getComponent(c);
        this.e2[k] = v[2].getComponent(c) - v[0].getComponent(c);
        this.normal[k] = n.getComponent(c);
        this.albedo[k] = albedo[c];
      }
    });
    this.groups = groups.map(({ first, last, box }) => ({ first, last, lo: box.min.toArray(), hi: box.max.toArray() }));
    // The distinct normals (tilts, (u, 3)) and each triangle's index among them (tiltOf, (t,)):
    // a sky's irradiance on a bounce surface's tilt is found once per tilt (phonepool.js
    // skyBounceTerms), not once per bounce.
    this.tilts = [];
    this.tiltOf = new Int32Array(t);
    const seen = new Map();
    for (let i = 0; i < t; i++) {
      const n = this.normalOf(i);
      const key = n.map((v) => v.toFixed(6)).join(' ');
      if (!seen.has(key)) {
        seen.set(key, this.tilts.length);
        this.tilts.push(n);
      }
      this.tiltOf[i] = seen.get(key);
    }
    this.hitT = 0; // the last cast's distance
  }

  /** The first triangle a ray meets (its index; -1: none), its distance in this.hitT. With
   * `any`, the first one found (shadow rays). */
  cast(o, d, any = false, tMax = Infinity) {
    let best = -1;
    let bestT = tMax;
    for (const g of this.groups) {
      if (!slab(g.lo, g.hi, o, d, bestT)) continue;
      for (let i = g.first; i < g.last; i++) {
        const t = this._tri(i, o, d);
        if (t > 1e-6 && t < bestT) {
          bestT = t;
          best = i;
          if (any) return best;
        }
      }
    }
    this.hitT = bestT;
    return best;
  }

  _tri(i, o, d) {
    // Moller-Trumbore, both faces
    const k = 3 * i;
    const e1x = this.e1[k]; const e1y = this.e1[k + 1]; const e1z = this.e1[k + 2];
    const e2x = this.e2[k]; const e2y = this.e2[k + 1]; const e2z = this.e2[k + 2];
    const px = d[1] * e2z - d[2] * e2y; const py = d[2] * e2x - d[0] * e2z; const pz = d[0] * e2y - d[1] * e2x;
    const det = e1x * px + e1y * py + e1z * pz;
    if (Math.abs(det) < 1e-12) return -1;
    const inv = 1 / det;
    const tx = o[0] - this.v0[k]; const ty = o[1] - this.v0[k + 1]; const tz = o[2] - this.v0[k + 2];
    const u = (tx * px + ty * py + tz * pz) * inv;
    if (u < 0 || u > 1) return -1;
    const qx = ty * e1z - tz * e1y; const qy = tz * e1x - tx * e1z; const qz = tx * e1y - ty * e1x;
    const v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv;
    if (v < 0 || u + v > 1) return -1;
    return (e2x * qx + e2y * qy + e2z * qz) * inv;
  }

  normalOf(i) { return [this.normal[3 * i], this.normal[3 * i + 1], this.normal[3 * i + 2]]; }

  albedoOf(i) { return [this.albedo[3 * i], this.albedo[3 * i + 1], this.albedo[3 * i + 2]]; }

  /** Signed distance of a point from triangle i's plane, metres. */
  planeDistance(i, p) {
    const k = 3 * i;
    return (p[0] - this.v0[k]) * this.normal[k] + (p[1] - this.v0[k + 1]) * this.normal[k + 1] + (p[2] - this.v0[k + 2]) * this.normal[k + 2];
  }
}

/** Slab test: does the ray meet the box before tMax? */
function slab(lo, hi, o, d, tMax) {
  let t0 = 0;
  let t1 = tMax;
  for (let c = 0; c < 3; c++) {
    const inv = 1 / d[c];
    let near = (lo[c] - o[c]) * inv;
    let far = (hi[c] - o[c]) * inv;
    if (near > far) [near, far] = [far, near];
    if (Number.isNaN(near) || Number.isNaN(far)) {
      if (o[c] < lo[c] || o[c] > hi[c]) return false;
      continue;
    }
    t0 = Math.max(t0, near);
    t1 = Math.min(t1, far);
    if (t0 > t1) return false;
  }
  return true;
}
