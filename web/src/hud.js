// The HUD: connection state, age of the light vector, frames per second, a view of the dome
// with each patch coloured by its measured radiance, and the visitor's controls. The panel
// folds away with its button (or the H key); it starts folded on a small portrait screen,
// where it would cover a fifth of the site. At the kiosk only an unobtrusive status line is
// shown (H shows the dome and the smoothing: a kiosk has one fixed view, so no modes).

import { luminance } from './colour.js';

const DOME_PX = 120;
const SMALL_PORTRAIT = '(orientation: portrait) and (max-width: 600px)'; // as in style.css

/** Why a mode cannot start on this page, or null: camera and AR need a secure context. */
export function insecureReason() {
  if (globalThis.isSecureContext !== false) return null;
  return 'the camera and AR need a secure connection (https://): ask the site\'s staff for the https address';
}

export class Hud {
  constructor(root, app) {
    this.root = root;
    this.app = app;
    this.kiosk = app.mode === 'kiosk';
    root.classList.toggle('kiosk', this.kiosk);
    root.innerHTML = `
      <div class="statusline" role="status" aria-live="polite"></div>
      <button class="paneltoggle" aria-controls="hud-panel" aria-expanded="true" title="Controls (H)">☰</button>
      <div class="panel" id="hud-panel">
        <canvas class="dome" width="${DOME_PX}" height="${DOME_PX}" aria-label="measured sky, north up"></canvas>
        <div class="controls">
          <div class="modes" role="group" aria-label="view" ${this.kiosk ? 'hidden' : ''}>
            <button data-mode="visit">Visit</button>
            <button data-mode="camera">Camera</button>
            <button data-mode="ar" hidden>AR</button>
          </div>
          <label class="visitonly"><input type="checkbox" class="shading" checked> shading &amp; shadows</label>
          <label class="visitonly">shading <select class="shadingmode">
            <option value="lightmap">lightmap</option><option value="hull">hull planes</option>
          </select></label>
          <label>light follows sky in <output class="tauout"></output>
            <input type="range" class="tau" min="0" max="60" step="1" aria-label="smoothing time constant, seconds"></label>
          <button class="align" hidden>Reset alignment</button>
        </div>
      </div>
      <div class="message" hidden></div>`;
    this.statusLine = root.querySelector('.statusline');
    this.dome = root.querySelector('.dome');
    this.message = root.querySelector('.message');
    this.panel = root.querySelector('.panel');
    this.toggle = root.querySelector('.paneltoggle');
    this.toggle.hidden = this.kiosk; // the kiosk's visitors should not fold its status away
    root.querySelectorAll('.visitonly').forEach((e) => { e.hidden = this.kiosk; });
    this.setPanel(!this.kiosk && !matchMedia(SMALL_PORTRAIT).matches);
    this.toggle.addEventListener('click', () => this.setPanel(this.panel.hidden));
    this.message.addEventListener('click', () => this.setMessage(null)); // a tap dismisses a note
    root.querySelectorAll('[data-mode]').forEach((b) => b.addEventListener('click', () => {
      const why = b.dataset.mode !== 'visit' && insecureReason();
      if (why) this.setMessage(`Not available here: ${why}.`, 'warn');
      else app.switchMode(b.dataset.mode);
    }));
    root.querySelector('.shading').addEventListener('change', (e) => app.setShading(e.target.checked));
    root.querySelector('.shadingmode').value = app.shadingMode;
    root.querySelector('.shadingmode').addEventListener('change', (e) => app.setShadingMode(e.target.value));
    const tau = root.querySelector('.tau');
    tau.value = String(app.smoothingS);
    root.querySelector('.tauout').textContent = `${app.smoothingS} s`;
    tau.addEventListener('input', () => {
      app.setSmoothing(Number(tau.value));
      root.querySelector('.tauout').textContent = `${tau.value} s`;
    });
    root.querySelector('.align').addEventListener('click', () => app.resetAlignment());
    addEventListener('keydown', (e) => {
      if (e.key === 'h' || e.key === 'H') this.setPanel(this.panel.hidden);
    });
    this._lastDomeSeq = -1;
  }

  /** Show (true) or fold away (false) the panel. */
  setPanel(shown) {
    this.panel.hidden = !shown;
    this.toggle.setAttribute('aria-expanded', String(shown));
    this.toggle.setAttribute('aria-label', shown ? 'Hide the controls' : 'Show the controls');
    this.toggle.textContent = shown ? '×' : '☰';
  }

  setShadingMode(mode) {
    this.root.querySelector('.shadingmode').value = mode;
  }

  /** Which mode buttons to offer. Without a secure context camera and AR are offered anyway,
   * marked unavailable, and a tap says why (instead of the buttons silently missing). */
  showModes({ ar, camera, align }) {
    const insecure = insecureReason() !== null;
    for (const [mode, available] of [['ar', ar], ['camera', camera]]) {
      const button = this.root.querySelector(`[data-mode="${mode}"]`);
      button.hidden = !available && !insecure;
      button.classList.toggle('unavailable', !available);
      button.title = available ? '' : insecureReason() ?? '';
    }
    this.root.querySelector('.align').hidden = !align;
    this.root.querySelectorAll('[data-mode]').forEach((b) => b.classList.toggle('active', b.dataset.mode === this.app.mode));
  }

  /** A message over the picture (asset failure, fallback); null hides it. */
  setMessage(text, kind = 'info') {
    this.message.hidden = !text;
    this.message.textContent = text ?? '';
    this.message.dataset.kind = kind;
  }

  update() {
    const s = this.app.status;
    const age = s.lightAgeMs === null ? '-' : formatAge(s.lightAgeMs);
    const phone = s.lightSource === 'phone'; // the phone's own estimate (phoneestimate.js)
    const state = phone ? `phone's estimate${s.stale ? ', stale' : ''}` : s.connected ? (s.stale ? 'stale' : 'live')
      : s.lightSource === 'kept' ? `kept light, ${s.connection}` : s.connection;
    this.statusLine.textContent = `${state} · light ${age} · ${s.fps.toFixed(0)} fps${s.lightsExact || s.lightSeq === null ? '' : s.coarse ? ` · refining the light, ${(s.bytesLoaded / 1e6).toFixed(1)} MB` : ' · loading sun images'}`;
    this.statusLine.dataset.state = s.stale || (!s.connected && !phone) ? 'stale' : 'live';
    const applied = this.app.relighter?.applied;
    if (!this.panel.hidden && applied && applied.sequence !== this._lastDomeSeq) {
      this._lastDomeSeq = applied.sequence;
      this.drawDome(applied.r, this.app.feed.saturated);
    }
  }

  /** Plan view of the dome from above: zenith in the centre, north up, east right. */
  drawDome(r, saturated) {
    const lights = this.app.assets?.manifest?.dome.lights;
    if (!lights || !r) return;
    const ctx = this.dome.getContext('2d');
    const c = DOME_PX / 2;
    const R = c - 2;
    ctx.clearRect(0, 0, DOME_PX, DOME_PX);
    let max = 1e-9;
    for (let i = 0; i < lights.length; i++) max = Math.max(max, patchLuminance(r, i));
    const project = ([x, y, z]) => {
      const theta = Math.acos(Math.max(-1, Math.min(1, y))); // zenith angle
      const h = Math.hypot(x, z) || 1;
      const rho = (theta / (Math.PI / 2)) * R; // equidistant
      return [c + (rho * x) / h, c + (rho * z) / h]; // +X east right, -Z north up
    };
    lights.forEach((light, i) => {
      const lum = Math.max(1e-9, patchLuminance(r, i));
      // Hue from the patch's own RGB, brightness (lum / max)^(1/4): the sun's patch can be a
      // hundred times the sky's, and the sky's own gradient should still show.
      const level = Math.pow(lum / max, 1 / 4) * 255;
      const rgb = [0, 1, 2].map((ch) => Math.min(255, Math.round((Math.max(0, r[3 * i + ch]) / lum) * level)));
      ctx.beginPath();
      light.vertices.map(project).forEach(([px, py], j) => (j ? ctx.lineTo(px, py) : ctx.moveTo(px, py)));
      ctx.closePath();
      ctx.fillStyle = `rgb(${rgb.join(',')})`;
      ctx.fill();
      ctx.strokeStyle = saturated?.[i] ? '#ff0' : 'rgba(0,0,0,0.25)';
      ctx.lineWidth = saturated?.[i] ? 1.5 : 0.5;
      ctx.stroke();
    });
    ctx.fillStyle = '#fff';
    ctx.font = '10px system-ui, sans-serif';
    ctx.fillText('N', c - 3, 10);
    ctx.fillText('E', DOME_PX - 9, c + 3);
  }
}

/** Light i's luminance in r (n x 3). */
function patchLuminance(r, i) {
  return luminance(r[3 * i], r[3 * i + 1], r[3 * i + 2]);
}

function formatAge(ms) {
  if (ms < 1000) return `${Math.round(ms)} ms`;
  if (ms < 120000) return `${(ms / 1000).toFixed(1)} s`;
  return `${Math.round(ms / 60000)} min`;
}
