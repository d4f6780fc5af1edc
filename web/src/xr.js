// WebXR immersive-ar (Android Chrome and other browsers that have it): the reconstruction over
// the passthrough camera at 1:1 scale. A reticle follows the ground found by hit-testing; a
// tap places the site's origin there; twisting two fingers turns it about the vertical; one
// finger drags it along the ground. The last alignment (relative to the session's floor
// origin, where the visitor started the session) is kept in localStorage and applied at the
// next start, so a visitor who starts from the same marked spot finds it in place.
import * as THREE from 'three';
import { XRPictureMeter } from './xrmeter.js';

const STORAGE_KEY = 'daylit.alignment.xr';
/** The overlay's class while a session runs: it takes every touch on the screen (style.css). */
const GESTURE_CLASS = 'xr-gestures';
/** A touch that moves less than this, CSS px, and lifts is a tap. */
const TAP_SLOP_PX = 10;

/** Whether a pointer event is still within the tap's slop of where the tap went down. */
function withinSlop(tap, e) {
  return Math.hypot(e.clientX - tap.x, e.clientY - tap.y) <= TAP_SLOP_PX;
}

/**
 * A three.js WebGLRenderer on `canvas` whose WebXR layer is antialiased whatever the canvas
 * is. three.js (0.187) gives the XR layer (XRWebGLLayer, or the projection layer's samples)
 * the context's own `antialias`, read once while the renderer is made; a visit's canvas has
 * none (its linear frame has its own MSAA: app.js), so AR entered from the visit would have
 * none either. The context is asked for what three.js itself asks for; it reads as
 * antialiased only while the renderer is made.
 * @param {HTMLCanvasElement} canvas
 * @param {{antialias: boolean, preserveDrawingBuffer: boolean, powerPreference: string}} options
 */
export function rendererWithXrAntialias(canvas, options) {
  const gl = canvas.getContext('webgl2', {
    alpha: true, depth: true, stencil: false, premultipliedAlpha: true,
    failIfMajorPerformanceCaveat: false, ...options,
  });
  if (!gl) return new THREE.WebGLRenderer({ canvas, ...options }); // three.js words the error
  const own = gl.getContextAttributes;
  gl.getContextAttributes = () => ({ ...own.call(gl), antialias: true });
  try {
    return new THREE.WebGLRenderer({ canvas, context: gl });
  } finally {
    delete gl.getContextAttributes; // the prototype's again: the canvas's true attributes
  }
}

export async function arSupported() {
  try {
    return !!(navigator.xr && await navigator.xr.isSessionSupported('immersive-ar'));
  } catch {
    return false;
  }
}

export class XRView {
  /** Start a session (call from a tap). Rejects when the browser refuses. */
  static async open(renderer, scene, siteRoot, overlay, onEnd) {
    const session = await navigator.xr.requestSession('immersive-ar', {
      requiredFeatures: ['local-floor'],
      // camera-access: the passthrough's picture, for the exposure (xrmeter.js)
      optionalFeatures: ['hit-test', 'dom-overlay', 'camera-access'],
      domOverlay: { root: overlay },
    });
    const view = new XRView(renderer, scene, siteRoot, overlay, session, onEnd);
    await view.init();
    return view;
  }

  constructor(renderer, scene, siteRoot, overlay, session, onEnd) {
    this.renderer = renderer;
    this.scene = scene;
    this.siteRoot = siteRoot;
    this.overlay = overlay;
    this.session = session;
    this.onEnd = onEnd;
    this.alignment = load();
    this.reticle = new THREE.Mesh(
      new THREE.RingGeometry(0.15, 0.2, 32).rotateX(-Math.PI / 2),
      new THREE.MeshBasicMaterial({ color: 0xffffff, transparent: true, opacity: 0.8 }),
    );
    this.reticle.matrixAutoUpdate = false;
    this.reticle.visible = false;
    scene.add(this.reticle);
    this.previousBackground = scene.background;
    scene.background = null; // the passthrough camera shows through
    this._touches = new Map();
    this.frames = 0;
    this.meter = new XRPictureMeter(renderer); // the exposure from the passthrough (app.js)
  }

  async init() {
    this.renderer.xr.enabled = true;
    this.renderer.xr.setReferenceSpaceType('local-floor');
    await this.renderer.xr.setSession(this.session);
    this.refSpace = this.renderer.xr.getReferenceSpace();
    try {
      const viewer = await this.session.requestReferenceSpace('viewer');
      this.hitSource = await this.session.requestHitTestSource?.({ space: viewer });
    } catch {
      this.hitSource = null; // no hit test: place in front of the visitor instead
    }
    // A controller's trigger (a headset) places the site through the session's select.
    this.session.addEventListener('select', () => this._place());
    this.session.addEventListener('end', () => this._ended());
    // The screen's touches are the overlay's (GESTURE_CLASS makes all of it take them: the
    // HUD lets touches through to the canvas elsewhere, and in a DOM overlay session a touch
    // that meets no element reaches no page code). Each touch on the overlay would also end
    // in an XR select, which would put the site back at the reticle after every drag and
    // twist: the overlay cancels those (beforexrselect) and a tap places the site itself.
    this.overlay.classList.add(GESTURE_CLASS);
    this._beforeSelect = (e) => e.preventDefault();
    this._down = (e) => this._pointerDown(e);
    this._up = (e) => this._pointerUp(e);
    this._move = (e) => this._gesture(e);
    this.overlay.addEventListener('beforexrselect', this._beforeSelect);
    this.overlay.addEventListener('pointerdown', this._down);
    this.overlay.addEventListener('pointerup', this._up);
    this.overlay.addEventListener('pointercancel', this._up);
    this.overlay.addEventListener('pointermove', this._move);
    this._apply();
  }

  _pointerDown(e) {
    // a tap: one finger on the overlay itself (not a HUD button), lifted where it went down
    this._tap = this._touches.size === 0 && e.target === this.overlay
      ? { id: e.pointerId, x: e.clientX, y: e.clientY } : null;
    this._touches.set(e.pointerId, [e.clientX, e.clientY]);
  }

  _pointerUp(e) {
    if (!this._touches.delete(e.pointerId)) return;
    const tap = this._tap;
    // checked at the lift too: a browser need not send a move for the last stretch
    if (e.type === 'pointerup' && tap?.id === e.pointerId && withinSlop(tap, e)) {
      this._place();
    }
    if (this._touches.size === 0) this._tap = null;
    save(this.alignment);
  }

  _place() {
    const p = new THREE.Vector3();
    if (this.reticle.visible) {
      p.setFromMatrixPosition(this.reticle.matrix);
    } else {
      const cam = this.renderer.xr.getCamera();
      p.set(0, 0, -3).applyMatrix4(cam.matrixWorld);
      p.y = 0;
    }
    this.alignment.position = [p.x, p.y, p.z];
    save(this.alignment);
    this._apply();
  }

  _gesture(e) {
    const last = this._touches.get(e.pointerId);
    if (!last) return;
    if (this._tap && (this._touches.size > 1 || !withinSlop(this._tap, e))) {
      this._tap = null; // a drag or a twist, not a tap
    }
    const points = [...this._touches.entries()];
    this._touches.set(e.pointerId, [e.clientX, e.clientY]);
    if (points.length === 2) {
      const [a, b] = points.map(([id, xy]) => (id === e.pointerId ? last : xy));
      const [a2, b2] = points.map(([id, xy]) => (id === e.pointerId ? [e.clientX, e.clientY] : xy));
      const before = Math.atan2(b[1] - a[1], b[0] - a[0]);
      const after = Math.atan2(b2[1] - a2[1], b2[0] - a2[0]);
      this.alignment.yawDeg -= THREE.MathUtils.radToDeg(after - before);
    } else if (points.length === 1) {
      const cam = this.renderer.xr.getCamera();
      const yaw = new THREE.Euler().setFromQuaternion(cam.quaternion, 'YXZ').y;
      const dx = (e.clientX - last[0]) / 100;
      const dz = (e.clientY - last[1]) / 100;
      this.alignment.position[0] += dx * Math.cos(yaw) + dz * Math.sin(yaw);
      this.alignment.position[2] += -dx * Math.sin(yaw) + dz * Math.cos(yaw);
    }
    this._apply();
  }

  _apply() {
    this.siteRoot.position.set(...this.alignment.position);
    this.siteRoot.rotation.set(0, THREE.MathUtils.degToRad(this.alignment.yawDeg), 0);
  }

  update(frame) {
    if (!frame) return;
    this.frames += 1; // XR frames drawn (the tests wait on it)
    if (!this.hitSource) return;
    const hits = frame.getHitTestResults(this.hitSource);
    if (hits.length) {
      const pose = hits[0].getPose(this.refSpace);
      this.reticle.visible = true;
      this.reticle.matrix.fromArray(pose.transform.matrix);
    } else {
      this.reticle.visible = false;
    }
  }

  resetAlignment() {
    localStorage.removeItem(STORAGE_KEY);
    this.alignment = load();
    this._apply();
  }

  _ended() {
    this.overlay.classList.remove(GESTURE_CLASS);
    this.overlay.removeEventListener('beforexrselect', this._beforeSelect);
    this.overlay.removeEventListener('pointerdown', this._down);
    this.overlay.removeEventListener('pointerup', this._up);
    this.overlay.removeEventListener('pointercancel', this._up);
    this.overlay.removeEventListener('pointermove', this._move);
    this.scene.remove(this.reticle);
    this.meter.dispose();
    this.scene.background = this.previousBackground;
    this.siteRoot.position.set(0, 0, 0);
    this.siteRoot.rotation.set(0, 0, 0);
    this.renderer.xr.enabled = false;
    this.onEnd?.();
  }

  dispose() {
    if (this.session) this.session.end().catch(() => {});
  }
}

function load() {
  try {
    return { position: [0, 0, -10], yawDeg: 0, ...JSON.parse(localStorage.getItem(STORAGE_KEY) ?? '{}') };
  } catch {
    return { position: [0, 0, -10], yawDeg: 0 };
  }
}

function save(alignment) {
  try {
    localStorage.setItem(STORAGE_KEY, JSON.stringify(alignment));
  } catch {
    // private browsing: kept for this session only
  }
}
