"""The JavaScript decoders (web/src/protocol.js) read the same test vectors as Python: the
light-stream messages of every version, the occlusion masks (docs/occlusion.md) and the
stored hello; and the client (web/src/lightstream.js) asks for version 3, falls back to 2
for a server of before version 3, and subscribes to the occlusion stream by its one name.
Node is required: without it these tests fail (tests/web/harness.py node_path)."""

import json
import subprocess
from pathlib import Path

import pytest

from server import protocol
from tests.web.harness import node_path

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "protocol_vectors"
PROTOCOL_JS = (ROOT / "web" / "src" / "protocol.js").as_uri()
LIGHTSTREAM_JS = (ROOT / "web" / "src" / "lightstream.js").as_uri()


def run_module(script: str) -> dict:
    """Run an ES module given as text with Node; its stdout is JSON."""
    script = script.replace("PROTOCOL_JS", PROTOCOL_JS).replace("LIGHTSTREAM_JS", LIGHTSTREAM_JS)
    result = subprocess.run([node_path(), "--input-type=module", "-e", script],
                            capture_output=True, text=True, timeout=60, check=True)
    return json.loads(result.stdout)


@pytest.mark.parametrize("script,vectors,expected_suffix,at_least", [
    ("decode_vectors.mjs", "*.bin", ".json", 14),
    ("decode_masks.mjs", "occlusion_rle_*.bin", ".mask.json", 10),
], ids=["messages", "occlusion-masks"])
def test_javascript_decoder_matches_the_vectors(script, vectors, expected_suffix, at_least):
    result = subprocess.run(
        [node_path(), str(ROOT / "tests" / "web" / script), str(VECTORS)],
        capture_output=True, text=True, timeout=60, check=True,
    )
    decoded = json.loads(result.stdout)
    names = sorted(p.stem for p in VECTORS.glob(vectors))
    assert sorted(decoded) == names and len(names) >= at_least
    # Every version is among them, the compact encoding too.
    versions = {json.loads((VECTORS / f"{n}.json").read_text()).get("version") for n in names}
    assert expected_suffix != ".json" or versions >= {1, 2, 3}
    for name in names:
        expected = json.loads((VECTORS / f"{name}{expected_suffix}").read_text())
        got = decoded[name]
        if "error" in expected:
            assert "error" in got, name
            assert expected["error"] in got["error"], (name, got["error"])
        else:
            assert got == expected, name


def test_javascript_client_asks_for_version_3_and_accepts_every_hello():
    out = run_module("""
    import { lightStreamUrl, parseHello, PROTOCOL_VERSION, FALLBACK_VERSION, Flags }
      from 'PROTOCOL_JS';
    const loc = { protocol: 'https:', host: 'site.example:8443' };
    const out = { version: PROTOCOL_VERSION, fallback: FALLBACK_VERSION,
      sunFlag: Flags.SUN_ESTIMATED, url: lightStreamUrl(loc, ['light', 'site-camera']),
      bare: lightStreamUrl(loc, []), two: lightStreamUrl(loc, ['light'], 2) };
    for (const p of [1, 2, 3, 4]) {
      try { out['hello' + p] = parseHello(JSON.stringify({ type: 'hello', protocol: p,
        lights: 4 })).protocol; } catch (err) { out['hello' + p] = err.message; }
    }
    process.stdout.write(JSON.stringify(out));
    """)
    assert out["version"] == protocol.PROTOCOL_VERSION == 3 and out["fallback"] == 2
    assert out["sunFlag"] == 32
    assert out["url"] == "wss://site.example:8443/ws/light?protocol=3&streams=light,site-camera"
    assert out["bare"] == "wss://site.example:8443/ws/light?protocol=3"
    assert out["two"] == "wss://site.example:8443/ws/light?protocol=2&streams=light"
    assert [out[f"hello{p}"] for p in (1, 2, 3)] == [1, 2, 3] and "protocol 4" in out["hello4"]


def test_the_kiosk_client_reads_the_stored_hello_and_subscribes_by_the_servers_name():
    """The hand-written hello (also checked against the server's, test_hello_vector.py) through
    the shipped LightStream with a stand-in WebSocket: what it sends back must be a subscribe
    the server accepts, with the occlusion stream."""
    hello = (VECTORS / "hello_kiosk_v3.json").read_text()
    out = run_module("""
    import { LightStream } from 'LIGHTSTREAM_JS';
    const sent = [];
    globalThis.WebSocket = class { static OPEN = 1; constructor(url) { this.url = url;
      this.readyState = 1; } send(m) { sent.push(m); } close() {} };
    let seen = null;
    const s = new LightStream({ siteCamera: true, onHello: (h) => { seen = h; },
      location: { protocol: 'http:', host: 'kiosk.local:8000' } });
    s._connect();
    s.ws.onmessage({ data: HELLO });
    s.stop();
    process.stdout.write(JSON.stringify({ url: s.url, sent, state: s.state,
      protocol: seen.protocol, encoding: seen.sky_encoding, streams: seen.available_streams }));
    """.replace("HELLO", json.dumps(hello)))
    assert out["url"] == "ws://kiosk.local:8000/ws/light?protocol=3&streams=light,site-camera"
    assert out["protocol"] == 3 and out["encoding"] == "float16"
    assert out["streams"] == ["light", "site-camera", "occlusion"]
    subscribes = [json.loads(m) for m in out["sent"] if json.loads(m)["type"] == "subscribe"]
    assert len(subscribes) == 1
    request = protocol.parse_client_message(json.dumps(subscribes[0]))  # the server's check
    assert sorted(request.streams) == ["light", "occlusion", "site-camera"]


def test_the_client_alternates_3_and_2_until_a_server_says_hello():
    """A server of before version 3 answers ?protocol=3 with HTTP 400, which a browser sees as
    a socket closed before the hello: the next attempt asks for 2, the one after for 3 again
    (a server that was only down), and a hello keeps the version that got it."""
    out = run_module("""
    import { LightStream } from 'LIGHTSTREAM_JS';
    globalThis.setTimeout = (f) => { queueMicrotask(f); return 0; }; // no backoff wait
    const urls = [];
    let answerTo = null; // the protocol that gets a hello (an older server: 2)
    globalThis.WebSocket = class { static OPEN = 1;
      constructor(url) { this.url = url; this.readyState = 1; urls.push(url);
        const asked = Number(new URL(url).searchParams.get('protocol'));
        queueMicrotask(() => {
          if (asked === answerTo) {
            this.onmessage({ data: JSON.stringify({ type: 'hello', protocol: asked, lights: 4 }) });
          } else { this.onclose(); }
        });
      }
      send() {} close() {} };
    const loc = { protocol: 'http:', host: 'old.example' };
    const s = new LightStream({ location: loc });
    s.start();
    await new Promise((r) => queueMicrotask(r));
    for (let i = 0; i < 20 && urls.length < 4; i++) await new Promise((r) => queueMicrotask(r));
    answerTo = 2; // from now on the stand-in says hello to version 2 (an older server)
    for (let i = 0; i < 50 && s.state !== 'open'; i++) await new Promise((r) => queueMicrotask(r));
    const opened = { state: s.state, version: s.hello && s.hello.protocol, asked: s.version };
    s.ws.onclose(); // a drop after the hello: reconnect asking the same version
    for (let i = 0; i < 20; i++) await new Promise((r) => queueMicrotask(r));
    s.stop();
    process.stdout.write(JSON.stringify({ urls: urls.map((u) => new URL(u).searchParams
      .get('protocol')), opened }));
    """)
    asked = out["urls"]
    # Four attempts closed before a hello (the fourth answered once the stand-in says hello to
    # version 2), then the reconnect after the drop.
    assert asked == ["3", "2", "3", "2", "2"], asked
    assert out["opened"] == {"state": "open", "version": 2, "asked": 2}
