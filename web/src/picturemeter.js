// The camera mode's exposure from the camera's own picture (docs/web.md, "Exposure"). The
// phone's camera already exposed its picture by its own meter; the virtual hall drawn over it
// must sit at that exposure, not at an assumed one. The meter reads the picture's open ground:
// a small copy of the video frame (METER_SIZE, drawn by the 2D canvas, which scales on the
// GPU), the pixels whose ray from the current pose meets the site's ground plane (y = 0) in
// front of the visitor, their median display-linear luminance. A virtual surface with the
// ground's albedo under the ground's irradiance is then drawn at that level (app.js: exposure =
// level / the ground's modelled radiance; camera mode's frame is not tone mapped, hdr.js).
//
// The median, not the mean: the virtual hall is not in the picture, but people, real buildings
// and the real ground's own shadows are; they are a minority of the ground pixels at a
// visitor's standpoint. The camera's response is taken as sRGB (phones encode so).
import * as THREE from 'three';
import { LINEAR_OF_CODE, luminance } from './colour.js';

/** The metered copy of the picture, pixels (w, h): 1296 rays, some 1 ms of CPU. */
export const METER_SIZE = [48, 27];
/** Re-metered at most this often, seconds (the exposure is smoothed over 1.5 s anyway). */
export const METER_PERIOD_S = 0.5;
/** Ground pixels needed for a reading: a phone held towards the sky meters nothing. */
export const MIN_GROUND_PIXELS = 40;
/** The ground plane counts from this far below the horizon, degrees, and out to MAX_GROUND_M. */
const MIN_DOWN_DEG = 2;
const MAX_GROUND_M = 300;

/**
 * The picture's ground level.
 * @param {Uint8ClampedArray} rgba (h, w, 4) sRGB codes, rows from the top
 * @param {number} w
 * @param {number} h
 * @param {THREE.Camera} camera the pose and projection the picture was taken with
 * @returns {{level: number, pixels: number}|null} the median linear luminance (0..1) of the
 *   ground pixels and their count; null with fewer than MIN_GROUND_PIXELS
 */
export function groundLevel(rgba, w, h, camera) {
  camera.updateMatrixWorld();
  const origin = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld);
  const ray = new THREE.Vector3();
  const minDown = Math.sin(THREE.MathUtils.degToRad(MIN_DOWN_DEG));
  const values = [];
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      ray.set((x + 0.5) / w * 2 - 1, 1 - (y + 0.5) / h * 2, 0.5).unproject(camera).sub(origin).normalize();
      if (ray.y > -minDown || origin.y / -ray.y > MAX_GROUND_M) continue;
      const i = 4 * (y * w + x);
      values.push(luminance(LINEAR_OF_CODE[rgba[i]], LINEAR_OF_CODE[rgba[i + 1]], LINEAR_OF_CODE[rgba[i + 2]]));
    }
  }
  if (values.length < MIN_GROUND_PIXELS) return null;
  values.sort((a, b) => a - b);
  return { level: values[values.length >> 1], pixels: values.length };
}

/** Meters a video element's picture from a camera's pose, at most every METER_PERIOD_S. */
export class PictureMeter {
  /** @param {HTMLVideoElement} video */
  constructor(video) {
    this.video = video;
    this.canvas = document.createElement('canvas');
    [this.canvas.width, this.canvas.height] = METER_SIZE;
    this.context = this.canvas.getContext('2d', { willReadFrequently: true });
    this.reading = null; // the last groundLevel (or null)
    this.lastS = -Infinity;
  }

  /**
   * @param {THREE.Camera} camera the pose the picture is drawn with now
   * @param {number} nowS seconds; with `force` the picture is metered whatever the time
   * @returns {{level: number, pixels: number}|null} the latest reading
   */
  read(camera, nowS, force = false) {
    if (!force && nowS - this.lastS < METER_PERIOD_S) return this.reading;
    if (this.video.readyState < 2) return this.reading; // no frame yet
    this.lastS = nowS;
    const [w, h] = METER_SIZE;
    this.context.drawImage(this.video, 0, 0, w, h);
    this.reading = groundLevel(this.context.getImageData(0, 0, w, h).data, w, h, camera);
    return this.reading;
  }
}
