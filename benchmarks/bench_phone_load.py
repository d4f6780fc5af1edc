"""Time and bytes to a phone's first relit frame on a slow link (issue 17): the real
``daylit serve``, a fresh browser cache, headless Chromium with the network throttled through
CDP (``Network.emulateNetworkConditions``: 1.6 Mbit/s down, 300 ms latency), against the same
page on loopback in the same run (the baseline).

For every request until the first relit frame: when it was sent and finished (seconds after
navigation), its bytes on the wire (``encodedDataLength``: headers and the body as sent,
compressed or not); the client's own figures (``status.firstRelitMs``, ``bytesLoaded``).

    .venv/bin/python benchmarks/bench_phone_load.py BUILD [BUILD ...] [--size 390x780]

The time a software GPU (SwiftShader) takes to transcode and relight is in the loopback
figure; the link's share is the difference.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.web.harness import CHROMIUM_FLAGS, DaylitServer, chromium_path  # noqa: E402

SLOW_LINK = {"offline": False, "latency": 300, "downloadThroughput": 1.6e6 / 8,
             "uploadThroughput": 0.75e6 / 8}


def replay_dir() -> Path:
    from tests.web.test_web_e2e import fisheye

    d = Path(tempfile.mkdtemp(prefix="daylit-bench-sky-"))
    cv2.imwrite(str(d / "a.png"), fisheye(sky_code=110, sun=(235, 22)))
    return d


def first_relit(browser, url: str, size, throttle: bool, query: str = "") -> dict:
    """One fresh page (its own context: an empty cache) until its first relit frame. Service
    workers blocked: the offline visit's worker (web/sw.js) takes the page's requests once it
    claims it, and its own fetches are neither throttled nor seen by the page's CDP session
    (runs before 2026-12-04 read 0 bytes on the wire for the build's files and no link for
    them); on a first visit a phone's worker fetches over the same slow link."""
    ctx = browser.new_context(viewport={"width": size[0], "height": size[1]},
                              device_scale_factor=2, is_mobile=True, has_touch=True,
                              service_workers="block")
    page = ctx.new_page()
    cdp = ctx.new_cdp_session(page)
    cdp.send("Network.enable")
    cdp.send("Network.setCacheDisabled", {"cacheDisabled": False})
    if throttle:
        cdp.send("Network.emulateNetworkConditions", SLOW_LINK)
    requests: dict[str, dict] = {}
    t0 = {}

    def sent(e):
        t0.setdefault("t", e["timestamp"])
        requests[e["requestId"]] = {"url": e["request"]["url"], "sent": e["timestamp"]}

    def received(e):
        r = requests.get(e["requestId"])
        if r is not None:
            r["status"] = e["response"]["status"]
            r["encoding"] = e["response"]["headers"].get("Content-Encoding", "")

    def finished(e):
        r = requests.get(e["requestId"])
        if r is not None:
            r["done"] = e["timestamp"]
            r["wire"] = e["encodedDataLength"]

    cdp.on("Network.requestWillBeSent", sent)
    cdp.on("Network.responseReceived", received)
    cdp.on("Network.loadingFinished", finished)
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type in ("error", "warning") else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{url}/?mode=visit&exposure=0.02{query}")
    page.wait_for_function("window.daylit.status.firstRelitMs !== null", timeout=300000)
    status = page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")
    page.wait_for_function("window.daylit.status.exactRelitMs !== null", timeout=600000)
    exact = page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")
    nav_ms = page.evaluate("performance.timeOrigin")
    ctx.close()
    start = t0["t"]
    relit_s = status["firstRelitMs"] / 1000
    rows = sorted(({**r, "sent": r["sent"] - start, "done": r.get("done", float("nan")) - start}
                   for r in requests.values()), key=lambda r: r["sent"])
    before = [r for r in rows if r["sent"] < relit_s and not r["url"].startswith("ws")]
    return {"first_relit_s": relit_s, "exact_s": exact["exactRelitMs"] / 1000,
            "coarse": status["coarse"], "bytes_loaded": status["bytesLoaded"],
            "bytes_exact": exact["bytesLoaded"], "status": status, "errors": errors,
            "wire_before": sum(r.get("wire", 0) for r in before),
            "requests_before": len(before), "rows": rows, "nav_ms": nav_ms}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("builds", nargs="+", type=Path)
    parser.add_argument("--size", default="390x780")
    parser.add_argument("--query", default="", help="more URL parameters, e.g. &profile=phone")
    parser.add_argument("--rows", action="store_true", help="print every request")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    sky_dir = replay_dir()
    from playwright.sync_api import sync_playwright

    results = {}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        try:
            for build in args.builds:
                with DaylitServer(build, "--sky", f"replay:{sky_dir}") as server:
                    for throttle in (False, True):
                        res = first_relit(browser, server.url, size, throttle, args.query)
                        results[f"{build} {'1.6 Mbit/s' if throttle else 'loopback'}"] = res
        finally:
            browser.close()
    for name, res in results.items():
        print(f"{name}: first relit {res['first_relit_s']:.2f} s"
              f"{' (coarse)' if res['coarse'] else ''}, exact {res['exact_s']:.2f} s "
              f"({res['bytes_exact'] / 1e6:.2f} MB counted); "
              f"{res['requests_before']} requests, {res['wire_before'] / 1e6:.2f} MB on the wire "
              f"before it; client counted {res['bytes_loaded'] / 1e6:.2f} MB; "
              f"start {res['status'].get('startMode')} ({res['status'].get('startAsked')}, "
              f"manifest at {(res['status'].get('startRateBytesPerS') or 0) / 1e3:.0f} kB/s, "
              f"full first download est. {res['status'].get('startFullFirstS') or 0:.2f} s)")
        if res["errors"]:
            print("   console:", res["errors"][:5])
        if args.rows:
            for r in res["rows"]:
                path = r["url"].split("//", 1)[-1].split("/", 1)[-1][:90]
                print(f"   {r['sent']:7.2f} {r['done']:7.2f} {r.get('wire', 0) / 1e3:8.1f} kB "
                      f"{r.get('encoding', ''):4s} {path}")
    out = REPO / "bench-results"
    out.mkdir(exist_ok=True)
    (out / "phone-load.json").write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
