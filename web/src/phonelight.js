// The camera's video read into the phone estimate's small copy (ESTIMATE_SIZE) at most every
// ESTIMATE_PERIOD_S, and handed to the estimator (phoneestimate.js; issue 16): an estimate, or
// under a server sky the pose's registration alone. docs/web.md, "The phone's own light".
import { ESTIMATE_PERIOD_S, ESTIMATE_SIZE } from './phoneestimate.js';

/** Reads the camera's video into a small copy and estimates (or only registers the pose), at
 * most every ESTIMATE_PERIOD_S. */
export class PhoneLight {
  /**
   * @param {HTMLVideoElement} video
   * @param {PhoneEstimator} estimator
   * @param {boolean} [held] no estimate unless forced (tests: only theirs, none of the frame
   *   loop's between them)
   */
  constructor(video, estimator, held = false) {
    this.video = video;
    this.estimator = estimator;
    this.held = held;
    this.canvas = document.createElement('canvas');
    this.resize(ESTIMATE_SIZE);
    this.context = this.canvas.getContext('2d', { willReadFrequently: true });
    this.lastS = -Infinity;
    this.estimates = 0; // estimates made (status.phoneEstimates)
    this.ms = null; // the last estimate's milliseconds of CPU
  }

  /** The copy's size, pixels [w, h] (ESTIMATE_SIZE; the benchmarks' baseline sets another). */
  resize([w, h]) {
    this.size = [w, h];
    [this.canvas.width, this.canvas.height] = this.size;
  }

  /** @returns {boolean} whether an estimate is due at nowS (s) and the video has a frame */
  due(nowS, force = false) {
    return (force || (!this.held && nowS - this.lastS >= ESTIMATE_PERIOD_S)) && this.video.readyState >= 2;
  }

  /** @returns {object|null} a new estimate, or null (not due, no frame, nothing to read) */
  read(camera, sun, nowS, force = false) {
    return this._withCopy(nowS, force, (rgba, w, h) => {
      const estimate = this.estimator.estimate(rgba, w, h, camera, sun);
      if (estimate) this.estimates += 1;
      return estimate;
    });
  }

  /** @returns {object|null} the pose's registration on the picture now (PhoneEstimator
   * register), or null (not due, no frame) */
  readShift(camera, sun, nowS, force = false) {
    return this._withCopy(nowS, force, (rgba, w, h) => this.estimator.register(rgba, w, h, camera, sun));
  }

  _withCopy(nowS, force, use) {
    if (!this.due(nowS, force)) return null;
    this.lastS = nowS;
    const t0 = performance.now();
    const [w, h] = this.size;
    this.context.drawImage(this.video, 0, 0, w, h);
    const result = use(this.context.getImageData(0, 0, w, h).data, w, h);
    this.ms = performance.now() - t0;
    return result;
  }
}
