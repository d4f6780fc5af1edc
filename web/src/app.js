// The daylit client: renderer, boot and recovery, the light stream feeding the relight pass,
// the modes (kiosk, virtual visit, camera, AR), the HUD and window.daylit.
import * as THREE from 'three';
import { AssetError, Assets } from './assets.js';
import { CameraView } from './camera-view.js';
import { exposureFor, exposureFromPicture } from './exposure.js';
import { GpuMemoryMeter } from './gpumemory.js';
import { HdrFrame } from './hdr.js';
import { Hud, insecureReason } from './hud.js';
import { IrradianceTargets } from './irradiance.js';
import { Kiosk } from './kiosk.js';
import { KioskSun } from './kiosksun.js';
import { openSkyIrradiance, skySH9 } from './lightmath.js';
import { LightFeed } from './lightfeed.js';
import { LightStream } from './lightstream.js';
import { keepForOffline, registerOffline } from './offline.js';
import { Relighter } from './relight.js';
import { Site } from './site.js';
import { makeStatus } from './status.js';
import { chooseStart, firstBytes, measuredRate } from './startmode.js';
import { mapSizeFor, SunShadows } from './sun.js';
import { SunBounce } from './sunbounce.js';
import { VisitView } from './visit.js';
import { arSupported, rendererWithXrAntialias, XRView } from './xr.js';

const RELIGHT_MIN_INTERVAL_S = 0.1; // while the smoothed light glides, relight at most 10 Hz
const RELIGHT_THRESHOLD = 1e-3;     // ... until it is within 0.1 % of the measured one
const RETRY_BOOT_MS = 10000;
const EXPOSURE_TAU_S = 1.5;

export class App {
  constructor({ canvas, hudRoot, params }) {
    this.canvas = canvas;
    this.hudRoot = hudRoot;
    this.params = params;
    this.mode = params.get('mode') ?? 'visit';
    if (!['kiosk', 'visit', 'camera', 'ar'].includes(this.mode)) this.mode = 'visit';
    this.testing = params.has('test');
    this.fixedExposure = params.has('exposure') ? Number(params.get('exposure')) : null;
    // ?targets=rgbe: a GPU without half-float targets (RGBA8 relight targets, the frame drawn
    // straight to the screen); ?frame=direct: only the latter. For tests and the benchmark.
    this.forceRgbe = params.get('targets') === 'rgbe';
    this.linearFrame = params.get('frame') !== 'direct' && !this.forceRgbe;
    this.smoothingS = Number(params.get('smoothing') ?? 0);
    // The device profile (docs/web.md, "GPU memory"): `phone` (a touch screen at most 600 CSS
    // px across, or ?profile=phone) draws the sun's shadow maps at 1024² instead of 2048² and
    // the linear frame without MSAA.
    this.profile = params.get('profile') ?? (isPhone() ? 'phone' : 'desktop');
    this.shadingOn = true;
    // Kakuta's two ways to shade the virtual objects; `?shading=hull` starts with hull planes.
    this.shadingMode = params.get('shading') === 'hull' ? 'hull' : 'lightmap';
    this.error = null;
    this.ready = false;
    this.contextLost = false;
    this.fps = 0;
    this.frameMs = 0;
    this.startChoice = null; // the start taken: {mode, asked, bytesPerS, fullFirstS, reason} (startmode.js)
    this.firstRelitMs = null; // the first relit frame (from a coarse start, if the build has one)
    this.exactRelitMs = null; // the first exactly relit frame (every layer, every light image)
    this.firstRelitBytes = null;
    this.readyBytes = null;
    // The light drawn: the server's, the phone's own estimate, or the kept one (lightfeed.js).
    this.feed = new LightFeed(this, params, () => { this._needRelight = true; });
    this.exposure = 1;
    this.exposureMeter = 'scene'; // what set it (status.exposureMeter)
    this.pictureReading = null; // camera mode's last picture meter reading (picturemeter.js)
    // The offline visit (offline.js): the service worker's state and what it has kept (the
    // last live light is the feed's).
    this.offlineWorker = 'none';
    this.offlineKept = null;
    this.status = makeStatus(this);
  }

  async start() {
    this.startS = performance.now() / 1000;
    this.hud = new Hud(this.hudRoot, this);
    this._createRenderer();
    const params = this.params;
    this._offlineRegistered = registerOffline(params).then((state) => { this.offlineWorker = state; });
    this.stream = new LightStream({
      siteCamera: this.mode === 'kiosk',
      // The kiosk URL's ?token= (docs/server.md, "Who can see what") opens the site camera.
      token: this.mode === 'kiosk' ? params.get('token') : null,
      onHello: () => this._onHello(),
      onLight: (m) => this.feed.push(m),
      onFrame: (f) => this.kiosk?.addFrame(f),
      onMask: (m) => this.kiosk?.addMask(m),
    });
    this.stream.start();
    await this._boot();
  }

  _createRenderer() {
    // The canvas's own MSAA only where the frame is drawn straight to it (AR, ?frame=direct, a
    // GPU without half-float targets): the linear frame has its own (hdr.js) and reaches the
    // canvas as one full-screen pass, which MSAA leaves as it was, while 4 samples of colour
    // and depth cost 42 MB at a phone's 780 x 1688 (docs/web.md, "GPU memory"). AR's layer
    // is antialiased either way, also when AR is chosen later from the visit.
    const direct = this.mode === 'ar' || !this.linearFrame || !HdrFrame.probe();
    const renderer = rendererWithXrAntialias(this.canvas, {
      antialias: this.mode !== 'kiosk' && direct,
      preserveDrawingBuffer: this.testing, // screenshots in tests
      powerPreference: 'high-performance',
    });
    // Counts every texture and render target from here on (docs/web.md, "GPU memory").
    this.gpuMemory = new GpuMemoryMeter(renderer.getContext());
    renderer.setPixelRatio(Math.min(devicePixelRatio, 2));
    renderer.outputColorSpace = THREE.SRGBColorSpace;
    renderer.toneMapping = THREE.NeutralToneMapping;
    renderer.toneMappingExposure = 1;
    this.renderer = renderer;
    this.hdrSupported = HdrFrame.supported(renderer);
    // ?msaa=N: the linear frame's samples whatever the GPU (the benchmark counts what a phone's
    // hardware GPU allocates, 4, on the tests' software one, which defaults to none).
    const msaa = Number.parseInt(this.params.get('msaa') ?? '', 10);
    this.hdrSamples = Number.isFinite(msaa) ? Math.max(0, msaa) : HdrFrame.defaultSamples(renderer, this.mode === 'kiosk', this.profile);
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.1, 2000);
    this.scene = new THREE.Scene();
    this._resize();
    addEventListener('resize', () => this._resize());
    this.canvas.addEventListener('webglcontextlost', (e) => {
      e.preventDefault(); // ask for it back
      this.contextLost = true;
      this.ready = false;
      this.hud?.setMessage('The graphics context was lost; restoring…', 'warn');
    });
    this.canvas.addEventListener('webglcontextrestored', () => {
      this.contextLost = false;
      // Every GPU resource is gone: build them again (the files come from the HTTP cache).
      this._teardown();
      this._boot();
    });
    this._lastFrameT = performance.now();
    renderer.setAnimationLoop((t, frame) => this._frame(t, frame));
  }

  _resize() {
    const w = innerWidth;
    const h = innerHeight;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.view?.fit?.(); // a phone turned to landscape: the site fills the new shape
  }

  async _boot() {
    const loading = (bytes) => this.hud.setMessage(this.mode === 'kiosk' ? null
      : `Loading the reconstruction… ${formatMB(bytes)}`);
    loading(0);
    try {
      this.assets = new Assets(this.params.get('manifest') ?? '/build/manifest.json',
        { textureMode: this.params.get('textures') ?? 'exact', onProgress: loading });
      this.assets.initTextures(this.renderer);
      const manifest = await this.assets.loadManifest();
      document.title = `${manifest.scene.name} under the live sky · daylit`;
      const kiosk = this.mode === 'kiosk';
      const view = manifest.views.find((v) => v.id === (this.params.get('view') ?? manifest.views[0]?.id));
      if (kiosk && !view) throw new AssetError('the manifest', 'the build has no fixed view for a kiosk');
      const stacks = kiosk ? Object.keys(view.stacks).map((s) => `${view.id}.${s}`)
        : manifest.atlases.flatMap((a) => Object.keys(a.stacks).map((s) => `${a.id}.${s}`));
      // The hull planes serve only hull-plane mode: loaded when it is chosen, not before (they
      // are the largest download of a phone).
      this._hullStacks = stacks.filter((key) => key.startsWith('hull.'));
      this.relighter = new Relighter(this.renderer, this.assets,
        { stacks, deferred: this._hullStacks, views: kiosk, dome: !kiosk, rgbe: this.forceRgbe });
      // The coarse start only where the link is slow (startmode.js; docs/web.md, "Slow links").
      const now = [...this.relighter.stacks.values()].filter((s) => !this.relighter.deferred.has(s.key));
      this.startChoice = chooseStart(this.params.get('start'),
        firstBytes(manifest, now.map((s) => s.compact)), await measuredRate(this.assets.manifestUrl));
      this.relighter.coarseStart = this.startChoice.mode === 'coarse';
      // The kiosk needs the model too, for the sun's shadows in its view (kiosksun.js).
      const [gltf] = await Promise.all([
        this.assets.gltf(manifest.model.path),
        this.relighter.load(),
        this.shadingMode === 'hull' ? this.relighter.activate(this._hullStacks) : null,
      ]);
      this.relighter.onApplied = (applied) => this._onApplied(applied);
      this.relighter.onRefineError = (err) => this.hud.setMessage(`${err.message}. Showing the coarse light meanwhile.`, 'warn');
      // Everything is here (or a coarse start: the status line counts the rest): the loading
      // note goes (before the mode, whose note must stay).
      this.assets.onProgress = null;
      this.readyBytes = this.assets.bytesLoaded; // the loading note's last count
      this.hud.setMessage(null);
      if (this.stream.hello) this._onHello(); // a kiosk's note that outlasts the loading
      if (kiosk) {
        // The view's sun bounce (its O and S images of the sun's patch, fetched when the sun
        // enters a patch, as the visit's atlases'); a build before 2026-11-25 has none.
        this.sunBounce = new SunBounce(this.renderer, this.assets, this.relighter.format, { view });
        this.kiosk = new Kiosk(this.renderer, this.relighter, view,
          new KioskSun(this.renderer, gltf, manifest, view, this.relighter.format), this.sunBounce);
      } else {
        // The hull planes' sun bounce too only once hull-plane mode is chosen (a phone's visit
        // fetched it for nothing in lightmap mode: 0.44 MB at 400 lights, final).
        this.sunBounce = new SunBounce(this.renderer, this.assets, this.relighter.format,
          { deferred: this.shadingMode === 'hull' ? [] : this._hullStacks });
        this.irradiance = new IrradianceTargets(this.renderer, this.relighter, this.sunBounce);
        this.site = new Site(gltf, manifest, this.relighter, this.irradiance);
        this.scene.add(this.site.root);
        if (this.site.sky) this.scene.add(this.site.sky);
        this.sunShadows = new SunShadows(this.renderer, this.scene,
          { virtual: this.site.nodes.virtual, real: this.site.nodes.real }, this.site.sun,
          { groundY: this.site.groundY, siteRoot: this.site.root, mapSize: mapSizeFor(this.profile) });
        this.sunShadows.setMaterials(this.site.sunMaterials());
        await this._enterMode(this.mode);
      }
      this.feed.keepFor(manifest.scene.id);
      this.ready = true;
      this.error = null;
      // What this visit loaded, kept for the next one without a network (offline.js).
      this._offlineRegistered.then(() => (this.offlineWorker === 'registered' ? keepForOffline() : null))
        .then((answer) => { this.offlineKept = answer; }, () => {});
      if (this.feed.smoother.value) this._needRelight = true;
      const ar = !kiosk && await arSupported();
      this.hud.showModes({ ar, camera: !kiosk && !!navigator.mediaDevices?.getUserMedia, align: this.mode === 'camera' || this.mode === 'ar' });
    } catch (err) {
      // Downloads still on their way must not write "Loading…" over the error.
      if (this.assets) this.assets.onProgress = null;
      this.error = err instanceof AssetError ? err.message : `Could not start: ${err.message}`;
      this.hud.setMessage(`${this.error}. Retrying in ${RETRY_BOOT_MS / 1000} s.`, 'error');
      this._teardown();
      clearTimeout(this._bootTimer);
      this._bootTimer = setTimeout(() => this._boot(), RETRY_BOOT_MS);
    }
  }

  /** A kiosk without the operator's token draws the baked view: say why. */
  _onHello() {
    if (this.stream.siteCameraDenied) {
      this.hud.setMessage('The site camera needs the operator\'s token: open this kiosk as ?mode=kiosk&token=…', 'warn');
    }
  }

  _teardown() {
    this.ready = false;
    this.view?.dispose?.();
    this.view = null;
    if (this.site) {
      this.scene.remove(this.site.root);
      if (this.site.sky) this.scene.remove(this.site.sky);
    }
    this.site = null;
    this.feed.forgetSite(); // the phone's estimator's proxies were the old site's meshes
    this.sunShadows?.dispose();
    this.sunShadows = null;
    this.sunBounce?.dispose();
    this.sunBounce = null;
    this.sunBounceDrawn = null;
    this.irradiance?.dispose();
    this.irradiance = null;
    this.hdr?.dispose();
    this.hdr = null;
    this.kiosk?.dispose();
    this.kiosk = null;
    this.relighter?.dispose();
    this.relighter = null;
    this.assets?.dispose();
  }

  async _enterMode(mode) {
    this.view?.dispose?.();
    this.view = null;
    if (mode === 'ar') {
      try {
        this.view = await XRView.open(this.renderer, this.scene, this.site.root, this.hudRoot, () => this.switchMode('visit'));
        this.site.setMode('passthrough', this.shadingMode);
        this.mode = 'ar';
        return;
      } catch (err) {
        this.hud.setMessage(`AR is not available here (${err.message}); trying the camera.`, 'warn');
        mode = 'camera';
      }
    }
    if (mode === 'camera') {
      try {
        this.view = await CameraView.open(this.camera, this.canvas, this.assets.manifest, this.scene);
        this.site.setMode('overlay', this.shadingMode);
        this.mode = 'camera';
        return;
      } catch (err) {
        // Stays until tapped: the visitor asked for the camera and should know why not.
        this.hud.setMessage(`No camera (${insecureReason() ?? err.message}): showing the virtual visit.`, 'warn');
      }
    }
    this.view = new VisitView(this.camera, this.canvas, this.site);
    this.site.setMode('visit', this.shadingMode);
    this.mode = 'visit';
  }

  async switchMode(mode) {
    if (!this.site || mode === this.mode) return;
    await this._enterMode(mode);
    this.hud.showModes({ ar: await arSupported(), camera: !!navigator.mediaDevices?.getUserMedia, align: this.mode !== 'visit' });
  }

  setShading(on) {
    this.shadingOn = on;
    this.site?.setShading(on);
  }

  /** 'lightmap' or 'hull' (hull planes, whose textures are fetched the first time). */
  async setShadingMode(mode) {
    this.shadingMode = mode === 'hull' ? 'hull' : 'lightmap';
    this.hud.setShadingMode(this.shadingMode);
    if (this.shadingMode === 'hull' && this.relighter) {
      this.hud.setMessage('Loading the hull planes…');
      try {
        await this.relighter.activate(this._hullStacks);
        const drawing = this.sunBounce?.activate(this._hullStacks);
        if (drawing) {
          await drawing;
          this.irradiance?.update();
        }
        this.hud.setMessage(null);
      } catch (err) {
        this.hud.setMessage(`${err.message}. Staying with the lightmap.`, 'warn');
        setTimeout(() => this.hud.setMessage(null), 5000);
        this.shadingMode = 'lightmap';
        this.hud.setShadingMode(this.shadingMode);
      }
    }
    this.site?.setMode(this.site.view, this.shadingMode); // the newest choice, after any await
  }

  setSmoothing(tauS) {
    this.smoothingS = Math.max(0, tauS);
    this.feed.smoother.tauS = this.smoothingS;
  }

  resetAlignment() {
    this.view?.resetAlignment?.();
  }

  // ---------------------------------------------------------------------------- light

  _maybeRelight(tS) {
    const smoother = this.feed.smoother;
    if (!this.ready || !smoother.value) return;
    smoother.step(tS);
    const gliding = smoother.remaining() > RELIGHT_THRESHOLD;
    const due = this._needRelight || (gliding && tS - (this._lastRelightS ?? 0) > RELIGHT_MIN_INTERVAL_S);
    if (!due) return;
    this._needRelight = false;
    this._lastRelightS = tS;
    const { r, sun } = this.feed.smoothed();
    this._pendingSun = sun;
    this.relighter.update(r, this.feed.light?.sequence ?? 0).catch((err) => {
      this.hud.setMessage(`${err.message}. Keeping the last light.`, 'warn');
      this._needRelight = true; // try the images again with the next vector
    });
  }

  _onApplied(applied) {
    const r = applied.r;
    const open = openSkyIrradiance(r, this.assets.manifest.dome.lights.map((l) => l.cosine_weighted_sr));
    const sun = this._pendingSun;
    this.sunShadows?.setSun(sun?.direction ?? [0, 0, 0], sun?.normalIrradiance ?? [0, 0, 0]);
    // The surfaces read the relit sky and the sun's bounce summed (irradiance.js): once when the
    // bounce is drawn at once (its images are here), else now with the new sky and again when
    // the new sun's bounce is drawn. Kept so that whoever waits for a drawn light
    // (debug.relight) can wait for the bounce too.
    const drawing = this.sunBounce?.update(sun) ?? null;
    this.irradiance?.update();
    this.sunBounceDrawn = drawing?.then(() => {
      this.irradiance?.update();
      this.kiosk?.onRelight(sun); // S' with the bounce, for the camera scale
    }, (err) => {
      this.hud.setMessage(`${err.message}. The sun's bounce follows with the next light.`, 'warn');
      setTimeout(() => this.hud.setMessage(null), 5000);
    }) ?? Promise.resolve();
    // The open ground's irradiance with the sun (unshadowed): the exposure's reference.
    const sunUp = sun ? Math.max(0, sun.direction[1]) : 0;
    const ground = open.map((e, c) => e + (sun ? sun.normalIrradiance[c] * sunUp : 0));
    const mean = (ground[0] + ground[1] + ground[2]) / 3;
    this.site?.setLight({
      L: skySH9(r, this.assets.manifest.dome.lights.map((l) => l.sh9)),
      openIrradiance: open,
      groundIrradiance: ground,
      flatIrradiance: [mean, mean, mean].map((v) => v * 0.8), // shading off: even, a little dimmer
    });
    this._groundIrradiance = ground; // the exposure's meter reading (_updateExposure)
    if (this.kiosk) this.kiosk.onRelight(sun);
    if (this.firstRelitMs === null) this._firstRelitPending = true;
    if (applied.exact && this.exactRelitMs === null) this._exactRelitPending = true;
  }

  _updateExposure(dtS, nowS = performance.now() / 1000) {
    if (this.fixedExposure !== null) {
      this.exposure = this.fixedExposure;
    } else if (this._groundIrradiance && this.assets?.manifest) {
      // Metered on the open ground (exposure.js): a lightness key in the visit and the kiosk's
      // synthesized picture, a camera's auto exposure over a camera picture.
      const meter = this.site?.view === 'overlay' || this.site?.view === 'passthrough' ? 'camera' : 'scene';
      const albedo = this.assets.manifest.ground.albedo;
      // Camera mode meters its own picture (picturemeter.js), AR its passthrough's where the
      // session gives the page the camera's images (xrmeter.js).
      this.pictureReading = this.view?.meter?.read(this.camera, nowS, !this._exposureSet) ?? null;
      const fromPicture = this.pictureReading
        ? exposureFromPicture(this.pictureReading.level, this._groundIrradiance, albedo) : null;
      this.exposureMeter = fromPicture !== null ? 'picture' : meter;
      const target = fromPicture ?? exposureFor(this._groundIrradiance, albedo, meter);
      const a = this._exposureSet ? 1 - Math.exp(-dtS / EXPOSURE_TAU_S) : 1;
      this._exposureSet = true;
      this.exposure += a * (target - this.exposure);
    }
    if (this.site) this.site.shared.exposure.value = this.exposure;
  }

  // ---------------------------------------------------------------------------- frames

  _frame(tMs, xrFrame) {
    const now = performance.now();
    const dt = Math.max(1e-3, (now - this._lastFrameT) / 1000);
    this._lastFrameT = now;
    this.fps = this.fps ? this.fps + 0.1 * (1 / dt - this.fps) : 1 / dt;
    if (this.contextLost) return;
    const t0 = performance.now();
    this.feed.tick(now / 1000);
    this._maybeRelight(now / 1000);
    this._updateExposure(dt, now / 1000);
    this.renderFrame(xrFrame);
    this.frameMs = performance.now() - t0;
    // One time for the frame: a first relit frame that is also exact has both equal (two
    // clock reads could straddle the browser's 0.1 ms clock step).
    const drawnMs = performance.now();
    if (this._firstRelitPending && this.relighter?.applied) {
      this._firstRelitPending = false;
      this.firstRelitMs = drawnMs;
      this.firstRelitBytes = this.assets.bytesLoaded; // what that picture waited for
    }
    if (this._exactRelitPending && this.relighter?.applied) {
      this._exactRelitPending = false;
      this.exactRelitMs = drawnMs;
    }
    this.hud.update();
  }

  /** One frame of the current mode (the benchmark calls it directly). */
  renderFrame(xrFrame) {
    const renderer = this.renderer;
    if (!this.ready || !this.relighter?.applied) {
      renderer.setClearColor(0x101418, 1);
      renderer.clear();
      return;
    }
    if (this.kiosk) {
      this.kiosk.render({ exposure: this.exposure, strength: this.shadingOn ? 1 : 0 });
      return;
    }
    this.view?.update(xrFrame);
    this.sunShadows?.follow(); // AR places and turns the site: the sun's uniforms follow it
    renderer.setClearColor(0x000000, this.mode === 'ar' ? 0 : 1);
    // Linear HDR, then one display pass (hdr.js); AR's passthrough and GPUs without half-float
    // targets draw straight to the screen (the shadowing planes' approximate fallback).
    const linear = this.mode !== 'ar' && !renderer.xr.isPresenting && this.hdrSupported && this.linearFrame;
    this.site?.setLinearFrame(linear);
    if (linear) {
      this.hdr ??= new HdrFrame(renderer, { samples: this.hdrSamples });
      this.hdr.render(this.scene, this.camera, this.site?.view !== 'overlay');
    } else {
      renderer.render(this.scene, this.camera);
    }
  }
}

/** A phone: a coarse pointer (touch) and a screen at most 600 CSS px across. */
function isPhone() {
  return matchMedia('(pointer: coarse)').matches && Math.min(screen.width, screen.height) <= 600;
}

function formatMB(bytes) {
  return `${(bytes / 1e6).toFixed(bytes < 1e7 ? 1 : 0)} MB`;
}
