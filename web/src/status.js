// window.daylit.status: a small read-only view of the client's state for tests and kiosk
// monitoring. Every field is a getter over the live state; assignments are refused.

export function makeStatus(source) {
  const fields = {
    connected: () => source.stream?.state === 'open',
    connection: () => source.stream?.state ?? 'closed',
    stale: () => source.feed.isStale(),
    lightSeq: () => source.relighter?.applied?.sequence ?? null,
    lightAgeMs: () => source.feed.ageMs(),
    lightsExact: () => source.relighter?.applied?.exact ?? false,
    relights: () => source.relighter?.relights ?? 0,
    fps: () => Math.round(source.fps * 10) / 10,
    frameMs: () => Math.round(source.frameMs * 100) / 100,
    mode: () => source.mode,
    shading: () => source.shadingOn,
    shadingMode: () => source.site?.shadingMode ?? null,
    smoothingS: () => source.smoothingS,
    error: () => source.error,
    ready: () => source.ready,
    bytesLoaded: () => source.assets?.bytesLoaded ?? 0,
    // The bytes loaded when the site was first shown and the loading note went (null before);
    // a coarse start and the sun's bounce images load more after it.
    readyBytes: () => source.readyBytes ?? null,
    firstRelitMs: () => source.firstRelitMs,
    exactRelitMs: () => source.exactRelitMs,
    firstRelitBytes: () => source.firstRelitBytes,
    // GPU memory the client allocated (gpumemory.js), bytes: textures and render targets'
    // textures, renderbuffers (depth, multisampled colour), the canvas's drawing buffer.
    gpuTextureBytes: () => source.gpuMemory?.textureBytes ?? 0,
    gpuRenderbufferBytes: () => source.gpuMemory?.renderbufferBytes ?? 0,
    gpuDrawingBufferBytes: () => source.gpuMemory?.drawingBufferBytes() ?? 0,
    coarse: () => source.relighter?.coarse ?? false,
    // The start taken (startmode.js): 'coarse' or 'full', the manifest's measured transfer
    // rate (bytes/s, null if not measured) and the estimated full first download (s).
    startMode: () => source.startChoice?.mode ?? null,
    startAsked: () => source.startChoice?.asked ?? null,
    startRateBytesPerS: () => source.startChoice?.bytesPerS ?? null,
    startFullFirstS: () => source.startChoice?.fullFirstS ?? null,
    startReason: () => source.startChoice?.reason ?? null,
    siteCameraFrames: () => source.kiosk?.framesShown ?? 0,
    occlusionMasks: () => source.stream?.messages.occlusion ?? 0,
    contextLost: () => source.contextLost,
    reconnects: () => source.stream?.reconnects ?? 0,
    integrity: () => source.assets?.verification ?? null,
    // How ETC1S files reach the GPU: 'etc2' (lossless, half a byte a texel), 'rgba8' or 'gpu'.
    etc1sTextures: () => source.assets?.etc1sFormat ?? null,
    // How UASTC files reach the GPU: 'rgba8' (exact), 'astc' (ASTC 4x4 blocks) or 'gpu'.
    uastcTextures: () => source.assets?.uastcFormat ?? null,
    profile: () => source.profile, // 'phone' or 'desktop' (docs/web.md, "GPU memory")
    refetched: () => [...(source.assets?.refetched ?? [])],
    siteCameraDenied: () => source.stream?.siteCameraDenied ?? false,
    // The kiosk's sun bounce: 'drawn' (the view's images of the sun's patch are in O' and S'),
    // 'none' (no sun, or its patch has none), 'absent: ...' (a build before 2026-11-25).
    kioskSunBounce: () => source.kiosk?.sunBounceNote ?? null,
    // The sky patch whose sun bounce is drawn (-1: no sun, or none; null: not drawn yet).
    sunBouncePatch: () => source.sunBounce?.patch ?? null,
    // The exposure and what set it: 'fixed' (?exposure=), 'scene' (the lightness key),
    // 'picture' (camera mode: the camera picture's ground, picturemeter.js), 'camera' (AR, or
    // no ground in the picture: the ground at middle grey); the picture's ground level.
    exposure: () => source.exposure,
    exposureMeter: () => (source.fixedExposure !== null ? 'fixed' : source.exposureMeter),
    pictureGroundLevel: () => source.pictureReading?.level ?? null,
    // Where the drawn light comes from: 'server' (its sky), 'phone' (camera mode's own estimate
    // from the picture, phoneestimate.js: no server sky, or ?sky=phone), 'kept' (no live light:
    // the last one this phone kept, offline.js), null (none yet); the
    // last estimate ({ratio, skyType, sunNormal, skyHorizontal (the picture's units), used,
    // sunlit, inlierFraction, pool}), how many were made and the last one's milliseconds.
    lightSource: () => { const l = source.feed.light; return l ? (l.phone ? 'phone' : l.kept ? 'kept' : 'server') : null; },
    phoneEstimate: () => source.feed.phoneEstimate,
    // Camera mode under a server sky: the last registration of the pose alone ({shiftPx,
    // turnDeg, fisher}; the view follows it), null before one.
    phoneRegistration: () => source.feed.registration,
    // The offline visit (offline.js): the service worker ('registered', or why not: 'insecure',
    // 'test', 'unsupported', 'failed: ...'; 'none' before it is asked) and its answer to
    // keeping this visit's files ({kept, failed}; null until it answered).
    offlineWorker: () => source.offlineWorker,
    offlineKept: () => source.offlineKept,
    phoneEstimates: () => source.feed.phoneLight?.estimates ?? 0,
    phoneEstimateMs: () => source.feed.phoneLight?.ms ?? null,
  };
  const status = {};
  for (const [name, get] of Object.entries(fields)) {
    Object.defineProperty(status, name, { get, enumerable: true });
  }
  return Object.freeze(status);
}
