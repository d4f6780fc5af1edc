// Runs web/src/lightfeed.js's LightFeed in Node over camera mode's first seconds, with the real
// CameraView (camera-view.js; the DOM it touches stubbed) and a stand-in for the picture's
// reader that registers every picture as the view's placeholder pose would (a turn of 12
// degrees left and 4 up, the kiosk view's error from a level view facing north). Input (JSON on
// stdin): {manifest: {scene, views}, time (?time=), orientation: {alpha, beta, gamma}}. Output:
// per source (?sky=phone's estimate; a server sky's registration alone) the reads and the
// alignment's registered turns before the device's orientation came (a null event, as from a
// phone without sensors, and none), and the first read after it: the registered turns of the
// pose it read with; and what light is drawn before and after (offline: the kept light until
// the phone's own estimate, and its note gone with it). For tests/web/test_phoneestimate_js.py.
import { readFileSync } from 'node:fs';
import * as THREE from 'three';
import { CameraView } from '../../web/src/camera-view.js';
import { LightFeed } from '../../web/src/lightfeed.js';

const input = JSON.parse(readFileSync(0, 'utf8'));
const element = () => ({ getContext: () => ({}), addEventListener() {}, removeEventListener() {} });
globalThis.document = { createElement: element };
globalThis.screen = { orientation: { angle: 0 } };

function run(query, { server = !query.includes('sky=phone'), kept = null } = {}) {
  const camera = new THREE.PerspectiveCamera(60, 16 / 9, 0.1, 100);
  const view = new CameraView(camera, element(), input.manifest, { background: null }, { getTracks: () => [] });
  const app = {
    ready: true, mode: 'camera', view, camera, site: { nodes: { real: [], ground: [] } },
    assets: { manifest: { ...input.manifest, dome: { lights: [], count: 0 } } }, startS: 0,
    hud: { message: null, setMessage(text) { this.message = text; } },
  };
  const feed = new LightFeed(app, new URLSearchParams(query), () => {});
  if (server) feed.push({ rgb: new Float32Array(0), sun: null }); // a server sky
  if (kept) feed.keptLight = { load: () => kept, save() {} }; // the last visit's light (offline.js)
  const drawn = () => ({ source: feed.light?.kept ? 'kept' : feed.light?.phone ? 'phone' : feed.light ? 'server' : null, note: app.hud.message !== null });
  const reads = [];
  const registration = () => {
    const a = view.alignment;
    reads.push({ headingDeg: a.registeredHeadingDeg, tiltDeg: a.registeredTiltDeg });
    return { dx: 19, dy: -6, fisher: 50, fisherAtZero: 5, turnDeg: [12, 4] };
  };
  feed.phoneEstimator = {
    lightVector: () => ({ rgb: new Float32Array(0), sun: null }), forgetPose() {},
  };
  feed.phoneLight = {
    video: view.video, held: false, estimates: 0, ms: null,
    due(nowS, force) { return force || nowS - (this.lastS ?? -Infinity) >= 2; },
    // an estimate that keeps a sun (the view follows only such a one's registration)
    read(cam, sun, nowS) { this.lastS = nowS; const s = registration(); return { ...s, shiftPx: [s.dx, s.dy], sunNormal: [1, 1, 1] }; },
    readShift(cam, sun, nowS) { this.lastS = nowS; return registration(); },
  };
  const turns = () => [view.alignment.registeredHeadingDeg, view.alignment.registeredTiltDeg];
  for (const t of [0.5, 2.5, 4.5]) feed.tick(t);
  view._onOrientation({ alpha: null, beta: null, gamma: null }); // no sensors (headless Chromium)
  for (const t of [6.5, 8.5]) feed.tick(t);
  const before = { reads: reads.length, turnsDeg: turns(), drawn: drawn() };
  const { alpha, beta, gamma } = input.orientation;
  view._onOrientation({ alpha, beta, gamma });
  feed.tick(10.5);
  // the client's clock (?time=), Unix seconds: the phone's sun is at that time, not the run's
  return { before, first: reads[before.reads] ?? null, after: drawn(), clockS: (Date.now() + feed.clockOffsetMs) / 1000 };
}

const kept = { rgb: [], sun: null, captureTime: Date.parse(input.time) / 1000 - 86400 };
process.stdout.write(JSON.stringify({
  phone: run(`sky=phone&time=${input.time}`),
  server: run(`time=${input.time}`),
  // An offline visit in camera mode: no server sky, the last visit's light kept on the phone.
  offline: run(`time=${input.time}`, { server: false, kept }),
}));
