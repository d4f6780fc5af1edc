// The offline visit's service worker (docs/web.md, "Offline"): what a visit loaded stays on
// the phone, so the page, three.js and the build open again without the server (a visitor who
// loaded the site on the entrance's Wi-Fi and walks out of its reach, a site without cameras).
// Network first for every file: online nothing changes (the server's cache headers and the
// client's SHA-256 checks decide as before); only when the network fails is the kept copy
// answered. The light stream (/ws/) and the operators' /api/ are never kept.

const CACHE = 'daylit-offline-1';

self.addEventListener('install', () => self.skipWaiting());
self.addEventListener('activate', (event) => event.waitUntil(self.clients.claim()));

/** Whether a request is one this worker keeps and answers. */
function kept(url, method) {
  if (method !== 'GET' || url.origin !== self.location.origin) return false;
  return !url.pathname.startsWith('/ws/') && !url.pathname.startsWith('/api/');
}

/** The cache's key of `url` (a URL): a page (`navigate`) under its path alone
 * (`/?mode=camera` opens offline as `/` was kept); every other file under its whole URL (a
 * build file's `?v=` is its version). */
function keyOf(url, navigate) {
  return navigate ? url.origin + url.pathname : url.href;
}

/** Keep `response` for `key`, dropping the other versions (`?v=`) of the same path. */
async function store(cache, key, response) {
  const url = new URL(key);
  if (url.searchParams.has('v')) {
    for (const old of await cache.keys()) {
      const o = new URL(old.url);
      if (o.pathname === url.pathname && o.href !== url.href) await cache.delete(old);
    }
  }
  await cache.put(key, response);
}

async function networkFirst(event) {
  const { request } = event;
  const key = keyOf(new URL(request.url), request.mode === 'navigate');
  try {
    const response = await fetch(request);
    // Whole answers only (a 206 range or an error page is not the file).
    if (response.status === 200) {
      const copy = response.clone();
      event.waitUntil(caches.open(CACHE).then((cache) => store(cache, key, copy)));
    }
    return response;
  } catch (err) {
    const cached = await caches.match(key, { cacheName: CACHE });
    if (cached) return cached;
    throw err;
  }
}

self.addEventListener('fetch', (event) => {
  if (kept(new URL(event.request.url), event.request.method)) event.respondWith(networkFirst(event));
});

// The page, once its site is drawn, names every file it loaded before this worker took over
// (offline.js keepForOffline); they are fetched again (from the HTTP cache, mostly) and kept.
// Answers on the message's port: { kept: files now kept, failed: files that could not be }.
self.addEventListener('message', (event) => {
  if (event.data?.type !== 'keep') return;
  const port = event.ports[0];
  event.waitUntil((async () => {
    const cache = await caches.open(CACHE);
    let failed = 0;
    for (const href of event.data.urls) {
      const url = new URL(href, self.location.origin);
      if (!kept(url, 'GET')) continue;
      try {
        const response = await fetch(url.href);
        if (response.status !== 200) throw new Error(String(response.status));
        await store(cache, keyOf(url, url.href === event.data.page), response);
      } catch {
        failed += 1;
      }
    }
    port?.postMessage({ kept: (await cache.keys()).length, failed });
  })());
});
