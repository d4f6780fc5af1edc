// The offline visit (docs/web.md, "Offline"): the service worker (web/sw.js) that keeps what a
// visit loaded, and the last live light kept on the phone for a visit that opens without the
// server.

/** How often a live light is written to the phone's storage (ms): the sky changes slowly,
 * and a write per vector (2 a second) would wear the storage for nothing. */
const KEEP_LIGHT_EVERY_MS = 60000;

/**
 * Register the service worker: in a secure context (a phone gives it nowhere else), not on a
 * test page unless `?sw` asks (the other tests' network conditions must reach the page's own
 * requests). Resolves to 'registered', or why not ('insecure', 'test', 'unsupported',
 * 'failed: ...').
 * @param {URLSearchParams} params
 */
export async function registerOffline(params) {
  if (!('serviceWorker' in navigator)) return 'unsupported';
  if (!isSecureContext) return 'insecure';
  if (params.has('test') && !params.has('sw')) return 'test';
  try {
    await navigator.serviceWorker.register('/sw.js');
    return 'registered';
  } catch (err) {
    return `failed: ${err.message}`;
  }
}

/**
 * Ask the service worker to keep every file this page has loaded (the ones fetched before it
 * took over included). Resolves to its answer { kept, failed } (files in its cache, files it
 * could not fetch), or null without a worker.
 */
export async function keepForOffline() {
  if (!(await navigator.serviceWorker?.getRegistration())) return null;
  const worker = (await navigator.serviceWorker.ready).active;
  const urls = [location.href, ...performance.getEntriesByType('resource').map((e) => e.name)];
  const channel = new MessageChannel();
  const answer = new Promise((resolve) => { channel.port1.onmessage = (e) => resolve(e.data); });
  worker.postMessage({ type: 'keep', page: location.href, urls }, [channel.port2]);
  return answer;
}

/**
 * The last live light of a site, kept in the phone's storage: shown, with its time, when a
 * visit opens and no live light comes (offline, or the server's sky is down).
 */
export class KeptLight {
  /** @param {string} sceneId the build's scene id (a phone may visit more than one site) */
  constructor(sceneId) {
    this.key = `daylit.light.${sceneId}`;
    this._savedMs = -Infinity;
  }

  /** Keep a server's light message ({rgb (n*3), sun, captureTime s}) at most once a minute. */
  save(m, nowMs = Date.now()) {
    if (nowMs - this._savedMs < KEEP_LIGHT_EVERY_MS) return;
    this._savedMs = nowMs;
    const sun = m.sun ? { direction: [...m.sun.direction], normalIrradiance: [...m.sun.normalIrradiance] } : null;
    try {
      localStorage.setItem(this.key, JSON.stringify({ rgb: [...m.rgb], sun, captureTime: m.captureTime }));
    } catch {
      // storage full or refused (a private window): the visit goes on without it
    }
  }

  /** The kept light ({rgb Float32Array, sun, captureTime s}), or null. */
  load() {
    try {
      const kept = JSON.parse(localStorage.getItem(this.key));
      if (!Array.isArray(kept?.rgb) || !Number.isFinite(kept.captureTime)) return null;
      return { rgb: Float32Array.from(kept.rgb), sun: kept.sun ?? null, captureTime: kept.captureTime };
    } catch {
      return null;
    }
  }
}
