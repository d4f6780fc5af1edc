import * as THREE from 'three';

// Hooks for the headless-browser tests and the benchmark (window.daylit.debug, only with
// ?test in the URL): relight with a given vector, read render targets back, time frames.

function toBase64(floats) {
  const bytes = new Uint8Array(floats.buffer, floats.byteOffset, floats.byteLength);
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

/** Names of the GPU objects the client's modules hold (WebGLTexture or WebGLRenderbuffer ->
 * e.g. 'hull.I base', 'sun all depth', 'hdr frame depth'), for the meter's breakdown. */
function gpuNames(app) {
  const names = new Map();
  const props = app.renderer.properties;
  const texture = (t, name) => {
    const gl = t && props.get(t).__webglTexture;
    if (gl) names.set(gl, name);
  };
  const target = (rt, name) => {
    if (!rt) return;
    texture(rt.texture, name);
    if (rt.depthTexture) texture(rt.depthTexture, `${name} depth`);
    const p = props.get(rt);
    if (p.__webglDepthbuffer && !Array.isArray(p.__webglDepthbuffer)) names.set(p.__webglDepthbuffer, `${name} depth`);
    if (p.__webglDepthRenderbuffer) names.set(p.__webglDepthRenderbuffer, `${name} depth (MSAA)`);
    for (const [i, rb] of (p.__webglColorRenderbuffer ?? []).entries()) if (rb) names.set(rb, `${name} colour ${i} (MSAA)`);
  };
  for (const [key, s] of app.relighter?.stacks ?? []) {
    texture(s.base, `${key} base`);
    texture(s.etc1s, `${key} etc1s`);
    texture(s.gain, `${key} gain`);
    target(s.target, `${key} target`);
    for (const [i, levels] of s.lights) levels.forEach((t, l) => texture(t, `${key} light ${i}.${l}`));
  }
  for (const [key, t] of Object.entries(app.relighter?.targets ?? {})) if (!names.has(props.get(t.texture).__webglTexture)) target(t, `${key} target`);
  for (const [key, t] of Object.entries(app.irradiance?.targets ?? {})) target(t, `irradiance ${key}`);
  for (const [key, s] of app.sunBounce?.stacks ?? []) target(s.target, `sun bounce ${key}`);
  target(app.sunShadows?.normals, 'sun normals (shared)');
  for (const [set, m] of Object.entries(app.sunShadows?.maps ?? {})) {
    texture(m.depth, `sun ${set} depth`);
    target(m.rows, `sun ${set} coarse rows`);
    target(m.coarse, `sun ${set} coarse`);
    target(m.visibility, `sun ${set} visibility`);
    target(m.groundVisibility, `sun ${set} ground visibility`);
  }
  target(app.hdr?.target, 'hdr frame');
  return names;
}

export function debugApi(app) {
  /** The camera's world matrix (16, column-major), vertical field of view (degrees) and aspect
   * as they are now (without updating the view). */
  const drawnPose = () => {
    app.camera.updateMatrixWorld();
    return { matrixWorld: app.camera.matrixWorld.toArray(), fovDeg: app.camera.fov, aspect: app.camera.aspect };
  };
  /** For each canvas pixel [x, y] (CSS px), `perPixel(hits, raycaster)` of the visible site's
   * surfaces along its ray (three's Raycaster, nearest first). */
  const siteHits = (pixels, perPixel) => {
    const rect = app.canvas.getBoundingClientRect();
    const raycaster = new THREE.Raycaster();
    const meshes = [];
    app.site.root.traverse((o) => { if (o.isMesh && o.visible && o.userData.daylit) meshes.push(o); });
    return pixels.map(([x, y]) => {
      raycaster.setFromCamera(new THREE.Vector2(2 * x / rect.width - 1, 1 - 2 * y / rect.height), app.camera);
      return perPixel(raycaster.intersectObjects(meshes, false), raycaster);
    });
  };
  return Object.freeze({
    /**
     * Relight with r (flat n x 3 array: the sky) and, optionally, the sun ({direction: [x, y,
     * z] toward it, normalIrradiance: [r, g, b] W/m^2}, as a version-2 light message carries
     * it), and wait until it is drawn with every light image.
     */
    async relight(r, sequence = 0, sun = null) {
      app.stream?.stop(); // the test's vector, not the server's
      app.feed.serverLights += 1; // (nor the phone's own estimate: it stays off unless ?sky=phone)
      app.feed.light = { rgb: Float32Array.from(r), sequence, captureTime: Date.now() / 1000, stale: false, sun };
      const v = Float64Array.from([...r, ...(sun?.normalIrradiance ?? [0, 0, 0])]);
      app.feed.smoother.push(v, performance.now() / 1000);
      app.feed.smoother.value = Float64Array.from(v);
      const { r: sky, sun: drawn } = app.feed.smoothed();
      app._pendingSun = drawn;
      let applied = await app.relighter.update(sky, sequence);
      if (!applied.exact) applied = await app.relighter.update(sky, sequence);
      await app.sunBounceDrawn; // the sun's bounce images are fetched when the sun enters a patch
      return { sequence: applied.sequence, exact: applied.exact, selected: applied.selected };
    },
    /**
     * What each canvas pixel [x, y] (CSS pixels, from the top left) shows: the world point,
     * normal and the mesh's role and name (three's Raycaster against the visible site), or
     * null over the sky. The tests evaluate the oracle there.
     */
    pick(pixels) {
      return siteHits(pixels, (hits, raycaster) => {
        if (!hits.length) return null;
        // Coplanar surfaces: the shadowing plane is drawn over the open ground (polygon offset).
        const hit = hits.find((h) => h.distance < hits[0].distance + 1e-3 && h.object.userData.daylit.role === 'shadowing-plane') ?? hits[0];
        const normal = hit.face.normal.clone().transformDirection(hit.object.matrixWorld);
        if (normal.dot(raycaster.ray.direction) > 0) normal.negate();
        const info = hit.object.userData.daylit;
        const albedo = hit.object.userData.albedo?.toArray() ?? null;
        return { point: hit.point.toArray(), normal: normal.toArray(), role: info.role, atlas: info.atlas ?? null, name: hit.object.name, albedo };
      });
    },
    /** Every visible surface along each pixel's ray, nearest first: [{role, atlas, name, distance}]. */
    pickAll(pixels) {
      return siteHits(pixels, (hits) => hits.map((h) => ({
        role: h.object.userData.daylit.role, atlas: h.object.userData.daylit.atlas ?? null,
        name: h.object.name, distance: h.distance, point: h.point.toArray(),
        normal: h.face.normal.clone().transformDirection(h.object.matrixWorld).toArray(),
      })));
    },
    /** Where world points appear on the canvas: [x, y] CSS pixels from the top left. */
    project(points) {
      const rect = app.canvas.getBoundingClientRect();
      app.camera.updateMatrixWorld();
      return points.map((p) => {
        const v = new THREE.Vector3(...p).project(app.camera);
        return [(v.x + 1) / 2 * rect.width, (1 - v.y) / 2 * rect.height];
      });
    },
    /** The displayed picture (after tone mapping and sRGB), RGBA8 as base64, rows from the top;
     * render false: the frame last drawn (in AR, the one the XR session's loop drew). */
    screen(render = true) {
      if (render) app.renderFrame();
      const gl = app.renderer.getContext();
      const w = gl.drawingBufferWidth;
      const h = gl.drawingBufferHeight;
      const px = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
      const flipped = new Uint8Array(px.length);
      for (let row = 0; row < h; row++) flipped.set(px.subarray((h - 1 - row) * w * 4, (h - row) * w * 4), row * w * 4);
      return { width: w, height: h, data: toBase64(flipped) };
    },
    /** Show the site as over a camera picture of one colour (sRGB 0-1), or back to the visit. */
    overlay(colour) {
      if (colour) {
        app.scene.background = new THREE.Color().setRGB(...colour, THREE.SRGBColorSpace);
        app.site.setMode('overlay', app.shadingMode);
      } else {
        app.scene.background = null;
        app.site.setMode('visit', app.shadingMode);
      }
    },
    /** Wait until the sun's bounce of the newest light is drawn (its images fetched). */
    async waitSunBounce() {
      await app.sunBounceDrawn;
    },
    /** Wait until the sun's bounce is drawn for the applied sun; its patch (-1: none). */
    async sunBounce() {
      const sun = app._pendingSun;
      if (app.sunBounce) await app.sunBounce.update(sun);
      app.irradiance?.update();
      return app.sunBounce?.patch ?? -1;
    },
    /** The sun's bounce target of an atlas stack ('ground.I') as base64 float32 RGBA. */
    readSunBounce(key) {
      const { width, height, data } = app.relighter.readTarget(app.sunBounce.stacks.get(key).target);
      return { width, height, data: toBase64(data) };
    },
    /** How often the sun's shadow maps were rendered (they follow the sun, not the frames). */
    sunShadowRenders: () => app.sunShadows?.renders ?? 0,
    /** Each shadow map's metres per texel and the maps' GPU bytes. */
    sunMaps: () => ({
      texelM: Object.fromEntries(Object.entries(app.sunShadows?.maps ?? {}).map(([k, m]) => [k, m.info.x])),
      gpuBytes: app.sunShadows?.gpuBytes ?? 0,
    }),
    targets: () => Object.keys(app.relighter.targets),
    /** The relight targets' format (passes.js targetFormat) and whether the frame is linear HDR. */
    formats: () => ({ rgbe: app.relighter.format.rgbe, linearFrame: !!app.site?.shared.linearOut.value }),
    /** The applied light vector and one target read back in the same instant. */
    /** GPU allocations (gpumemory.js) logged from gpuLog(true) to gpuLog(false), which
     * returns them: [[GL target, 'storage' or 'target:level', bytes]]. */
    gpuLog(start) {
      const log = app.gpuMemory.log ?? null;
      app.gpuMemory.log = start ? [] : null;
      return log;
    },
    /** Every live GPU allocation, named where a module holds it, largest first:
     * [{name, bytes, format, w, h, d, samples}] (docs/web.md, "GPU memory"). */
    gpuBreakdown() {
      const names = gpuNames(app);
      return app.gpuMemory.allocations((o) => names.get(o));
    },
    snapshot(key) {
      const applied = app.relighter.applied;
      const { width, height, data } = app.relighter.read(key);
      return { sequence: applied.sequence, r: Array.from(applied.r), width, height, data: toBase64(data) };
    },
    /** A relight target as base64 float32 RGBA, rows from the top. */
    read(key) {
      const { width, height, data } = app.relighter.read(key);
      return { width, height, data: toBase64(data) };
    },
    /** The kiosk's linear composite at the view's resolution. */
    kioskComposite(options = {}) {
      const { width, height, data } = app.kiosk.readComposite(options);
      return { width, height, data: toBase64(data) };
    },
    kioskState: () => ({
      hasFrame: app.kiosk.uniforms.hasFrame.value, hasOcclusion: app.kiosk.uniforms.hasOcclusion.value,
      frameCaptureTime: app.kiosk.shown?.captureTime ?? null,
      maskCaptureTime: app.kiosk.shownMask?.captureTime ?? null,
      cameraScale: app.kiosk.cameraScale, framesShown: app.kiosk.framesShown,
    }),
    setCameraScale: (k) => app.kiosk.setCameraScale(k),
    /** The kiosk's sun term (kiosksun.js): drawn or not, and how often its view pass ran. */
    kioskSun: () => ({ on: app.kiosk?.sun?.on ?? false, renders: app.kiosk?.sun?.renders ?? 0,
      mapRenders: app.kiosk?.sun?.shadows.renders ?? 0 }),
    /** Milliseconds of one sun move at the kiosk: both shadow maps and the view pass, waited
     * for (a 1-pixel read). */
    timeKioskSun() {
      const ks = app.kiosk.sun;
      const t0 = performance.now();
      ks.shadows.render();
      ks.render();
      app.relighter.readTarget(ks.targets.S); // waits for the GPU
      return performance.now() - t0;
    },
    /** Force the kiosk to pick a frame now (tests step it without waiting for rAF). */
    kioskTick: () => app.kiosk.render({ exposure: app.exposure, strength: 1 }),
    setExposure: (e) => { app.fixedExposure = e; },
    /** The HUD's alignment reset: the visitor's and the registration's turns go. */
    resetAlignment: () => app.resetAlignment(),
    /** Camera mode: stand at a site point (metres; the two-finger walk's standpoint, and its
     * height, a phone held up on a balcony or at eye height). */
    standAt: (position) => {
      app.view.alignment.position = position.slice();
      app.view.update();
    },
    /** The camera's pose as drawn now: world matrix (16, column-major) and vertical field of
     * view, degrees (camera mode: from the standpoint and the device's orientation). */
    cameraPose: () => {
      app.view?.update?.();
      return drawnPose();
    },
    /** The phone's own estimate from the picture now (phoneestimate.js; null: none possible),
     * its light applied as the app applies it, and the pose and sun it was made with; `turned`:
     * the pose after the registration turned the view (camera-view.js turnBy). */
    phoneEstimate: () => {
      app.view?.update?.();
      const read = drawnPose();
      const estimate = app.feed.estimate(performance.now() / 1000, true);
      return estimate && { ...estimate, sun: app.feed.sunNow(), ...read, turned: drawnPose() };
    },
    /** Camera mode under a server sky: the pose's registration on the picture now (lightfeed.js
     * register: {shiftPx, turnDeg, fisher}; null: none made), the pose it read with and
     * `turned`, the pose after the view followed it. */
    phoneRegister: () => {
      app.view?.update?.();
      const read = drawnPose();
      const shift = app.feed.register(performance.now() / 1000, true);
      return shift && { ...shift, ...read, turned: drawnPose() };
    },
    /** The frame loop's phone estimates and registrations held (true) or let go: only
     * phoneEstimate()'s and phoneRegister()'s are made, so that a test knows the pose each was
     * read with. False outside camera mode. */
    holdPhoneEstimates: (held) => {
      const reader = app.feed.phoneReader();
      if (reader) reader.held = !!held;
      return !!reader;
    },
    /** The phone estimate's pose registration (poseregister.js) on or off: the benchmark's
     * baseline. Takes effect from the next estimate. */
    registerPose: (on) => {
      app.feed.phoneReader(); // the estimator exists (before the orientation too)
      app.feed.phoneEstimator.registerPose = !!on;
    },
    /** The seed of the phone estimate's pool (its pixels and their bounce directions;
     * phonepool.js poolForPose): the benchmarks' spread over seeds; with `perezClear` false,
     * the clear sky's CIE shape without the Perez fit (their baseline). Takes effect from the
     * next estimate, with a new pool. */
    phonePoolSeed: (seed, perezClear = true) => {
      app.feed.phoneReader();
      app.feed.phoneEstimator.poolSeed = seed;
      app.feed.phoneEstimator.perezClear = perezClear;
      app.feed.phoneEstimator.forgetPose();
    },
    /** The phone estimate's copy of the picture at [w, h] pixels instead of ESTIMATE_SIZE
     * (phoneestimate.js): the benchmarks' baseline. Takes effect from the next estimate, with a
     * new pool. False outside camera mode. */
    phoneCopySize: (size) => {
      const reader = app.feed.phoneReader();
      if (!reader) return false;
      reader.resize(size);
      app.feed.phoneEstimator.forgetPose();
      return true;
    },
    /** What the phone's last estimate read ({used, shaded, topUp, shadeSamples, types: [[CIE
     * type, the fit's sun/sky ratio]...]}): why it made none. */
    phoneEstimateWhy: () => app.feed.phoneEstimator?.why ?? null,
    /** The phone estimate's shade top-up (phoneshade.js; off unless asked for) and its bounce
     * surfaces lit by the model sky on their tilt (on unless asked off): the benchmarks'
     * variants (both off is the estimate before 2026-12-06, later). Takes effect from the
     * next estimate, with a new pool. */
    phoneEstimateParts: ({ shadeTopUp = false, bounceOnTilt = true } = {}) => {
      app.feed.phoneReader();
      app.feed.phoneEstimator.shadeTopUp = !!shadeTopUp;
      app.feed.phoneEstimator.bounceOnTilt = !!bounceOnTilt;
      app.feed.phoneEstimator.forgetPose();
    },
    /** Mean milliseconds of n phone estimates (the pose held: the pose's registration, pixels
     * and the fit), of n without the registration, and of one with the pool of the pose made
     * again; and of n picture meter readings, the same-run baseline (both read the video into
     * their copy). */
    timePhoneEstimate(n = 5) {
      const now = performance.now() / 1000;
      app.feed.estimate(now, true);
      const time = (f) => {
        const t0 = performance.now();
        for (let i = 0; i < n; i++) f();
        return (performance.now() - t0) / n;
      };
      const estimateMs = time(() => app.feed.phoneLight.read(app.camera, app.feed.sunNow(), now, true));
      const registering = app.feed.phoneEstimator.registerPose;
      app.feed.phoneEstimator.registerPose = false; // the pose registration's share (poseregister.js)
      const unregisteredMs = time(() => app.feed.phoneLight.read(app.camera, app.feed.sunNow(), now, true));
      app.feed.phoneEstimator.registerPose = registering;
      const t0 = performance.now();
      app.feed.phoneEstimator.forgetPose();
      app.feed.phoneLight.read(app.camera, app.feed.sunNow(), now, true);
      const newPoseMs = performance.now() - t0;
      const meterMs = time(() => app.view.meter.read(app.camera, now, true));
      return { estimateMs, unregisteredMs, newPoseMs, meterMs, pool: app.feed.phoneEstimator.pool.length };
    },
    /** The camera mode's last device orientation read ({alpha, beta, gamma} degrees; null
     * before the first event or outside the camera mode). */
    cameraOrientation: () => {
      const o = app.view?.orientation;
      return o ? { alpha: o.alpha, beta: o.beta, gamma: o.gamma } : null;
    },
    /** Draw in linear HDR (true, where supported; `samples`: its MSAA) or straight to the screen
     * (the fallback). */
    setLinearFrame: (on, samples = null) => {
      app.linearFrame = on;
      if (samples !== null && samples !== app.hdrSamples) {
        app.hdrSamples = samples;
        app.hdr?.dispose();
        app.hdr = null;
      }
    },
    /** The automatic exposure at once at its target for the applied light (no adaptation). */
    settleExposure: () => {
      app._exposureSet = false;
      app._updateExposure(0);
      return app.exposure;
    },
    /** The visit's camera: its distance to the orbit's target, metres (null outside the visit). */
    orbitDistanceM: () => (app.view?.controls ? app.camera.position.distanceTo(app.view.controls.target) : null),
    /**
     * Place the visit's camera by its world matrix (16 numbers, column-major, as three.js and
     * WebXR write it) and vertical field of view (degrees): the pose an AR test computed.
     */
    setCameraMatrix(matrixWorld, fovDeg) {
      app.view?.dispose?.();
      app.view = null;
      new THREE.Matrix4().fromArray(matrixWorld).decompose(app.camera.position, app.camera.quaternion, app.camera.scale);
      app.camera.fov = fovDeg;
      app.camera.updateProjectionMatrix();
      app.camera.updateMatrixWorld();
    },
    /**
     * The AR session as drawn: XR frames seen, the reticle (shown, world position, metres), the
     * site's world matrix, and the first view's camera (world matrix and projection; the
     * emulated device draws its left eye), all column-major 16-arrays in the session's
     * local-floor space; whether the XR layer and the canvas are antialiased.
     */
    xrState() {
      const view = app.view;
      if (!view?.session) return null;
      const eye = app.renderer.xr.getCamera().cameras[0];
      app.site.root.updateMatrixWorld();
      return {
        frames: view.frames,
        reticleVisible: view.reticle.visible,
        reticle: new THREE.Vector3().setFromMatrixPosition(view.reticle.matrix).toArray(),
        site: app.site.root.matrixWorld.toArray(),
        alignment: view.alignment,
        cameraAccess: view.meter.available, // the passthrough's picture metered (xrmeter.js)
        meterReads: view.meter.reads,
        // The XR layer's MSAA (an XRWebGLLayer's own; xr.js rendererWithXrAntialias) and the
        // canvas's, which the visit's linear frame leaves off.
        layerAntialias: app.renderer.xr.getBaseLayer()?.antialias ?? null,
        canvasAntialias: app.renderer.getContext().getContextAttributes().antialias,
        eye: eye ? { matrixWorld: eye.matrixWorld.toArray(), projection: eye.projectionMatrix.toArray() } : null,
      };
    },
    /** The visit's orbit: the camera's world position and the orbit's target (metres), and
     * whether it still turns by itself; null outside the visit. */
    orbit() {
      const controls = app.view?.controls;
      if (!controls) return null;
      return { position: app.camera.position.toArray(), target: controls.target.toArray(),
        autoRotate: controls.autoRotate };
    },
    setCamera(position, target) {
      app.view?.dispose?.();
      app.view = null;
      app.camera.position.set(...position);
      app.camera.lookAt(...target);
      app.camera.updateMatrixWorld();
    },
    /** Mean CPU+GPU milliseconds per frame over n frames drawn back to back (glFinish-like). */
    timeFrames(n = 30) {
      const gl = app.renderer.getContext();
      const px = new Uint8Array(4);
      app.renderFrame();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      const t0 = performance.now();
      for (let i = 0; i < n; i++) {
        app.renderFrame();
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      }
      return (performance.now() - t0) / n;
    },
    /** Milliseconds of one relight pass with the current vector, the GPU wait cancelled as
     * in timeRelightStack. */
    timeRelight(n = 5) {
      const applied = app.relighter.applied;
      const passes = (count) => {
        const t0 = performance.now();
        for (let i = 0; i < count; i++) app.relighter._render(applied);
        app.relighter.finish();
        return performance.now() - t0;
      };
      passes(1);
      const one = passes(1);
      return Math.max(0, (passes(n + 1) - one) / n);
    },
    /**
     * Milliseconds of one stack's relight pass, with its k and size: the time of n + 1 passes
     * and one read minus that of 1 pass and one read, over n, so that the cost of waiting for
     * the GPU (tens of ms on SwiftShader, whatever the work) cancels.
     */
    timeRelightStack(key, n = 5) {
      const stack = app.relighter.stacks.get(key);
      const { r, perStack } = app.relighter.applied;
      const selected = perStack.get(key);
      const gl = app.renderer.getContext();
      const px = new Float32Array(4);
      const passes = (count) => {
        const t0 = performance.now();
        for (let i = 0; i < count; i++) stack.render(app.renderer, r, selected);
        app.renderer.setRenderTarget(stack.target);
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, px);
        app.renderer.setRenderTarget(null);
        return performance.now() - t0;
      };
      passes(1);
      const one = passes(1);
      const many = passes(n + 1);
      return { ms: Math.max(0, (many - one) / n), syncMs: one, k: stack.k,
        layers: stack.compact.layers.length, slots: stack.slots, texels: stack.width * stack.height };
    },
    /** The stacks being relit (deferred ones count once activated). */
    stacks: () => app.relighter.active().map((s) => s.key),
    /** Load and relight the deferred stacks (the hull planes) without changing the view. */
    activateAll: () => app.relighter.activate().then(() => null),
    /**
     * The benchmark's baseline: the same meshes drawn the ordinary three.js way
     * (MeshStandardMaterial, a DirectionalLight with a 2048^2 shadow map, a HemisphereLight),
     * no shadowing planes; false puts daylit's materials back.
     */
    useStandardMaterials(on) {
      const site = app.site;
      if (on && !app._standard) {
        const saved = new Map();
        site.root.traverse((o) => {
          if (!o.isMesh) return;
          saved.set(o, { material: o.material, visible: o.visible, cast: o.castShadow, receive: o.receiveShadow });
          const role = o.userData.daylit?.role;
          if (role === 'shadowing-plane' || !o.userData.daylit) { o.visible = false; return; }
          const a = o.userData.albedo;
          o.material = new THREE.MeshStandardMaterial({ color: new THREE.Color(a.x, a.y, a.z), roughness: 0.9, metalness: 0 });
          o.visible = true;
          o.castShadow = role !== 'ground';
          o.receiveShadow = true;
        });
        const sun = new THREE.DirectionalLight(0xffffff, 3);
        sun.position.set(-40, 30, 40);
        sun.castShadow = true;
        sun.shadow.mapSize.set(2048, 2048);
        Object.assign(sun.shadow.camera, { left: -60, right: 60, top: 60, bottom: -60, near: 1, far: 200 });
        const hemi = new THREE.HemisphereLight(0xbfd4ff, 0x6b6050, 1);
        app.scene.add(sun, hemi);
        app.renderer.shadowMap.enabled = true;
        app.renderer.shadowMap.type = THREE.PCFSoftShadowMap;
        app._standard = { saved, lights: [sun, hemi] };
      } else if (!on && app._standard) {
        for (const [o, s] of app._standard.saved) {
          if (o.material !== s.material) o.material.dispose();
          Object.assign(o, { material: s.material, visible: s.visible, castShadow: s.cast, receiveShadow: s.receive });
        }
        for (const l of app._standard.lights) { app.scene.remove(l); l.dispose?.(); }
        app.renderer.shadowMap.enabled = false;
        app._standard = null;
      }
    },
    loseContext() {
      const ext = app.renderer.getContext().getExtension('WEBGL_lose_context');
      ext.loseContext();
      setTimeout(() => ext.restoreContext(), 200);
    },
  });
}
