// Which start a visit takes (docs/web.md, "Slow links"): the coarse start (the first base
// layers of each stack, bake/coarse.py) only where the link is slow, the full arrays at once
// where it is fast (the coarse files would then be an extra download and a coarse flash).
//
// `?start=coarse` and `?start=full` force it; `?start=auto` (the default) measures the rate at
// which the manifest's body arrived (Resource Timing: its bytes on the wire over responseStart
// to responseEnd, so neither the server's time nor the round trip counts) and takes the coarse
// start when the full first download would take more than COARSE_ABOVE_S at that rate.

export const COARSE_ABOVE_S = 3;
// A body that arrived in one piece (a fast link, or a tiny manifest) has no measurable time:
// at least this long, so that the rate stays finite (bytes per millisecond, bytes/ms).
const MIN_BODY_MS = 1;

/**
 * The manifest's transfer as Resource Timing saw it: {bytes, ms, bytesPerS}, or null when
 * it was not measured or came from the HTTP cache (no bytes on the wire for its body).
 * Its entry may be added a moment after the body was read: looked for a few times.
 * @param {string} url the manifest's URL (relative to the page or absolute)
 */
export async function measuredRate(url) {
  const href = new URL(url, location.href).href;
  let entry = null;
  for (let tries = 0; !entry && tries < 5; tries += 1) {
    if (tries) await new Promise((resolve) => setTimeout(resolve, 20));
    entry = performance.getEntriesByName(href, 'resource').at(-1) ?? null;
  }
  // From the cache (transferSize 0) or revalidated (304: headers only): no rate to tell.
  if (!entry || !entry.encodedBodySize || entry.transferSize < entry.encodedBodySize) return null;
  const bytes = entry.encodedBodySize;
  const ms = Math.max(entry.responseEnd - entry.responseStart, MIN_BODY_MS);
  return { bytes, ms, bytesPerS: (bytes / ms) * 1000 };
}

/** The bytes each start downloads before its first picture, from the manifest's file list:
 * {full, coarse} (coarse null if some stack has no coarse start). The model counts in both.
 * @param {object} manifest
 * @param {object[]} compacts the `compact` entries of the stacks loaded at once */
export function firstBytes(manifest, compacts) {
  const size = new Map(manifest.files.map((f) => [f.path, f.bytes]));
  const sum = (paths) => [...new Set(paths)].reduce((s, p) => s + (size.get(p) ?? 0), 0);
  const model = [manifest.model.path];
  const gains = compacts.filter((c) => c.gain).map((c) => c.gain.ktx2);
  const full = sum([...model, ...gains, ...compacts.flatMap((c) => [c.ktx2, c.v.path, ...(c.etc1s ? [c.etc1s.ktx2] : [])])]);
  const haveCoarse = compacts.length > 0 && compacts.every((c) => c.coarse);
  const coarse = haveCoarse ? sum([...model, ...gains, ...compacts.flatMap((c) => [c.coarse.ktx2, c.coarse.v.path])]) : null;
  return { full, coarse };
}

/**
 * The start to take: {mode: 'coarse' | 'full', asked, bytesPerS, fullFirstS, reason}.
 * @param {string|null} asked `?start=`: 'auto' (or null), 'coarse' or 'full'
 * @param {{full: number, coarse: number|null}} bytes from firstBytes
 * @param {{bytesPerS: number}|null} rate from measuredRate
 */
export function chooseStart(asked, bytes, rate) {
  asked = asked ?? 'auto';
  const bytesPerS = rate ? Math.round(rate.bytesPerS) : null;
  const fullFirstS = rate ? bytes.full / rate.bytesPerS : null;
  const result = (mode, reason) => ({ mode, asked, bytesPerS, fullFirstS, reason });
  if (bytes.coarse === null) return result('full', 'the build has no coarse start');
  if (asked === 'full' || asked === 'coarse') return result(asked, `?start=${asked}`);
  if (asked !== 'auto') {
    console.warn(`?start=${asked}: expected auto, coarse or full; taking auto`);
    asked = 'auto';
  }
  if (!rate) return result('full', 'the manifest came from the cache: no rate measured');
  return fullFirstS > COARSE_ABOVE_S
    ? result('coarse', `the full first download would take ${fullFirstS.toFixed(1)} s`)
    : result('full', `the full first download would take ${fullFirstS.toFixed(1)} s`);
}
