// The light the hall is drawn with (docs/web.md, "The phone's own light" and "Offline"): the
// server's stream; in camera mode the phone's own estimate from its picture
// (phoneestimate.js) when no server sky came NO_SERVER_SKY_AFTER_S after the start, or
// ?sky=phone asks for it; else the last live light kept on this phone (offline.js). In camera
// mode the view follows the picture's registration of the pose whichever lights it. Each new
// vector goes into the smoother, the sun's normal irradiance as three more numbers after the
// sky's, so that the sun glides with the sky; the app relights from `smoothed()`.
import { LightSmoother } from './lightmath.js';
import { KeptLight } from './offline.js';
import { ESTIMATE_PERIOD_S, PhoneEstimator } from './phoneestimate.js';
import { PhoneLight } from './phonelight.js';
import { sunPosition } from './sunposition.js';

const STALE_AFTER_MS = 16000; // three missed keep-alives (the server sends every 5 s)
// Camera mode draws with the phone's own estimate when no server sky came this long after the
// start (offline, a server without cameras): a server's first vector usually takes < 1 s.
const NO_SERVER_SKY_AFTER_S = 5;
const MIN_TURN_DEG = 0.1; // a smaller registration turn leaves the view as it is
// The registration turns the view only where its shift splits the picture's sun from its shade
// this much better than the pose as it is (Fisher's ratio; the one-pixel steps of a settled
// view gained 0.4-1.2 %, the real corrections 7-23 %, on Radiance frames of the test site).
const MIN_FISHER_GAIN = 0.02;
// A shift found twice in a row is followed without that gain only this close to the pose (a
// settled view's last pixel): a picture whose brightness the model's shadows do not explain
// (no shadows, a wall of two colours) found the same far shift on every registration and
// walked the view 10 degrees away. Two pixels of the 384 x 216 copy (phoneestimate.js
// ESTIMATE_SIZE): the one pixel of the 192 x 108 copy the rule was made at.
const SETTLE_SHIFT_PX = 2;

export class LightFeed {
  /**
   * @param {object} app the App it feeds: its mode, view, site, assets, camera, stream, hud,
   *   ready and start time are read as they are now
   * @param {URLSearchParams} params the page's (?smoothing=, ?sky=phone, ?time=)
   * @param {() => void} onNew called when a new vector came (the app relights)
   */
  constructor(app, params, onNew) {
    this.app = app;
    this.onNew = onNew;
    this.smoother = new LightSmoother(Number(params.get('smoothing') ?? 0));
    this.light = null; // the newest message
    this.saturated = null;
    this.serverLights = 0;
    this.phoneForced = params.get('sky') === 'phone';
    // ?register=off: the view follows the device's sensors and the visitor's fingers only
    // (a picture that is not of the site; the camera mode's orientation tests).
    this.registerPose = params.get('register') !== 'off';
    this.phoneLight = null; // PhoneLight: the camera's video read into a copy
    this.phoneEstimator = null;
    this.phoneEstimate = null; // the last estimate (status.phoneEstimate)
    this.registration = null; // the last registration alone, under a server sky (status)
    this._heldShift = undefined; // the last registration's shift the view did not follow (_follow)
    this._phoneSequence = 0;
    this.keptLight = null; // the scene's KeptLight, once the manifest is known (keepFor)
    this._keptLightTried = false; // the kept light is looked for once a visit (useKept)
    // ?time= (ISO 8601 or Unix seconds): the client's clock starts there (the phone's sun
    // without a server; tests and demos). Only the phone's estimate reads it.
    const startMs = clockStartMs(params.get('time'));
    this.clockOffsetMs = Number.isFinite(startMs) ? startMs - Date.now() : 0;
  }

  /** A light vector message: the server's, the phone's estimate (m.phone) or the kept one
   * (m.kept). */
  push(m) {
    if (!m.phone && !m.kept) {
      this.serverLights += 1;
      this.keptLight?.save(m);
      if (this.phoneForced) return; // ?sky=phone: the phone's own estimate only
    }
    if (this.light?.kept && !m.kept) this.app.hud.setMessage(null); // live or the phone's own: the kept light's note goes
    this.light = m;
    this.saturated = m.saturated;
    const sun = m.sun?.normalIrradiance ?? [0, 0, 0];
    const v = new Float64Array(m.rgb.length + 3);
    v.set(m.rgb);
    v.set(sun, m.rgb.length);
    this.smoother.push(v, performance.now() / 1000);
    this.onNew();
  }

  /** The site is known: its last live light is kept on this phone from now on (and the one
   * already drawn, if live). */
  keepFor(sceneId) {
    this.keptLight = new KeptLight(sceneId);
    if (this.light && !this.light.phone && !this.light.kept) this.keptLight.save(this.light);
  }

  /** The smoothed sky (n x 3) and the sun to draw with it (null: none, as from a version-1
   * server, whose sky vector still holds the sun in its patch). */
  smoothed() {
    const v = this.smoother.value;
    const n3 = v.length - 3;
    const direction = this.light?.sun?.direction; // (0, 0, 0) from a server with no sun now
    const known = direction && direction.some((x) => x !== 0);
    const sun = known ? { direction, normalIrradiance: Array.from(v.subarray(n3)) } : null;
    return { r: v.slice(0, n3), sun };
  }

  isStale() {
    const light = this.light;
    const stream = this.app.stream;
    if (!light) return true;
    if (light.phone) return Date.now() / 1000 - light.captureTime > 3 * ESTIMATE_PERIOD_S; // three missed estimates
    if (light.kept) return true;
    if (stream?.state !== 'open' || light.stale) return true;
    return performance.now() - stream.lastMessageMs > STALE_AFTER_MS;
  }

  ageMs() {
    const light = this.light;
    if (!light) return null;
    if (light.phone || light.kept) return Math.max(0, Math.round(Date.now() - light.captureTime * 1000));
    return Math.max(0, Math.round(this.app.stream.ageS(light.captureTime) * 1000));
  }

  /** The phone's sun (sunposition.js) at the client's clock (?time= moves it). */
  sunNow() {
    const s = this.app.assets.manifest.scene;
    return sunPosition(s.latitude_deg, s.longitude_deg, (Date.now() + this.clockOffsetMs) / 1000).direction;
  }

  /** Whether camera mode lights the hall with the phone's own estimate: asked for, or no
   * server sky has come (an offline visit, a site without cameras). */
  phoneWanted(nowS = performance.now() / 1000) {
    const app = this.app;
    return app.mode === 'camera' && !!app.view?.video && !!app.site
      && (this.phoneForced || (this.serverLights === 0 && nowS - app.startS > NO_SERVER_SKY_AFTER_S));
  }

  /** Each frame: the phone's estimate when due (or, under a server sky, only its pose's
   * registration, which the view follows), or the kept light when nothing else came. */
  tick(nowS) {
    this.estimate(nowS);
    this.register(nowS);
    this.useKept(nowS);
  }

  /** No live light NO_SERVER_SKY_AFTER_S after the start and none of the phone's own yet: draw
   * the last live light kept on this phone (offline.js), once, and say how old it is. Camera
   * mode draws it too until its own estimate comes, which may be never (a device that does not
   * tell its orientation, a sky whose type does not settle): an old light beats none. */
  useKept(nowS) {
    const app = this.app;
    if (!app.ready || this.light || this.serverLights > 0 || this._keptLightTried
      || nowS - app.startS <= NO_SERVER_SKY_AFTER_S) return;
    this._keptLightTried = true;
    const kept = this.keptLight?.load();
    if (!kept || kept.rgb.length !== 3 * app.assets.manifest.dome.count) return;
    this.push({ ...kept, saturated: null, sequence: 0, stale: true, flags: 0, kept: true });
    const when = new Date(kept.captureTime * 1000).toLocaleString([], { dateStyle: 'medium', timeStyle: 'short' });
    app.hud.setMessage(`No live sky (offline?): the light of ${when}, kept from the last visit.`, 'warn');
  }

  /** Whether camera mode knows the device's orientation (its first deviceorientation event with
   * angles came). Before it the view is a placeholder, level and facing north: a picture read
   * there is not of that pose, and a registration there turned the view by the placeholder's
   * error, a turn kept (and stored with the alignment) once the orientation came. So the phone
   * neither estimates nor registers until it is known; a device that never tells it (no
   * sensors, iOS's permission refused) gets neither. */
  posed() {
    return !!this.app.view?.orientation;
  }

  /** The reader of camera mode's video (estimates, registrations), or null outside it. */
  phoneReader() {
    const app = this.app;
    if (!app.ready || app.mode !== 'camera' || !app.view?.video || !app.site) return null;
    if (!this.phoneLight || this.phoneLight.video !== app.view.video) {
      if (!this.phoneEstimator) {
        this.phoneEstimator = new PhoneEstimator([...app.site.nodes.real, ...app.site.nodes.ground], app.assets.manifest.ground.albedo);
        this.phoneEstimator.registerPose = this.registerPose;
      }
      this.phoneLight = new PhoneLight(app.view.video, this.phoneEstimator, this.phoneLight?.held);
    }
    return this.phoneLight;
  }

  /** The site went (its meshes are the estimator's proxies): the phone's reader goes with it. */
  forgetSite() {
    this.phoneEstimator = null;
    this.phoneLight = null;
  }

  /** Camera mode without a server sky: estimate the light from the picture, at most every
   * ESTIMATE_PERIOD_S (force: now), and draw with it as with a server's vector
   * (phoneestimate.js). Returns the estimate, or null when none was made. */
  estimate(nowS, force = false) {
    if (!this.phoneWanted(nowS) || !this.posed() || !this.phoneReader()?.due(nowS, force)) return null; // the pose and sun only when it reads
    const app = this.app;
    app.view.update(); // the pose the picture is read with
    const sun = this.sunNow();
    if (sun[1] <= 0) return null; // night: nothing to estimate (the last light stays)
    const estimate = this.phoneLight.read(app.camera, sun, nowS, force);
    if (!estimate) return null;
    this.phoneEstimate = estimate;
    this._follow(estimate, estimate.sunNormal);
    const v = this.phoneEstimator.lightVector(estimate, app.assets.manifest.dome.lights, sun);
    this._phoneSequence += 1;
    this.push({ rgb: v.rgb, saturated: null, sequence: this._phoneSequence, captureTime: Date.now() / 1000, stale: false, flags: 0, sun: v.sun, phone: true });
    return estimate;
  }

  /** Camera mode under a server sky: the pose registered on the picture (at the estimates'
   * pace; force: now), the view turned by it. Returns the registration ({shiftPx, turnDeg,
   * fisher}), or null when none was made (not camera mode, the phone's own light, not due,
   * the sun down). */
  register(nowS, force = false) {
    if (this.phoneWanted(nowS) || !this.posed() || !this.phoneReader()?.due(nowS, force)) return null;
    const app = this.app;
    app.view.update();
    const sun = this.sunNow();
    if (sun[1] <= 0) return null; // no sun, no shadows to register on
    const shift = this.phoneLight.readShift(app.camera, sun, nowS, force);
    if (!shift) return null;
    this.registration = { shiftPx: [shift.dx, shift.dy], turnDeg: shift.turnDeg, fisher: shift.fisher, fisherAtZero: shift.fisherAtZero };
    this._follow(this.registration, this.light?.sun?.normalIrradiance ?? null);
    return this.registration;
  }

  /** The registration's turn puts the drawn model on the picture where the shifted reading
   * splits sun from shade better than the pose as it is by MIN_FISHER_GAIN, or where the last
   * registration that left the view found the same shift of a pixel (a smaller gain once is the
   * picture's noise: under a soft-shadowed sky the best shift wanders a pixel from one
   * estimate to the next; the same shift twice is not), and the turn passes a tenth of a
   * degree. Only under a sun: a registration is a split of sun from shade, and where the light
   * has no sun (cloud) the split it finds is the sky's (a wall that sees half the sky reads
   * darker per albedo than open ground); following it walked the demo's kiosk view 11-15
   * degrees away in five estimates under an overcast sky, until it saw no shade and estimated
   * nothing.
   * @param {number[]|null} sunNormal the light's sun normal irradiance (RGB): the phone's
   *   estimate's, or the server's now; null where it is not known (a protocol-version-1
   *   server), followed as before */
  _follow({ shiftPx, turnDeg, fisher, fisherAtZero }, sunNormal) {
    if (sunNormal && !(Math.max(...sunNormal) > 0)) return;
    const gains = fisher > fisherAtZero * (1 + MIN_FISHER_GAIN);
    const settling = Math.max(Math.abs(shiftPx[0]), Math.abs(shiftPx[1])) <= SETTLE_SHIFT_PX;
    const again = settling && (shiftPx[0] !== 0 || shiftPx[1] !== 0)
      && this._heldShift?.[0] === shiftPx[0] && this._heldShift?.[1] === shiftPx[1];
    if (!(gains || again) || Math.hypot(...turnDeg) <= MIN_TURN_DEG) {
      this._heldShift = shiftPx; // not followed: the next registration may confirm it
      return;
    }
    this._heldShift = undefined;
    this.app.view.turnBy(...turnDeg);
    this.phoneEstimator.forgetPose();
  }
}

/**
 * The client's clock start from ?time= (Unix seconds, or ISO 8601), in ms; NaN when absent or
 * not understood. A query string decodes '+' as a space, so `?time=2026-10-15T09:30:00+09:00`
 * as typed arrives as `...09:30:00 09:00`: a space before a trailing zone offset is read back
 * as '+' (before this, such a time was ignored and the phone's sun was the real clock's).
 * @param {string|null} text
 * @returns {number}
 */
export function clockStartMs(text) {
  if (text === null) return NaN;
  if (/^[0-9.]+$/.test(text)) return Number(text) * 1000;
  return Date.parse(text.replace(/ (\d{2}(:?\d{2})?)$/, '+$1'));
}
